"""Least-squares shapes for checking scans (VDI/VDE 2634-2 style): spheres and planes fitted to points,
and the range of their residuals.

Points are (N, 3) float64, WCS mm. Residuals are signed distances to the fitted shape (mm): radial for a
sphere (positive outside), along the normal for a plane.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class SphereFit:
    """centre (3,) mm, radius_mm, residuals (N,) mm."""

    centre: np.ndarray
    radius_mm: float
    residuals: np.ndarray


@dataclass
class PlaneFit:
    """centroid (3,) mm, unit normal (3,), residuals (N,) mm."""

    centroid: np.ndarray
    normal: np.ndarray
    residuals: np.ndarray


def fit_sphere(points: np.ndarray, *, iterations: int = 10) -> SphereFit:
    """Geometric least-squares sphere (minimises the sum of squared radial residuals): the algebraic fit
    starts Gauss-Newton.

    Parameters
    ----------
    points : (N, 3) float
        N >= 4 points, mm (any Cartesian frame); ValueError for fewer.
    iterations : int
        The most Gauss-Newton steps (it stops when a step is below 1e-12 mm).

    Returns
    -------
    fit : SphereFit
        ``centre`` (3,) mm in the points' frame, ``radius_mm``, ``residuals`` (N,) mm (distance from the
        centre minus the radius).
    """
    p = np.asarray(points, np.float64).reshape(-1, 3)
    if len(p) < 4:
        raise ValueError(f"a sphere needs at least 4 points, got {len(p)}")
    mean = p.mean(axis=0)
    q = p - mean
    a = np.column_stack([2 * q, np.ones(len(q))])
    sol = np.linalg.lstsq(a, (q * q).sum(axis=1), rcond=None)[0]
    c, r = sol[:3], np.sqrt(sol[3] + sol[:3] @ sol[:3])
    for _ in range(iterations):
        v = q - c
        dist = np.linalg.norm(v, axis=1)
        res = dist - r
        jac = np.column_stack([-v / dist[:, None], -np.ones(len(q))])
        step = np.linalg.lstsq(jac, -res, rcond=None)[0]
        c, r = c + step[:3], r + step[3]
        if np.abs(step).max() < 1e-12:
            break
    return SphereFit(c + mean, float(r), np.linalg.norm(q - c, axis=1) - r)


def fit_plane(points: np.ndarray) -> PlaneFit:
    """Orthogonal least-squares plane.

    Parameters
    ----------
    points : (N, 3) float
        N >= 3 points, mm; ValueError for fewer.

    Returns
    -------
    fit : PlaneFit
        ``centroid`` (3,) mm, unit ``normal`` (3,), signed ``residuals`` (N,) mm along it.
    """
    p = np.asarray(points, np.float64).reshape(-1, 3)
    if len(p) < 3:
        raise ValueError(f"a plane needs at least 3 points, got {len(p)}")
    c = p.mean(axis=0)
    n = np.linalg.svd(p - c, full_matrices=False)[2][-1]
    return PlaneFit(c, n, (p - c) @ n)


def trimmed_range(residuals: np.ndarray, *, keep: float = 0.997) -> float:
    """The form error: the range of the residuals after removing the largest (VDI/VDE 2634-2 allows
    removing up to 0.3 %).

    Parameters
    ----------
    residuals : (N,) float
        Residuals of a fit, mm (`fit_sphere`, `fit_plane`).
    keep : float
        The fraction kept: the 1 - `keep` fraction with the largest absolute values is removed; 1: the
        plain range.

    Returns
    -------
    range : float
        max - min of the kept residuals, mm.
    """
    r = np.asarray(residuals, np.float64)
    if keep < 1:
        r = r[np.abs(r) <= np.quantile(np.abs(r), keep)]
    return float(r.max() - r.min())

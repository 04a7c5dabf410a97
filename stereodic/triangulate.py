"""Triangulation of matched virtual pixels of a rectified rig: 3D points (WCS, mm) and the ray gap.

A match is (x_left, row) in the left virtual image and (x_right, row) in the right one (sub-pixel
positions; integers at virtual pixel centres). Each position gives a ray through its point on the
common plane (`VirtualSensor.points`):
- corrected=True (default): the camera's model-less ray there, i.e. the pinhole ray corrected by the
  EVM - the real ray that the rectified image shows at that position (directions interpolated
  bilinearly in the virtual grid). This is right for every lens, also for surfaces far from the plane;
- corrected=False: the pinhole ray from the camera's optical centre (what the Q matrix computes).
The point is the midpoint of the closest points of the two rays; `gap_mm` is their distance (zero for a
perfect match of a perfect rig; a quality figure). Rays that are blank or parallel give NaN.
Vectorised and chunked: millions of matches at a time in bounded memory.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stereodic.rig import Rig
from stereodic.sampling import bilinear


@dataclass
class Triangulation:
    """points: (..., 3) WCS mm, midpoints of the two rays; gap_mm: (...,) distance between the rays."""

    points: np.ndarray
    gap_mm: np.ndarray


def rays_at(rig: Rig, side: str, x: np.ndarray, row: np.ndarray, corrected: bool = True
            ) -> tuple[np.ndarray, np.ndarray]:
    """Rays of virtual positions (x, row) of camera `side`: (points on the common plane (N, 3) WCS mm,
    unit directions (N, 3)); see the module docstring for `corrected`."""
    p = rig.sensor.points(x, row)
    if corrected:
        d = bilinear(rig.camera(side).direction, x, row)
    else:
        d = p - rig.camera(side).centre
    return p, d / np.linalg.norm(d, axis=-1, keepdims=True)


def closest_points(o1: np.ndarray, d1: np.ndarray, o2: np.ndarray, d2: np.ndarray) -> Triangulation:
    """Midpoints and distances of the closest points of lines (o1, d1) and (o2, d2), (N, 3) each, d unit."""
    w = o1 - o2
    b = np.einsum("ij,ij->i", d1, d2)
    d = np.einsum("ij,ij->i", d1, w)
    e = np.einsum("ij,ij->i", d2, w)
    with np.errstate(divide="ignore", invalid="ignore"):
        den = 1.0 - b * b
        s = np.where(den > 1e-15, (b * e - d) / den, np.nan)
        t = np.where(den > 1e-15, (e - b * d) / den, np.nan)
    p1 = o1 + s[:, None] * d1
    p2 = o2 + t[:, None] * d2
    return Triangulation((p1 + p2) / 2, np.linalg.norm(p1 - p2, axis=-1))


def triangulate(rig: Rig, x_left, x_right, row, row_right=None, corrected: bool = True,
                chunk: int = 1 << 20) -> Triangulation:
    """3D points of matches (x_left, row) <-> (x_right, row_right) (arrays of one shape; row_right
    defaults to row, the rectified case). Returns points (..., 3) WCS mm and gap_mm (...)."""
    x_left, x_right, row = np.broadcast_arrays(*(np.asarray(a, np.float64) for a in (x_left, x_right, row)))
    row_right = row if row_right is None else np.broadcast_to(np.asarray(row_right, np.float64), row.shape)
    shape = row.shape
    xl, xr, rl, rr = (a.ravel() for a in (x_left, x_right, row, row_right))
    points = np.empty((xl.size, 3))
    gap = np.empty(xl.size)
    for s in range(0, xl.size, chunk):
        k = slice(s, s + chunk)
        t = closest_points(*rays_at(rig, "left", xl[k], rl[k], corrected),
                           *rays_at(rig, "right", xr[k], rr[k], corrected))
        points[k], gap[k] = t.points, t.gap_mm
    return Triangulation(points.reshape(shape + (3,)), gap.reshape(shape))

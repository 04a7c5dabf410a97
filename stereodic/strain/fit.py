"""Strain from a displacement field by local least-squares fitting (virtual strain gauge).

Around every point of a grid, the displacement of the valid points in a window of `window` x `window`
grid points is fitted by a plane (a + b s + c t) in local surface coordinates (s, t); its slopes give
the deformation gradient and the Green-Lagrange strain E = (F^T F - I) / 2.

- `strain_2d`: in-plane field on the image grid: u, v along x, y.
- `strain_3d`: surface points X (any units, e.g. mm) and 3-D displacements D: fitted on the local tangent
  plane of the surface (normal by principal components of the window's points), so that out-of-plane
  motion and the surface's tilt are handled; components in the tangent frame (e1, e2), e1 the
  projection of the x axis on the plane, e2 = n x e1, n oriented towards +z. `StrainFit` does the same
  for many displacement fields on one surface (a sequence's states on its reference shape); the fits
  run in one compiled kernel, the grid's rows in parallel (C with OpenMP: `stereodic.strain._kernels`,
  stereodic/strain/src).
Strains are dimensionless; NaN (with valid = False) where the window holds too few valid points or
the centre point is not valid.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stereodic.strain._kernels import fit_all


@dataclass
class Strain:
    """Green-Lagrange components (ny, nx) in the local frame, `valid` (ny, nx) bool; `grad` (ny, nx,
    3, 2): the displacement's derivatives along e1 and e2; `normal`, `e1` (ny, nx, 3) the frame."""

    exx: np.ndarray
    eyy: np.ndarray
    exy: np.ndarray
    valid: np.ndarray
    grad: np.ndarray
    normal: np.ndarray
    e1: np.ndarray


def strain_3d(X: np.ndarray, D: np.ndarray, *, window: int = 5, min_fraction: float = 0.6) -> Strain:
    """Surface strain of a 3-D displacement field, fitted on the local tangent plane (module docstring).

    Parameters
    ----------
    X : (ny, nx, 3) float
        The surface points on a grid, any length unit (e.g. mm); NaN where not measured.
    D : (ny, nx, 3) float
        Their displacements, the same unit and frame; NaN where not measured.
    window : int
        Grid points per side of each fit (odd, >= 3; ValueError otherwise).
    min_fraction : float
        The least fraction of valid points in a window for a fit.

    Returns
    -------
    strain : Strain
        Green-Lagrange ``exx``, ``eyy``, ``exy`` (ny, nx), dimensionless, in the tangent frame (e1 the
        projection of x on the plane, e2 = n x e1), NaN where not ``valid``; ``grad``, ``normal``, ``e1``
        (normal (0, 0, 1) and e1 (1, 0, 0) where the window holds too few points for a plane).
    """
    return StrainFit(X, window=window, min_fraction=min_fraction)(D)


class StrainFit:
    """`strain_3d` of many displacement fields on one surface (a sequence's states on its reference
    shape): calling it with D gives the Strain.

    Parameters
    ----------
    X : (ny, nx, 3) float
        The surface points on a grid, any length unit; NaN where not measured.
    window, min_fraction
        As `strain_3d`.
    """

    def __init__(self, X: np.ndarray, *, window: int = 5, min_fraction: float = 0.6):
        if window < 3 or window % 2 == 0:
            raise ValueError(f"strain window must be odd and >= 3, got {window}")
        self.X, self.window, self.min_fraction = np.ascontiguousarray(X, np.float64), window, min_fraction

    def __call__(self, D: np.ndarray) -> Strain:
        """The strain of one displacement field of the surface.

        Parameters
        ----------
        D : (ny, nx, 3) float
            The displacements of X, its unit and frame; NaN where not measured.

        Returns
        -------
        strain : Strain
            As `strain_3d(X, D)`.
        """
        X = self.X
        D = np.ascontiguousarray(D, np.float64)
        if D.shape != X.shape or X.ndim != 3 or X.shape[-1] != 3:
            raise ValueError(f"strain fit: displacements {D.shape} do not fit the points {X.shape} (ny, nx, 3)")
        shape = X.shape[:2]
        exx, eyy, exy = (np.empty(shape) for _ in range(3))
        ok = np.empty(shape, np.bool_)
        grad = np.empty(shape + (3, 2))
        normal, e1 = np.empty(shape + (3,)), np.empty(shape + (3,))
        fit_all(X, D, self.window, self.min_fraction * self.window ** 2, exx, eyy, exy, ok, grad, normal, e1)
        return Strain(exx, eyy, exy, ok, grad, normal, e1)


def strain_2d(xs: np.ndarray, ys: np.ndarray, u: np.ndarray, v: np.ndarray, *, window: int = 5,
              min_fraction: float = 0.6) -> Strain:
    """In-plane strain of a 2-D displacement field on a grid (module docstring).

    Parameters
    ----------
    xs : (nx,) float
        The grid's x positions (e.g. pixels, `Grid.xs`).
    ys : (ny,) float
        Its y positions, the same unit.
    u, v : (ny, nx) float
        The displacement along x and y, the same unit; NaN where not measured.
    window, min_fraction
        As `strain_3d`.

    Returns
    -------
    strain : Strain
        Green-Lagrange ``exx``, ``eyy``, ``exy`` (ny, nx), dimensionless, frame e1 = x, e2 = y; NaN where
        not ``valid``.
    """
    Xg, Yg = np.meshgrid(np.asarray(xs, np.float64), np.asarray(ys, np.float64))
    X = np.stack([Xg, Yg, np.zeros_like(Xg)], -1)
    D = np.stack([u, v, np.zeros_like(u)], -1)
    return strain_3d(X, D, window=window, min_fraction=min_fraction)

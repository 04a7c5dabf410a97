"""Strain from a displacement field by local least-squares fitting (virtual strain gauge).

Around every point of a grid, the displacement of the valid points in a window of `window` x `window`
grid points is fitted by a plane (a + b s + c t) in local surface coordinates (s, t); its slopes give
the deformation gradient and the Green-Lagrange strain E = (F^T F - I) / 2.

- `strain_2d`: in-plane field on the image grid: u, v along x, y.
- `strain_3d`: surface points X (any units, e.g. mm) and 3-D displacements D: fitted on the local tangent
  plane of the surface (normal by principal components of the window's points), so that out-of-plane
  motion and the surface's tilt are handled; components in the tangent frame (e1, e2), e1 the
  projection of the x axis on the plane, e2 = n x e1, n oriented towards +z. `StrainFit` does the same
  for many displacement fields on one surface (a sequence's states on its reference shape), keeping
  the part of the work that depends on the surface only.
Strains are dimensionless; NaN (with valid = False) where the window holds too few valid points or
the centre point is not valid.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage


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


def _box_sum(a: np.ndarray, window: int) -> np.ndarray:
    """Sum over window x window neighbours along the first two axes (zero outside)."""
    size = (window, window) + (1,) * (a.ndim - 2)
    return ndimage.uniform_filter(a, size=size, mode="constant", cval=0.0) * (window * window)


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
        projection of x on the plane, e2 = n x e1), NaN where not ``valid``; ``grad``, ``normal``, ``e1``.
    """
    return StrainFit(X, window=window, min_fraction=min_fraction)(D)


@dataclass
class _Frame:
    """What the fits on a surface depend on besides the displacements, for one set of valid points."""

    valid: np.ndarray
    Xc: np.ndarray      # positions less their mean, 0 where not valid
    normal: np.ndarray
    e1: np.ndarray
    E: np.ndarray       # (ny, nx, 2, 3): e1, e2
    ok: np.ndarray
    N_inv: np.ndarray   # (ny, nx, 3, 3): the inverse normal matrix of the fit (identity where not ok)


class StrainFit:
    """`strain_3d` of many displacement fields on one surface: calling it with D gives the Strain.

    What depends on X and on which points are valid only - the local frames and the fits' normal
    matrices, most of the work - is kept for the last set of valid points, so that the states of a
    sequence (all fitted on the reference surface, mostly with the same points) share it.

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
        self.X, self.window, self.min_fraction = X, window, min_fraction
        self._frame: _Frame | None = None

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
        valid = np.isfinite(self.X).all(-1) & np.isfinite(D).all(-1)
        if self._frame is None or not np.array_equal(valid, self._frame.valid):
            self._frame = self._frame_of(valid)
        f, window = self._frame, self.window
        Dc = np.where(f.valid[..., None], D, 0.0)
        SD = _box_sum(Dc, window)
        SXD = _box_sum(f.Xc[..., :, None] * Dc[..., None, :], window)
        C = SXD - f.Xc[..., :, None] * SD[..., None, :]  # moments about the centre point: sum (X - c) D^T
        rhs_st = np.einsum("...ij,...jk->...ik", f.E, C)  # (2, 3): sum s D, sum t D
        rhs = np.concatenate([SD[..., None, :], rhs_st], -2)  # (3, 3): rows 1, s, t; columns D components
        coef = np.einsum("...ij,...jk->...ik", f.N_inv, np.where(f.ok[..., None, None], rhs, 0))
        grad = np.swapaxes(coef[..., 1:, :], -1, -2)  # (ny, nx, 3, 2): dD/ds, dD/dt
        g1 = f.E[..., 0, :] + grad[..., 0]
        g2 = f.E[..., 1, :] + grad[..., 1]
        nan = np.nan
        exx = np.where(f.ok, 0.5 * (np.sum(g1 * g1, -1) - 1.0), nan)
        eyy = np.where(f.ok, 0.5 * (np.sum(g2 * g2, -1) - 1.0), nan)
        exy = np.where(f.ok, 0.5 * np.sum(g1 * g2, -1), nan)
        grad = np.where(f.ok[..., None, None], grad, nan)
        return Strain(exx, eyy, exy, f.ok, grad, f.normal, f.e1)

    def _frame_of(self, valid: np.ndarray) -> _Frame:
        X, window = self.X, self.window
        m = valid.astype(np.float64)
        Xc = np.where(valid[..., None], X, 0.0)  # the window's point positions, 0 where invalid
        # shift all positions by their mean, so that the sums stay small
        origin = Xc[valid].mean(0) if valid.any() else np.zeros(3)
        Xc = np.where(valid[..., None], Xc - origin, 0.0)
        S1 = _box_sum(m, window)
        SX = _box_sum(Xc, window)
        SXX = _box_sum(Xc[..., :, None] * Xc[..., None, :], window)
        enough = valid & (S1 >= self.min_fraction * window * window)
        n = np.maximum(S1, 1.0)[..., None]
        mean = SX / n
        cov = SXX / n[..., None] - mean[..., :, None] * mean[..., None, :]
        evals, evecs = np.linalg.eigh(np.where(enough[..., None, None], cov, np.diag([1.0, 1.0, 0.0])))
        normal = evecs[..., :, 0]
        normal = np.where((normal[..., 2:3] < 0), -normal, normal)
        flat_enough = evals[..., 1] > 1e-6 * np.maximum(evals[..., 2], 1e-300)
        ex = np.array([1.0, 0.0, 0.0])
        e1 = ex - (normal @ ex)[..., None] * normal
        e1_norm = np.linalg.norm(e1, axis=-1, keepdims=True)
        flat_enough &= e1_norm[..., 0] > 1e-6  # a surface facing along x has no defined e1
        e1 /= np.maximum(e1_norm, 1e-300)
        e2 = np.cross(normal, e1)
        # moments about the centre point c: sum (X - c), sum (X - c)(X - c)^T
        c = Xc
        A = SX - S1[..., None] * c
        B = SXX - c[..., :, None] * SX[..., None, :] - SX[..., :, None] * c[..., None, :] \
            + S1[..., None, None] * c[..., :, None] * c[..., None, :]
        E = np.stack([e1, e2], -2)  # (ny, nx, 2, 3)
        s_sum = np.einsum("...ij,...j->...i", E, A)  # sum of (s, t)
        st = np.einsum("...ij,...jk,...lk->...il", E, B, E)  # 2x2 sums of products of (s, t)
        N = np.zeros(S1.shape + (3, 3))
        N[..., 0, 0] = S1
        N[..., 0, 1:] = s_sum
        N[..., 1:, 0] = s_sum
        N[..., 1:, 1:] = st
        ok = enough & flat_enough & (np.linalg.det(np.where(enough[..., None, None], N, np.eye(3))) > 0)
        N_inv = np.linalg.inv(np.where(ok[..., None, None], N, np.eye(3)))
        return _Frame(valid, Xc, normal, e1, E, ok, N_inv)


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

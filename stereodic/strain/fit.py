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
  run in one compiled kernel, the grid's rows in parallel.
Strains are dimensionless; NaN (with valid = False) where the window holds too few valid points or
the centre point is not valid.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np


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
        _fit(X, D, self.window, self.min_fraction * self.window ** 2, exx, eyy, exy, ok, grad, normal, e1)
        return Strain(exx, eyy, exy, ok, grad, normal, e1)


@numba.njit(cache=True, inline="always")
def _smallest_eigenvector(a, out):  # pragma: no cover - numba kernel
    """Eigenvalues of the symmetric 3x3 `a` (overwritten) by cyclic Jacobi rotations, returned ascending
    as (l0, l1, l2); `out` gets the unit eigenvector of l0."""
    v = np.eye(3)
    for _ in range(50):
        off = a[0, 1] * a[0, 1] + a[0, 2] * a[0, 2] + a[1, 2] * a[1, 2]
        if off <= 1e-36 * (a[0, 0] * a[0, 0] + a[1, 1] * a[1, 1] + a[2, 2] * a[2, 2]) or off == 0.0:
            break
        for p, q in ((0, 1), (0, 2), (1, 2)):
            if a[p, q] == 0.0:
                continue
            theta = (a[q, q] - a[p, p]) / (2.0 * a[p, q])
            t = (1.0 if theta >= 0 else -1.0) / (abs(theta) + np.sqrt(theta * theta + 1.0))
            c = 1.0 / np.sqrt(t * t + 1.0)
            s = t * c
            for k in range(3):  # a <- J^T a J, J the rotation in the (p, q) plane
                akp, akq = a[k, p], a[k, q]
                a[k, p] = c * akp - s * akq
                a[k, q] = s * akp + c * akq
            for k in range(3):
                apk, aqk = a[p, k], a[q, k]
                a[p, k] = c * apk - s * aqk
                a[q, k] = s * apk + c * aqk
            for k in range(3):
                vkp, vkq = v[k, p], v[k, q]
                v[k, p] = c * vkp - s * vkq
                v[k, q] = s * vkp + c * vkq
    i0 = 0
    for i in range(1, 3):
        if a[i, i] < a[i0, i0]:
            i0 = i
    i1, i2 = (i0 + 1) % 3, (i0 + 2) % 3
    if a[i1, i1] > a[i2, i2]:
        i1, i2 = i2, i1
    for k in range(3):
        out[k] = v[k, i0]
    return a[i0, i0], a[i1, i1], a[i2, i2]


@numba.njit(cache=True, parallel=True)
def _fit(X, D, window, min_count, exx, eyy, exy, ok, grad, normal, e1):  # pragma: no cover - numba kernel
    """The plane fits of `StrainFit` (module docstring), one grid row per task. Per centre point c:
    the moments of the window's valid points about c give the covariance, whose smallest eigenvector is
    the normal n (towards +z); e1 = x projected on the plane, e2 = n x e1; the plane D = a + b s + c t in
    (s, t) = ((X - c).e1, (X - c).e2) is solved from its 3x3 normal equations. A point is valid where it
    and its displacement are finite, its window holds min_count valid points, the points are not all on
    a line (second eigenvalue > 1e-6 of the largest), x is not along n, and the normal matrix is regular."""
    ny, nx = X.shape[0], X.shape[1]
    h = window // 2
    nan = np.nan
    for i in numba.prange(ny):
        cov = np.empty((3, 3))
        B = np.empty((3, 3))
        C = np.empty((3, 3))
        N = np.empty((3, 3))
        Ni = np.empty((3, 3))
        rhs = np.empty((3, 3))
        A = np.empty(3)
        SD = np.empty(3)
        n = np.empty(3)
        f1 = np.empty(3)
        f2 = np.empty(3)
        p = np.empty(3)
        for j in range(nx):
            exx[i, j] = eyy[i, j] = exy[i, j] = nan
            ok[i, j] = False
            for a in range(3):
                normal[i, j, a] = 1.0 if a == 2 else 0.0
                e1[i, j, a] = 1.0 if a == 0 else 0.0
                grad[i, j, a, 0] = grad[i, j, a, 1] = nan
            if not _finite(X, D, i, j):
                continue
            count = 0.0
            A[:] = 0.0
            SD[:] = 0.0
            B[:] = 0.0
            C[:] = 0.0
            for ii in range(max(0, i - h), min(ny, i + h + 1)):
                for jj in range(max(0, j - h), min(nx, j + h + 1)):
                    if not _finite(X, D, ii, jj):
                        continue
                    count += 1.0
                    for a in range(3):
                        p[a] = X[ii, jj, a] - X[i, j, a]
                    for a in range(3):
                        A[a] += p[a]
                        SD[a] += D[ii, jj, a]
                        for b in range(3):
                            B[a, b] += p[a] * p[b]
                            C[a, b] += p[a] * D[ii, jj, b]
            if count < min_count:
                continue
            for a in range(3):
                for b in range(3):
                    cov[a, b] = B[a, b] / count - A[a] * A[b] / (count * count)
            _, l1, l2 = _smallest_eigenvector(cov, n)
            if n[2] < 0:
                for a in range(3):
                    n[a] = -n[a]
            for a in range(3):
                f1[a] = (1.0 if a == 0 else 0.0) - n[0] * n[a]
            norm = np.sqrt(f1[0] * f1[0] + f1[1] * f1[1] + f1[2] * f1[2])
            for a in range(3):
                normal[i, j, a] = n[a]
                f1[a] /= max(norm, 1e-300)
                e1[i, j, a] = f1[a]
            if not (l1 > 1e-6 * max(l2, 1e-300)) or not (norm > 1e-6):
                continue
            f2[0] = n[1] * f1[2] - n[2] * f1[1]
            f2[1] = n[2] * f1[0] - n[0] * f1[2]
            f2[2] = n[0] * f1[1] - n[1] * f1[0]
            # normal equations of (1, s, t) and their right-hand sides (rows 1, s, t; columns D's components)
            N[0, 0] = count
            N[0, 1] = N[1, 0] = f1[0] * A[0] + f1[1] * A[1] + f1[2] * A[2]
            N[0, 2] = N[2, 0] = f2[0] * A[0] + f2[1] * A[1] + f2[2] * A[2]
            N[1, 1] = N[1, 2] = N[2, 1] = N[2, 2] = 0.0
            for a in range(3):
                for b in range(3):
                    N[1, 1] += f1[a] * B[a, b] * f1[b]
                    N[1, 2] += f1[a] * B[a, b] * f2[b]
                    N[2, 2] += f2[a] * B[a, b] * f2[b]
            N[2, 1] = N[1, 2]
            det = (N[0, 0] * (N[1, 1] * N[2, 2] - N[1, 2] * N[2, 1]) - N[0, 1] * (N[1, 0] * N[2, 2] - N[1, 2] * N[2, 0])
                   + N[0, 2] * (N[1, 0] * N[2, 1] - N[1, 1] * N[2, 0]))
            if not (det > 0):
                continue
            for a in range(3):
                for b in range(3):  # the inverse from the cofactors (N is symmetric)
                    r0, r1 = (b + 1) % 3, (b + 2) % 3
                    c0, c1 = (a + 1) % 3, (a + 2) % 3
                    Ni[a, b] = (N[r0, c0] * N[r1, c1] - N[r0, c1] * N[r1, c0]) / det
            for b in range(3):
                rhs[0, b] = SD[b]
                rhs[1, b] = f1[0] * C[0, b] + f1[1] * C[1, b] + f1[2] * C[2, b]
                rhs[2, b] = f2[0] * C[0, b] + f2[1] * C[1, b] + f2[2] * C[2, b]
            g11 = g22 = g12 = 0.0
            for b in range(3):  # b: D's component; its slopes along s and t
                ds = Ni[1, 0] * rhs[0, b] + Ni[1, 1] * rhs[1, b] + Ni[1, 2] * rhs[2, b]
                dt = Ni[2, 0] * rhs[0, b] + Ni[2, 1] * rhs[1, b] + Ni[2, 2] * rhs[2, b]
                grad[i, j, b, 0] = ds
                grad[i, j, b, 1] = dt
                u1 = f1[b] + ds
                u2 = f2[b] + dt
                g11 += u1 * u1
                g22 += u2 * u2
                g12 += u1 * u2
            exx[i, j] = 0.5 * (g11 - 1.0)
            eyy[i, j] = 0.5 * (g22 - 1.0)
            exy[i, j] = 0.5 * g12
            ok[i, j] = True


@numba.njit(cache=True, inline="always")
def _finite(X, D, i, j):  # pragma: no cover - numba kernel
    return (np.isfinite(X[i, j, 0]) and np.isfinite(X[i, j, 1]) and np.isfinite(X[i, j, 2])
            and np.isfinite(D[i, j, 0]) and np.isfinite(D[i, j, 1]) and np.isfinite(D[i, j, 2]))


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

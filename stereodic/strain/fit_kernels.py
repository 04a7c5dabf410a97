"""The numba kernels of `stereodic.strain.fit` (the 3-D strain fit), in a module of their own: importing
`stereodic.strain.fit` does not import numba (0.15 s of a command's start, serial), which its functions
import with these kernels where they are first called."""

import numba
import numpy as np


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
def fit_all(X, D, window, min_count, exx, eyy, exy, ok, grad, normal, e1):  # pragma: no cover - numba kernel
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

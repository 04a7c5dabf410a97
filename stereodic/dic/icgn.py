"""Inverse-compositional Gauss-Newton (IC-GN) sub-pixel registration of square subsets, ZNSSD criterion.

Warp parameters of one point, relative to its reference position (x0, y0), local offsets (dx, dy):
  affine (6):     p = (u, ux, uy, v, vx, vy)
  quadratic (12): p = (u, ux, uy, uxx, uxy, uyy, v, vx, vy, vxx, vxy, vyy)
  x' = x0 + dx + sum_i p[i] phi_i(dx, dy),  y' = y0 + dy + sum_i p[nb + i] phi_i(dx, dy)
  with phi = (1, dx, dy) or (1, dx, dy, dx^2/2, dx dy, dy^2/2), nb = len(phi); pixels.

Per point, the reference subset's values, gradients (from the B-spline), steepest-descent images and
Hessian are computed once (the point of the inverse-compositional scheme); each iteration samples the
deformed image's B-spline only. The criterion is zero-normalised SSD, so offset and scale changes of the
intensity between images do not bias the result. Status codes say why a point is not trusted.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from stereodic.dic.interpolation import FAST, sample_any, sample_cubic, sample_with_gradient

OK, NO_TEXTURE, OUTSIDE, DIVERGED, LOW_ZNCC, UNREACHED, INCONSISTENT, LOW_TEXTURE = 0, 1, 2, 3, 4, 5, 6, 7
STATUS_NAMES = ("ok", "no_texture", "outside", "diverged", "low_zncc", "unreached", "inconsistent", "low_texture")
SHAPE_PARAMS = {"affine": 6, "quadratic": 12}


def quadratic_fit_matrix(half: int) -> np.ndarray:
    """(6, 9) least-squares matrix fitting phi-coefficients to displacements at the 3x3 points
    (-half, 0, half)^2, used to compose quadratic warps."""
    s = np.array([(dx, dy) for dy in (-half, 0, half) for dx in (-half, 0, half)], dtype=np.float64)
    phi = np.stack([np.ones(9), s[:, 0], s[:, 1], s[:, 0] ** 2 / 2, s[:, 0] * s[:, 1], s[:, 1] ** 2 / 2], 1)
    return np.linalg.pinv(phi)


@njit(cache=True, fastmath=FAST, inline="always")
def _displacement(p, nb, off, dx, dy):
    """Displacement component whose coefficients start at p[off], at local offset (dx, dy)."""
    d = p[off] + p[off + 1] * dx + p[off + 2] * dy
    if nb == 6:
        d += 0.5 * p[off + 3] * dx * dx + p[off + 4] * dx * dy + 0.5 * p[off + 5] * dy * dy
    return d


@njit(cache=True)
def shift_warp(p, ox, oy, out):
    """Warp `p` of a point re-expressed for a point offset by (ox, oy) pixels (for guesses)."""
    n = p.size
    nb = n // 2
    for c in range(2):
        o = c * nb
        out[o] = _displacement(p, nb, o, ox, oy)
        if nb == 3:
            out[o + 1] = p[o + 1]
            out[o + 2] = p[o + 2]
        else:
            out[o + 1] = p[o + 1] + p[o + 3] * ox + p[o + 4] * oy
            out[o + 2] = p[o + 2] + p[o + 4] * ox + p[o + 5] * oy
            out[o + 3] = p[o + 3]
            out[o + 4] = p[o + 4]
            out[o + 5] = p[o + 5]


@njit(cache=True, fastmath=FAST)
def _cholesky_solve_inplace(H, n):
    """Cholesky factor of H (n x n) in its lower triangle; False if not clearly positive definite."""
    dmax = 0.0
    for i in range(n):
        dmax = max(dmax, H[i, i])
    if dmax <= 0.0:
        return False
    for j in range(n):
        s = H[j, j]
        for k in range(j):
            s -= H[j, k] * H[j, k]
        if s <= 1e-12 * dmax:
            return False
        d = np.sqrt(s)
        H[j, j] = d
        for i in range(j + 1, n):
            s = H[i, j]
            for k in range(j):
                s -= H[i, k] * H[j, k]
            H[i, j] = s / d
    return True


@njit(cache=True, fastmath=FAST)
def _solve_L(L, b, n, out):
    for i in range(n):
        s = b[i]
        for k in range(i):
            s -= L[i, k] * out[k]
        out[i] = s / L[i, i]
    for i in range(n - 1, -1, -1):
        s = out[i]
        for k in range(i + 1, n):
            s -= L[k, i] * out[k]
        out[i] = s / L[i, i]


@njit(cache=True, fastmath=FAST)
def _compose_affine(p, d):
    """p <- p o d^-1 for affine warps (local frame)."""
    a = 1.0 + d[1]
    b = d[2]
    c = d[4]
    e = 1.0 + d[5]
    det = a * e - b * c
    ia = e / det
    ib = -b / det
    ic = -c / det
    ie = a / det
    tx = -(ia * d[0] + ib * d[3])
    ty = -(ic * d[0] + ie * d[3])
    pa = 1.0 + p[1]
    pb = p[2]
    pc = p[4]
    pe = 1.0 + p[5]
    u = pa * tx + pb * ty + p[0]
    v = pc * tx + pe * ty + p[3]
    na = pa * ia + pb * ic
    nb = pa * ib + pb * ie
    nc = pc * ia + pe * ic
    ne = pc * ib + pe * ie
    p[0] = u
    p[1] = na - 1.0
    p[2] = nb
    p[3] = v
    p[4] = nc
    p[5] = ne - 1.0


@njit(cache=True, fastmath=FAST)
def _compose_quadratic(p, d, fit, half):
    """p <- p o d^-1 for quadratic warps, fitted (least squares) at 3x3 points of the subset."""
    du = np.empty(9)
    dv = np.empty(9)
    k = 0
    for sy in (-half, 0, half):
        for sx in (-half, 0, half):
            # invert z + w_d(z) = s by Newton
            zx = sx - _displacement(d, 6, 0, sx, sy)
            zy = sy - _displacement(d, 6, 6, sx, sy)
            for _ in range(4):
                rx = zx + _displacement(d, 6, 0, zx, zy) - sx
                ry = zy + _displacement(d, 6, 6, zx, zy) - sy
                j11 = 1.0 + d[1] + d[3] * zx + d[4] * zy
                j12 = d[2] + d[4] * zx + d[5] * zy
                j21 = d[7] + d[9] * zx + d[10] * zy
                j22 = 1.0 + d[8] + d[10] * zx + d[11] * zy
                det = j11 * j22 - j12 * j21
                zx -= (j22 * rx - j12 * ry) / det
                zy -= (-j21 * rx + j11 * ry) / det
            du[k] = zx + _displacement(p, 6, 0, zx, zy) - sx
            dv[k] = zy + _displacement(p, 6, 6, zx, zy) - sy
            k += 1
    for i in range(6):
        su = 0.0
        sv = 0.0
        for k in range(9):
            su += fit[i, k] * du[k]
            sv += fit[i, k] * dv[k]
        p[i] = su
        p[6 + i] = sv


@njit(cache=True, fastmath=FAST)
def _sums_affine(J, fc, H, JS, JF):
    """Lower triangle of H = J^T J, JS = sum J, JF = sum J fc, for 6 parameters (scalar sums: fast)."""
    h00 = h10 = h11 = h20 = h21 = h22 = h30 = 0.0
    h31 = h32 = h33 = h40 = h41 = h42 = h43 = 0.0
    h44 = h50 = h51 = h52 = h53 = h54 = h55 = 0.0
    s0 = s1 = s2 = s3 = s4 = s5 = f0 = f1 = f2 = f3 = f4 = f5 = 0.0
    for k in range(fc.size):
        c = fc[k]
        j0 = J[k, 0]
        j1 = J[k, 1]
        j2 = J[k, 2]
        j3 = J[k, 3]
        j4 = J[k, 4]
        j5 = J[k, 5]
        s0 += j0
        s1 += j1
        s2 += j2
        s3 += j3
        s4 += j4
        s5 += j5
        f0 += j0 * c
        f1 += j1 * c
        f2 += j2 * c
        f3 += j3 * c
        f4 += j4 * c
        f5 += j5 * c
        h00 += j0 * j0
        h10 += j1 * j0
        h11 += j1 * j1
        h20 += j2 * j0
        h21 += j2 * j1
        h22 += j2 * j2
        h30 += j3 * j0
        h31 += j3 * j1
        h32 += j3 * j2
        h33 += j3 * j3
        h40 += j4 * j0
        h41 += j4 * j1
        h42 += j4 * j2
        h43 += j4 * j3
        h44 += j4 * j4
        h50 += j5 * j0
        h51 += j5 * j1
        h52 += j5 * j2
        h53 += j5 * j3
        h54 += j5 * j4
        h55 += j5 * j5
    H[0, 0] = h00
    H[1, 0] = h10
    H[1, 1] = h11
    H[2, 0] = h20
    H[2, 1] = h21
    H[2, 2] = h22
    H[3, 0] = h30
    H[3, 1] = h31
    H[3, 2] = h32
    H[3, 3] = h33
    H[4, 0] = h40
    H[4, 1] = h41
    H[4, 2] = h42
    H[4, 3] = h43
    H[4, 4] = h44
    H[5, 0] = h50
    H[5, 1] = h51
    H[5, 2] = h52
    H[5, 3] = h53
    H[5, 4] = h54
    H[5, 5] = h55
    JS[0] = s0
    JS[1] = s1
    JS[2] = s2
    JS[3] = s3
    JS[4] = s4
    JS[5] = s5
    JF[0] = f0
    JF[1] = f1
    JF[2] = f2
    JF[3] = f3
    JF[4] = f4
    JF[5] = f5


@njit(cache=True, fastmath=FAST)
def _prepare_reference(ref, refpix, order, width, height, x0, y0, half, J, fc, H, JS, JF):
    """Reference side of one subset: steepest-descent images J (m, n), zero-mean values fc (m,), the
    Hessian's Cholesky factor H (n, n), sums JS = sum J, JF = sum J fc. Returns (norm of fc, status)."""
    n = J.shape[1]
    nb = n // 2
    side = 2 * half + 1
    m = side * side
    if not (0.0 <= x0 - half and x0 + half <= width - 1 and 0.0 <= y0 - half and y0 + half <= height - 1):
        return 0.0, OUTSIDE
    fsum = 0.0
    on_pixel = x0 == np.floor(x0) and y0 == np.floor(y0)
    ix0 = int(x0)
    iy0 = int(y0)
    k = 0
    for j in range(side):
        dy = j - half
        for i in range(side):
            dx = i - half
            if on_pixel:
                f = refpix[0, iy0 + dy, ix0 + dx]
                gx = refpix[1, iy0 + dy, ix0 + dx]
                gy = refpix[2, iy0 + dy, ix0 + dx]
            else:
                f, gx, gy = sample_with_gradient(ref, order, x0 + dx, y0 + dy)
            fc[k] = f
            fsum += f
            J[k, 0] = gx
            J[k, 1] = gx * dx
            J[k, 2] = gx * dy
            J[k, nb] = gy
            J[k, nb + 1] = gy * dx
            J[k, nb + 2] = gy * dy
            if nb == 6:
                J[k, 3] = 0.5 * gx * dx * dx
                J[k, 4] = gx * dx * dy
                J[k, 5] = 0.5 * gx * dy * dy
                J[k, 9] = 0.5 * gy * dx * dx
                J[k, 10] = gy * dx * dy
                J[k, 11] = 0.5 * gy * dy * dy
            k += 1
    fmean = fsum / m
    ss = 0.0
    for k in range(m):
        fc[k] -= fmean
        ss += fc[k] * fc[k]
    if ss <= 1e-10 * m:
        return 0.0, NO_TEXTURE
    if n == 6:
        _sums_affine(J, fc, H, JS, JF)
    else:
        H[:] = 0.0
        JS[:] = 0.0
        JF[:] = 0.0
        for k in range(m):
            for a in range(n):
                ja = J[k, a]
                JS[a] += ja
                JF[a] += ja * fc[k]
                for b in range(a + 1):
                    H[a, b] += ja * J[k, b]
    if not _cholesky_solve_inplace(H, n):
        return 0.0, NO_TEXTURE
    return np.sqrt(ss), OK


@njit(cache=True, parallel=True)
def reference_status(ref, refpix, order, width, height, xs, ys, half, nparams, status):
    """Whether each reference subset can be registered at all (OK, NO_TEXTURE or OUTSIDE), from the
    reference alone: status (N,) is filled."""
    m = (2 * half + 1) ** 2
    for k in prange(xs.size):
        J = np.empty((m, nparams))
        _, status[k] = _prepare_reference(ref, refpix, order, width, height, xs[k], ys[k], half, J,
                                          np.empty(m), np.empty((nparams, nparams)), np.empty(nparams),
                                          np.empty(nparams))


@njit(cache=True, fastmath=FAST)
def _pass_generic(dfm, order, J, fc, p, x0, y0, half, width, height, SJg):
    """One pass over the warped subset in the deformed image: returns (sum g, sum g^2, sum fc g,
    inside) and fills SJg = sum J g; inside is False if the warped subset leaves the image."""
    n = p.size
    nb = n // 2
    side = 2 * half + 1
    SJg[:] = 0.0
    sg = 0.0
    sgg = 0.0
    sfg = 0.0
    k = 0
    for j in range(side):
        dy = j - half
        for i in range(side):
            dx = i - half
            xw = x0 + dx + _displacement(p, nb, 0, dx, dy)
            yw = y0 + dy + _displacement(p, nb, nb, dx, dy)
            if not (-0.5 <= xw <= width - 0.5 and -0.5 <= yw <= height - 0.5):
                return sg, sgg, sfg, False
            g = sample_any(dfm, order, xw, yw)
            sg += g
            sgg += g * g
            sfg += fc[k] * g
            for a in range(n):
                SJg[a] += J[k, a] * g
            k += 1
    return sg, sgg, sfg, True


@njit(cache=True, fastmath=FAST)
def _pass_affine_cubic(dfm, J, fc, p, x0, y0, half, width, height, SJg):
    """`_pass_generic` specialised for affine warps and bicubic interpolation (the common, fast case)."""
    side = 2 * half + 1
    a11 = 1.0 + p[1]
    a12 = p[2]
    a21 = p[4]
    a22 = 1.0 + p[5]
    # the warped subset is a parallelogram: inside if its corners are
    for cy in (-half, half):
        for cx in (-half, half):
            xw = x0 + p[0] + a11 * cx + a12 * cy
            yw = y0 + p[3] + a21 * cx + a22 * cy
            if not (-0.5 <= xw <= width - 0.5 and -0.5 <= yw <= height - 0.5):
                return 0.0, 0.0, 0.0, False
    s0 = s1 = s2 = s3 = s4 = s5 = 0.0
    sg = 0.0
    sgg = 0.0
    sfg = 0.0
    k = 0
    for j in range(side):
        dy = j - half
        xr = x0 + p[0] + a12 * dy - a11 * half
        yr = y0 + p[3] + a22 * dy - a21 * half
        for i in range(side):
            g = sample_cubic(dfm, xr + a11 * i, yr + a21 * i)
            sg += g
            sgg += g * g
            sfg += fc[k] * g
            s0 += J[k, 0] * g
            s1 += J[k, 1] * g
            s2 += J[k, 2] * g
            s3 += J[k, 3] * g
            s4 += J[k, 4] * g
            s5 += J[k, 5] * g
            k += 1
    SJg[0] = s0
    SJg[1] = s1
    SJg[2] = s2
    SJg[3] = s3
    SJg[4] = s4
    SJg[5] = s5
    return sg, sgg, sfg, True


@njit(cache=True, fastmath=FAST)
def solve_point(ref, refpix, dfm, order, width, height, x0, y0, half, p, fit, max_iter, tol, min_zncc):
    """Register one subset of half-width `half` centred on (x0, y0) in the reference.

    ref, dfm: padded B-spline coefficients (see interpolation.BSplineImage) of the reference and deformed
    images; refpix: the reference's `pixel_gradients()`, used when (x0, y0) is a pixel centre; p: initial
    warp, refined in place. Returns (zncc, iterations, status)."""
    n = p.size
    nb = n // 2
    side = 2 * half + 1
    m = side * side
    J = np.empty((m, n))
    fc = np.empty(m)
    H = np.empty((n, n))
    JS = np.empty(n)
    JF = np.empty(n)
    df, st = _prepare_reference(ref, refpix, order, width, height, x0, y0, half, J, fc, H, JS, JF)
    if st != OK:
        return np.nan, 0, st
    SJg = np.empty(n)
    rhs = np.empty(n)
    dp = np.empty(n)
    zncc = np.nan
    h2 = 0.5 * half * half
    for it in range(1, max_iter + 1):
        if nb == 3 and order == 3:
            sg, sgg, sfg, inside = _pass_affine_cubic(dfm, J, fc, p, x0, y0, half, width, height, SJg)
        else:
            sg, sgg, sfg, inside = _pass_generic(dfm, order, J, fc, p, x0, y0, half, width, height, SJg)
        if not inside:
            return np.nan, it, OUTSIDE
        gmean = sg / m
        vg = sgg - sg * gmean
        if not vg > 1e-10 * m:
            return np.nan, it, NO_TEXTURE
        dg = np.sqrt(vg)
        zncc = sfg / (df * dg)
        ratio = df / dg
        for a in range(n):
            rhs[a] = -(JF[a] - ratio * (SJg[a] - gmean * JS[a]))
        _solve_L(H, rhs, n, dp)
        if nb == 3:
            _compose_affine(p, dp)
            norm = dp[0] ** 2 + dp[3] ** 2 + half * half * (dp[1] ** 2 + dp[2] ** 2 + dp[4] ** 2 + dp[5] ** 2)
        else:
            _compose_quadratic(p, dp, fit, half)
            norm = (dp[0] ** 2 + dp[6] ** 2
                    + half * half * (dp[1] ** 2 + dp[2] ** 2 + dp[7] ** 2 + dp[8] ** 2)
                    + h2 * h2 * (dp[3] ** 2 + dp[4] ** 2 + dp[5] ** 2 + dp[9] ** 2 + dp[10] ** 2 + dp[11] ** 2))
        if not np.isfinite(norm) or norm > 1e6:
            return zncc, it, DIVERGED
        if norm < tol * tol:
            return zncc, it, OK if zncc >= min_zncc else LOW_ZNCC
    return zncc, max_iter, DIVERGED


@njit(cache=True, parallel=True)
def solve_points(ref, refpix, dfm, order, width, height, xs, ys, half, P, fit, max_iter, tol, min_zncc,
                 zncc, iters, status):
    """`solve_point` for every point (xs[k], ys[k]) in parallel; P (N, n) holds the guesses on entry and
    the warps on return; zncc, iters, status are filled."""
    for k in prange(xs.size):
        z, it, st = solve_point(ref, refpix, dfm, order, width, height, xs[k], ys[k], half, P[k], fit, max_iter,
                                tol, min_zncc)
        zncc[k] = z
        iters[k] = it
        status[k] = st

"""The numba kernels of `stereodic.stereo.triangulate` (the fused triangulation and the rays' distances), in a module of their own: importing
`stereodic.stereo.triangulate` does not import numba (0.15 s of a command's start, serial), which its functions
import with these kernels where they are first called."""

import numba
import numpy as np


@numba.njit(cache=True, inline="always")
def _bilinear3(field, u, v, out):  # pragma: no cover - numba kernel
    """`stereodic.virtual.sampling.bilinear` of an (H, W, 3) field at one (u, v), into out (3,)."""
    h, w = field.shape[0], field.shape[1]
    if not (np.isfinite(u) and np.isfinite(v)):
        out[:] = np.nan
        return
    i = min(max(int(np.floor(u)), 0), w - 2)
    j = min(max(int(np.floor(v)), 0), h - 2)
    a, b = u - i, v - j
    for c in range(3):
        p00, p10, p01, p11 = field[j, i, c], field[j, i + 1, c], field[j + 1, i, c], field[j + 1, i + 1, c]
        out[c] = p00 + a * (p10 - p00) + b * (p01 - p00) + a * b * (p11 - p10 - p01 + p00)


@numba.njit(cache=True, parallel=True)
def triangulate_all(xl, rl, xr, rr, origin, eu, ev, dir_l, dir_r, c_l, c_r, corrected, points, gap
                 ):  # pragma: no cover - numba kernel
    # scalar code per point: array expressions inside a prange become nested parallel loops, which
    # numba takes ~10 s to compile
    for k in numba.prange(xl.size):
        o1 = np.empty(3)
        o2 = np.empty(3)
        d1 = np.empty(3)
        d2 = np.empty(3)
        for c in range(3):
            o1[c] = origin[c] + xl[k] * eu[c] + rl[k] * ev[c]
            o2[c] = origin[c] + xr[k] * eu[c] + rr[k] * ev[c]
        if corrected:
            _bilinear3(dir_l, xl[k], rl[k], d1)
            _bilinear3(dir_r, xr[k], rr[k], d2)
        else:
            for c in range(3):
                d1[c] = o1[c] - c_l[c]
                d2[c] = o2[c] - c_r[c]
        n1 = np.sqrt(d1[0] * d1[0] + d1[1] * d1[1] + d1[2] * d1[2])
        n2 = np.sqrt(d2[0] * d2[0] + d2[1] * d2[1] + d2[2] * d2[2])
        b = d = e = 0.0
        for c in range(3):
            d1[c] /= n1
            d2[c] /= n2
        for c in range(3):
            w = o1[c] - o2[c]
            b += d1[c] * d2[c]
            d += d1[c] * w
            e += d2[c] * w
        den = 1.0 - b * b
        if den > 1e-15:
            s = (b * e - d) / den
            t = (e - b * d) / den
        else:
            s = np.nan
            t = np.nan
        g = 0.0
        for c in range(3):
            p1 = o1[c] + s * d1[c]
            p2 = o2[c] + t * d2[c]
            points[k, c] = (p1 + p2) / 2
            g += (p1 - p2) * (p1 - p2)
        gap[k] = np.sqrt(g)


@numba.njit(cache=True, parallel=True)
def distances_all(xl, rl, xr, rr, origin, eu, ev, dir_l, dir_r, out):  # pragma: no cover - numba kernel
    for k in numba.prange(xl.size):
        d1 = np.empty(3)
        d2 = np.empty(3)
        _bilinear3(dir_l, xl[k], rl[k], d1)
        _bilinear3(dir_r, xr[k], rr[k], d2)
        n0 = d1[1] * d2[2] - d1[2] * d2[1]
        n1 = d1[2] * d2[0] - d1[0] * d2[2]
        n2 = d1[0] * d2[1] - d1[1] * d2[0]
        dot = 0.0
        for c in range(3):   # o2 - o1, the two rays' points on the common plane
            w = (xr[k] - xl[k]) * eu[c] + (rr[k] - rl[k]) * ev[c]
            dot += w * (n0 if c == 0 else n1 if c == 1 else n2)
        out[k] = dot / np.sqrt(n0 * n0 + n1 * n1 + n2 * n2)

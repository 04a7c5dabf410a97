"""The numba kernels of `stereodic.virtual.imm` (`build_imm`'s Newton inversion), in a module of their own: importing
`stereodic.virtual.imm` does not import numba (0.15 s of a command's start, serial), which its functions
import with these kernels where they are first called."""

import numba
import numpy as np


@numba.njit(cache=True, parallel=True)
def invert_rows(q, start, start_scale, target_step, iterations, tol_px, map_x, map_y, valid):  # pragma: no cover
    """For every output node (col, row), i.e. virtual point (col, row) * target_step: start from `start`
    (Hs, Ws, 2) real (u, v) sampled bilinearly at (col, row) * start_scale, then Newton on the bilinear
    interpolant of the projected real pixels q (H, W, 2), cell by cell, until the plane residual is
    below 1e-9 px. Writes the real (u, v) and validity (see build_imm). A numba kernel."""
    h, w = q.shape[0], q.shape[1]
    nv, nu = start.shape[0], start.shape[1]
    hv, wv = map_x.shape
    for row in numba.prange(hv):
        for col in range(wv):
            tx, ty = col * target_step, row * target_step
            gx, gy = col * start_scale, row * start_scale
            i0, j0 = min(int(gx), nu - 2), min(int(gy), nv - 2)
            a, b = gx - i0, gy - j0
            u = ((1 - a) * (1 - b) * start[j0, i0, 0] + a * (1 - b) * start[j0, i0 + 1, 0]
                 + (1 - a) * b * start[j0 + 1, i0, 0] + a * b * start[j0 + 1, i0 + 1, 0])
            v = ((1 - a) * (1 - b) * start[j0, i0, 1] + a * (1 - b) * start[j0, i0 + 1, 1]
                 + (1 - a) * b * start[j0 + 1, i0, 1] + a * b * start[j0 + 1, i0 + 1, 1])
            norm = np.inf
            for _ in range(iterations):
                if not (np.isfinite(u) and np.isfinite(v)):
                    norm = np.inf
                    break
                i = min(max(int(np.floor(u)), 0), w - 2)
                j = min(max(int(np.floor(v)), 0), h - 2)
                a, b = u - i, v - j
                ux = q[j, i + 1, 0] - q[j, i, 0]
                uy = q[j, i + 1, 1] - q[j, i, 1]
                vx = q[j + 1, i, 0] - q[j, i, 0]
                vy = q[j + 1, i, 1] - q[j, i, 1]
                cx = q[j + 1, i + 1, 0] - q[j, i + 1, 0] - q[j + 1, i, 0] + q[j, i, 0]
                cy = q[j + 1, i + 1, 1] - q[j, i + 1, 1] - q[j + 1, i, 1] + q[j, i, 1]
                rx = q[j, i, 0] + a * ux + b * vx + a * b * cx - tx
                ry = q[j, i, 1] + a * uy + b * vy + a * b * cy - ty
                norm = np.sqrt(rx * rx + ry * ry)
                if not norm >= 1e-9:  # converged (or NaN: an invalid real pixel)
                    break
                jux, juy = ux + b * cx, uy + b * cy  # d(plane)/du
                jvx, jvy = vx + a * cx, vy + a * cy  # d(plane)/dv
                det = jux * jvy - juy * jvx
                u -= (jvy * rx - jvx * ry) / det
                v -= (jux * ry - juy * rx) / det
            eps = 1e-9
            if norm < tol_px and -eps <= u <= w - 1 + eps and -eps <= v <= h - 1 + eps:
                map_x[row, col] = min(max(u, 0.0), w - 1.0)
                map_y[row, col] = min(max(v, 0.0), h - 1.0)
                valid[row, col] = True

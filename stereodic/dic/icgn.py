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

The kernels are compiled (stereodic/dic/src/icgn.c, Pan, Li & Tong, Exp. Mech. 53, 2013); arrays are
C-contiguous, of the dtypes named:
- `solve_points(ref, refpix, dfm, order, width, height, xs, ys, half, P, fit, max_iter, tol, min_zncc,
  zncc, iters, status)`: register the subsets of half-width `half` centred on (xs[k], ys[k]) (float64,
  reference pixels) in parallel. ref, dfm: padded float32 B-spline coefficients (`BSplineImage.coef`) of
  the reference and deformed images of width x height pixels; refpix: the reference's
  `pixel_gradients()`, used where a point is a pixel centre; P (N, 6 or 12) float64 holds the guesses on
  entry and the warps on return; fit: `quadratic_fit_matrix(half)`; a point stops when its update moves
  the subset edge by less than `tol` pixels, after `max_iter` iterations at most, and is LOW_ZNCC below
  `min_zncc`. Fills zncc (float64), iters (int32), status (int8).
- `reference_status(ref, refpix, order, width, height, xs, ys, half, nparams, status)`: whether each
  reference subset can be registered at all (OK, NO_TEXTURE or OUTSIDE), into status (int8).
- `shift_warp(p, ox, oy, out)`: the warp `p` of a point re-expressed for a point offset by (ox, oy)
  pixels (for guesses), into out.
"""

from __future__ import annotations

import numpy as np

from stereodic.dic._kernels import reference_status, shift_warp, solve_points

OK, NO_TEXTURE, OUTSIDE, DIVERGED, LOW_ZNCC, UNREACHED, INCONSISTENT, LOW_TEXTURE = 0, 1, 2, 3, 4, 5, 6, 7
STATUS_NAMES = ("ok", "no_texture", "outside", "diverged", "low_zncc", "unreached", "inconsistent", "low_texture")
SHAPE_PARAMS = {"affine": 6, "quadratic": 12}

__all__ = ["DIVERGED", "INCONSISTENT", "LOW_TEXTURE", "LOW_ZNCC", "NO_TEXTURE", "OK", "OUTSIDE", "SHAPE_PARAMS",
           "STATUS_NAMES", "UNREACHED", "quadratic_fit_matrix", "reference_status", "shift_warp", "solve_points"]


def quadratic_fit_matrix(half: int) -> np.ndarray:
    """(6, 9) least-squares matrix fitting phi-coefficients to displacements at the 3x3 points
    (-half, 0, half)^2, used to compose quadratic warps."""
    s = np.array([(dx, dy) for dy in (-half, 0, half) for dx in (-half, 0, half)], dtype=np.float64)
    phi = np.stack([np.ones(9), s[:, 0], s[:, 1], s[:, 0] ** 2 / 2, s[:, 0] * s[:, 1], s[:, 1] ** 2 / 2], 1)
    return np.ascontiguousarray(np.linalg.pinv(phi))

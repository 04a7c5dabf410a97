"""The numba kernels of `calib.intensity` (`fit_intensity`'s per-pixel least squares), in a module of their own: importing
`calib.intensity` does not import numba (0.15 s of a command's start, serial), which its functions
import with these kernels where they are first called."""

import numba
import numpy as np


@numba.njit(cache=True, parallel=True)
def fit_pixels(stack, order, lum, full, min_range, offset, gain):  # pragma: no cover - compiled
    """Per pixel: least-squares offset + gain * lum over the unsaturated frames stack[order[j]]; NaN
    where the brightest and darkest frames differ by less than min_range, fewer than 2 frames are
    unsaturated, or the gain is not positive."""
    for i in numba.prange(stack.shape[1]):
        sw = sy = syy = si = syi = np.float32(0)
        for j in range(order.size):
            v = stack[order[j], i]
            if v < full:
                y = lum[j]
                sw += 1
                sy += y
                syy += y * y
                si += v
                syi += y * v
        det = sw * syy - sy * sy
        g = (sw * syi - sy * si) / det if det != 0 else np.float32(np.nan)
        span = stack[order[-1], i] - stack[order[0], i]
        if span >= min_range and sw >= 2 and g > 0:
            gain[i] = g
            offset[i] = (si - g * sy) / sw
        else:
            gain[i] = offset[i] = np.nan

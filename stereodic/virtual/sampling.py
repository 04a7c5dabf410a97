"""Bilinear sampling of per-pixel arrays at fractional pixel coordinates, in float64.

The one sampler behind the IMM's inversion, the virtual rays and the field boundary. It interpolates
exactly as `cv2.remap(..., INTER_LINEAR)` does, but keeps float64 and several channels.
"""

from __future__ import annotations

import numpy as np


def bilinear(array: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Values of `array` (H, W) or (H, W, C) at pixel coordinates (u, v) = (column, row), integers at
    pixel centres. Returns shape u.shape (+ (C,)), float64. Points outside [0, W-1] x [0, H-1] are
    extrapolated from the nearest cell; NaN in any of the 4 neighbours, or in (u, v), gives NaN.
    """
    h, w = array.shape[:2]
    u, v = np.asarray(u, np.float64), np.asarray(v, np.float64)
    lost = ~(np.isfinite(u) & np.isfinite(v))
    if lost.any():
        u, v = np.where(lost, np.nan, u), np.where(lost, np.nan, v)
    i = np.clip(np.floor(np.nan_to_num(u)), 0, w - 2).astype(np.intp)
    j = np.clip(np.floor(np.nan_to_num(v)), 0, h - 2).astype(np.intp)
    a, b = u - i, v - j
    if array.ndim == 3:
        a, b = a[..., None], b[..., None]
    flat = array.reshape(h * w, *array.shape[2:])
    k = j * w + i
    p00, p10, p01, p11 = flat[k], flat[k + 1], flat[k + w], flat[k + w + 1]
    return p00 + a * (p10 - p00) + b * (p01 - p00) + a * b * (p11 - p10 - p01 + p00)

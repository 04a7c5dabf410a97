"""How well a subset's texture can be registered: the image noise and the predicted random error.

For a subset with intensity gradients g_x at its pixels and independent Gaussian noise of standard
deviation sigma in both images, the random error of the displacement u is about
    sigma_u = sqrt(2) sigma / sqrt(sum g_x^2)          (and v likewise with g_y)
(Pan et al., the noise bound the benchmarks check). `predicted_noise` gives the larger of the two per
point; points above a threshold have too little texture to trust, even if they converge.
"""

from __future__ import annotations

import cv2
import numpy as np

from stereodic.dic.interpolation import BSplineImage

# Immerkaer's noise operator: the difference of two Laplacians, blind to linear intensity ramps
_KERNEL = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)


def estimate_noise(image: np.ndarray) -> float:
    """Standard deviation (grey levels) of the image's white noise (Immerkaer 1996: mean absolute
    response of a 3x3 operator that cancels smooth content, scaled for Gaussian noise). Texture adds a
    little; for speckle images this is an upper bound, which errs on the side of caution."""
    img = np.asarray(image, np.float32)
    if min(img.shape) < 3:
        return 0.0
    r = cv2.filter2D(img, cv2.CV_32F, _KERNEL, borderType=cv2.BORDER_REFLECT)[1:-1, 1:-1]
    return float(np.sqrt(np.pi / 2) / 6.0 * np.mean(np.abs(r), dtype=np.float64))


def sssig(ref: BSplineImage, half: int) -> tuple[np.ndarray, np.ndarray]:
    """The sum of squared subset intensity gradients (SSSIG, Pan et al. 2008) of the subset of half-width
    `half` centred on every pixel: two (height, width) float32 maps, sum of (d/dx)^2 (for u) and of
    (d/dy)^2 (for v), grey levels^2 (the interpolant's gradients; a subset crossing the border sums the
    pixels inside)."""
    g = ref.pixel_gradients()
    side = 2 * half + 1
    sx, sy = (cv2.boxFilter(np.square(g[c], dtype=np.float32), cv2.CV_32F, (side, side), normalize=False,
                            borderType=cv2.BORDER_CONSTANT) for c in (1, 2))
    return sx, sy


def predicted_noise(ref: BSplineImage, xs: np.ndarray, ys: np.ndarray, half: int, sigma: float,
                    sums: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """(N,) predicted random error (pixels) of the subsets of half-width `half` at (xs, ys) (rounded to
    pixels), max over u and v, for image noise `sigma` (grey levels); inf where a subset has no gradient,
    NaN where it leaves the image. sums: `sssig(ref, half)` if already computed."""
    sums = sssig(ref, half) if sums is None else sums
    ix = np.rint(np.asarray(xs)).astype(np.int64)
    iy = np.rint(np.asarray(ys)).astype(np.int64)
    inside = (ix >= 0) & (ix < ref.width) & (iy >= 0) & (iy < ref.height)
    out = np.full(ix.shape, np.nan)
    least = np.maximum(np.minimum(sums[0][iy[inside], ix[inside]], sums[1][iy[inside], ix[inside]]), 0.0)
    least = least.astype(np.float64)  # float32 box sums of zero gradients can round below 0
    with np.errstate(divide="ignore"):
        out[inside] = np.sqrt(2.0) * sigma / np.sqrt(least)
    return out

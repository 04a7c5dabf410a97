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

# the core of a subset that must be on the specimen (`specimen_mask`): its half-width (pixels, at least) and
# the RMS of its gradients over the noise's. No 7 x 7 core of white noise passes (none of 336,400); of a
# speckle so faint that a fifth to two thirds of its 21-41 px subsets pass the subset's test, the core test
# takes at most 0.12 %; a core of subset // 8 held to the subset's contrast of 3 took 65-70 % (docs/dic.md)
CORE_HALF, CORE_CONTRAST = 3, 1.75

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


def noise_gradient_gain(order: int = 3) -> float:
    """Mean squared x-gradient of the B-spline interpolant of unit white noise, per pixel (the sum of
    the squared taps of the linear filter that gives the gradients at pixel centres, from its impulse
    response)."""
    impulse = np.zeros((33, 33), np.float64)
    impulse[16, 16] = 1.0
    g = BSplineImage.from_image(impulse, order=order, prefilter_sigma=0.0).pixel_gradients()
    return float(np.sum(np.square(g[1], dtype=np.float64)))


def specimen_mask(image: np.ndarray, *, subset: int, contrast: float = 3.0, noise: float | None = None) -> np.ndarray:
    """Where a subset of the image has speckle to register: (H, W) bool over subset centres.

    A subset is usable where its texture's gradients, in x and in y (the smaller SSSIG, `sssig`), have at
    least `contrast` times the RMS that the image's noise alone gives (`estimate_noise`,
    `noise_gradient_gain`): a dark background, a blank fixture or a saturated patch has only the noise's
    gradients. Its centre must be on the specimen too: the core of the subset (`CORE_HALF` or `subset` // 8
    pixels about it, whichever is larger) must have gradients of CORE_CONTRAST times the noise's RMS, holes
    in that map smaller than a subset's area (the gaps of a sparse speckle) filled. A subset centred off
    the part's edge has speckle in a strip of it only, and its centre's displacement is an extrapolation
    from that strip: errors of tenths of a pixel, where the part's own points have thousandths
    (docs/dic.md). Subsets leaving the image are not usable; patches of usable subsets smaller than 4
    subsets' area (isolated specks) are left out, or, in an image too small for that, smaller than half of
    the subset centres that fit in it.

    Parameters
    ----------
    image : (H, W) array
        The reference image, grey levels (blank pixels 0).
    subset : int
        The subset side, pixels.
    contrast : float
        The ratio of RMS gradients, texture to noise, of a usable subset.
    noise : float, optional
        The image's `estimate_noise`, grey levels, where it was computed already (the DIC's reference
        keeps it, `correlate.ImageRef.sigma`); None: estimated here.

    Returns
    -------
    mask : (H, W) bool
        True at the centres of usable subsets.
    """
    img = np.asarray(image, np.float64)
    h, w = img.shape
    half = subset // 2
    b = BSplineImage.from_image(img, order=3, prefilter_sigma=0.0)
    sx, sy = sssig(b, half)
    sigma = max(estimate_noise(img) if noise is None else noise, 1e-3 * max(float(np.ptp(img)), 1e-12))
    noise_energy = noise_gradient_gain() * sigma ** 2            # per pixel and direction
    mask = np.minimum(sx, sy) >= contrast ** 2 * noise_energy * subset ** 2
    core = max(CORE_HALF, subset // 8)
    cx, cy = sssig(b, core)
    on = np.minimum(cx, cy) >= CORE_CONTRAST ** 2 * noise_energy * (2 * core + 1) ** 2
    mask &= _fill_small_holes(on, subset ** 2)
    inside = np.zeros((h, w), bool)
    inside[half:h - half, half:w - half] = True
    mask &= inside
    count, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    big = stats[:, cv2.CC_STAT_AREA] >= min(4 * subset ** 2, inside.sum() / 2)
    big[0] = False
    return big[labels]


def _fill_small_holes(mask: np.ndarray, area: int) -> np.ndarray:
    """`mask` (H, W bool) with its holes (4-connected False patches) smaller than `area` pixels set True."""
    count, labels, stats, _ = cv2.connectedComponentsWithStats((~mask).astype(np.uint8), connectivity=4)
    small = stats[:, cv2.CC_STAT_AREA] < area
    small[0] = False                                  # label 0: the mask's own pixels
    return mask | small[labels]

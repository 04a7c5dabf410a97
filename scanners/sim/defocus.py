"""Defocus and diffraction blur of a supersampled image-plane radiance, then pixel-area integration.

The blur is applied in IMAGE space, on the radiance sampled at S x S points per pixel: the thin-lens
blur circle is defined on the sensor, it may vary across it (a tilted sensor, a tilted display), and the
supersampled radiance is already at hand; blurring before the S x S box reduction keeps the display's
pixel grid (finer than a camera pixel) from aliasing. A field-varying blur diameter is handled by
blurring with a few uniform diameters spanning the field's range and interpolating linearly per pixel.
"""

from __future__ import annotations

import cv2
import numpy as np

MAX_LEVELS = 4


def disk_kernel(diameter: float) -> np.ndarray:
    """Normalised float32 kernel of a uniform disk (pillbox) of `diameter` samples, anti-aliased by
    8 x 8 sub-cell coverage; a 1 x 1 identity below one sample."""
    if diameter <= 1.0:
        return np.ones((1, 1), np.float32)
    half = int(np.ceil(diameter / 2))
    t = (np.arange(-half * 8, (half + 1) * 8) + 0.5) / 8 - 0.5
    inside = (t[:, None] ** 2 + t[None, :] ** 2) <= (diameter / 2) ** 2
    k = inside.reshape(2 * half + 1, 8, 2 * half + 1, 8).mean(axis=(1, 3)).astype(np.float32)
    return k / k.sum()


def psf_kernel(diameter: float, sigma: float) -> np.ndarray:
    """Normalised float32 kernel (in samples) of a disk of `diameter` convolved with a Gaussian of
    standard deviation `sigma` (the diffraction spot); 1 x 1 when both are negligible."""
    k = disk_kernel(diameter)
    if sigma > 0.3:
        pad = int(np.ceil(3 * sigma))
        k = cv2.GaussianBlur(np.pad(k, pad), (2 * pad + 1, 2 * pad + 1), sigma, borderType=cv2.BORDER_CONSTANT)
    return (k / k.sum()).astype(np.float32)


def blur_and_integrate(radiance_ss: np.ndarray, supersample: int, diameter_px: np.ndarray,
                       sigma_px: float = 0.0) -> np.ndarray:
    """Pixel irradiance (H, W) float32 from radiance sampled on an (H*S, W*S) grid.

    diameter_px: (H, W) defocus blur-circle diameters in pixels; sigma_px: a further Gaussian blur
    (diffraction), in pixels. Each pixel is the mean of its S x S blurred samples. Diameters varying
    across the field use up to MAX_LEVELS uniform blurs, interpolated linearly per pixel.
    """
    s = supersample
    h, w = radiance_ss.shape[0] // s, radiance_ss.shape[1] // s
    lo, hi = float(diameter_px.min()), float(diameter_px.max())
    n = 1 if hi - lo < 0.25 else min(MAX_LEVELS, int(np.ceil((hi - lo) / 0.5)) + 1)
    levels = np.linspace(lo, hi, n) if n > 1 else np.array([0.5 * (lo + hi)])
    out = []
    for d in levels:
        k = psf_kernel(d * s, sigma_px * s)
        img = cv2.filter2D(radiance_ss, cv2.CV_32F, k, borderType=cv2.BORDER_REFLECT) if k.size > 1 else radiance_ss
        out.append(cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA))     # exact S x S box mean
    if n == 1:
        return out[0]
    pos = np.clip((diameter_px - lo) / (levels[1] - levels[0]), 0, n - 1 - 1e-9)
    i0 = pos.astype(int)
    f = (pos - i0).astype(np.float32)
    result = np.zeros((h, w), np.float32)
    for i, img in enumerate(out):          # linear interpolation between the two nearest diameters
        result += img * np.where(i0 == i, 1 - f, 0) + img * np.where(i0 + 1 == i, f, 0)
    return result

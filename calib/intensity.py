"""The Intensity Matrix (IM): each pixel's response linearised individually, normalised globally.

From flat frames at several display code values L_j (tip 3.6, before the geometry calibration) every
camera pixel p follows I_p(L) = offset_p + gain_p * Y(L): Y is the display's relative luminance response
(gamma and all, the same for every pixel, estimated from all pixels together), offset_p and gain_p are the
pixel's own dark level and sensitivity (vignetting, per-pixel gain, the display's brightness
non-uniformity). Applying the IM to a frame returns the relative luminance y = (I - offset_p) / gain_p every pixel saw, on
one common scale. Decoding works on y (where the noise is even); the periodic phase error that the
display's nonlinearity gives a plain fringe is then removed exactly with the known waveform Y(fringe)
(`fringe_waveform`, `calib.phase.WaveformCorrection`) - converting y back to code values instead would
multiply the noise of the dark half of the fringe by the slope of Y^-1, large near black.

The global response Y is also the measured display response that pre-compensates patterns
(`calib.patterns.DisplayResponse`); a pre-compensated fringe emits a cosine and needs no correction.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.patterns import DisplayResponse


@dataclass
class IntensityMatrix:
    """offset, gain: (H, W) float32 in camera values (gain per unit of relative luminance, Y spanning
    0 at the lowest flat level to 1 at the highest); response: the display's relative luminance."""

    offset: np.ndarray
    gain: np.ndarray
    response: DisplayResponse

    def luminance(self, image: np.ndarray) -> np.ndarray:
        """Relative luminance (float32, H x W) seen by each pixel, on the common scale."""
        return (np.asarray(image, np.float32) - self.offset) / self.gain

    def fringe_waveform(self, low: float, high: float, samples: int = 1024) -> np.ndarray:
        """Relative luminance over one period of a plain (not pre-compensated) fringe of code values in
        [low, high]: (samples,) at phase 2*pi*j/samples, for `calib.phase.WaveformCorrection`."""
        phi = 2 * np.pi * np.arange(samples) / samples
        return self.response(low + (high - low) / 2 * (1 + np.cos(phi)))

    def filled(self, other: "IntensityMatrix") -> "IntensityMatrix":
        """This IM with the pixels it lacks (gain NaN: they saw no display) taken from `other` (e.g. the
        flats of another stage position, where they do); the response stays this one's."""
        missing = ~np.isfinite(self.gain)
        return IntensityMatrix(np.where(missing, other.offset, self.offset),
                               np.where(missing, other.gain, self.gain), self.response)

    def to_arrays(self, prefix: str = "im_") -> dict[str, np.ndarray]:
        """Arrays for a PRVM file's extra keys."""
        return {f"{prefix}offset": self.offset.astype(np.float32), f"{prefix}gain": self.gain.astype(np.float32),
                f"{prefix}levels": np.asarray(self.response.levels, np.float64),
                f"{prefix}luminance": np.asarray(self.response.luminance, np.float64)}

    @classmethod
    def from_arrays(cls, arrays: dict, prefix: str = "im_") -> "IntensityMatrix":
        return cls(arrays[f"{prefix}offset"], arrays[f"{prefix}gain"],
                   DisplayResponse(arrays[f"{prefix}levels"], arrays[f"{prefix}luminance"]))


def fit_intensity(levels, images, full_scale: float, min_range: float) -> IntensityMatrix:
    """Fit the IM from flat frames.

    levels: (J,) display code values, J >= 3; images: the camera frame at each level (averaged over
    repeats; a list of (H, W) arrays of any numeric dtype, or one (J, H, W) float32 array, used without
    a copy); full_scale: the raw saturation value; min_range: the smallest useful brightness difference
    between the darkest and brightest flat (camera values); pixels below it are given gain NaN (they
    see no display). Samples at full_scale are left out (saturated).
    Raises ValueError when fewer than 3 distinct levels are given or no pixel responds.
    """
    levels = np.asarray(levels, float)
    if len(np.unique(levels)) < 3:
        raise ValueError("the intensity calibration needs flat frames at 3 or more distinct levels")
    stack = images if isinstance(images, np.ndarray) and images.dtype == np.float32 else \
        np.stack([np.asarray(img, np.float32) for img in images])
    order = np.argsort(levels, kind="stable")
    # mostly saturated: no shape
    order = np.array([i for i in order if float(np.mean(stack[i] < full_scale)) >= 0.5], int)
    if len(order) < 3:
        raise ValueError("fewer than 3 flat levels are below saturation")
    levels = levels[order]
    span = stack[order[-1]] - stack[order[0]]
    good = span >= min_range
    for i in order:
        good &= stack[i] < full_scale
    if good.sum() < 16:
        raise ValueError("no pixel responds to the flat frames (all dark or all saturated)")
    # global shape: median of each pixel's normalised curve (robust to vignetting and gain)
    sub = np.flatnonzero(good.ravel())[:: max(1, int(good.sum()) // 200_000)]
    flat = np.stack([stack[i].ravel()[sub] for i in order])
    norm = (flat - flat[0]) / (flat[-1] - flat[0])
    response = smooth_response(levels, np.median(norm, axis=1))
    # per pixel: offset + gain * Y(L) by least squares over the unsaturated levels
    h, w = span.shape
    offset, gain = np.empty((h, w), np.float32), np.empty((h, w), np.float32)
    from calib.intensity_kernels import fit_pixels
    fit_pixels(stack.reshape(len(stack), -1), order, response(levels).astype(np.float32), np.float32(full_scale),
               np.float32(min_range), offset.reshape(-1), gain.reshape(-1))
    return IntensityMatrix(offset, gain, response)


def smooth_response(levels: np.ndarray, luminance: np.ndarray, samples: int = 256) -> DisplayResponse:
    """A dense monotone response table through measured (level, relative luminance) samples.

    A display's response is close to a power law a + b * (L / L_max) ** gamma: that model is fitted
    first and the remaining (small, smooth) difference interpolated, so a handful of flat levels
    describe a gamma curve to a small fraction of a code value (plain interpolation of a gamma curve
    through 5-9 levels errs by several code values near black).
    """
    from scipy.interpolate import PchipInterpolator
    from scipy.optimize import minimize_scalar
    levels, luminance = np.asarray(levels, float), np.asarray(luminance, float)
    x = levels / levels.max()

    def fit(gamma):
        design = np.stack([np.ones_like(x), x ** gamma], axis=1)
        coef, *_ = np.linalg.lstsq(design, luminance, rcond=None)
        return coef, design @ coef - luminance

    gamma = minimize_scalar(lambda g: float(np.sum(fit(g)[1] ** 2)), bounds=(0.2, 5.0), method="bounded").x
    coef, resid = fit(gamma)
    dense = np.linspace(levels[0], levels[-1], samples)
    xd = dense / levels.max()
    lum = coef[0] + coef[1] * xd ** gamma - PchipInterpolator(levels, resid)(dense)
    lum = np.maximum.accumulate(lum) + np.arange(samples) * 1e-9         # strictly increasing
    return DisplayResponse(dense, lum)

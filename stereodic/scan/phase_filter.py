"""Noise filtering of absolute phase maps in the rectified virtual images (structured light), before
matching: a local quadratic fit, masked so that it never reaches across an edge or a hole.

Filter: at each pixel, the weighted least-squares quadratic a0 + a1 x + a2 y + a3 x^2 + a4 xy + a5 y^2
through the phase of the (2r+1) x (2r+1) window, Gaussian weights w(x) w(y) of `sigma_px` (r = ceil(2.5
sigma)); the filtered phase is a0. With the full window valid this is a fixed convolution (a 2-D
Savitzky-Golay kernel) K(x, y) = w(x) w(y) (alpha + beta (x^2 + y^2)), three separable passes. A fit
of order 2, not a plain average: a plain (or linear-fit) average of a curved surface's phase is biased
by about sigma^2 / R (a sphere of radius R looks smaller by that), a quadratic fit is not.

Mask: a pixel is filtered only if its whole window holds valid pixels and no discontinuity; otherwise
it becomes NaN. A discontinuity is a pair of neighbours whose phase step is not in (0, max_step) along
the row (the direction in which the phase increases) or whose vertical step is >= max_step: occlusion
edges, unwrapping errors, and the mixed pixels on a silhouette, whose phase lies between the two
surfaces'. So the measured region is eroded by r pixels at holes, the border and depth discontinuities.

Noise: white phase noise of standard deviation s becomes `noise_gain(sigma_px)` * s (the root sum of
squares of K); filtered values of neighbouring pixels are correlated over about the window.
"""

from __future__ import annotations

import cv2
import numpy as np

from stereodic.scan.matching import phase_step

TRUNCATE = 2.5          # window radius in units of sigma


def radius(sigma_px: float) -> int:
    """The window radius r (pixels) of the filter of `sigma_px`."""
    return int(np.ceil(TRUNCATE * sigma_px))


def _kernels(sigma_px: float) -> tuple[np.ndarray, np.ndarray, float, float]:
    """1-D factors w(x), x^2 w(x) (x = -r..r) and alpha, beta of K = w w (alpha + beta (x^2 + y^2))."""
    r = radius(sigma_px)
    x = np.arange(-r, r + 1, dtype=np.float64)
    w = np.exp(-x * x / (2 * sigma_px * sigma_px))
    m0, m2, m4 = w.sum(), (x ** 2 * w).sum(), (x ** 4 * w).sum()
    # normal equations of (a0, a3, a5) (the odd terms decouple by symmetry): rows 1, x^2, y^2
    n = np.array([[m0 * m0, m2 * m0, m2 * m0],
                  [m2 * m0, m4 * m0, m2 * m2],
                  [m2 * m0, m2 * m2, m4 * m0]])
    row = np.linalg.inv(n)[0]
    return w, x * x * w, float(row[0]), float(row[1])     # row[1] == row[2] by symmetry


def kernel(sigma_px: float) -> np.ndarray:
    """(2r+1, 2r+1) float64: the filter's weights for a full window (they sum to 1)."""
    w, x2w, alpha, beta = _kernels(sigma_px)
    return alpha * np.outer(w, w) + beta * (np.outer(w, x2w) + np.outer(x2w, w))


def noise_gain(sigma_px: float) -> float:
    """Standard deviation of the filtered phase per unit of white input noise: sqrt(sum K^2)."""
    return float(np.sqrt((kernel(sigma_px) ** 2).sum()))


def row_slope(phase: np.ndarray, lag: int = 1) -> float:
    """The median signed phase step along the rows, per pixel, from pixels `lag` apart (0 if none)."""
    rows = phase[:: max(1, phase.shape[0] // 64)]
    d = (rows[:, lag:] - rows[:, :-lag]) / lag
    d = d[np.isfinite(d)]
    return float(np.median(d)) if d.size else 0.0


def continuous(phase: np.ndarray, max_step: float | None = None, *, plateaus: bool = False) -> np.ndarray:
    """(H, W) bool: valid pixels none of whose valid 4-neighbours makes a discontinuity with them
    (module docstring).
    max_step: default 4 x the median phase step along the rows; plateaus: equal neighbours along a row
    are continuous too (a Gray-code coordinate is constant across each stripe)."""
    phase = np.asarray(phase, np.float32)
    if max_step is None:
        max_step = 4.0 * phase_step(phase)
    sign = -1.0 if row_slope(phase, 16 if plateaus else 1) < 0 else 1.0
    ok = np.isfinite(phase)
    step = sign * np.diff(phase, axis=1)
    vert = np.diff(phase, axis=0)
    rising = step >= 0 if plateaus else step > 0
    bad_h = ok[:, :-1] & ok[:, 1:] & ~(rising & (step < max_step))          # pairs with a NaN are no edge:
    bad_v = ok[:-1] & ok[1:] & ~(np.abs(vert) < max_step)                  # the NaN is masked itself
    ok[:, :-1] &= ~bad_h
    ok[:, 1:] &= ~bad_h
    ok[:-1] &= ~bad_v
    ok[1:] &= ~bad_v
    return ok


def smooth_phase(phase: np.ndarray, *, sigma_px: float, max_step: float | None = None,
                 plateaus: bool = False) -> np.ndarray:
    """An absolute phase map filtered by the masked local quadratic fit (module docstring).

    Parameters
    ----------
    phase : (H, W) float32
        The phase (e.g. projector pixels) in a rectified virtual image, NaN where not measured.
    sigma_px : float
        The Gaussian weights' sigma, virtual pixels; <= 0 returns a copy of the phase unchanged.
    max_step : float, optional
        The largest phase step between neighbours still continuous, phase units; None: 4 x the median
        step along the rows.
    plateaus : bool
        Equal neighbours along a row are continuous (a Gray-code coordinate's stairs, which the fit
        turns into a smooth ramp).

    Returns
    -------
    smoothed : (H, W) float32
        The filtered phase; NaN where the window is not whole and continuous.
    """
    phase = np.asarray(phase, np.float32)
    if sigma_px <= 0:
        return phase.copy()
    r = radius(sigma_px)
    window = np.ones((2 * r + 1, 2 * r + 1), np.uint8)
    core = cv2.erode(continuous(phase, max_step, plateaus=plateaus).view(np.uint8), window,
                     borderType=cv2.BORDER_CONSTANT, borderValue=0).view(bool)
    # filter the phase minus a ramp c + s x (the filter reproduces a ramp exactly, so it is added back
    # unfiltered): small numbers keep float32 sums exact to ~1e-5 phase units
    x = np.arange(phase.shape[1], dtype=np.float64)
    slope = row_slope(phase, 16 if plateaus else 1)
    offset = float(np.nanmedian(phase - slope * x)) if np.isfinite(phase).any() else 0.0
    ramp = (offset + slope * x).astype(np.float32)
    out = convolve(np.where(np.isfinite(phase), phase - ramp, np.float32(0)), sigma_px) + ramp
    out[~core] = np.nan
    return out


def convolve(values: np.ndarray, sigma_px: float) -> np.ndarray:
    """(H, W) float32: the full-window filter K * values (three separable passes; zero outside the
    image). The linear part of `smooth_phase`, also for pushing noise fields through it."""
    w, x2w, alpha, beta = _kernels(sigma_px)
    w, x2w = w.astype(np.float32), x2w.astype(np.float32)
    values = np.asarray(values, np.float32)
    border = cv2.BORDER_CONSTANT
    a = cv2.sepFilter2D(values, cv2.CV_32F, w, w, borderType=border)
    b = cv2.sepFilter2D(values, cv2.CV_32F, x2w, w, borderType=border)
    b += cv2.sepFilter2D(values, cv2.CV_32F, w, x2w, borderType=border)
    return np.float32(alpha) * a + np.float32(beta) * b

"""1-D matching of a rectified pair by equal phase along each row (structured light, seed "Virtual stereo
camera": rows of the rectified pair are epipolar lines, so a match is a search along one row).

Input: two (H, W) float32 maps of an absolute phase that increases along the rows (e.g. the projector
column, in projector pixels), NaN where not measured. For each left pixel x the match is the sub-pixel
position x_r in the same row of the right map where the right phase, interpolated linearly between two
neighbouring valid pixels, equals the left pixel's phase.

Checks, each making a left pixel unmatched (NaN):
- monotonicity: only right intervals whose phase step is in (0, max_step) are used (a step <= 0 or a
  jump is an occlusion edge, noise on a flat phase or an unwrapping error), and the left pixel itself
  must lie on such a step with a neighbour;
- slope: the right interval's phase step must be within a factor `max_ratio` of the left pixel's local
  step (the surface cannot foreshorten so differently in the two views);
- left-right consistency: matching the right map to the left one, the back-match at x_r (interpolated
  linearly) must return to x within `tolerance_px`.

The sweep per row walks a pointer over the right row's valid intervals, forwards or backwards from the
previous match: O(W) per row when the phase is monotonic (a merge), still correct when the row holds
several surfaces. numba, rows in parallel.
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, parallel=True)
def _sweep(src, dst, max_step, max_ratio, out):  # pragma: no cover - numba kernel
    h, w = src.shape
    for r in numba.prange(h):
        lo = np.empty(w, np.float32)
        hi = np.empty(w, np.float32)
        ks = np.empty(w, np.int64)
        n = 0
        for k in range(w - 1):
            step = dst[r, k + 1] - dst[r, k]
            if step > 0 and step < max_step:
                lo[n] = dst[r, k]
                hi[n] = dst[r, k + 1]
                ks[n] = k
                n += 1
        j = 0
        for x in range(w):
            out[r, x] = np.nan
            p = src[r, x]
            if n == 0 or not (p == p):
                continue
            s = np.float32(np.inf)          # the left pixel's local phase step (smallest good one)
            if x + 1 < w:
                d = src[r, x + 1] - p
                if d > 0 and d < max_step:
                    s = d
            if x > 0:
                d = p - src[r, x - 1]
                if d > 0 and d < max_step and d < s:
                    s = d
            if s == np.inf:
                continue
            if hi[j] <= p:
                while j < n - 1 and hi[j] <= p:
                    j += 1
            elif lo[j] > p:
                while j > 0 and lo[j] > p:
                    j -= 1
            if lo[j] <= p < hi[j]:
                step = hi[j] - lo[j]
                if step <= max_ratio * s and s <= max_ratio * step:
                    out[r, x] = ks[j] + (p - lo[j]) / step


@numba.njit(cache=True, parallel=True)
def _check_back(forward, back, tolerance, out):  # pragma: no cover - numba kernel
    h, w = forward.shape
    for r in numba.prange(h):
        for x in range(w):
            xr = forward[r, x]
            out[r, x] = np.nan
            if not (xr == xr):
                continue
            k = min(int(np.floor(xr)), w - 2)
            f = xr - k
            b = back[r, k] * (1 - f) + back[r, k + 1] * f
            if abs(b - x) <= tolerance:
                out[r, x] = xr


def phase_step(phase: np.ndarray) -> float:
    """The median absolute phase step between row neighbours (phase units per pixel), 0 if none."""
    d = np.diff(phase[:: max(1, phase.shape[0] // 64)], axis=1)
    d = np.abs(d[np.isfinite(d)])
    return float(np.median(d)) if d.size else 0.0


def match_rows(left: np.ndarray, right: np.ndarray, *, max_step: float | None = None, max_ratio: float = 4.0,
               tolerance_px: float = 0.5, check: bool = True) -> np.ndarray:
    """Match a rectified pair's phase maps along the rows (module docstring).

    Parameters
    ----------
    left, right : (H, W) float32
        Absolute phase maps of the rectified pair (e.g. the projector column, projector pixels), NaN
        where not measured; they may decrease along the rows (both are then negated).
    max_step : float, optional
        The largest phase step between neighbouring pixels still taken as continuous, phase units;
        None: 4 x the median step.
    max_ratio : float
        The largest ratio of the right interval's phase step to the left pixel's.
    tolerance_px : float
        Left-right consistency: the back-match must return within this, pixels.
    check : bool
        Do the left-right consistency check.

    Returns
    -------
    x_right : (H, W) float32
        The sub-pixel column in `right` (same row) matching each left pixel, virtual pixels; NaN where
        unmatched.
    """
    left = np.ascontiguousarray(left, np.float32)
    right = np.ascontiguousarray(right, np.float32)
    if left.shape != right.shape or left.ndim != 2:
        raise ValueError(f"phase maps must be two arrays of one 2-D shape, got {left.shape} and {right.shape}")
    d = np.diff(left[:: max(1, left.shape[0] // 64)], axis=1)
    d = d[np.isfinite(d)]
    if d.size and np.median(d) < 0:
        left, right = -left, -right
    if max_step is None:
        max_step = 4.0 * phase_step(left)
    forward = np.empty(left.shape, np.float32)
    if max_step <= 0:
        forward.fill(np.nan)
        return forward
    _sweep(left, right, np.float32(max_step), np.float32(max_ratio), forward)
    if not check:
        return forward
    back = np.empty(left.shape, np.float32)
    _sweep(right, left, np.float32(max_step), np.float32(max_ratio), back)
    out = np.empty(left.shape, np.float32)
    _check_back(forward, back, np.float32(tolerance_px), out)
    return out

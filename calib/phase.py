"""Phase decoding: wrapped phase from N known shifts, per-pixel quality, temporal unwrapping.

Each frame of a fringe set is I_k = A + B cos(theta - delta_k) + noise = A + b cos(delta_k) + c sin(delta_k)
with b = B cos(theta), c = B sin(theta). `FringeSums` accumulates, frame by frame, the sums that the
least-squares solution for (A, b, c) needs (sum I, sum I cos delta, sum I sin delta, sum I^2), so a set is
never held in memory and repeated frames (tip 3.3, averaging) simply add rows. For N equally spaced shifts
theta = atan2(sum I sin delta, sum I cos delta) (formula (4) for N = 3); other known shifts are solved
exactly. The phase noise is sigma_theta = sqrt(2/N) * sigma_I / B.

`unwrap_temporal` turns the wrapped phases of several periods into the absolute display coordinate
(display pixels), longest period first; the longest must cover the display so that its phase is absolute.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# quality flags (bits of the per-pixel `quality` array; 0 = good)
DARK, SATURATED, LOW_MODULATION, UNWRAP, NO_DATA = 1, 2, 4, 8, 16
QUALITY_NAMES = {DARK: "too dark", SATURATED: "saturated", LOW_MODULATION: "low modulation",
                 UNWRAP: "unwrapping inconsistent", NO_DATA: "not decoded"}


@dataclass
class WrappedPhase:
    """One decoded fringe set. phase: wrapped, radians in (-pi, pi] (float32, H x W); offset: A and
    modulation: B, in the units of the frames given (float32); noise: per-pixel sigma_I estimated from the
    fit residual (float32; NaN when the set has no redundancy, i.e. 3 frames); quality: flag bits."""

    phase: np.ndarray
    offset: np.ndarray
    modulation: np.ndarray
    noise: np.ndarray
    quality: np.ndarray
    frames: int


class FringeSums:
    """Accumulate the frames of one fringe set (one axis, one period, one stage position).

    add(image, shift_rad, raw): `image` is the frame in the decoding domain (float32, e.g. linearised by
    the intensity matrix), `raw` the camera's values (for the saturation and darkness checks).
    """

    def __init__(self, shape: tuple[int, int]):
        self.sums = np.zeros((4,) + tuple(shape), np.float32)   # I, I cos d, I sin d, I^2
        self.normal = np.zeros((3, 3))
        self.raw_max = np.zeros(shape, np.float32)
        self.raw_min = np.full(shape, np.inf, np.float32)
        self.frames = 0

    def add(self, image: np.ndarray, shift_rad: float, raw: np.ndarray | None = None) -> None:
        c, s = np.cos(shift_rad), np.sin(shift_rad)
        x = np.array([1.0, c, s])
        self.normal += np.outer(x, x)
        img = np.asarray(image, np.float32)
        self.sums[0] += img
        self.sums[1] += np.float32(c) * img
        self.sums[2] += np.float32(s) * img
        self.sums[3] += img * img
        r = img if raw is None else raw
        np.maximum(self.raw_max, r, out=self.raw_max)
        np.minimum(self.raw_min, r, out=self.raw_min)
        self.frames += 1

    def solve(self, full_scale: float, dark_level: float, min_modulation: float) -> WrappedPhase:
        """The wrapped phase and its quality.

        full_scale: the raw saturation value (a frame reaching it marks the pixel SATURATED);
        dark_level: raw values whose brightest frame stays below it are DARK; min_modulation: B below it
        (decoding units) is LOW_MODULATION. Raises ValueError if the shifts do not determine the phase.
        """
        if np.linalg.matrix_rank(self.normal) < 3:
            raise ValueError("the phase shifts of this fringe set do not determine the phase "
                             "(need 3 or more distinct shifts)")
        inv = np.linalg.inv(self.normal).astype(np.float32)
        s = self.sums
        a = inv[0, 0] * s[0] + inv[0, 1] * s[1] + inv[0, 2] * s[2]
        b = inv[1, 0] * s[0] + inv[1, 1] * s[1] + inv[1, 2] * s[2]
        c = inv[2, 0] * s[0] + inv[2, 1] * s[1] + inv[2, 2] * s[2]
        phase = np.arctan2(c, b)
        modulation = np.hypot(b, c)
        dof = self.frames - 3
        if dof > 0:
            rss = s[3] - (a * s[0] + b * s[1] + c * s[2])
            noise = np.sqrt(np.maximum(rss, 0) / dof)
        else:
            noise = np.full(a.shape, np.nan, np.float32)
        quality = np.zeros(a.shape, np.uint8)
        quality[self.raw_max < dark_level] |= DARK
        quality[self.raw_max >= full_scale] |= SATURATED
        quality[~(modulation >= min_modulation)] |= LOW_MODULATION
        return WrappedPhase(phase.astype(np.float32), a.astype(np.float32), modulation.astype(np.float32),
                            noise.astype(np.float32), quality, self.frames)


class WaveformCorrection:
    """Removes the periodic phase error of a fringe whose emitted waveform is not a pure cosine.

    A display with a nonlinear response (gamma) turns a cosine of code values into a waveform F(phi) with
    harmonics; N-step decoding of F errs by a periodic function of the phase (for N = 3 mostly at 3x the
    fringe frequency). That error does not depend on the pixel's offset or modulation, only on F and the
    shifts, so it is computed once by decoding F itself at every phase and inverted.

    waveform: (K,) values of F at phi = 2*pi*j/K, j = 0..K-1 (one period, any scale and offset);
    shifts: the shift (radians) of each frame of the set, repeats included.
    """

    def __init__(self, waveform: np.ndarray, shifts):
        k = len(waveform)
        phi = 2 * np.pi * np.arange(k) / k
        shifts = np.asarray(shifts, float)
        x = np.stack([np.ones_like(shifts), np.cos(shifts), np.sin(shifts)], axis=1)
        # frames of the pure waveform: F(phi - delta) by periodic interpolation
        idx = (phi[:, None] - shifts[None, :]) / (2 * np.pi) * k
        lo = np.floor(idx).astype(int)
        f = idx - lo
        frames = (1 - f) * waveform[lo % k] + f * waveform[(lo + 1) % k]
        a_b_c = np.linalg.solve(x.T @ x, x.T @ frames.T)
        decoded = np.arctan2(a_b_c[2], a_b_c[1])
        err = np.angle(np.exp(1j * (decoded - phi)))
        self.max_error = float(np.abs(err).max())
        est = phi + err                                  # decoded phase, unwrapped, increasing
        if np.any(np.diff(est) <= 0):
            raise ValueError("the fringe waveform is too distorted to be decoded with these shifts")
        # the error as a function of the decoded phase, on a uniform grid over one period
        grid = 2 * np.pi * np.arange(k + 1) / k - np.pi
        x = np.concatenate([est[-1:] - 2 * np.pi, est, est[:1] + 2 * np.pi])
        y = np.concatenate([err[-1:], err, err[:1]])
        self._table = np.interp(np.mod(grid - x[0], 2 * np.pi) + x[0], x, y).astype(np.float32)
        self._scale = np.float32(k / (2 * np.pi))

    def __call__(self, phase: np.ndarray) -> np.ndarray:
        """The true phase (radians, (-pi, pi]) of decoded phases (float32)."""
        t = (np.asarray(phase, np.float32) + np.float32(np.pi)) * self._scale
        i = np.clip(t.astype(np.int32), 0, len(self._table) - 2)
        t -= i
        lo = self._table[i]
        out = phase - (lo + t * (self._table[i + 1] - lo))
        out[out > np.pi] -= np.float32(2 * np.pi)
        out[out <= -np.pi] += np.float32(2 * np.pi)
        return out


def phase_sigma(steps: int, sigma_i: np.ndarray | float, modulation: np.ndarray | float) -> np.ndarray:
    """Phase noise (radians) of an N-step set: sqrt(2/N) * sigma_I / B."""
    return np.sqrt(2.0 / steps) * np.asarray(sigma_i) / np.asarray(modulation)


@dataclass
class Unwrapped:
    """Absolute display coordinate along one axis. coord: display pixels (float64, H x W);
    consistent: False where a shorter period disagreed with the longer one by more than a quarter period;
    mismatch_sigma: per period ratio step, the robust spread of that disagreement (in periods of the
    shorter fringe), the measured safety margin of the period ratio."""

    coord: np.ndarray
    consistent: np.ndarray
    mismatch_sigma: list[float]


def unwrap_temporal(periods: list[float], phases: list[np.ndarray], extent_px: int,
                    valid: np.ndarray | None = None, tolerance: float = 0.25) -> Unwrapped:
    """Hierarchical temporal unwrapping to the absolute display coordinate.

    periods: display pixels, in any order; phases: the wrapped phase (radians) of each period; extent_px:
    the display's size along the fringe axis. The longest period must be >= extent_px (its phase is
    then absolute; pixels within 5 sigma of its wrap, outside the display when it is longer than the
    display, are marked inconsistent); each shorter one is unwrapped with the coordinate of the one before. A pixel whose
    fractional disagreement exceeds `tolerance` (in periods) is marked inconsistent. The result keeps the
    precision of the shortest period.
    """
    order = np.argsort(periods)[::-1]
    periods = [float(periods[i]) for i in order]
    phases = [phases[i] for i in order]
    if periods[0] < extent_px:
        raise ValueError(f"the longest period ({periods[0]:g} px) is shorter than the display "
                         f"({extent_px} px): its phase is ambiguous")
    two_pi = 2 * np.pi
    p0 = periods[0]
    coord = np.mod(phases[0].astype(np.float64), two_pi) * (p0 / two_pi)
    # the unused part of the longest period lies beyond the display: fold it around its middle
    cut = (extent_px - 1) / 2 + p0 / 2
    coord[coord >= cut] -= p0
    first = coord.copy()
    consistent = np.ones(coord.shape, bool)
    mismatch = []
    for period, ph in zip(periods[1:], phases[1:]):
        cycles = coord / period - ph.astype(np.float64) / two_pi
        k = np.rint(cycles)
        frac = cycles - k
        consistent &= np.abs(frac) <= tolerance
        sel = consistent if valid is None else consistent & valid
        f = frac[sel][:: max(1, int(sel.sum()) // 200_000)]
        mismatch.append(float(1.4826 * np.median(np.abs(f - np.median(f)))) if f.size else float("nan"))
        coord = (ph.astype(np.float64) / two_pi + k) * period
    if len(periods) > 1 and np.isfinite(mismatch[0]):
        # where the longest period's phase is near its wrap, noise can move a pixel by a whole period
        # of it, which the shorter periods (often its divisors) cannot see: leave a 5-sigma margin
        margin = 5 * mismatch[0] * periods[1]
        near = np.minimum(np.abs(first - cut), np.abs(first - (cut - p0)))
        consistent &= near > margin
    return Unwrapped(coord, consistent, mismatch)

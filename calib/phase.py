"""Phase decoding: wrapped phase from N known shifts, per-pixel quality, temporal unwrapping.

Each frame of a fringe set is I_k = A + B cos(theta - delta_k) + noise = A + b cos(delta_k) + c sin(delta_k)
with b = B cos(theta), c = B sin(theta). `FringeSums` accumulates, frame by frame, the sums that the
least-squares solution for (A, b, c) needs (sum I, sum I cos delta, sum I sin delta, sum I^2), so a set is
never held in memory and repeated frames (tip 3.3, averaging) simply add rows. For N equally spaced shifts
theta = atan2(sum I sin delta, sum I cos delta) (formula (4) for N = 3); other known shifts are solved
exactly. The phase noise is sigma_theta = sqrt(2/N) * sigma_I / B.

`decode_frames` decodes a set whose frames are all in memory in one pass (the sums stay per row, in
cache), the waveform correction included.

`unwrap_temporal` turns the wrapped phases of several periods into the absolute display coordinate
(display pixels), longest period first; the longest must cover the display so that its phase is absolute.

The per-pixel work runs in numba kernels over the flattened arrays (rows in parallel): a frame is read
once, in float32, without temporaries (a 5 MP frame in ~10 ms); the phase comes from a polynomial
atan2 (2e-7 rad, about one float32 step near pi).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
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

    add(image, shift_rad, raw): `image` is the frame in the decoding domain (the camera's values, or
    e.g. linearised by the intensity matrix), `raw` the camera's values (for the saturation and darkness
    checks; default `image`). A per-pixel affine linearisation y = (I - offset) / gain (the intensity
    matrix's `luminance`) need not be applied to each frame: pass it to `solve` instead, which gives
    the same result (the least-squares fit is linear in the frames) without reading two more arrays
    per frame. squares=False leaves out the sum of I^2 (25 % less memory traffic per frame) when the
    set will have 3 frames, whose fit has no redundancy to estimate the noise from.
    """

    def __init__(self, shape: tuple[int, int], squares: bool = True):
        self.shape = tuple(shape)
        # I, I cos d, I sin d and, for the noise estimate (N > 3 frames), I^2
        self.sums = np.zeros((4 if squares else 3,) + self.shape, np.float32)
        self.normal = np.zeros((3, 3))
        self.raw_max: np.ndarray | None = None        # in the raw frames' dtype
        self.frames = 0

    def add(self, image: np.ndarray, shift_rad: float, raw: np.ndarray | None = None) -> None:
        img = np.asarray(image)
        if img.dtype.kind not in "fu":
            img = img.astype(np.float32)
        raw = img if raw is None else np.asarray(raw)
        if img.shape != self.shape or raw.shape != self.shape:
            raise ValueError(f"frame of shape {img.shape} added to fringe sums of shape {self.shape}")
        if self.raw_max is None:
            self.raw_max = np.zeros(self.shape, raw.dtype)
        c, s = np.cos(shift_rad), np.sin(shift_rad)
        x = np.array([1.0, c, s])
        self.normal += np.outer(x, x)
        _accumulate(_flat(img), _flat(raw).astype(self.raw_max.dtype, copy=False), np.float32(c), np.float32(s),
                    self.sums.reshape(len(self.sums), -1), self.raw_max.reshape(-1))
        self.frames += 1

    def solve(self, full_scale: float, dark_level: float, min_modulation: float,
              linearise: tuple[np.ndarray, np.ndarray] | None = None) -> WrappedPhase:
        """The wrapped phase and its quality.

        full_scale: the raw saturation value (a frame reaching it marks the pixel SATURATED);
        dark_level: raw values whose brightest frame stays below it are DARK; min_modulation: B below it
        (decoding units) is LOW_MODULATION; linearise: (offset, gain) (H, W) of y = (I - offset) / gain,
        the decoding domain of offset, modulation and noise (the phase does not depend on it; NaN
        where the gain is NaN). Raises ValueError if the shifts do not determine the phase.
        """
        if np.linalg.matrix_rank(self.normal) < 3:
            raise ValueError("the phase shifts of this fringe set do not determine the phase "
                             "(need 3 or more distinct shifts)")
        inv = np.linalg.inv(self.normal).astype(np.float32)
        phase, offset, modulation, noise = (np.empty(self.shape, np.float32) for _ in range(4))
        quality = np.empty(self.shape, np.uint8)
        lin_offset, lin_gain = (_EMPTY, _EMPTY) if linearise is None else \
            (_flat(np.asarray(linearise[0], np.float32)), _flat(np.asarray(linearise[1], np.float32)))
        dof = self.frames - 3 if len(self.sums) == 4 else 0
        _solve(self.sums.reshape(len(self.sums), -1), inv, dof, np.float32(full_scale), np.float32(dark_level),
               np.float32(min_modulation), self.raw_max.reshape(-1).astype(np.float32), lin_offset, lin_gain,
               *(o.reshape(-1) for o in (phase, offset, modulation, noise, quality)))
        return WrappedPhase(phase, offset, modulation, noise, quality, self.frames)


_EMPTY = np.zeros(0, np.float32)


def _flat(a: np.ndarray) -> np.ndarray:
    """A 1-D view (a copy only if `a` is not contiguous)."""
    return np.ascontiguousarray(a).reshape(-1)


@numba.njit(cache=True, parallel=True)
def _accumulate(values, raw, c, s, sums, raw_max):  # pragma: no cover - compiled
    squares = sums.shape[0] == 4
    for i in numba.prange(values.size):
        y = np.float32(values[i])
        sums[0, i] += y
        sums[1, i] += c * y
        sums[2, i] += s * y
        if squares:
            sums[3, i] += y * y
        if raw[i] > raw_max[i]:
            raw_max[i] = raw[i]


@numba.njit(cache=True, inline="always")
def _atan2(y, x):  # pragma: no cover - compiled
    """atan2 to 2e-7 rad (Abramowitz & Stegun 4.4.49 on [0, 1], then the octant), branch-free enough to
    vectorise: ~40 times faster than libm's."""
    ax, ay = abs(x), abs(y)
    big = max(ax, ay)
    if big == 0:
        return np.float32(0)
    a = min(ax, ay) / big
    s = a * a
    r = a * (0.9999993329 + s * (-0.3332985605 + s * (0.1994653599 + s * (-0.1390853351 + s * (
        0.0964200441 + s * (-0.0559098861 + s * (0.0218612288 + s * -0.0040540580)))))))
    if ay > ax:
        r = np.pi / 2 - r
    if x < 0:
        r = np.pi - r
    if y < 0:
        r = -r
    return r


@numba.njit(cache=True, inline="always")
def _pixel(s0, s1, s2, s3, inv, dof, lin_offset, lin_gain, raw_max, full, dark, min_mod):  # pragma: no cover
    """One pixel from its sums (I, I cos d, I sin d, I^2): least-squares (A, b, c) of A + b cos d + c sin d,
    y = (I - lin_offset) / lin_gain applied to them -> (phase, offset, modulation, noise, quality flags)."""
    a = inv[0, 0] * s0 + inv[0, 1] * s1 + inv[0, 2] * s2
    b = inv[1, 0] * s0 + inv[1, 1] * s1 + inv[1, 2] * s2
    c = inv[2, 0] * s0 + inv[2, 1] * s1 + inv[2, 2] * s2
    if dof > 0:
        rss = (s3 - (a * s0 + b * s1 + c * s2)) / (lin_gain * lin_gain)
        noise = np.sqrt(max(rss, np.float32(0)) / dof)
    else:
        noise = np.float32(np.nan)
    a = (a - lin_offset) / lin_gain
    b /= lin_gain
    c /= lin_gain
    m = np.sqrt(b * b + c * c)
    q = 0
    if raw_max < dark:
        q |= DARK
    if raw_max >= full:
        q |= SATURATED
    if not (m >= min_mod):
        q |= LOW_MODULATION
    return _atan2(c, b), a, m, noise, q


@numba.njit(cache=True, parallel=True)
def _solve(sums, inv, dof, full, dark, min_mod, raw_max, lin_offset, lin_gain, phase, offset, modulation, noise,
           quality):  # pragma: no cover - compiled
    """`_pixel` of every pixel of the accumulated sums."""
    linearise = lin_offset.size > 0
    zero, one = np.float32(0), np.float32(1)
    for i in numba.prange(offset.size):
        s3 = sums[3, i] if dof > 0 else zero
        o, g = (lin_offset[i], lin_gain[i]) if linearise else (zero, one)
        phase[i], offset[i], modulation[i], noise[i], quality[i] = _pixel(
            sums[0, i], sums[1, i], sums[2, i], s3, inv, dof, o, g, raw_max[i], full, dark, min_mod)


def decode_frames(frames: list[np.ndarray], shifts, full_scale: float, dark_level: float, min_modulation: float,
                  correction: WaveformCorrection | None = None) -> WrappedPhase:
    """One fringe set whose frames are in memory, in one pass: `FringeSums` of `frames` (N of (H, W), the
    camera's raw values) at `shifts` (radians), solved (full_scale, dark_level, min_modulation as in
    `FringeSums.solve`; the noise for N > 3), then `correction` (the display's `WaveformCorrection`, or
    None) applied to the phase. ValueError if the shifts do not determine the phase."""
    shifts = np.asarray(shifts, np.float64)
    x = np.stack([np.ones_like(shifts), np.cos(shifts), np.sin(shifts)], axis=1)
    if np.linalg.matrix_rank(x) < 3:
        raise ValueError("the phase shifts of this fringe set do not determine the phase "
                         "(need 3 or more distinct shifts)")
    inv = np.linalg.inv(x.T @ x).astype(np.float32)
    stack = np.stack(frames)
    shape = stack.shape[1:]
    out = WrappedPhase(*(np.empty(shape, np.float32) for _ in range(4)), np.empty(shape, np.uint8), len(frames))
    table, scale = (_EMPTY, np.float32(0)) if correction is None else (correction._table, correction._scale)
    _decode(stack, x[:, 1].astype(np.float32), x[:, 2].astype(np.float32), inv, len(frames) - 3,
            np.float32(full_scale), np.float32(dark_level), np.float32(min_modulation), table, scale, out.phase,
            out.offset, out.modulation, out.noise, out.quality)
    return out


@numba.njit(cache=True, parallel=True)
def _decode(stack, cos, sin, inv, dof, full, dark, min_mod, table, scale, phase, offset, modulation, noise,
            quality):  # pragma: no cover - compiled
    """Per row: the sums of `FringeSums.add` over the N frames, `_pixel`, then `_undistort` (if a table)."""
    n, h, w = stack.shape
    zero, one = np.float32(0), np.float32(1)
    for r in numba.prange(h):
        s0, s1, s2 = np.zeros(w, np.float32), np.zeros(w, np.float32), np.zeros(w, np.float32)
        s3, hi = np.zeros(w, np.float32), np.zeros(w, np.float32)
        for k in range(n):
            c, s = cos[k], sin[k]
            for x in range(w):
                v = np.float32(stack[k, r, x])
                s0[x] += v
                s1[x] += c * v
                s2[x] += s * v
                if dof > 0:
                    s3[x] += v * v
                hi[x] = max(hi[x], v)
        for x in range(w):
            ph, offset[r, x], modulation[r, x], noise[r, x], quality[r, x] = _pixel(
                s0[x], s1[x], s2[x], s3[x], inv, dof, zero, one, hi[x], full, dark, min_mod)
            phase[r, x] = _undistort(ph, table, scale) if table.size > 0 else ph


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
        phase = np.asarray(phase, np.float32)
        out = np.empty_like(phase)
        _correct(_flat(phase), self._table, self._scale, out.reshape(-1))
        return out


@numba.njit(cache=True, parallel=True)
def _correct(phase, table, scale, out):  # pragma: no cover - compiled
    for i in numba.prange(phase.size):
        out[i] = _undistort(phase[i], table, scale)


@numba.njit(cache=True, inline="always")
def _undistort(phase, table, scale):  # pragma: no cover - compiled
    """The true phase (radians, (-pi, pi]) of a decoded one: minus the tabulated error, linear between nodes."""
    pi = np.float32(np.pi)
    two_pi = np.float32(2 * np.pi)
    t = (phase + pi) * scale
    j = min(max(int(t), 0), table.size - 2)
    f = t - j
    v = phase - (table[j] + f * (table[j + 1] - table[j]))
    if v > pi:
        v -= two_pi
    elif v <= -pi:
        v += two_pi
    return v


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
    per = np.array([float(periods[i]) for i in order])
    if per[0] < extent_px:
        raise ValueError(f"the longest period ({per[0]:g} px) is shorter than the display "
                         f"({extent_px} px): its phase is ambiguous")
    shape = np.shape(phases[0])
    dtype = np.result_type(np.float32, *(np.asarray(ph).dtype for ph in phases))
    stack = np.stack([_flat(np.asarray(phases[i], dtype)) for i in order])
    n = stack.shape[1]
    # the unused part of the longest period lies beyond the display: fold it around its middle
    cut = (extent_px - 1) / 2 + per[0] / 2
    coord, near = np.empty(n), np.empty(n, np.float32)
    passed = np.empty(n, np.uint8)
    frac = np.empty((max(len(per) - 1, 1), n), np.float32)
    _unwrap(stack, per, cut, tolerance, coord, near, passed, frac)
    ok = None if valid is None else _flat(np.asarray(valid, bool))
    mismatch = []
    for i in range(len(per) - 1):
        sel = passed > i if ok is None else (passed > i) & ok
        f = frac[i][sel]
        f = f[:: max(1, f.size // 200_000)].astype(np.float64)
        mismatch.append(float(1.4826 * np.median(np.abs(f - np.median(f)))) if f.size else float("nan"))
    consistent = passed == len(per) - 1
    if len(per) > 1 and np.isfinite(mismatch[0]):
        # where the longest period's phase is near its wrap, noise can move a pixel by a whole period
        # of it, which the shorter periods (often its divisors) cannot see: leave a 5-sigma margin
        consistent &= near > 5 * mismatch[0] * per[1]
    return Unwrapped(coord.reshape(shape), consistent.reshape(shape), mismatch)


@numba.njit(cache=True, parallel=True)
def _unwrap(phases, periods, cut, tolerance, coord, near, passed, frac):  # pragma: no cover - compiled
    """Per pixel: the coordinate (float64 display px), the distance of the longest period's coordinate
    from its wrap, how many shorter periods agreed before the first disagreement, and each step's
    fractional disagreement (periods)."""
    m = phases.shape[0]
    two_pi = 2 * np.pi
    p0 = periods[0]
    for i in numba.prange(phases.shape[1]):
        t = np.float64(phases[0, i]) / two_pi
        c = (t - np.floor(t)) * p0
        if c >= cut:
            c -= p0
        near[i] = min(abs(c - cut), abs(c - (cut - p0)))
        ok = 0
        failed = False
        for k in range(1, m):
            ph = np.float64(phases[k, i]) / two_pi
            cycles = c / periods[k] - ph
            j = np.rint(cycles)
            fr = cycles - j
            frac[k - 1, i] = fr
            if not failed and abs(fr) <= tolerance:
                ok += 1
            else:
                failed = True
            c = (ph + j) * periods[k]
        passed[i] = ok
        coord[i] = c

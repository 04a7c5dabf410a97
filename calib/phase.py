"""Phase decoding: wrapped phase from N known shifts, per-pixel quality, temporal unwrapping.

Each frame of a fringe set is I_k = A + B cos(theta - delta_k) + noise = A + b cos(delta_k) + c sin(delta_k)
with b = B cos(theta), c = B sin(theta). `FringeSums` accumulates, frame by frame, the sums that the
least-squares solution for (A, b, c) needs (sum I, sum I cos delta, sum I sin delta, sum I^2), so a set is
never held in memory and repeated frames (tip 3.3, averaging) simply add rows. For N equally spaced shifts
theta = atan2(sum I sin delta, sum I cos delta) (formula (4) for N = 3); other known shifts are solved
exactly. The phase noise is sigma_theta = sqrt(2/N) * sigma_I / B.

Clipped samples: a frame value at the sensor's full scale (or at 0) says only that the light was at
least (or at most) that much, so it carries no phase. Given the full scale, `FringeSums` records per
pixel which frames were clipped (a bit mask, no more arrays in the frame loop) and `solve` removes
them from that pixel's normal equations and sums: the pixel is solved exactly from its unclipped
samples (known shifts, unknown offset and amplitude) where at least three remain that determine the
phase, and flagged SATURATED otherwise. The display-response correction depends on the shifts used,
so such pixels get the correction of their own subset (`correct_phase`).

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
DARK, SATURATED, LOW_MODULATION, UNWRAP, NO_DATA, EDGE, UNDECIDED = 1, 2, 4, 8, 16, 32, 64
QUALITY_NAMES = {DARK: "too dark", SATURATED: "saturated", LOW_MODULATION: "low modulation",
                 UNWRAP: "unwrapping inconsistent", NO_DATA: "not decoded", EDGE: "display edge",
                 UNDECIDED: "Gray-code bit undecided"}


@dataclass
class WrappedPhase:
    """One decoded fringe set. phase: wrapped, radians in (-pi, pi] (float32, H x W); offset: A and
    modulation: B, in the units of the frames given (float32); noise: per-pixel sigma_I estimated from the
    fit residual (float32; NaN when the pixel's fit has no redundancy, e.g. 3 frames); quality: flag
    bits; clipped: (K, H, W) uint64 per-pixel bit masks of the frames left out as clipped (bit j of
    word k: frame 64 k + j), or None where clipping was not tracked; raw_modulation: B in the raw
    frames' units, before any linearisation (float32; None unless asked for)."""

    phase: np.ndarray
    offset: np.ndarray
    modulation: np.ndarray
    noise: np.ndarray
    quality: np.ndarray
    frames: int
    clipped: np.ndarray | None = None
    raw_modulation: np.ndarray | None = None


class FringeSums:
    """Accumulate the frames of one fringe set (one axis, one period, one stage position).

    add(image, shift_rad, raw): `image` is the frame in the decoding domain (the camera's values, or
    e.g. linearised by the intensity matrix), `raw` the camera's values (for the saturation and darkness
    checks; default `image`). A per-pixel affine linearisation y = (I - offset) / gain (the intensity
    matrix's `luminance`) need not be applied to each frame: pass it to `solve` instead, which gives
    the same result (the least-squares fit is linear in the frames) without reading two more arrays
    per frame. squares=False leaves out the sum of I^2 (25 % less memory traffic per frame) when the
    set will have 3 frames, whose fit has no redundancy to estimate the noise from.
    full_scale: the raw value at which the sensor clips; given, each pixel's clipped samples (raw at
    full_scale or at 0) are recorded and left out of its fit (module docstring; `image` must then be
    the raw frame itself); None, a pixel reaching `solve`'s full_scale in any frame is SATURATED.
    """

    def __init__(self, shape: tuple[int, int], squares: bool = True, full_scale: float | None = None):
        self.shape = tuple(shape)
        # I, I cos d, I sin d and, for the noise estimate (N > 3 frames), I^2
        self.sums = np.zeros((4 if squares else 3,) + self.shape, np.float32)
        self.normal = np.zeros((3, 3))
        self.raw_max: np.ndarray | None = None        # in the raw frames' dtype
        self.frames = 0
        self.full_scale = full_scale
        self.shifts: list[float] = []
        # per pixel, bit masks of the clipped frames and of those clipped at full scale (64 frames a word;
        # zero pages until a pixel clips)
        self.clip = np.zeros((0,) + self.shape, np.uint64)
        self.high = np.zeros((0,) + self.shape, np.uint64)

    def add(self, image: np.ndarray, shift_rad: float, raw: np.ndarray | None = None) -> None:
        img = np.asarray(image)
        if img.dtype.kind not in "fu":
            img = img.astype(np.float32)
        if self.full_scale is not None and raw is not None and raw is not image:
            raise ValueError("clipped samples are tracked in the raw frames: add them as `image`")
        raw = img if raw is None else np.asarray(raw)
        if img.shape != self.shape or raw.shape != self.shape:
            raise ValueError(f"frame of shape {img.shape} added to fringe sums of shape {self.shape}")
        if self.raw_max is None:
            self.raw_max = np.zeros(self.shape, raw.dtype)
        word, bit = divmod(self.frames, 64)
        if self.full_scale is not None and word == len(self.clip):
            self.clip = np.concatenate([self.clip, np.zeros((1,) + self.shape, np.uint64)])
            self.high = np.concatenate([self.high, np.zeros((1,) + self.shape, np.uint64)])
        c, s = np.cos(shift_rad), np.sin(shift_rad)
        x = np.array([1.0, c, s])
        self.normal += np.outer(x, x)
        track = self.full_scale is not None
        _accumulate(_flat(img), _flat(raw).astype(self.raw_max.dtype, copy=False), np.float32(c), np.float32(s),
                    self.sums.reshape(len(self.sums), -1), self.raw_max.reshape(-1),
                    np.float32(self.full_scale if track else np.inf), word, np.uint64(1 << bit),
                    self.clip.reshape(len(self.clip), -1) if track else _NO_MASK,
                    self.high.reshape(len(self.high), -1) if track else _NO_MASK)
        self.shifts.append(float(shift_rad))
        self.frames += 1

    def solve(self, full_scale: float, dark_level: float, min_modulation: float,
              linearise: tuple[np.ndarray, np.ndarray] | None = None, raw_modulation: bool = False) -> WrappedPhase:
        """The wrapped phase and its quality.

        full_scale: the raw saturation value (with clipping tracked, the one given to the constructor;
        without, a frame reaching it marks the pixel SATURATED); dark_level: raw values whose brightest
        frame stays below it are DARK; min_modulation: B below it (decoding units) is LOW_MODULATION;
        linearise: (offset, gain) (H, W) of y = (I - offset) / gain, the decoding domain of offset,
        modulation and noise (the phase does not depend on it; NaN where the gain is NaN);
        raw_modulation: also return B in the raw frames' units (defined where the gain is NaN too).
        Raises ValueError if the shifts do not determine the phase.
        """
        if np.linalg.matrix_rank(self.normal) < 3:
            raise ValueError("the phase shifts of this fringe set do not determine the phase "
                             "(need 3 or more distinct shifts)")
        track = self.full_scale is not None
        if track and full_scale != self.full_scale:
            raise ValueError(f"solve's full scale {full_scale} differs from the tracked {self.full_scale}")
        inv = np.linalg.inv(self.normal).astype(np.float32)
        phase, offset, modulation, noise = (np.empty(self.shape, np.float32) for _ in range(4))
        quality = np.empty(self.shape, np.uint8)
        lin_offset, lin_gain = (_EMPTY, _EMPTY) if linearise is None else \
            (_flat(np.asarray(linearise[0], np.float32)), _flat(np.asarray(linearise[1], np.float32)))
        squares = len(self.sums) == 4
        dof = self.frames - 3 if squares else 0
        shifts = np.asarray(self.shifts)
        raw_mod = np.empty(self.shape, np.float32) if raw_modulation else None
        _solve(self.sums.reshape(len(self.sums), -1), inv, dof, squares, self.normal, np.cos(shifts),
               np.sin(shifts), self.clip.reshape(len(self.clip), -1) if track else _NO_MASK,
               self.high.reshape(len(self.high), -1) if track else _NO_MASK,
               np.float32(full_scale), np.float32(dark_level), np.float32(min_modulation),
               self.raw_max.reshape(-1).astype(np.float32), lin_offset, lin_gain,
               *(o.reshape(-1) for o in (phase, offset, modulation, noise, quality)),
               _EMPTY if raw_mod is None else raw_mod.reshape(-1))
        return WrappedPhase(phase, offset, modulation, noise, quality, self.frames, self.clip if track else None,
                            raw_mod)


_EMPTY = np.zeros(0, np.float32)
_NO_INDEX = np.zeros(0, np.int64)
_NO_MASK = np.zeros((0, 0), np.uint64)


def _flat(a: np.ndarray) -> np.ndarray:
    """A 1-D view (a copy only if `a` is not contiguous)."""
    return np.ascontiguousarray(a).reshape(-1)


@numba.njit(cache=True, parallel=True)
def _accumulate(values, raw, c, s, sums, raw_max, full, word, bit, clip, high):  # pragma: no cover - compiled
    squares = sums.shape[0] == 4
    track = clip.shape[0] > 0
    for i in numba.prange(values.size):
        y = np.float32(values[i])
        sums[0, i] += y
        sums[1, i] += c * y
        sums[2, i] += s * y
        if squares:
            sums[3, i] += y * y
        if raw[i] > raw_max[i]:
            raw_max[i] = raw[i]
        if track:
            if y >= full:
                clip[word, i] |= bit
                high[word, i] |= bit
            elif y <= 0:
                clip[word, i] |= bit


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
def _pixel(a, b, c, noise, lin_offset, lin_gain, raw_max, full, dark, min_mod):  # pragma: no cover
    """One pixel from its least-squares (A, b, c) of A + b cos d + c sin d and raw noise, with
    y = (I - lin_offset) / lin_gain applied -> (phase, offset, modulation, noise, quality flags);
    SATURATED if raw_max reaches `full` (pass inf where clipped samples were left out instead)."""
    noise = noise / abs(lin_gain)
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


@numba.njit(cache=True, inline="always")
def _fit(s0, s1, s2, s3, inv, dof):  # pragma: no cover - compiled
    """Least-squares (A, b, c) from the sums with the inverse normal matrix, and the residual sigma of
    the raw values (NaN without redundancy, dof = 0)."""
    a = inv[0, 0] * s0 + inv[0, 1] * s1 + inv[0, 2] * s2
    b = inv[1, 0] * s0 + inv[1, 1] * s1 + inv[1, 2] * s2
    c = inv[2, 0] * s0 + inv[2, 1] * s1 + inv[2, 2] * s2
    if dof > 0:
        rss = s3 - (a * s0 + b * s1 + c * s2)
        noise = np.sqrt(max(rss, 0.0) / dof)
    else:
        noise = np.nan
    return a, b, c, noise


@numba.njit(cache=True, inline="always")
def _fit_unclipped(s0, s1, s2, s3, squares, normal, cos, sin, clip, high, i, full):  # pragma: no cover
    """(A, b, c, raw noise, ok) of pixel i fitted to its unclipped samples only: the clipped frames'
    rows taken out of the normal matrix and their values (full scale, or 0) out of the sums; ok False
    when fewer than 3 remain or they do not determine the phase."""
    n = normal.copy()
    t0, t1, t2, t3 = np.float64(s0), np.float64(s1), np.float64(s2), np.float64(s3)
    left = cos.size
    for k in range(cos.size):
        word, bit = k // 64, np.uint64(1) << np.uint64(k % 64)
        if clip[word, i] & bit:
            x1, x2 = cos[k], sin[k]
            n[0, 0] -= 1.0
            n[0, 1] -= x1
            n[0, 2] -= x2
            n[1, 1] -= x1 * x1
            n[1, 2] -= x1 * x2
            n[2, 2] -= x2 * x2
            left -= 1
            if high[word, i] & bit:
                t0 -= full
                t1 -= full * x1
                t2 -= full * x2
                t3 -= full * full
    n[1, 0], n[2, 0], n[2, 1] = n[0, 1], n[0, 2], n[1, 2]
    if left < 3:
        return np.nan, np.nan, np.nan, np.nan, False
    # the inverse by cofactors; singular (the remaining shifts do not fix the phase) below 1e-9 of
    # the matrix's scale
    c00 = n[1, 1] * n[2, 2] - n[1, 2] * n[2, 1]
    c01 = n[0, 2] * n[2, 1] - n[0, 1] * n[2, 2]
    c02 = n[0, 1] * n[1, 2] - n[0, 2] * n[1, 1]
    det = n[0, 0] * c00 + n[1, 0] * c01 + n[2, 0] * c02
    if not (det > 1e-9 * left ** 3):
        return np.nan, np.nan, np.nan, np.nan, False
    inv = np.empty((3, 3))
    inv[0, 0], inv[0, 1], inv[0, 2] = c00 / det, c01 / det, c02 / det
    inv[1, 1] = (n[0, 0] * n[2, 2] - n[0, 2] * n[2, 0]) / det
    inv[1, 2] = (n[0, 2] * n[1, 0] - n[0, 0] * n[1, 2]) / det
    inv[2, 2] = (n[0, 0] * n[1, 1] - n[0, 1] * n[1, 0]) / det
    inv[1, 0], inv[2, 0], inv[2, 1] = inv[0, 1], inv[0, 2], inv[1, 2]
    a, b, c, noise = _fit(t0, t1, t2, t3, inv, left - 3 if squares else 0)
    return a, b, c, noise, True


@numba.njit(cache=True, parallel=True)
def _solve(sums, inv, dof, squares, normal, cos, sin, clip, high, full, dark, min_mod, raw_max, lin_offset,
           lin_gain, phase, offset, modulation, noise, quality, raw_mod):  # pragma: no cover - compiled
    """`_pixel` of every pixel of the accumulated sums (`_fit_unclipped` where samples were clipped);
    raw_mod (if not empty) gets the modulation before the linearisation."""
    linearise = lin_offset.size > 0
    track = clip.shape[0] > 0
    zero, one = np.float32(0), np.float32(1)
    inf = np.float32(np.inf)
    want_raw = raw_mod.size > 0
    for i in numba.prange(offset.size):
        s3 = sums[3, i] if squares else zero
        o, g = (lin_offset[i], lin_gain[i]) if linearise else (zero, one)
        clipped = False
        if track:
            for word in range(clip.shape[0]):
                if clip[word, i] != 0:
                    clipped = True
        if clipped:
            a, b, c, sd, ok = _fit_unclipped(sums[0, i], sums[1, i], sums[2, i], s3, squares, normal, cos, sin,
                                             clip, high, i, full)
        else:
            a, b, c, sd = _fit(sums[0, i], sums[1, i], sums[2, i], s3, inv, dof)
            ok = True
        if want_raw:
            raw_mod[i] = np.sqrt(b * b + c * c)
        phase[i], offset[i], modulation[i], noise[i], quality[i] = _pixel(
            a, b, c, sd, o, g, raw_max[i], inf if track else full, dark, min_mod)
        if not ok:
            quality[i] |= SATURATED


def decode_frames(frames: list[np.ndarray], shifts, full_scale: float, dark_level: float, min_modulation: float,
                  correction: WaveformCorrection | None = None) -> WrappedPhase:
    """One fringe set whose frames are in memory, in one pass: `FringeSums` of `frames` (N of (H, W), the
    camera's raw values, clipped samples left out) at `shifts` (radians), solved (full_scale,
    dark_level, min_modulation as in `FringeSums.solve`; the noise where a pixel has more than 3
    samples), then `correction` (the display's `WaveformCorrection`, or None) applied to the phase
    (`correct_phase`). ValueError if the shifts do not determine the phase."""
    shifts = np.asarray(shifts, np.float64)
    x = np.stack([np.ones_like(shifts), np.cos(shifts), np.sin(shifts)], axis=1)
    if np.linalg.matrix_rank(x) < 3:
        raise ValueError("the phase shifts of this fringe set do not determine the phase "
                         "(need 3 or more distinct shifts)")
    normal = x.T @ x
    inv = np.linalg.inv(normal).astype(np.float32)
    stack = np.stack(frames)
    shape = stack.shape[1:]
    out = WrappedPhase(*(np.empty(shape, np.float32) for _ in range(4)), np.empty(shape, np.uint8), len(frames))
    out.clipped = np.zeros(((len(frames) + 63) // 64,) + shape, np.uint64)
    high = np.zeros_like(out.clipped)
    table, scale = (_EMPTY, np.float32(0)) if correction is None else (correction._table, correction._scale)
    _decode(stack, x[:, 1].astype(np.float32), x[:, 2].astype(np.float32), inv, len(frames) - 3, normal, x[:, 1],
            x[:, 2], np.float32(full_scale), np.float32(dark_level), np.float32(min_modulation), table, scale,
            out.phase, out.offset, out.modulation, out.noise, out.quality, out.clipped, high)
    if correction is not None:
        correct_phase(out, correction, unclipped_done=True)
    return out


@numba.njit(cache=True, parallel=True)
def _decode(stack, cos, sin, inv, dof, normal, cos64, sin64, full, dark, min_mod, table, scale, phase, offset,
            modulation, noise, quality, clip, high):  # pragma: no cover - compiled
    """Per row: the sums of `FringeSums.add` over the N frames and the clipped frames' masks, `_pixel`
    (`_fit_unclipped` where samples were clipped), then `_undistort` (if a table; not where clipped:
    `correct_phase` does those)."""
    n, h, w = stack.shape
    zero, one = np.float32(0), np.float32(1)
    inf = np.float32(np.inf)
    for r in numba.prange(h):
        s0, s1, s2 = np.zeros(w, np.float32), np.zeros(w, np.float32), np.zeros(w, np.float32)
        s3, hi = np.zeros(w, np.float32), np.zeros(w, np.float32)
        any_clip = np.zeros(w, np.bool_)
        for k in range(n):
            c, s = cos[k], sin[k]
            word, bit = k // 64, np.uint64(1) << np.uint64(k % 64)
            for x in range(w):
                v = np.float32(stack[k, r, x])
                s0[x] += v
                s1[x] += c * v
                s2[x] += s * v
                if dof > 0:
                    s3[x] += v * v
                hi[x] = max(hi[x], v)
                if v >= full:
                    clip[word, r, x] |= bit
                    high[word, r, x] |= bit
                    any_clip[x] = True
                elif v <= 0:
                    clip[word, r, x] |= bit
                    any_clip[x] = True
        flat_clip = clip[:, r, :]
        flat_high = high[:, r, :]
        for x in range(w):
            if any_clip[x]:
                a, b, c, sd, ok = _fit_unclipped(s0[x], s1[x], s2[x], s3[x], dof > 0, normal, cos64, sin64,
                                                 flat_clip, flat_high, x, full)
            else:
                a, b, c, sd = _fit(s0[x], s1[x], s2[x], s3[x], inv, dof)
                ok = True
            ph, offset[r, x], modulation[r, x], noise[r, x], quality[r, x] = _pixel(
                a, b, c, sd, zero, one, hi[x], inf, dark, min_mod)
            if not ok:
                quality[r, x] |= SATURATED
            phase[r, x] = _undistort(ph, table, scale) if table.size > 0 and not any_clip[x] else ph


def correct_phase(wrapped: WrappedPhase, correction: WaveformCorrection, unclipped_done: bool = False) -> None:
    """Apply the display-response correction to `wrapped.phase` (in place): `correction` where a pixel
    was fitted to every frame (unless done already: unclipped_done), and where it was fitted without
    its clipped frames, the correction of the shifts it kept (one per distinct set of clipped frames);
    a pixel whose kept shifts cannot be corrected is flagged SATURATED."""
    raw = wrapped.phase
    out = raw.copy() if unclipped_done else correction(raw)
    if wrapped.clipped is not None:
        solved = (wrapped.clipped != 0).any(axis=0) & ((wrapped.quality & SATURATED) == 0)
        idx = np.flatnonzero(solved)
        if idx.size:
            masks = wrapped.clipped.reshape(len(wrapped.clipped), -1)[:, idx].T      # (pixels, words)
            kinds, which = np.unique(masks, axis=0, return_inverse=True)
            which = which.ravel()
            k = np.arange(wrapped.frames)
            tables = np.empty((len(kinds), correction._table.size), np.float32)
            usable = np.ones(len(kinds), bool)
            for j, mask in enumerate(kinds):
                keep = (mask[k // 64] >> (k % 64).astype(np.uint64)) & np.uint64(1) == 0
                try:
                    tables[j] = correction.subset(keep)._table
                except ValueError:
                    usable[j] = False
                    tables[j] = correction._table
            fixed = np.empty(idx.size, np.float32)
            _correct(np.ascontiguousarray(raw.reshape(-1)[idx]), tables, which, correction._scale, fixed)
            out.reshape(-1)[idx] = fixed
            wrapped.quality.reshape(-1)[idx[~usable[which]]] |= SATURATED
    wrapped.phase = out


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
        self.waveform = np.asarray(waveform, float)
        self.shifts = np.asarray(shifts, float)
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

    def subset(self, keep: np.ndarray) -> "WaveformCorrection":
        """The correction for the same waveform decoded from the frames `keep` (a bool per shift) alone;
        ValueError if the waveform is too distorted for them."""
        return WaveformCorrection(self.waveform, self.shifts[np.asarray(keep, bool)])

    def __call__(self, phase: np.ndarray) -> np.ndarray:
        """The true phase (radians, (-pi, pi]) of decoded phases (float32)."""
        phase = np.asarray(phase, np.float32)
        out = np.empty_like(phase)
        _correct(_flat(phase), self._table[None], _NO_INDEX, self._scale, out.reshape(-1))
        return out


@numba.njit(cache=True, parallel=True)
def _correct(phase, tables, which, scale, out):  # pragma: no cover - compiled
    """out = `_undistort` of each phase with the table tables[which[i]] (which empty: tables[0])."""
    one = which.size == 0
    for i in numba.prange(phase.size):
        out[i] = _undistort(phase[i], tables[0] if one else tables[which[i]], scale)


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

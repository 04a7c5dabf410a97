"""Display patterns for calibration: phase-shifting fringes, flat grey levels, and their manifest.

A fringe along axis "x" with period P display pixels and shift delta (radians) has, at display column c,
the value low + (high - low) / 2 * (1 + cos(2*pi*c/P - delta)) (DESIGN.md; axis "y" uses the row r).
The seed's three-step set is delta = 0, +2pi/3, -2pi/3; N steps use delta_k = 2*pi*k/N wrapped to
(-pi, pi]. Values stay inside [low, high] (tip 1.7, default [20, 240]).

With a measured display response (`DisplayResponse`, from `calib.intensity`) the fringe is
pre-compensated: the code values are chosen so that the *emitted luminance*, not the code value, follows
the cosine. Such patterns carry `"precompensated": true` in their description, and the decoder then
works in luminance instead of code values.

Gray code (`gray_image`, `gray_sequence`): bit B of the binary-reflected Gray code of the column
(axis "x") or row, `high` where the bit is 1 and `low` where 0, each followed by its inverse; then a
white and a black flat for the decoder's contrast (`calib.graycode`). With a fringe period P the bits
stop at the stripes of at most P / 2 pixels (one finer than the period: the complementary bit that keeps
the period order right at the period's edges) and the N shifted fringes of period P follow.

The manifest `patterns.json` (format "stereodic.patterns/1") lists every written image with its
pattern description, in the order to show them:
    {"format": "stereodic.patterns/1", "display": {"width_px": .., "height_px": ..},
     "patterns": [{"file": "x_P60_s0.png", "pattern": {"type": "fringe", "axis": "x", ...}}, ...]}
The acquisition copies each `pattern` object into the frames of its `capture.json`.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calib.atomic import write_json
from calib.capture import Pattern
from calib.graycode import gray_bits, gray_profile
from calib.imageio import write_gray

PATTERNS_FORMAT = "stereodic.patterns/1"
PATTERNS_MANIFEST = "patterns.json"


@dataclass(frozen=True)
class DisplayResponse:
    """Relative luminance the display emits for each code value (a monotone table).

    levels: (K,) code values, increasing. luminance: (K,) relative luminance at those codes, increasing
    (any scale; only its shape matters). Between samples the table is interpolated monotonically.
    """

    levels: np.ndarray
    luminance: np.ndarray

    def __call__(self, code: np.ndarray) -> np.ndarray:
        """Relative luminance of code values (float64)."""
        from scipy.interpolate import PchipInterpolator
        return PchipInterpolator(self.levels, self.luminance, extrapolate=True)(np.asarray(code, float))

    def inverse(self, luminance: np.ndarray) -> np.ndarray:
        """Code values (float64, fractional) that emit the given relative luminance."""
        codes = np.linspace(self.levels[0], self.levels[-1], 4096)
        return np.interp(np.asarray(luminance, float), self(codes), codes)

    def to_json(self) -> dict:
        return {"levels": [float(v) for v in self.levels], "luminance": [float(v) for v in self.luminance]}

    @classmethod
    def from_json(cls, d: dict) -> "DisplayResponse":
        levels, lum = np.asarray(d["levels"], float), np.asarray(d["luminance"], float)
        if levels.ndim != 1 or levels.shape != lum.shape or len(levels) < 2:
            raise ValueError("a display response needs matching 'levels' and 'luminance' lists, 2 or more")
        if np.any(np.diff(levels) <= 0) or np.any(np.diff(lum) <= 0):
            raise ValueError("a display response must increase with the code value")
        return cls(levels, lum)


def step_shifts(steps: int) -> np.ndarray:
    """The N phase shifts (radians) of an N-step set: 2*pi*k/N wrapped to (-pi, pi]; N >= 3.

    For N = 3 this is the seed's 0, +2pi/3, -2pi/3.
    """
    if steps < 3:
        raise ValueError(f"phase shifting needs at least 3 steps, got {steps}")
    d = 2 * np.pi * np.arange(steps) / steps
    return np.where(d > np.pi + 1e-12, d - 2 * np.pi, d)


def fringe_profile(n: int, period_px: float, shift_rad: float, low: float = 20, high: float = 240,
                   response: DisplayResponse | None = None) -> np.ndarray:
    """Code values (float64, unquantised) of a fringe along one display axis of n pixels.

    Without `response` the code value follows the cosine; with it the emitted luminance does.
    """
    wave = 0.5 * (1 + np.cos(2 * np.pi * np.arange(n) / period_px - shift_rad))
    if response is None:
        return low + (high - low) * wave
    y_low, y_high = response(low), response(high)
    return response.inverse(y_low + (y_high - y_low) * wave)


def fringe_image(display_w: int, display_h: int, *, axis: str, period_px: float, shift_rad: float,
                 low: float = 20, high: float = 240, response: DisplayResponse | None = None) -> np.ndarray:
    """One phase-shifted fringe as a display image (module docstring).

    Parameters
    ----------
    display_w, display_h : int
        The display's size, display pixels.
    axis : {"x", "y"}
        "x": the value varies along the display's columns (vertical fringes); "y": along its rows.
    period_px : float
        The period, display pixels.
    shift_rad : float
        The phase shift delta, radians.
    low, high : float
        The code values the cosine spans.
    response : DisplayResponse, optional
        The display's measured response: the emitted luminance, not the code value, follows the cosine.

    Returns
    -------
    image : (display_h, display_w) uint8
        Code values rounded to the nearest integer.
    """
    if axis not in ("x", "y"):
        raise ValueError(f"axis must be 'x' or 'y', got {axis!r}")
    n = display_w if axis == "x" else display_h
    line = np.clip(np.rint(fringe_profile(n, period_px, shift_rad, low, high, response)), 0, 255)
    line = line.astype(np.uint8)
    if axis == "x":
        return np.broadcast_to(line[None, :], (display_h, display_w)).copy()
    return np.broadcast_to(line[:, None], (display_h, display_w)).copy()


def flat_image(display_w: int, display_h: int, level: int) -> np.ndarray:
    """A uniform uint8 (display_h, display_w) image of one code value."""
    return np.full((display_h, display_w), int(level), np.uint8)


def fringe_pattern(axis: str, period_px: float, shift_rad: float, low: float, high: float,
                   precompensated: bool = False) -> Pattern:
    """The manifest description of a fringe."""
    params = {"axis": axis, "period_px": period_px, "shift_rad": float(shift_rad), "low": low, "high": high}
    if precompensated:
        params["precompensated"] = True
    return Pattern("fringe", params)


def calibration_sequence(display_w: int, display_h: int, *, periods, steps: int = 3, axes=("x", "y"),
                         low: float = 20, high: float = 240, flat_levels=(),
                         response: DisplayResponse | None = None) -> list[tuple[Pattern, np.ndarray]]:
    """Every pattern of a calibration, in display order: flats first (intensity calibration before
    geometry, tip 3.6), then for each axis and each period (longest first) the N shifted fringes.

    Parameters
    ----------
    display_w, display_h : int
        The display's size, display pixels.
    periods : sequence of float
        Fringe periods, display pixels; the longest should cover the display along each axis so that the
        phase is absolute.
    steps : int
        Phase steps per period (N >= 3, `step_shifts`).
    axes : sequence of {"x", "y"}
        The fringe axes, in order (`fringe_image`).
    low, high : float
        The code values the fringes span.
    flat_levels : sequence of int
        Code values of the flat images shown first.
    response : DisplayResponse, optional
        Pre-compensate the fringes for the display's measured response.

    Returns
    -------
    sequence : list of (Pattern, (display_h, display_w) uint8)
        Each pattern's manifest description and its image.
    """
    seq = [(Pattern("flat", {"level": int(v)}), flat_image(display_w, display_h, int(v))) for v in flat_levels]
    for axis in axes:
        for period in sorted(periods, reverse=True):
            for delta in step_shifts(steps):
                pat = fringe_pattern(axis, period, delta, low, high, response is not None)
                seq.append((pat, fringe_image(display_w, display_h, axis=axis, period_px=period, shift_rad=delta,
                                              low=low, high=high, response=response)))
    return seq


def gray_image(display_w: int, display_h: int, *, axis: str, bit: int, inverse: bool = False,
               low: int = 0, high: int = 255) -> np.ndarray:
    """One Gray-code bit as a display image (module docstring).

    Parameters
    ----------
    display_w, display_h : int
        The display's size, display pixels.
    axis : {"x", "y"}
        "x": the code of the column (vertical stripes); "y": of the row.
    bit : int
        The bit, 0 = least significant (stripes of 2**(bit + 1) pixels, the first half as wide).
    inverse : bool
        The complement.
    low, high : int
        The code values of 0 and 1.

    Returns
    -------
    image : (display_h, display_w) uint8
    """
    if axis not in ("x", "y"):
        raise ValueError(f"axis must be 'x' or 'y', got {axis!r}")
    n = display_w if axis == "x" else display_h
    line = np.where(gray_profile(n, bit, inverse) == 1, high, low).astype(np.uint8)
    shape = (display_h, display_w)
    return np.broadcast_to(line[None, :] if axis == "x" else line[:, None], shape).copy()


def gray_sequence(display_w: int, display_h: int, *, axes=("x",), period_px: float | None = None,
                  steps: int = 16, low: int = 0, high: int = 255,
                  fringe_low: float = 20, fringe_high: float = 240) -> list[tuple[Pattern, np.ndarray]]:
    """Every pattern of a Gray-code scan, in display order (module docstring): per axis the bits, most
    significant first, each followed by its inverse; the white and black flats; with `period_px` the
    `steps` shifted fringes of that period along the first axis.

    Parameters
    ----------
    display_w, display_h : int
        The display's (projector's) size, pixels.
    axes : sequence of {"x", "y"}
        The coded axes, in order.
    period_px : float, optional
        Gray code plus phase shifting: the fringe period, pixels (the code stops at stripes of at most
        half of it); None: the full Gray code, down to single pixels.
    steps : int
        Phase steps of the fringe (N >= 3).
    low, high : int
        The Gray code's code values.
    fringe_low, fringe_high : float
        The code values the fringe spans.

    Returns
    -------
    sequence : list of (Pattern, (display_h, display_w) uint8)
    """
    low_bit = 0 if period_px is None else int(np.floor(np.log2(period_px / 2)))
    if low_bit < 0:
        raise ValueError(f"a fringe period of {period_px} px is too short for Gray code (>= 2 px)")
    seq = []
    for axis in axes:
        for bit in reversed(range(low_bit, gray_bits(display_w if axis == "x" else display_h))):
            for inverse in (False, True):
                seq.append((Pattern("gray", {"axis": axis, "bit": bit, "inverse": inverse}),
                            gray_image(display_w, display_h, axis=axis, bit=bit, inverse=inverse, low=low,
                                       high=high)))
    seq += [(Pattern("flat", {"level": int(v)}), flat_image(display_w, display_h, int(v))) for v in (high, low)]
    if period_px is not None:
        for delta in step_shifts(steps):
            seq.append((fringe_pattern(axes[0], period_px, delta, fringe_low, fringe_high),
                        fringe_image(display_w, display_h, axis=axes[0], period_px=period_px, shift_rad=delta,
                                     low=fringe_low, high=fringe_high)))
    return seq


def pattern_filename(pattern: Pattern, index: int) -> str:
    """A readable, unique file name for the index-th pattern of a sequence."""
    if pattern.type == "flat":
        return f"{index:03d}_flat_{pattern.level}.png"
    if pattern.type == "gray":
        return f"{index:03d}_{pattern.axis}_gray{pattern.bit}{'_inv' if pattern.inverse else ''}.png"
    return f"{index:03d}_{pattern.axis}_P{pattern.period_px:g}_s{pattern.shift_rad:+.4f}.png"


def write_patterns(out_dir: str | os.PathLike, display_w: int, display_h: int,
                   sequence: list[tuple[Pattern, np.ndarray]]) -> Path:
    """Write each image as PNG (display resolution exactly) and the manifest; returns its path."""
    out_dir = Path(out_dir)
    entries = []
    for i, (pattern, image) in enumerate(sequence):
        name = pattern_filename(pattern, i)
        write_gray(out_dir / name, image)
        entries.append({"file": name, "pattern": pattern.to_json()})
    path = out_dir / PATTERNS_MANIFEST
    write_json(path, {"format": PATTERNS_FORMAT, "display": {"width_px": display_w, "height_px": display_h},
                      "patterns": entries})
    return path

"""The 8-bit images the simulated display shows, built from the manifest's pattern records.

This is the simulator's own generator (it shares nothing with the calibration's pattern code): every
value is computed in float64 from the pattern's definition in DESIGN.md and rounded to the nearest
8-bit level, as a graphics card would send it.
"""

from __future__ import annotations

import numpy as np

from calib.capture import Pattern
from calib.patterns import gray_image


def fringe_shifts(steps: int) -> list[float]:
    """Shifts (radians) of an N-step set: 2*pi*k/N wrapped to (-pi, pi] (N = 3: 0, +2pi/3, -2pi/3)."""
    out = []
    for k in range(steps):
        d = 2 * np.pi * k / steps
        out.append(float(d - 2 * np.pi if d > np.pi + 1e-12 else d))
    return out


def screen_image(pattern: Pattern, width_px: int, height_px: int) -> np.ndarray:
    """(height_px, width_px) uint8 image of a `fringe`, `flat`, `gray` or `chessboard` pattern.

    fringe: low + (high - low)/2 * (1 + cos(2*pi*c/period_px - shift_rad)), c the column (axis x) or
    row (axis y). flat: `level` everywhere. gray: `calib.patterns.gray_image`. chessboard: `squares` = [columns, rows] of `square_px`
    display pixels from display pixel `origin_px` = [c, r] (the top-left corner of the board), the
    top-left square `low` (default 0), the others alternating with `high` (default 255); `high` around.
    """
    if pattern.type == "flat":
        return np.full((height_px, width_px), _level(pattern.level), np.uint8)
    if pattern.type == "fringe":
        n = width_px if pattern.axis == "x" else height_px
        t = np.arange(n, dtype=np.float64)
        line = pattern.low + (pattern.high - pattern.low) / 2 * (
            1 + np.cos(2 * np.pi * t / pattern.period_px - pattern.shift_rad))
        line = np.clip(np.rint(line), 0, 255).astype(np.uint8)
        return np.broadcast_to(line[None, :] if pattern.axis == "x" else line[:, None],
                               (height_px, width_px)).copy()
    if pattern.type == "gray":
        return gray_image(width_px, height_px, axis=pattern.axis, bit=pattern.bit,
                          inverse=bool(pattern.params.get("inverse", False)), low=pattern.params.get("low", 0),
                          high=pattern.params.get("high", 255))
    if pattern.type == "chessboard":
        cols, rows = pattern.squares
        size = float(pattern.square_px)
        c0, r0 = pattern.params.get("origin_px", [0, 0])
        low, high = pattern.params.get("low", 0), pattern.params.get("high", 255)
        img = np.full((height_px, width_px), _level(high), np.uint8)
        c = np.floor((np.arange(width_px) - c0) / size).astype(int)
        r = np.floor((np.arange(height_px) - r0) / size).astype(int)
        inside = (r[:, None] >= 0) & (r[:, None] < rows) & (c[None, :] >= 0) & (c[None, :] < cols)
        dark = inside & ((r[:, None] + c[None, :]) % 2 == 0)
        img[dark] = _level(low)
        return img
    raise ValueError(f"the simulated display cannot show a {pattern.type!r} pattern")


def _level(v) -> int:
    return int(np.clip(np.rint(float(v)), 0, 255))

"""The simulated LCD: 8-bit values through gamma onto a pixel grid with black gaps, under cover glass.

Display coordinates (c, r) are continuous (column, row) in display pixels, pixel centres at integers.
Display pixel (c, r) lies at (c * pitch_x, r * pitch_y, 0) in the display's own frame, which a
`scanners.sim.pose.DisplayPose` places in the WCS (at stage position z along the stage axis
(ax, ay, az): (c * pitch_x, r * pitch_y, 0) + z * (ax/az, ay/az, 1), DESIGN.md).

Each display pixel emits from `stripes` vertical sub-pixel stripes (R, G, B of a monochrome grey seen by
a monochrome camera) that together fill `fill_factor[0]` of its width and `fill_factor[1]` of its
height; the rest is the black matrix. Luminance is relative to a full-white lit area:
L(value) = black_level + (1 - black_level) * (value / 255) ** gamma.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from calib.capture import CoverGlass, Display
from scanners.sim.optics import through_slab
from scanners.sim.pose import DisplayPose


@dataclass(frozen=True)
class SimDisplay:
    """A 24-inch 1080p IPS monitor by default (pitch 0.2745 mm, gamma 2.2, contrast 1000:1)."""

    width_px: int = 1920
    height_px: int = 1080
    pitch_mm: tuple[float, float] = (0.2745, 0.2745)
    gamma: float = 2.2
    black_level: float = 0.001
    fill_factor: tuple[float, float] = (0.75, 0.85)
    stripes: int = 3
    cover_glass: CoverGlass | None = None

    def __post_init__(self):
        for name in ("pitch_mm", "fill_factor"):         # tuples: the display is a (hashable) cache key
            object.__setattr__(self, name, tuple(float(x) for x in getattr(self, name)))
        if not all(0 < f <= 1 for f in self.fill_factor):
            raise ValueError(f"fill_factor must be in (0, 1], got {self.fill_factor}")
        if self.stripes < 1 or self.gamma <= 0 or not 0 <= self.black_level < 1:
            raise ValueError("display needs stripes >= 1, gamma > 0 and 0 <= black_level < 1")

    @property
    def size_mm(self) -> tuple[float, float]:
        return self.width_px * self.pitch_mm[0], self.height_px * self.pitch_mm[1]

    def record(self) -> Display:
        """The display as the manifest states it (calib.capture.Display), gamma and cover glass included."""
        return Display(self.width_px, self.height_px, tuple(self.pitch_mm), self.gamma, self.cover_glass)

    def luminance(self, values: np.ndarray) -> np.ndarray:
        """Relative luminance (float32) of 8-bit display values (any shape)."""
        lut = (self.black_level + (1 - self.black_level) * (np.arange(256) / 255.0) ** self.gamma)
        return lut.astype(np.float32)[np.asarray(values, np.uint8)]

    def luminance_at(self, image: np.ndarray, c: np.ndarray, r: np.ndarray,
                     window: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
        """Mean luminance (float32, shape of c) of the display showing `image` ((height_px, width_px)
        uint8) over a window of window = (wc, wr) display pixels (each <= 1) centred at (c, r); a zero
        window samples the point. Outside the display it is black (0)."""
        if image.shape != (self.height_px, self.width_px) or image.dtype != np.uint8:
            raise ValueError(f"display image must be uint8 {self.height_px}x{self.width_px}, "
                             f"got {image.dtype} {image.shape}")
        if not (0 <= window[0] <= 1 and 0 <= window[1] <= 1):
            raise ValueError(f"window must be within 0..1 display pixels, got {window}")
        c, r = np.broadcast_arrays(np.asarray(c, np.float32), np.asarray(r, np.float32))
        out = np.empty(c.size, np.float32)
        _gather(self.luminance(image), np.ascontiguousarray(c).ravel(), np.ascontiguousarray(r).ravel(),
                float(window[0]) / 2, float(window[1]) / 2, float(self.fill_factor[0]),
                float(self.fill_factor[1]), int(self.stripes), out)
        return out.reshape(c.shape)

    def hit(self, origin: np.ndarray, direction: np.ndarray, pose: DisplayPose) -> tuple[np.ndarray, np.ndarray]:
        """Display coordinates (c, r) (float64) where WCS rays (origin, direction (..., 3)) reach the
        pixel plane of the display at `pose`, refracted through the cover glass if there is one."""
        o, d = pose.to_display(origin, direction)
        if self.cover_glass is not None and self.cover_glass.thickness_mm > 0:
            g = self.cover_glass
            p, _ = through_slab(o, d, np.array([0.0, 0.0, -g.thickness_mm]), np.array([0.0, 0.0, 1.0]),
                                g.thickness_mm, g.refractive_index)
        else:
            p = o + (-o[..., 2] / d[..., 2])[..., None] * d
        return p[..., 0] / self.pitch_mm[0], p[..., 1] / self.pitch_mm[1]


@numba.njit(cache=True, inline="always")
def _weights(x, h, fill, stripes):
    """Fractions of the window [x - h, x + h] lit by display pixels floor(x) and floor(x) + 1."""
    k0 = np.floor(x)
    half = 0.5 * fill / stripes
    w0 = 0.0
    w1 = 0.0
    for j in range(stripes):
        off = (j + 0.5) / stripes - 0.5
        for which in range(2):
            sc = k0 + which + off
            if h > 0:
                lit = min(x + h, sc + half) - max(x - h, sc - half)
                lit = max(lit, 0.0) / (2 * h)
            else:
                lit = 1.0 if abs(x - sc) < half else 0.0
            if which == 0:
                w0 += lit
            else:
                w1 += lit
    return int(k0), w0, w1


@numba.njit(cache=True, parallel=True)
def _gather(lum, c, r, hc, hr, fill_c, fill_r, stripes, out):
    height, width = lum.shape
    for i in numba.prange(c.size):
        kc, wc0, wc1 = _weights(c[i], hc, fill_c, stripes)
        kr, wr0, wr1 = _weights(r[i], hr, fill_r, 1)
        acc = 0.0
        for b in range(2):
            rr = kr + b
            wr = wr0 if b == 0 else wr1
            if wr == 0.0 or rr < 0 or rr >= height:
                continue
            for a in range(2):
                cc = kc + a
                wc = wc0 if a == 0 else wc1
                if wc == 0.0 or cc < 0 or cc >= width:
                    continue
                acc += wr * wc * lum[rr, cc]
        out[i] = acc

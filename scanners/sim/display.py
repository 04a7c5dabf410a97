"""The simulated LCD: 8-bit values through gamma onto a pixel grid with black gaps, under cover glass,
framed by its bezel.

Display coordinates (c, r) are continuous (column, row) in display pixels, pixel centres at integers.
Display pixel (c, r) lies at (c * pitch_x, r * pitch_y, z_bow) in the display's own frame (z_bow = 0 for
a flat panel), which a `scanners.sim.pose.DisplayPose` places in the WCS (at stage position z along the
stage axis (ax, ay, az): (c * pitch_x, r * pitch_y, 0) + z * (ax/az, ay/az, 1), DESIGN.md).

Each display pixel emits from `stripes` vertical sub-pixel stripes (R, G, B of a monochrome grey seen by
a monochrome camera) that together fill `fill_factor[0]` of its width and `fill_factor[1]` of its
height; the rest is the black matrix. Luminance is relative to a full-white lit area:
L(value) = black_level + (1 - black_level) * (value / 255) ** gamma. Outside the pixel area the camera
sees the bezel, dark but for the room light it reflects (`bezel`, the same relative units).

A real bench's display flaws, each off by default (`SimDisplay.flaws` lists them for the truth):
- `bow_mm`: the panel is not flat: its pixel surface is the paraboloid z_bow = bow_mm * (1 - rho^2),
  rho the distance from the centre of the pixel area over the distance from there to a corner pixel
  (the centre bow_mm farther from the camera than the plane through the corners);
- `pitch_error`: the true pitch is pitch_mm * (1 + pitch_error), while the manifest states pitch_mm;
- `falloff`, `gamma_tilt`: an IPS panel's viewing-angle dependence: seen at angle theta from its
  normal, the luminance is L * (1 - falloff * sin^2 theta) computed with the gamma
  gamma * (1 + gamma_tilt * sin^2 theta).
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
    """A 24-inch 1080p IPS monitor by default (pitch 0.2745 mm, gamma 2.2, contrast 1000:1, a matte black
    bezel reflecting 0.5 % of white), flat, of exactly its stated pitch, the same from every angle."""

    width_px: int = 1920
    height_px: int = 1080
    pitch_mm: tuple[float, float] = (0.2745, 0.2745)
    gamma: float = 2.2
    black_level: float = 0.001
    fill_factor: tuple[float, float] = (0.75, 0.85)
    stripes: int = 3
    cover_glass: CoverGlass | None = None
    bezel: float = 0.005
    bow_mm: float = 0.0
    pitch_error: float = 0.0
    falloff: float = 0.0
    gamma_tilt: float = 0.0

    def __post_init__(self):
        for name in ("pitch_mm", "fill_factor"):         # tuples: the display is a (hashable) cache key
            object.__setattr__(self, name, tuple(float(x) for x in getattr(self, name)))
        if not all(0 < f <= 1 for f in self.fill_factor):
            raise ValueError(f"fill_factor must be in (0, 1], got {self.fill_factor}")
        if self.stripes < 1 or self.gamma <= 0 or not 0 <= self.black_level < 1:
            raise ValueError("display needs stripes >= 1, gamma > 0 and 0 <= black_level < 1")
        if not (0 <= self.bezel < 1 and 0 <= self.falloff < 1 and abs(self.pitch_error) < 0.1
                and self.gamma * (1 + min(self.gamma_tilt, 0)) > 0 and abs(self.bow_mm) < 10):
            raise ValueError("display needs 0 <= bezel < 1, 0 <= falloff < 1, |pitch_error| < 0.1, "
                             "|bow_mm| < 10 and a positive gamma at every angle")

    @property
    def true_pitch_mm(self) -> tuple[float, float]:
        """The pitch the pixels really have (mm): the stated one times 1 + pitch_error."""
        return tuple(p * (1 + self.pitch_error) for p in self.pitch_mm)

    @property
    def size_mm(self) -> tuple[float, float]:
        px, py = self.true_pitch_mm
        return self.width_px * px, self.height_px * py

    @property
    def angular(self) -> bool:
        """Whether the luminance depends on the viewing angle."""
        return self.falloff != 0 or self.gamma_tilt != 0

    def flaws(self) -> dict:
        """The display's flaws and its bezel, for the truth's metadata."""
        return {"bezel": self.bezel, "bow_mm": self.bow_mm, "pitch_error": self.pitch_error,
                "true_pitch_mm": list(self.true_pitch_mm), "falloff": self.falloff, "gamma_tilt": self.gamma_tilt}

    def record(self) -> Display:
        """The display as the manifest states it (calib.capture.Display): the stated pitch, gamma and cover
        glass."""
        return Display(self.width_px, self.height_px, tuple(self.pitch_mm), self.gamma, self.cover_glass)

    def luminance(self, values: np.ndarray) -> np.ndarray:
        """Relative luminance (float32) of 8-bit display values (any shape), seen along the normal."""
        lut = (self.black_level + (1 - self.black_level) * (np.arange(256) / 255.0) ** self.gamma)
        return lut.astype(np.float32)[np.asarray(values, np.uint8)]

    def luminance_at(self, image: np.ndarray, c: np.ndarray, r: np.ndarray,
                     window: tuple[float, float] = (0.0, 0.0), sin2: np.ndarray | None = None) -> np.ndarray:
        """Mean luminance (float32, shape of c) of the display showing `image` ((height_px, width_px)
        uint8) over a window of window = (wc, wr) display pixels (each <= 1) centred at (c, r); a zero
        window samples the point. The part of a window outside the pixel area sees the bezel. sin2:
        sin^2 of the viewing angle at each point (shape of c), needed when the display is `angular`."""
        if image.shape != (self.height_px, self.width_px) or image.dtype != np.uint8:
            raise ValueError(f"display image must be uint8 {self.height_px}x{self.width_px}, "
                             f"got {image.dtype} {image.shape}")
        if not (0 <= window[0] <= 1 and 0 <= window[1] <= 1):
            raise ValueError(f"window must be within 0..1 display pixels, got {window}")
        c, r = np.broadcast_arrays(np.asarray(c, np.float32), np.asarray(r, np.float32))
        out = np.empty(c.size, np.float32)
        if self.angular:
            if sin2 is None or np.shape(sin2) != c.shape:
                raise ValueError("an angle-dependent display needs sin2 of the viewing angle at every point")
            values = (np.arange(256) / 255.0).astype(np.float32)[image]
            s2 = np.ascontiguousarray(sin2, np.float32).ravel()
        else:
            values, s2 = self.luminance(image), np.zeros(0, np.float32)
        _gather(values, np.ascontiguousarray(c).ravel(), np.ascontiguousarray(r).ravel(),
                float(window[0]) / 2, float(window[1]) / 2, float(self.fill_factor[0]),
                float(self.fill_factor[1]), int(self.stripes), float(self.bezel), s2, float(self.black_level),
                float(self.gamma), float(self.gamma_tilt), float(self.falloff), out)
        return out.reshape(c.shape)

    def bow(self, x_mm: np.ndarray, y_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The pixel surface's height z_bow (display frame, mm) at in-plane points (x, y) (mm), and its
        slopes dz/dx, dz/dy."""
        px, py = self.true_pitch_mm
        xc, yc = (self.width_px - 1) / 2 * px, (self.height_px - 1) / 2 * py
        k = self.bow_mm / (xc * xc + yc * yc)
        dx, dy = x_mm - xc, y_mm - yc
        return self.bow_mm - k * (dx * dx + dy * dy), -2 * k * dx, -2 * k * dy

    def hit(self, origin: np.ndarray, direction: np.ndarray, pose: DisplayPose) -> tuple[np.ndarray, np.ndarray]:
        """Display coordinates (c, r) (float64) where WCS rays (origin, direction (..., 3)) reach the
        pixel surface of the display at `pose`, refracted through the cover glass if there is one."""
        o, d = pose.to_display(origin, direction)
        glass = self.cover_glass if self.cover_glass is not None and self.cover_glass.thickness_mm > 0 else None
        if self.bow_mm != 0:
            p = self._hit_bowed(o, d, glass)
        elif glass is not None:
            p, _ = through_slab(o, d, np.array([0.0, 0.0, -glass.thickness_mm]), np.array([0.0, 0.0, 1.0]),
                                glass.thickness_mm, glass.refractive_index)
        else:
            p = o + (-o[..., 2] / d[..., 2])[..., None] * d
        px, py = self.true_pitch_mm
        return p[..., 0] / px, p[..., 1] / py

    def _hit_bowed(self, o: np.ndarray, d: np.ndarray, glass: CoverGlass | None) -> np.ndarray:
        """Display-frame points (..., 3) where rays (display frame) reach the bowed pixel surface, through
        a cover glass of uniform thickness lying on it (its front face z_bow - thickness, refracting with
        the face's local normal)."""
        if glass is not None:
            p = self._intersect_bow(o, d, -glass.thickness_mm)
            _, sx, sy = self.bow(p[..., 0], p[..., 1])
            n = np.stack([-sx, -sy, np.ones_like(sx)], axis=-1)
            n /= np.linalg.norm(n, axis=-1, keepdims=True)
            u = d / np.linalg.norm(d, axis=-1, keepdims=True)
            cos_i = np.einsum("...i,...i->...", u, n)
            eta = 1.0 / glass.refractive_index
            cos_t = np.sqrt(1.0 - eta * eta * (1.0 - cos_i * cos_i))
            o, d = p, eta * u + (cos_t - eta * cos_i)[..., None] * n
        return self._intersect_bow(o, d, 0.0)

    def _intersect_bow(self, o: np.ndarray, d: np.ndarray, offset_mm: float) -> np.ndarray:
        """Points where lines o + t d meet the surface z = z_bow(x, y) + offset_mm (Newton's method from
        the plane z = offset_mm; the surface's slopes are ~1e-3, so a few steps reach 1e-12 mm)."""
        t = (offset_mm - o[..., 2]) / d[..., 2]
        for _ in range(8):
            p = o + t[..., None] * d
            z, sx, sy = self.bow(p[..., 0], p[..., 1])
            g = p[..., 2] - z - offset_mm
            t = t - g / (d[..., 2] - sx * d[..., 0] - sy * d[..., 1])
            if np.abs(g).max(initial=0.0) < 1e-13:
                break
        return o + t[..., None] * d

    def sin2_view(self, direction: np.ndarray, pose: DisplayPose) -> np.ndarray:
        """sin^2 of the angle between WCS ray directions (..., 3) and the display's normal at `pose`."""
        d = np.asarray(direction, float) @ pose.R
        return 1.0 - d[..., 2] ** 2 / np.einsum("...i,...i->...", d, d)


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


@numba.njit(cache=True, inline="always")
def _outside(x, h, n):
    """The fraction of the window [x - h, x + h] (a point if h = 0) outside the pixel area [-0.5, n - 0.5]."""
    if h <= 0:
        return 1.0 if (x < -0.5 or x > n - 0.5) else 0.0
    inside = min(x + h, n - 0.5) - max(x - h, -0.5)
    return 1.0 - max(inside, 0.0) / (2 * h)


@numba.njit(cache=True, parallel=True)
def _gather(values, c, r, hc, hr, fill_c, fill_r, stripes, bezel, sin2, black, gamma, gamma_tilt, falloff,
            out):
    """Per point: the lit-area-weighted luminance of the (at most 2 x 2) display pixels its window
    touches, plus the bezel over the window's part outside the pixel area. values: the luminance of each
    display pixel, or (an angle-dependent display, sin2 given) its code value / 255, turned into a
    luminance with the gamma and falloff of the point's viewing angle."""
    height, width = values.shape
    angular = sin2.size > 0
    for i in numba.prange(c.size):
        kc, wc0, wc1 = _weights(c[i], hc, fill_c, stripes)
        kr, wr0, wr1 = _weights(r[i], hr, fill_r, 1)
        g, scale = gamma, 1.0
        if angular:
            g = gamma * (1.0 + gamma_tilt * sin2[i])
            scale = 1.0 - falloff * sin2[i]
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
                v = values[rr, cc]
                if angular:
                    v = scale * (black + (1.0 - black) * (v ** g if v > 0 else 0.0))
                acc += wr * wc * v
        if bezel > 0:
            oc, orow = _outside(c[i], hc, width), _outside(r[i], hr, height)
            acc += bezel * (1.0 - (1.0 - oc) * (1.0 - orow))
        out[i] = acc

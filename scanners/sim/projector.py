"""The simulated fringe projector: an inverse camera (pinhole lens with mild radial distortion) casting
8-bit patterns through its own gamma.

Frames: like `scanners.sim.lenses`, the projector frame has x along panel columns, y along panel rows,
z forward (the optical axis, towards the scene); `rotation` maps projector-frame vectors to the WCS,
`centre_mm` is the projection centre in the WCS (mm). Panel coordinates (c, r) are continuous (column,
row), pixel centres at integers.

Emission: an 8-bit panel value v gives the relative radiant intensity
L(v) = black_level + (1 - black_level) * (v / 255) ** gamma; between pixel centres the panel image is
interpolated linearly along the fringe axis (the projector lens's blur of about one panel pixel). The
irradiance on a surface is L * cos(incidence) * (distance_mm / d)^2 * cos^4(field angle): 1 for a
surface facing the projector at the nominal distance on its axis.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.capture import Pattern
from scanners.sim.lenses import look_at
from scanners.sim.screens import screen_image


@dataclass
class Projector:
    """width_px, height_px: panel size; fx, fy, cx, cy: pinhole intrinsics (panel pixels); k1, k2:
    radial distortion on normalised coordinates (projection: x_d = x (1 + k1 r^2 + k2 r^4));
    rotation: 3x3 projector-to-WCS; centre_mm: (3,) WCS; distance_mm: nominal throw (irradiance 1 there);
    gamma, black_level: the emission curve (module docstring)."""

    width_px: int
    height_px: int
    fx: float
    fy: float
    cx: float
    cy: float
    rotation: np.ndarray
    centre_mm: np.ndarray
    distance_mm: float
    k1: float = -0.02
    k2: float = 0.005
    gamma: float = 2.2
    black_level: float = 0.002

    def project(self, points_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Panel coordinates (c, r) of WCS points (..., 3) and the cosine of their field angle; c is NaN
        for points behind the projector or outside the panel."""
        p = (np.asarray(points_mm, np.float64) - self.centre_mm) @ self.rotation
        z = p[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            x, y = p[..., 0] / z, p[..., 1] / z
        r2 = x * x + y * y
        k = 1 + self.k1 * r2 + self.k2 * r2 * r2
        c, r = self.fx * x * k + self.cx, self.fy * y * k + self.cy
        out = ~((z > 0) & (c >= -0.5) & (c <= self.width_px - 0.5) & (r >= -0.5) & (r <= self.height_px - 0.5))
        c = np.where(out, np.nan, c)
        return c, r, 1.0 / np.sqrt(1.0 + r2)

    def luminance(self, values: np.ndarray) -> np.ndarray:
        """Relative emission (float64) of 8-bit panel values."""
        return self.black_level + (1 - self.black_level) * (np.asarray(values, np.float64) / 255.0) ** self.gamma

    def emission(self, pattern: Pattern, c: np.ndarray) -> np.ndarray:
        """Relative emission (float32) towards panel columns c (an x-axis fringe or a flat; NaN c -> 0)."""
        if pattern.type == "fringe" and pattern.axis != "x":
            raise ValueError("the simulated scanner projects fringes along the panel columns (axis x)")
        line = self.luminance(screen_image(pattern, self.width_px, 1)[0])
        ok = np.isfinite(c)
        t = np.clip(np.where(ok, c, 0.0), 0, self.width_px - 1)
        i = np.minimum(t.astype(np.int64), self.width_px - 2)
        f = t - i
        return np.where(ok, line[i] * (1 - f) + line[i + 1] * f, 0.0).astype(np.float32)

    def irradiance_factor(self, points_mm: np.ndarray, normals: np.ndarray, cos_field: np.ndarray) -> np.ndarray:
        """Geometric irradiance factor (float64, (...)) of surface points with unit normals: cos(incidence)
        * (distance_mm / d)^2 * cos^4(field angle); 0 where the surface faces away."""
        to = self.centre_mm - points_mm
        d = np.linalg.norm(to, axis=-1)
        cos_inc = np.einsum("...i,...i->...", to, normals) / d
        return np.clip(cos_inc, 0, None) * (self.distance_mm / d) ** 2 * cos_field ** 4

    def record(self) -> dict:
        """The projector as the scan manifest's top-level `projector` block states it."""
        return {"width_px": self.width_px, "height_px": self.height_px, "gamma": self.gamma,
                "black_level": self.black_level}


def make_projector(target_mm, distance_mm: float = 420.0, offset_mm=(0.0, -60.0), field_width_mm: float = 320.0,
                   width_px: int = 1280, height_px: int = 800, gamma: float = 2.2, **lens) -> Projector:
    """A projector `distance_mm` in front of `target_mm` (along -z), moved by `offset_mm` (x, y), aimed at
    the target, whose panel width covers `field_width_mm` there. `lens` overrides k1, k2, black_level."""
    target = np.asarray(target_mm, np.float64)
    centre = target + np.array([offset_mm[0], offset_mm[1], -distance_mm])
    throw = float(np.linalg.norm(target - centre))
    f = width_px * throw / field_width_mm
    return Projector(width_px, height_px, f, f, (width_px - 1) / 2, (height_px - 1) / 2,
                     look_at(centre, target), centre, throw, gamma=gamma, **lens)

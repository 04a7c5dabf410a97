"""A tiny independent calibration-capture generator for the unit tests (not the simulator).

A pinhole camera with radial distortion looks at the display; each camera pixel sees the display point
where its true ray meets the pixel plane (through the cover glass if any), and the frame value is the
displayed code value (8-bit rounded, through a gamma) at that continuous display position, plus noise.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from calib.capture import CaptureWriter, CoverGlass, Display, Frame, Pattern
from calib.patterns import step_shifts
from calib.prvm_file import PRVM

DISPLAY = Display(480, 360, (0.25, 0.25))


def true_rays(w=96, h=72, k1=-0.15, f=150.0, dist=150.0):
    """(origin on z=0, direction) (h, w, 3) of a distorted pinhole camera centred on the display."""
    v, u = np.mgrid[0:h, 0:w].astype(float)
    xn, yn = (u - (w - 1) / 2) / f, (v - (h - 1) / 2) / f
    r2 = xn * xn + yn * yn
    xd, yd = xn * (1 + k1 * r2), yn * (1 + k1 * r2)
    d = np.stack([xd, yd, np.ones_like(xd)], axis=-1)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    centre = np.array([DISPLAY.width_px * DISPLAY.pitch_mm[0] / 2, DISPLAY.height_px * DISPLAY.pitch_mm[1] / 2,
                       -dist])
    t = -centre[2] / d[..., 2]
    return centre + t[..., None] * d, d


def _hit(origin, direction, z, glass):
    """Display pixel coordinates (c, r) the ray lights up at stage position z."""
    t = (z - origin[..., 2]) / direction[..., 2]
    p = origin + t[..., None] * direction
    if glass is not None:
        s = direction[..., :2] / direction[..., 2:3]
        t2 = (s * s).sum(-1, keepdims=True)
        sin2 = t2 / (1 + t2)
        tan_in = np.sqrt(sin2 / glass.refractive_index ** 2 / (1 - sin2 / glass.refractive_index ** 2))
        tan_air = np.sqrt(t2)
        with np.errstate(invalid="ignore", divide="ignore"):
            p[..., :2] -= glass.thickness_mm * s * np.where(tan_air > 0, 1 - tan_in / tan_air, 0)
    return p[..., 0] / DISPLAY.pitch_mm[0], p[..., 1] / DISPLAY.pitch_mm[1]


def make_capture(root: Path, w=96, h=72, zs=(0.0, 40.0), periods=(480, 60, 12), steps=3, gamma=1.0,
                 noise=0.0, flat_levels=(), glass: CoverGlass | None = None, seed=0, low=20, high=240,
                 bit_depth=8, gain=1.0, axes=("x", "y"), display=DISPLAY, cover=None):
    """Write a dataset under `root`; returns (capture manifest path, true PRVM).

    cover: optional (c0, c1, r0, r1) display pixel window that shows the pattern (default the whole
    display); outside it the camera sees black. steps: one number, or one per period.
    """
    if cover is None:
        cover = (-0.5, display.width_px - 0.5, -0.5, display.height_px - 0.5)
    rng = np.random.default_rng(seed)
    origin, direction = true_rays(w, h)
    disp = Display(display.width_px, display.height_px, display.pitch_mm, None, glass)
    writer = CaptureWriter(root, "calibration", {"cam0": (w, h)}, disp, bit_depth={"cam0": bit_depth})
    full = 2 ** bit_depth - 1
    scale = full / 255 * gain

    def shoot(code, c, r):
        lum = 255 * (np.clip(code, 0, 255) / 255) ** gamma         # a continuous (interpolated) display
        inside = (c >= cover[0]) & (c <= cover[1]) & (r >= cover[2]) & (r <= cover[3])
        lum = np.where(inside, lum, 0)
        img = lum * scale + rng.normal(0, noise, lum.shape)
        return np.clip(np.rint(img), 0, full).astype(np.uint8 if bit_depth <= 8 else np.uint16)

    for zi, z in enumerate(zs):
        c, r = _hit(origin, direction, z, glass)
        for level in flat_levels:
            f = Frame("cam0", f"z{zi}/flat_{level}.png", Pattern("flat", {"level": level}), z_mm=z)
            writer.add(f, shoot(np.full(c.shape, float(level)), c, r))
        for axis in axes:
            coord = c if axis == "x" else r
            for period, n in zip(periods, [steps] * len(periods) if np.isscalar(steps) else steps):
                for k, delta in enumerate(step_shifts(n)):
                    code = low + (high - low) / 2 * (1 + np.cos(2 * np.pi * coord / period - delta))
                    f = Frame("cam0", f"z{zi}/{axis}_P{period}_s{k}.png",
                              Pattern("fringe", {"axis": axis, "period_px": period, "shift_rad": float(delta),
                                                 "low": low, "high": high}), z_mm=z)
                    writer.add(f, shoot(code, c, r))
    truth = PRVM(origin, direction, np.ones((h, w), bool), None, {"reference_z_mm": 0.0})
    return writer.capture.manifest_path, truth

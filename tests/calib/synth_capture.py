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


def _refraction(direction, glass):
    """(..., 2) how far short (mm, in the display's x, y) of the straight air ray's point on the pixel
    plane a ray of `direction` (the display's frame) lands after crossing the cover glass."""
    if glass is None:
        return np.zeros(direction.shape[:-1] + (2,))
    s = direction[..., :2] / direction[..., 2:3]
    t2 = (s * s).sum(-1, keepdims=True)
    sin2 = t2 / (1 + t2)
    tan_in = np.sqrt(sin2 / glass.refractive_index ** 2 / (1 - sin2 / glass.refractive_index ** 2))
    tan_air = np.sqrt(t2)
    with np.errstate(invalid="ignore", divide="ignore"):
        return glass.thickness_mm * s * np.where(tan_air > 0, 1 - tan_in / tan_air, 0)


def _hit(origin, direction, z, glass):
    """Display pixel coordinates (c, r) the ray lights up at stage position z."""
    t = (z - origin[..., 2]) / direction[..., 2]
    p = origin + t[..., None] * direction
    p[..., :2] -= _refraction(direction, glass)
    return p[..., 0] / DISPLAY.pitch_mm[0], p[..., 1] / DISPLAY.pitch_mm[1]


def _hit_pose(origin, direction, rotation, translation, display, glass=None):
    """Display pixel coordinates (c, r) the ray lights up on a display in pose X = R q + t (through its
    cover glass, if any, lying on the camera's side of the pixel plane)."""
    normal = rotation[:, 2]
    s = ((translation - origin) @ normal) / (direction @ normal)
    q = (origin + s[..., None] * direction - translation) @ rotation
    q[..., :2] -= _refraction(direction @ rotation, glass)
    return q[..., 0] / display.pitch_mm[0], q[..., 1] / display.pitch_mm[1]


def make_capture(root: Path, w=96, h=72, zs=(0.0, 40.0), periods=(480, 60, 12), steps=3, gamma=1.0,
                 noise=0.0, flat_levels=(), glass: CoverGlass | None = None, seed=0, low=20, high=240,
                 bit_depth=8, gain=1.0, axes=("x", "y"), display=DISPLAY, cover=None, poses=None, bayer=None,
                 stage_poses=None):
    """Write a dataset under `root`; returns (capture manifest path, true PRVM).

    cover: optional (c0, c1, r0, r1) display pixel window that shows the pattern (default the whole
    display); outside it the camera sees black. steps: one number, or one per period. poses: instead of
    stage positions, display poses [(R, t), ...] in the cameras' frame (X = R q + t), frames with `pose`,
    flats at pose 0 only; the truth is then in the display's frame at pose 0. stage_poses: with `zs`, the
    display's true pose [(R, t), ...] at each stage position (a stage with errors; the manifest keeps the
    nominal z). bayer: (pattern, {colour: (gain, gamma)}), a raw Bayer camera whose colours see the
    display with their own gain and gamma (instead of `gamma`).
    """
    if cover is None:
        cover = (-0.5, display.width_px - 0.5, -0.5, display.height_px - 0.5)
    rng = np.random.default_rng(seed)
    origin, direction = true_rays(w, h)
    disp = Display(display.width_px, display.height_px, display.pitch_mm, None, glass)
    writer = CaptureWriter(root, "calibration", {"cam0": (w, h)}, disp, bit_depth={"cam0": bit_depth},
                           bayer={"cam0": bayer[0]} if bayer else None)
    full = 2 ** bit_depth - 1
    scale = np.full((h, w), full / 255 * gain)
    power = np.full((h, w), float(gamma))
    if bayer:
        for dy in (0, 1):
            for dx in (0, 1):
                g, gam = bayer[1][bayer[0][2 * dy + dx]]
                scale[dy::2, dx::2] *= g
                power[dy::2, dx::2] = gam

    def shoot(code, c, r):
        lum = 255 * (np.clip(code, 0, 255) / 255) ** power         # a continuous (interpolated) display
        inside = (c >= cover[0]) & (c <= cover[1]) & (r >= cover[2]) & (r <= cover[3])
        lum = np.where(inside, lum, 0)
        img = lum * scale + rng.normal(0, noise, lum.shape)
        return np.clip(np.rint(img), 0, full).astype(np.uint8 if bit_depth <= 8 else np.uint16)

    places = [{"z_mm": z} for z in zs] if poses is None else [{"pose": k} for k in range(len(poses))]
    for zi, where in enumerate(places):
        if stage_poses is not None:
            c, r = _hit_pose(origin, direction, *stage_poses[zi], display, glass)
        elif poses is None:
            c, r = _hit(origin, direction, where["z_mm"], glass)
        else:
            c, r = _hit_pose(origin, direction, *poses[zi], display, glass)
        for level in flat_levels if poses is None or zi == 0 else ():
            f = Frame("cam0", f"z{zi}/flat_{level}.png", Pattern("flat", {"level": level}), **where)
            writer.add(f, shoot(np.full(c.shape, float(level)), c, r))
        for axis in axes:
            coord = c if axis == "x" else r
            for period, n in zip(periods, [steps] * len(periods) if np.isscalar(steps) else steps):
                for k, delta in enumerate(step_shifts(n)):
                    code = low + (high - low) / 2 * (1 + np.cos(2 * np.pi * coord / period - delta))
                    f = Frame("cam0", f"z{zi}/{axis}_P{period}_s{k}.png",
                              Pattern("fringe", {"axis": axis, "period_px": period, "shift_rad": float(delta),
                                                 "low": low, "high": high}), **where)
                    writer.add(f, shoot(code, c, r))
    truth = PRVM(origin, direction, np.ones((h, w), bool), None, {"reference_z_mm": 0.0})
    if poses is not None:                          # the truth in the display's frame at pose 0
        r0, t0 = poses[0]
        d = direction @ r0
        o = (origin - t0) @ r0
        truth = PRVM(o - (o[..., 2] / d[..., 2])[..., None] * d, d, truth.valid, None, truth.meta)
    return writer.capture.manifest_path, truth

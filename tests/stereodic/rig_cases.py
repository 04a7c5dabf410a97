"""Shared set-up of the rig tests: small simulated stereo pairs from the simulator's true rays (no
rendering), and where world points appear in the rectified images."""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from scanners.sim.stereo import project_true, stereo_lenses
from stereodic.stereo.rig import Rig, build_rig
from stereodic.virtual.sampling import bilinear
from stereodic.virtual.camera import project_to_plane

W, H = 320, 256
PIXEL_MM = 0.0053 * 1280 / W          # the full 1280-pixel field of view on a small sensor


@lru_cache(maxsize=8)
def pair(left: str = "brown", right: str = "brown", seed: int = 0):
    """(left lens, right lens, left truth PRVM, right truth PRVM, rig) of a converging pair 200 mm apart."""
    lenses = stereo_lenses(left, right, W, H, seed, pixel_mm=PIXEL_MM)
    prvms = [lens.true_prvm(dataset="simulated stereo") for lens in lenses]
    return (*lenses, *prvms, build_rig(prvms[0], prvms[1]))


def volume_points(rig: Rig, n: int, depth_mm: float, seed: int = 0) -> np.ndarray:
    """(n, 3) WCS points over the common field, at signed distances uniform in +-depth_mm from the plane."""
    rng = np.random.default_rng(seed)
    u, v = rng.uniform(0, rig.sensor.width - 1, n), rng.uniform(0, rig.sensor.height - 1, n)
    h = rng.uniform(-depth_mm, depth_mm, n)
    return rig.sensor.points(u, v) + h[:, None] * rig.sensor.normal


def seen_at(rig: Rig, lens, prvm, points: np.ndarray) -> np.ndarray:
    """(n, 2) virtual (x, row) where each world point appears in the rectified image of the camera with
    true `lens` and calibration `prvm`: the true real pixel seeing it, mapped through the calibration to
    the plane (the inverse of the IMM)."""
    uv = project_true(lens, points)
    return bilinear(project_to_plane(prvm, rig.sensor), uv[:, 0], uv[:, 1])


def inside(rig: Rig, *positions: np.ndarray) -> np.ndarray:
    """Mask of points whose positions all lie on the virtual images."""
    ok = np.ones(len(positions[0]), bool)
    for p in positions:
        ok &= np.isfinite(p).all(axis=1) & (p[:, 0] >= 0) & (p[:, 0] <= rig.sensor.width - 1) \
            & (p[:, 1] >= 0) & (p[:, 1] <= rig.sensor.height - 1)
    return ok

"""Benchmark of the simulated rig (scanners.sim): the time to render one camera frame, the time to
compute a stage position's sub-sample geometry (once per position), and the time and peak memory of
generating the default calibration dataset (`simulate_calibration` defaults: brown lens, 1280x1024,
3x3 supersampling, periods 60/360/1920, 3 steps, 2 positions, 9 flats = 54 frames)."""

from __future__ import annotations

import tempfile
import time

import numpy as np

from stereodic.bench import Figure, best_time, run_isolated


def _render_setup(width: int, height: int):
    from scanners.sim.camera import SimCamera
    from scanners.sim.display import SimDisplay
    from scanners.sim.lenses import make_lens
    cam = SimCamera(make_lens("brown", width=width, height=height), supersample=3)
    display = SimDisplay()
    x = np.arange(display.width_px)
    fringe = np.tile(np.uint8(np.rint(130 + 110 * np.cos(2 * np.pi * x / 60))), (display.height_px, 1))
    return cam, display, fringe


def _dataset(width: int, height: int, positions: tuple) -> int:
    from scanners.sim.calibration import simulate_calibration
    with tempfile.TemporaryDirectory() as tmp:
        return len(simulate_calibration(tmp, width=width, height=height, z_positions=positions).frames)


def run(quick: bool = False) -> list[Figure]:
    from scanners.sim.pose import DisplayPose
    w, h = (320, 256) if quick else (1280, 1024)
    size = f"{w}x{h}"
    cam, display, fringe = _render_setup(w, h)
    cam.view(display, DisplayPose.staged(0.0))   # the first view also compiles the kernels
    t0 = time.perf_counter()
    cam.view(display, DisplayPose.staged(10.0))
    geometry = time.perf_counter() - t0
    render = best_time(lambda: cam.render(fringe, display, DisplayPose.staged(0.0)), repeat=3)
    positions = (0.0,) if quick else (0.0, 50.0)
    seconds, peak, frames = run_isolated(_dataset, w, h, positions)
    return [
        Figure("sim", f"render one {size} frame, 3x3 supersampled", render, "s",
               "project goal", 2.0, "<= 2 s at 1280x1024", render <= 2.0 if not quick else None),
        Figure("sim", f"sub-sample geometry of one stage position, {size}", geometry, "s"),
        Figure("sim", f"default calibration dataset ({frames} frames, {size})", seconds, "s",
               "project goal", 60.0, "< 60 s at 1280x1024", seconds < 60 if not quick else None),
        Figure("sim", "peak memory generating it", peak / 2 ** 20, "MiB"),
    ]

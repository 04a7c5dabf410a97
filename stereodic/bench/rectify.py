"""`stereodic bench rectify`: virtual cameras - applying and building the IMM, its accuracy, straightness.

Each figure group is one function `(quick) -> list[Figure]` listed in SECTIONS; the rectified stereo
pair adds its own sections to that list. Inputs come from the simulated lenses' true rays.
"""

from __future__ import annotations

import cv2
import numpy as np

from scanners.sim.lenses import LENS_FAMILIES, make_lens
from stereodic.bench import Figure, best_time, rig
from stereodic.bench.lines import line_centres, render_lines, straightness_rms
from stereodic.virtual.imm import apply_imm, build_imm
from stereodic.virtual.sampling import bilinear
from stereodic.virtual.camera import default_camera, fit_optical_centre, miss_in_pixels

GROUP = "rectify"
FULL = (2592, 2048)  # 5 MP
QUICK = (640, 512)


def _lens(family: str, size: tuple[int, int]):
    """A simulated lens with the full 1280-pixel field of view on a sensor of `size`."""
    w, h = size
    return make_lens(family, width=w, height=h, seed=1, pixel_mm=0.0053 * 1280 / w)


def _model(family: str) -> str:
    return "telecentric" if family == "telecentric" else "pinhole"


def _paired_best(a, b, repeat: int = 15) -> tuple[float, float]:
    """Best times (s) of `a()` and `b()`, measured alternately so that a busy machine slows both alike."""
    ta, tb = best_time(a, repeat=1), best_time(b, repeat=1)
    for _ in range(repeat - 1):
        ta, tb = min(ta, best_time(a, 1, 0)), min(tb, best_time(b, 1, 0))
    return ta, tb


def imm_speed(quick: bool) -> list[Figure]:
    """IMM build time, and applying it to an 8-bit image against cv2.remap with the same kind of map."""
    size = QUICK if quick else FULL
    prvm = _lens("brown", size).true_prvm()
    cam = default_camera(prvm)
    imm = build_imm(prvm, cam.sensor)  # also the warm-up (first-call imports of scipy's Delaunay)
    build = best_time(lambda: build_imm(prvm, cam.sensor), repeat=2, warmup=0)
    mp = size[0] * size[1] / 1e6
    figs = [Figure(GROUP, f"IMM build, {mp:.1f} MP", build, "s", goal="<= 5 s at 5 MP",
                   ok=build <= 5.0 * mp / 5.3)]
    img = (np.random.default_rng(0).random(size[::-1]) * 255).astype(np.uint8)
    m1, m2 = imm.fixed_point()
    for kind, fixed, maps in (("float32", False, (imm.map_x, imm.map_y)), ("fixed-point", True, (m1, m2))):
        ours, ref = _paired_best(lambda: apply_imm(img, imm, fixed_point=fixed),
                                 lambda: cv2.remap(img, maps[0], maps[1], cv2.INTER_LINEAR,
                                                   borderMode=cv2.BORDER_CONSTANT))
        figs.append(Figure(GROUP, f"IMM apply, {mp:.1f} MP 8-bit, {kind} maps", ours * 1e3, "ms",
                           reference=f"cv2.remap, {kind} maps", reference_value=ref * 1e3,
                           goal="<= 1.1 x reference", ok=ours <= 1.1 * ref))
    return figs


def imm_accuracy(quick: bool) -> list[Figure]:
    """Round-trip closure against the true rays, and the grey-level error of the two map kinds."""
    size = QUICK if quick else FULL
    lens = _lens("brown", size)
    prvm = lens.true_prvm()
    cam = default_camera(prvm)
    imm = build_imm(prvm, cam.sensor)
    o, d = lens.rays(imm.map_x.astype(np.float64), imm.map_y.astype(np.float64))
    uv = cam.sensor.intersect(o, d)
    v, u = np.mgrid[0:size[1], 0:size[0]]
    closure = float(np.sqrt(np.mean((uv[..., 0] - u) ** 2 + (uv[..., 1] - v) ** 2)))
    figs = [Figure(GROUP, "IMM round trip (virtual -> real -> true ray -> virtual), RMS", closure, "px",
                   goal="<= 0.005 px", ok=closure <= 0.005)]
    rng = np.random.default_rng(1)
    img = cv2.GaussianBlur(rng.random(size[::-1]).astype(np.float32), (0, 0), 1.5)
    img = cv2.normalize(img, None, 0, 255, cv2.NORM_MINMAX)
    exact = bilinear(img, imm.map_x, imm.map_y)
    for kind, fixed in (("float32", False), ("fixed-point", True)):
        err = float(np.sqrt(np.mean((apply_imm(img, imm, fixed_point=fixed) - exact) ** 2)))
        figs.append(Figure(GROUP, f"{kind} maps: grey error vs exact bilinear, RMS (texture "
                                  f"{np.sqrt(np.mean(np.square(np.gradient(img)))):.0f} grey/px)", err, "grey"))
    return figs


def straightness(quick: bool) -> list[Figure]:
    """Lines on the plane z = 60 mm through each lens family's true rays, straightness after the IMM."""
    size = (240, 180) if quick else (640, 480)
    figs = []
    for family in LENS_FAMILIES:
        lens = _lens(family, size)
        prvm = lens.true_prvm()
        cam = default_camera(prvm, model=_model(family))
        imm = build_imm(prvm, cam.sensor)
        pitch = cam.sensor.pitch_mm[0]
        rms = []
        for axis in "xy":
            img = render_lines(lens.rays, *size, 60.0, spacing_mm=pitch * size[0] / 8, sigma_mm=2 * pitch,
                               axis=axis)
            rms.append(straightness_rms(line_centres(apply_imm(img, imm), imm.valid, axis, 2.0)))
        value = float(np.sqrt(np.mean(np.square(rms))))
        central = family != "noncentral"
        figs.append(Figure(GROUP, f"straightness, {family} ({_model(family)} model), RMS", value, "px",
                           goal="<= 0.02 px" if central else "", ok=value <= 0.02 if central else None))
        if family == "noncentral":
            centre, miss = fit_optical_centre(prvm)
            px = miss_in_pixels(prvm, centre, miss, 60.0)
            figs.append(Figure(GROUP, "noncentral: pinhole error at z = 60 mm, max", float(np.nanmax(px)), "px"))
    return figs


SECTIONS = [imm_speed, imm_accuracy, straightness, *rig.SECTIONS]


def run(quick: bool = False) -> list[Figure]:
    return [f for section in SECTIONS for f in section(quick)]

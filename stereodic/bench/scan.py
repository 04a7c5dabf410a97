"""`stereodic bench scan`: the structured-light scanner's acceptance test in the manner of VDI/VDE 2634
Part 2, with comparison rows, and its speed.

Data: the default simulated scanner (`scanners.sim.scan.default_scan_rig`: 1280 x 1024 8-bit cameras
with noise, ~200 mm field, 200 mm baseline, 400 mm working distance; periods 1280, 160, 32, 8 panel px
with 3, 3, 3, 16 steps) scans the acceptance scenes (`standard_scenes`: a 50 mm sphere in 2 poses, a
150 mm ball bar in 7 poses, a 180 x 40 mm plate in 4 poses). The same scanner with lenses no pinhole
model follows (RUNS: "noncentral", a camera behind a tilted window; "freeform", a smartphone-like
distortion) scans the sphere and plate poses. The rig is built from the cameras' true PRVMs (no
calibration error: the figures show the scanner's own errors). L0 = the diagonal of the 200 x 160 x
100 mm measuring volume.

Figures, each from the cloud after statistical outlier removal, the points within 0.5 mm of the object
(the object's region; the background plate is not part of it), 99.7 %-trimmed where a range is taken
(the standard allows removing up to 0.3 % of points):
  PF  probing error form: range of radial residuals of a least-squares sphere (max over sphere poses)
  PS  probing error size: fitted minus true diameter (largest magnitude over sphere poses)
  SD  sphere-spacing error: fitted minus true centre distance of the ball bar (largest magnitude, 7 poses)
  F   flatness: range of residuals of a least-squares plane (max over plate poses)
Methods: "virtual pair + EVM" (the scan: rectified virtual pair, filtered phase, model-less rays);
"... no phase filter" (the same without `stereodic.scan.phase_filter`); "virtual pair, pinhole rays" (the
scan's matches, pinhole rays: no EVM); "OpenCV stereoRectify" (each camera's OpenCV model - 14
coefficients, fitted to its true rays - cv2.stereoRectify, the phase maps rectified with
initUndistortRectifyMap and filtered like ours, the same 1-D matcher, cv2.triangulatePoints).

Noise-limited bound (the reference of a figure): what an error-free scanner with the same noise and the
same points would measure. Each real pixel's phase noise sqrt(2/N) sigma_I / B (sigma_I from the sensor
model: shot, read and quantisation noise at the pixel's mean level; B its modulation; N the finest
period's steps) scales a draw of white noise in the real image; it goes through the IMM into the virtual
image and through the phase filter exactly as the phase does, so the draw has the scan's correlations
(the filter's 6.4-fold reduction of white noise is only ~4-fold on the IMM-interpolated phase, and it
correlates neighbouring points, which matters for the averages PS and SD). The match shift is
(n_left - n_right) / (right phase step per pixel); triangulating x_right + shift gives each point's
displacement along the true surface normal. The true surface points plus those displacements are
fitted the same way (5 draws); the bound is the mean figure.
"""

from __future__ import annotations

import shutil
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from calib.capture import Capture
from calib.opencv_baseline import calibrate_opencv
from calib.imageio import write_gray
from calib.phase import phase_sigma
from stereodic.scan.pipeline import SMOOTH_PX, match_and_triangulate, scan_state, virtual_phase
from scanners.sim.scan import (CAMERAS, DEFAULT_PERIODS, L0_MM, ScanRig, default_scan_rig, lit_view, load_truth,
                               render_frame,
                               scan_frames, simulate_scan, standard_scenes)
from scanners.sim.scan_scene import Plane, Sphere, surface_from_dict
from stereodic.bench import Figure, best_time
from stereodic.scan.cloud import make_cloud
from stereodic.scan.fit import fit_plane, fit_sphere, trimmed_range
from stereodic.scan.matching import match_rows
from stereodic.scan.phase_filter import convolve, smooth_phase
from stereodic.stereo.rig import build_rig, load_rig, rig_from_files, save_rig
from stereodic.stereo.triangulate import triangulate

GROUP = "scan"
GOAL_UM = 10.0
EVM, UNFILTERED, PINHOLE, OPENCV = ("virtual pair + EVM", "virtual pair + EVM, no phase filter",
                                    "virtual pair, pinhole rays", "OpenCV stereoRectify")
REGION_MM = 0.5
FRINGES, GRAY_PHASE, GRAY = "fringes", "Gray code + phase shifting", "Gray code alone"
# (lens family, objects): the default scanner, and lenses a pinhole or OpenCV's model cannot follow
RUNS = (("brown", ("sphere", "ballbar", "plane")), ("noncentral", ("sphere", "plane")),
        ("freeform", ("sphere", "plane")))


@dataclass
class Setup:
    """A simulated scan dataset with its scanner, rig and truth."""

    scanner: ScanRig
    capture: object
    rig: object
    truth: dict
    periods: tuple
    lens: str
    smooth_px: float
    code: str = FRINGES


def _setup(folder: str, quick: bool, lens: str = "brown", objects=("sphere", "ballbar", "plane"),
           code: str = FRINGES) -> Setup:
    """The dataset of one scanner; code: FRINGES (the multi-period fringes), GRAY_PHASE (Gray code ordering
    the finest period, 16 steps) or GRAY (Gray code alone)."""
    size, periods = ((320, 256), (1280, 160, 32)) if quick else ((1280, 1024), DEFAULT_PERIODS)
    scanner = default_scan_rig(width=size[0], height=size[1], lens=lens)
    kind = {FRINGES: dict(periods=periods), GRAY_PHASE: dict(periods=periods[-1:], steps=16, gray=True),
            GRAY: dict(periods=(), gray=True)}[code]
    cap = simulate_scan(folder, scenes=standard_scenes(objects=objects), rig=scanner, **kind)
    save_rig(f"{folder}/rig.npz", rig_from_files(f"{folder}/truth_cam0.npz", f"{folder}/truth_cam1.npz"))
    # the phase filter keeps its footprint on the object: SMOOTH_PX at 1280 pixels across
    return Setup(scanner, cap, load_rig(f"{folder}/rig.npz"), load_truth(folder), periods, lens,
                 SMOOTH_PX * size[0] / 1280, code)


# ------------------------------------------------------------------------------------------ OpenCV

@dataclass
class OpenCVPair:
    """OpenCV's rectified stereo pair: per camera the rectification maps and pose, P1, P2."""

    maps: list
    rot: list
    tvec: list
    rect: list
    P1: np.ndarray
    P2: np.ndarray


def opencv_pair(scanner: ScanRig) -> OpenCVPair:
    """Each camera's OpenCV model fitted (calib.opencv_baseline) to its true rays at z = -60 and +60 mm
    (every 8th pixel), then cv2.stereoRectify and initUndistortRectifyMap (float maps, same size)."""
    cams = []
    for lens in (scanner.left, scanner.right):
        v, u = np.mgrid[0:lens.height:8, 0:lens.width:8].astype(np.float64)
        o, d = lens.rays(u.ravel(), v.ravel())
        obj = np.concatenate([o + ((z - o[:, 2]) / d[:, 2])[:, None] * d for z in (-60.0, 60.0)])
        img = np.tile(np.column_stack([u.ravel(), v.ravel()]), (2, 1))
        cams.append(calibrate_opencv(obj, img, lens.width, lens.height))
    size = (scanner.left.width, scanner.left.height)
    r1, r2 = (cv2.Rodrigues(c.rvec)[0] for c in cams)
    t1, t2 = (c.tvec.reshape(3) for c in cams)
    rot = r2 @ r1.T
    R1, R2, P1, P2, _, _, _ = cv2.stereoRectify(cams[0].camera_matrix, cams[0].dist, cams[1].camera_matrix,
                                                cams[1].dist, size, rot, (t2 - rot @ t1).reshape(3, 1),
                                                flags=0, alpha=-1)
    maps = [cv2.initUndistortRectifyMap(c.camera_matrix, c.dist, r, p, size, cv2.CV_32FC1)
            for c, r, p in zip(cams, (R1, R2), (P1, P2))]
    return OpenCVPair(maps, [r1, r2], [t1, t2], [R1, R2], P1, P2)


def opencv_points(pair: OpenCVPair, real_left: np.ndarray, real_right: np.ndarray, smooth_px: float) -> np.ndarray:
    """(N, 3) WCS points from two real absolute-phase maps (NaN = not measured) through OpenCV's pipeline,
    the rectified phase filtered as the scan filters ours (`smooth_phase`), so that only the geometry
    differs."""
    rect = [smooth_phase(cv2.remap(img, m[0], m[1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                                   borderValue=float("nan")), sigma_px=smooth_px)
            for img, m in zip((real_left, real_right), pair.maps)]
    xr = match_rows(rect[0], rect[1])
    row, xl = np.nonzero(np.isfinite(xr))
    pts = np.stack([xl, row]).astype(np.float64), np.stack([xr[row, xl], row]).astype(np.float64)
    x4 = cv2.triangulatePoints(pair.P1, pair.P2, pts[0], pts[1])
    x_rect = (x4[:3] / x4[3]).T
    x_cam = x_rect @ pair.rect[0]                           # R1^T x_rect
    return (x_cam - pair.tvec[0]) @ pair.rot[0]             # R^T (x_cam - t)


# ---------------------------------------------------------------------------------------- figures

def _objects(state: dict) -> list:
    return [surface_from_dict(s) for s in state["surfaces"]]


def _region(points: np.ndarray, surface) -> np.ndarray:
    return points[np.abs(surface.distance(points)) <= REGION_MM]


def _figures(points: np.ndarray, objects: list) -> dict:
    """{"PF", "PS"} for a sphere, {"SD"} for a bar (two spheres), {"F"} for a plane, in mm."""
    if isinstance(objects[0], Plane):
        return {"F": trimmed_range(fit_plane(_region(points, objects[0])).residuals)}
    fits = [fit_sphere(_region(points, s)) for s in objects if isinstance(s, Sphere)]
    if len(fits) == 1:
        return {"PF": trimmed_range(fits[0].residuals), "PS": 2 * (fits[0].radius_mm - objects[0].radius_mm)}
    true = np.linalg.norm(objects[0].centre - objects[1].centre)
    return {"SD": float(np.linalg.norm(fits[0].centre - fits[1].centre) - true)}


def _real_sigma(pm, sensor, period: float) -> np.ndarray:
    """(H, W) phase noise of a real camera's absolute phase (projector px): sqrt(2/N) sigma_I / B of the
    finest period, sigma_I from the sensor model (shot, read and quantisation noise) at the pixel's mean
    level; fractions of full scale throughout."""
    e = np.clip(pm.offset - sensor.dark_offset, 0, None) * sensor.full_well_e
    sigma_i = np.sqrt(e / sensor.full_well_e ** 2 + (sensor.read_noise_e / sensor.full_well_e) ** 2
                      + 1.0 / (12 * sensor.max_dn ** 2))
    with np.errstate(divide="ignore", invalid="ignore"):
        return phase_sigma(pm.steps, sigma_i, pm.modulation) * period / (2 * np.pi)


def _noise_draws(setup: Setup, result, maps: dict, smooth_px: float, draws: int, seed: int = 0) -> np.ndarray:
    """(draws, N) displacement (mm) of each scan point along its own ray pair's depth direction, per
    draw of the sensor noise: white noise of each real pixel's phase sigma, mapped through the IMM into
    the virtual image and through the phase filter exactly as the scan maps the phase (so neighbouring
    points are correlated as in the scan), gives the match shift dx = (n_left - n_right) / (right phase
    step per pixel); returned as dx, to be scaled by the triangulation's d point / d x_right."""
    rig, rng = setup.rig, np.random.default_rng(seed)
    sig = [np.nan_to_num(_real_sigma(pm, setup.scanner.sensor, min(setup.periods)), nan=0.0, posinf=0.0)
           for pm in maps["real"]]
    row = result.row
    xl = result.x_left.astype(np.intp)
    k = np.clip(np.floor(result.x_right).astype(np.intp), 0, rig.sensor.width - 2)
    f = (result.x_right - k).astype(np.float32)
    ph = maps["phase"][1]
    slope = ph[row, k + 1] - ph[row, k]
    out = np.empty((draws, len(row)))
    for d in range(draws):
        fields = []
        for side, s in zip(("left", "right"), sig):
            n = np.nan_to_num(virtual_phase(rig, side, rng.standard_normal(s.shape).astype(np.float32) * s))
            fields.append(convolve(n, smooth_px) if smooth_px > 0 else n)
        n_right = fields[1][row, k] * (1 - f) + fields[1][row, k + 1] * f
        out[d] = (fields[0][row, xl] - n_right) / slope
    return out


def _normals(points: np.ndarray, objects: list) -> np.ndarray:
    d = np.stack([np.abs(s.distance(points)) for s in objects])
    nearest = np.argmin(d, axis=0)
    n = np.zeros_like(points)
    for k, s in enumerate(objects):
        sel = nearest == k
        n[sel] = s.normal if isinstance(s, Plane) else (points[sel] - s.centre) / s.radius_mm
    return n


def _bound(setup: Setup, result, maps: dict, sel: np.ndarray, objects: list, smooth_px: float,
           draws: int = 5) -> dict:
    """Mean figures of the true surface points (the scan's, projected onto the truth) moved by draws of
    the propagated sensor noise (`_noise_draws`), along the true normals: the noise-limited bound."""
    rig = setup.rig
    moved = triangulate(rig, result.x_left[sel], result.x_right[sel] + 0.01, result.row[sel].astype(np.float64))
    points = result.points[sel]
    normal = _normals(points, objects)
    along = np.einsum("ij,ij->i", (moved.points - points) / 0.01, normal)        # mm per pixel of x_right
    dist = np.stack([s.distance(points) for s in objects])
    nearest = np.argmin(np.abs(dist), axis=0)
    on = points - dist[nearest, np.arange(len(points))][:, None] * normal
    out: dict = {}
    for dx in _noise_draws(setup, result, maps, smooth_px, draws)[:, sel]:
        fake = on + (along * dx)[:, None] * normal
        for k, v in _figures(fake, objects).items():
            out.setdefault(k, []).append(abs(v))
    return {k: float(np.mean(v)) for k, v in out.items()}


def acceptance(setup: Setup, compare: bool = True) -> list[Figure]:
    """The PF, PS, SD, F table of one scanner (module docstring): the scan (filtered phase, EVM rays)
    and its bound; with `compare` also the unfiltered scan with its bound, the pinhole rays and OpenCV."""
    truth, rig = setup.truth, setup.rig
    pair = opencv_pair(setup.scanner) if compare else None
    viewpoint = (rig.left.centre + rig.right.centre) / 2
    methods = (EVM, UNFILTERED, PINHOLE, OPENCV) if compare else (EVM,)
    per: dict = {m: {} for m in methods}
    bounds: dict = {m: {} for m in (EVM, UNFILTERED)}
    for st in truth["states"]:
        objects = [s for s in _objects(st) if not (isinstance(s, Plane) and s.size_mm[0] > 300)]  # no background
        clouds = {}
        for m, smooth in ((EVM, setup.smooth_px), (UNFILTERED, 0.0)):
            if m not in methods:
                continue
            result, maps = scan_state(rig, setup.capture, st["state"], smooth_px=smooth)
            _, keep = make_cloud(result.points, {"quality": result.quality}, viewpoint)
            clouds[m] = result.points[keep]
            near = np.min([np.abs(s.distance(result.points)) for s in objects], axis=0) <= REGION_MM
            no_bound = setup.code == GRAY                   # a staircase, not a phase with a noise model
            for k, v in ({} if no_bound else _bound(setup, result, maps, keep & near, objects, smooth)).items():
                bounds[m].setdefault(k, []).append(v)
            if m == EVM and compare:
                pin = match_and_triangulate(rig, *maps["phase"], *maps["modulation"], corrected=False,
                                            matches=maps["matches"])
                clouds[PINHOLE] = pin.points[make_cloud(pin.points, {}, viewpoint)[1]]
                cv = opencv_points(pair, maps["real"][0].coord, maps["real"][1].coord, setup.smooth_px)
                clouds[OPENCV] = cv[make_cloud(cv, {}, viewpoint)[1]]
        for m, pts in clouds.items():
            for k, v in _figures(pts, objects).items():
                per[m].setdefault(k, []).append(v)
    names = {"PF": "probing error form PF", "PS": "probing error size PS", "SD": "sphere-spacing error SD",
             "F": "flatness F"}
    figs = []
    for m in methods:
        for k in ("PF", "PS", "SD", "F"):
            if k not in per[m]:
                continue
            vals = np.asarray(per[m][k])
            worst = float(vals[np.argmax(np.abs(vals))])
            bound = float(np.max(bounds[m][k])) * 1e3 if bounds.get(m, {}).get(k) else None
            ok = abs(worst * 1e3) <= GOAL_UM if m == EVM and setup.lens == "brown" and setup.code != GRAY else None
            what = setup.lens + " lens" + ("" if setup.code == FRINGES else f", {setup.code}")
            figs.append(Figure(GROUP, f"{what}: {names[k]} ({len(vals)} poses), {m}", worst * 1e3, "um",
                               reference="noise-limited bound" if bound is not None else "",
                               reference_value=bound, goal=f"<= {GOAL_UM:g} um" if ok is not None else "", ok=ok))
    return figs


# ------------------------------------------------------------------------------------------ speed

def speed(quick: bool, folder: str) -> list[Figure]:
    """Decode + rectify + filter + match + triangulate one pair of 3 periods x 3 steps, the images
    already in memory, and again read from PNG files; and the 1-D matcher's throughput. Full size:
    2592 x 2048 (5.3 MP) cameras rendered without supersampling (the sampling does not change the work
    of the scan) of the 50 mm sphere before the plate."""
    size = (640, 512) if quick else (2592, 2048)
    scanner = default_scan_rig(width=size[0], height=size[1], supersample=1)
    scene = standard_scenes(objects=("sphere",))[0]
    periods = (1280, 160, 32) if quick else (1280, 120, 12)
    frames = scan_frames(0, periods, 3, 10, 250)
    images = {}
    for name, cam in zip(CAMERAS, scanner.cameras(0)):
        view = lit_view(cam, scene, scanner.projector)
        for f in frames:
            if f.camera == name:
                images[f.file] = render_frame(cam, view, scanner.projector, f.pattern, scanner.ambient)
                write_gray(Path(folder) / f.file, images[f.file])
    truths = [lens.true_prvm(camera=n, wcs="bench") for n, lens in zip(CAMERAS, (scanner.left, scanner.right))]
    rig = build_rig(*truths)
    cap = Capture(Path(folder), "scan", {n: size for n in CAMERAS}, frames, None,
                  (0.0, 0.0, 1.0), {"projector": {**scanner.projector.record(), "periods_px": list(periods),
                                                  "steps": 3}}, {n: 8 for n in CAMERAS})
    mp = size[0] * size[1] / 1e6
    holder = {}

    def run():
        holder["r"] = scan_state(rig, cap, 0, images=images)

    t = best_time(run, repeat=3)
    t_png = best_time(lambda: scan_state(rig, cap, 0), repeat=2)
    result, maps = holder["r"]
    what = f"{mp:.1f} MP pair, 3 periods x 3 steps ({len(result.points) / 1e6:.2f} M points)"
    figs = [Figure(GROUP, f"decode + rectify + filter + match + triangulate, {what}, images in memory", t, "s",
                   goal="<= 2 s at 5 MP", ok=t <= 2.0 * mp / 5.3 if not quick else None),
            Figure(GROUP, "the same, reading the 18 PNG files", t_png, "s")]
    tm = best_time(lambda: match_rows(*maps["phase"]), repeat=5)
    rate = maps["phase"][0].size / tm / 1e6
    figs.append(Figure(GROUP, f"1-D matching throughput ({size[0]}x{size[1]} virtual pair, both directions + "
                              f"consistency)", rate, "Mpx/s", goal=">= 20 Mpx/s", ok=rate >= 20))
    return figs


def run(quick: bool = False) -> list[Figure]:
    figs = []
    with tempfile.TemporaryDirectory(prefix="bench-scan-") as tmp:
        for k, (lens, objects) in enumerate(RUNS[:1] if quick else RUNS):
            t0 = time.perf_counter()
            setup = _setup(f"{tmp}/{lens}", quick, lens, objects)
            sim = time.perf_counter() - t0
            figs += acceptance(setup)
            figs.append(Figure(GROUP, f"{lens} lens: simulating the {len(setup.truth['states'])} acceptance scans",
                               sim, "s"))
            shutil.rmtree(f"{tmp}/{lens}")
        for code in (GRAY_PHASE, GRAY):
            setup = _setup(f"{tmp}/gray", quick, "brown", RUNS[0][1], code)
            figs += acceptance(setup, compare=False)
            shutil.rmtree(f"{tmp}/gray")
        figs.append(Figure(GROUP, "measuring volume diagonal L0", L0_MM, "mm"))
        figs += speed(quick, f"{tmp}/speed")
    return figs

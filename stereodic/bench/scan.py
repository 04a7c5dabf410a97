"""`stereodic bench scan`: the structured-light scanner's acceptance test in the manner of VDI/VDE 2634
Part 2, with comparison rows, and its speed.

Data: the default simulated scanner (`scanners.sim.scan.default_scan_rig`: 1280 x 1024 8-bit cameras
with noise, ~200 mm field, 200 mm baseline, 400 mm working distance; periods 1280, 120, 12 panel px, 3
steps) scans the acceptance scenes (`standard_scenes`: a 50 mm sphere in 2 poses, a 150 mm ball bar in 7
poses, a 180 x 40 mm plate in 4 poses). The rig is built from the cameras' true PRVMs (no calibration
error: the figures show the scanner's own errors). L0 = the diagonal of the 200 x 160 x 100 mm
measuring volume.

Figures, each from the cloud after statistical outlier removal, the points within 0.5 mm of the object
(the object's region; the background plate is not part of it), 99.7 %-trimmed where a range is taken
(the standard allows removing up to 0.3 % of points):
  PF  probing error form: range of radial residuals of a least-squares sphere (max over sphere poses)
  PS  probing error size: fitted minus true diameter (largest magnitude over sphere poses)
  SD  sphere-spacing error: fitted minus true centre distance of the ball bar (largest magnitude, 7 poses)
  F   flatness: range of residuals of a least-squares plane (max over plate poses)
Methods: "virtual pair + EVM" (the scan: rectified virtual pair, model-less rays), "virtual pair,
pinhole rays" (the same matches, pinhole rays: no EVM), "OpenCV" (each camera's OpenCV model - 14
coefficients, fitted to its true rays - cv2.stereoRectify, the phase maps rectified with
initUndistortRectifyMap, the same 1-D matcher, cv2.triangulatePoints).

Noise-limited bound (the reference of each figure): what an error-free scanner with the same per-point
noise and the same points would measure. Per point, the phase noise of each camera, sqrt(2/N) sigma_I / B
(sigma_I from the sensor model: shot, read and quantisation noise at the pixel's mean level; B its
modulation), scaled by the bilinear interpolation into the virtual image, gives the right image's match
noise sigma_x = sqrt(sigma_L^2 + sigma_R^2) / (phase step per pixel); triangulating x_right + dx gives
the point's displacement, whose component along the true surface normal is the point's noise. The true
surface points plus that Gaussian noise are fitted the same way (5 draws); the bound is the mean figure
(a range for PF and F, |error| for PS and SD, ~ sigma / sqrt(N) for those).
"""

from __future__ import annotations

import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from calib.capture import Capture
from calib.opencv_baseline import calibrate_opencv
from scanners.scan import match_and_triangulate, scan_state
from scanners.sim.scan import (CAMERAS, L0_MM, ScanRig, default_scan_rig, lit_view, load_truth, render_frame,
                               scan_frames, simulate_scan, standard_scenes)
from scanners.sim.scan_scene import Plane, Sphere, surface_from_dict
from stereodic.bench import Figure, best_time
from stereodic.cloud import make_cloud
from stereodic.fit import fit_plane, fit_sphere, trimmed_range
from stereodic.matching import match_rows
from stereodic.rig import build_rig, load_rig
from stereodic.triangulate import triangulate

GROUP = "scan"
GOAL_UM = 10.0
METHODS = ("virtual pair + EVM", "virtual pair, pinhole rays", "OpenCV stereoRectify")
REGION_MM = 0.5


@dataclass
class Setup:
    """A simulated scan dataset with its scanner, rig and truth."""

    scanner: ScanRig
    capture: object
    rig: object
    truth: dict
    periods: tuple


def _setup(folder: str, quick: bool) -> Setup:
    size, periods = ((320, 256), (1280, 160, 32)) if quick else ((1280, 1024), (1280, 120, 12))
    scanner = default_scan_rig(*size)
    scenes = standard_scenes(("sphere", "ballbar", "plane"))
    cap = simulate_scan(folder, scenes, scanner, periods)
    return Setup(scanner, cap, load_rig(f"{folder}/rig.npz"), load_truth(folder), periods)


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


def opencv_points(pair: OpenCVPair, real_left: np.ndarray, real_right: np.ndarray) -> np.ndarray:
    """(N, 3) WCS points from two real absolute-phase maps (NaN = not measured) through OpenCV's pipeline."""
    rect = [cv2.remap(img, m[0], m[1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=float("nan"))
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


def _point_noise(setup: Setup, result, maps: dict, objects: list, steps: int) -> np.ndarray:
    """(N,) predicted noise (mm) of each scan point along its true surface normal (module docstring)."""
    rig, sensor = setup.rig, setup.scanner.sensor
    period = min(setup.periods)
    row = result.row
    xl = result.x_left.astype(np.intp)
    xr = np.clip(np.rint(result.x_right).astype(np.intp), 0, rig.sensor.width - 2)
    sig = []
    for side, x in (("left", xl), ("right", xr)):
        off = maps["offset"][0 if side == "left" else 1][row, x]
        mod = maps["modulation"][0 if side == "left" else 1][row, x]
        e = np.clip(off - sensor.dark_offset, 0, None) * sensor.full_well_e
        sigma_i = np.sqrt(e / sensor.full_well_e ** 2 + (sensor.read_noise_e / sensor.full_well_e) ** 2
                          + 1.0 / (12 * sensor.max_dn ** 2))
        imm = rig.camera(side).imm
        a = imm.map_x[row, x] % 1.0
        b = imm.map_y[row, x] % 1.0
        interp = np.sqrt(((1 - a) ** 2 + a ** 2) * ((1 - b) ** 2 + b ** 2))
        sig.append(np.sqrt(2.0 / steps) * sigma_i / mod * period / (2 * np.pi) * interp)
    ph = maps["phase"][1]
    slope = np.abs(ph[row, xr + 1] - ph[row, xr])
    sigma_x = np.hypot(*sig) / slope
    moved = triangulate(rig, result.x_left, result.x_right + 0.01, row.astype(np.float64)).points
    dp = (moved - result.points) / 0.01
    normal = _normals(result.points, objects)
    return np.abs(np.einsum("ij,ij->i", dp, normal)) * sigma_x


def _normals(points: np.ndarray, objects: list) -> np.ndarray:
    d = np.stack([np.abs(s.distance(points)) for s in objects])
    nearest = np.argmin(d, axis=0)
    n = np.zeros_like(points)
    for k, s in enumerate(objects):
        sel = nearest == k
        n[sel] = s.normal if isinstance(s, Plane) else (points[sel] - s.centre) / s.radius_mm
    return n


def _bound(points: np.ndarray, sigma: np.ndarray, objects: list, draws: int = 5) -> dict:
    """Mean figures of the true surface points (the scan's, projected onto the truth) plus Gaussian
    noise `sigma` along the normals."""
    normal = _normals(points, objects)
    dist = np.stack([s.distance(points) for s in objects])
    nearest = np.argmin(np.abs(dist), axis=0)
    on = points - dist[nearest, np.arange(len(points))][:, None] * normal
    rng = np.random.default_rng(0)
    out: dict = {}
    for _ in range(draws):
        fake = on + (rng.standard_normal(len(on)) * sigma)[:, None] * normal
        for k, v in _figures(fake, objects).items():
            out.setdefault(k, []).append(abs(v))
    return {k: float(np.mean(v)) for k, v in out.items()}


def acceptance(setup: Setup) -> list[Figure]:
    """The PF, PS, SD, F table (module docstring)."""
    truth, rig = setup.truth, setup.rig
    pair = opencv_pair(setup.scanner)
    viewpoint = (rig.left.centre + rig.right.centre) / 2
    steps = setup.capture.extra["projector"]["steps"]
    per = {m: {} for m in METHODS}
    bounds: dict = {}
    for st in truth["states"]:
        objects = [s for s in _objects(st) if not (isinstance(s, Plane) and s.size_mm[0] > 300)]  # no background
        result, maps = scan_state(rig, setup.capture, st["state"])
        _, keep = make_cloud(result.points, {"quality": result.quality}, viewpoint)
        pin = match_and_triangulate(rig, *maps["phase"], *maps["modulation"], corrected=False,
                                    matches=maps["matches"])
        cv = opencv_points(pair, maps["real"][0].coord, maps["real"][1].coord)
        _, keep_cv = make_cloud(cv, {}, viewpoint)
        _, keep_pin = make_cloud(pin.points, {}, viewpoint)
        clouds = {METHODS[0]: result.points[keep], METHODS[1]: pin.points[keep_pin], METHODS[2]: cv[keep_cv]}
        for m, pts in clouds.items():
            for k, v in _figures(pts, objects).items():
                per[m].setdefault(k, []).append(v)
        sigma = _point_noise(setup, result, maps, objects, steps)
        near = np.min([np.abs(s.distance(result.points)) for s in objects], axis=0) <= REGION_MM
        sel = keep & near
        for k, v in _bound(result.points[sel], sigma[sel], objects).items():
            bounds.setdefault(k, []).append(v)
    names = {"PF": "probing error form PF", "PS": "probing error size PS", "SD": "sphere-spacing error SD",
             "F": "flatness F"}
    figs = []
    for m in METHODS:
        for k in ("PF", "PS", "SD", "F"):
            vals = np.asarray(per[m][k])
            worst = float(vals[np.argmax(np.abs(vals))])
            bound = float(np.max(bounds[k]))
            value_um = worst * 1e3
            ok = abs(value_um) <= GOAL_UM if m == METHODS[0] else None
            figs.append(Figure(GROUP, f"{names[k]} ({len(vals)} poses), {m}", value_um, "um",
                               reference="noise-limited bound", reference_value=bound * 1e3,
                               goal=f"<= {GOAL_UM:g} um" if m == METHODS[0] else "", ok=ok))
    figs.append(Figure(GROUP, "measuring volume diagonal L0", L0_MM, "mm"))
    return figs


# ------------------------------------------------------------------------------------------ speed

def speed(quick: bool, folder: str) -> list[Figure]:
    """Decode + rectify + match + triangulate one pair of 3 periods x 3 steps (images in memory), and the
    1-D matcher's throughput. Full size: 2592 x 2048 (5.3 MP) cameras rendered without supersampling
    (the sampling does not change the work of the scan) of the 50 mm sphere before the plate."""
    size = (640, 512) if quick else (2592, 2048)
    scanner = default_scan_rig(*size, supersample=1)
    scene = standard_scenes(("sphere",))[0]
    periods = (1280, 160, 32) if quick else (1280, 120, 12)
    frames = scan_frames(0, periods, 3, 10, 250)
    images = {}
    for name, cam in zip(CAMERAS, scanner.cameras(0)):
        view = lit_view(cam, scene, scanner.projector)
        for f in frames:
            if f.camera == name:
                images[f.file] = render_frame(cam, view, scanner.projector, f.pattern, scanner.ambient)
    truths = [lens.true_prvm(camera=n, wcs="bench") for n, lens in zip(CAMERAS, (scanner.left, scanner.right))]
    rig = build_rig(*truths)
    cap = Capture(Path(folder), "scan", {n: size for n in CAMERAS}, frames, None,
                  (0.0, 0.0, 1.0), {"projector": {**scanner.projector.record(), "periods_px": list(periods),
                                                  "steps": 3}}, {n: 8 for n in CAMERAS})
    mp = size[0] * size[1] / 1e6
    holder = {}

    def run():
        holder["r"] = scan_state(rig, cap, 0, images=images)

    t = best_time(run, repeat=2)
    result, maps = holder["r"]
    figs = [Figure(GROUP, f"decode + rectify + match + triangulate, {mp:.1f} MP pair, 3 periods x 3 steps "
                          f"({len(result.points) / 1e6:.2f} M points)", t, "s", goal="<= 2 s at 5 MP",
                   ok=t <= 2.0 * mp / 5.3 if not quick else None)]
    tm = best_time(lambda: match_rows(*maps["phase"]), repeat=5)
    rate = maps["phase"][0].size / tm / 1e6
    figs.append(Figure(GROUP, f"1-D matching throughput ({size[0]}x{size[1]} virtual pair, both directions + "
                              f"consistency)", rate, "Mpx/s", goal=">= 20 Mpx/s", ok=rate >= 20))
    return figs


def run(quick: bool = False) -> list[Figure]:
    with tempfile.TemporaryDirectory(prefix="bench-scan-") as tmp:
        t0 = time.perf_counter()
        setup = _setup(f"{tmp}/data", quick)
        sim = time.perf_counter() - t0
        figs = acceptance(setup)
        figs.append(Figure(GROUP, f"simulating the {len(setup.truth['states'])} acceptance scans", sim, "s"))
        figs += speed(quick, f"{tmp}/speed")
    return figs

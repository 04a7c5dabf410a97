"""`stereodic bench rectify`, the rectified stereo pair: row error, EVM vs pinhole triangulation, the
OpenCV comparison, export exactness and rectification speed (group "rectify", beside the
virtual-camera figures of stereodic.bench.rectify).

Row error: true 3D points over the common field, +-60 mm about the common plane; each camera sees a
point at the true real pixel whose TRUE ray passes through it (`scanners.sim.stereo.project_true`), and
the rectified image shows it at the virtual pixel whose calibrated ray crosses the plane there (the
inverse of the IMM). The error is the RMS of row(left) - row(right).

OpenCV comparison (one run, same simulated rig, display and stage): ours = fringe dataset -> calibrate
both cameras -> rig; OpenCV = chessboards rendered on the same display at the same stage positions
(5 placements in the common field per position) -> findChessboardCornersSB -> calibrateCamera
(5 coefficients, initialised as calib.opencv_baseline does) per camera -> stereoCalibrate ->
stereoRectify -> the true real pixels through undistortPoints(R1, P1) / (R2, P2). The two pipelines
rectify at different scales, so both row errors are given in real-camera pixels (times the real focal
length over the rectified one).
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from scanners.sim.stereo import project_true, simulate_stereo, stereo_lenses
from stereodic.bench import Figure
from stereodic.stereo.rig import Rig, build_rig
from stereodic.virtual.sampling import bilinear
from stereodic.stereo.triangulate import triangulate
from stereodic.virtual.camera import project_to_plane

GROUP = "rectify"
CENTRAL_MIXES = (("brown", "brown"), ("brown", "freeform"), ("freeform", "scheimpflug"))
POINTS = 20_000


def _pair(left: str, right: str, width: int, height: int):
    lenses = stereo_lenses(left, right, width, height, seed=2, pixel_mm=0.0053 * 1280 / width)
    prvms = [lens.true_prvm(dataset="bench") for lens in lenses]
    return lenses, prvms


def _volume(rig: Rig, n: int, depth_mm: float, exact: bool = False, seed: int = 0) -> np.ndarray:
    """(n, 3) WCS points over the common field, +-depth_mm from the plane (uniform, or exactly +-)."""
    rng = np.random.default_rng(seed)
    u, v = rng.uniform(0, rig.sensor.width - 1, n), rng.uniform(0, rig.sensor.height - 1, n)
    h = rng.choice([-depth_mm, depth_mm], n) if exact else rng.uniform(-depth_mm, depth_mm, n)
    return rig.sensor.points(u, v) + h[:, None] * rig.sensor.normal


def _seen(rig: Rig, lens, prvm, x: np.ndarray, uv: np.ndarray | None = None) -> np.ndarray:
    """(n, 2) rectified position of world points x in the camera of true `lens`, calibration `prvm`."""
    uv = project_true(lens, x) if uv is None else uv
    return bilinear(project_to_plane(prvm, rig.sensor), uv[:, 0], uv[:, 1])


def _inside(rig: Rig, *pos) -> np.ndarray:
    ok = np.ones(len(pos[0]), bool)
    for p in pos:
        ok &= np.isfinite(p).all(1) & (p[:, 0] >= 0) & (p[:, 0] <= rig.sensor.width - 1) & (p[:, 1] >= 0) \
            & (p[:, 1] <= rig.sensor.height - 1)
    return ok


def row_error(quick: bool) -> list[Figure]:
    """Row error with the true rays as the calibration (the rig's geometry alone), per lens mix."""
    size = (320, 256) if quick else (1280, 1024)
    figs = []
    for left, right in CENTRAL_MIXES + (("noncentral", "noncentral"),):
        lenses, prvms = _pair(left, right, *size)
        rig = build_rig(*prvms)
        x = _volume(rig, POINTS // 4 if quick else POINTS, 60.0)
        pl, pr = (_seen(rig, ln, p, x) for ln, p in zip(lenses, prvms))
        ok = _inside(rig, pl, pr)
        rms = float(np.sqrt(np.mean((pl[ok, 1] - pr[ok, 1]) ** 2)))
        central = left != "noncentral"
        figs.append(Figure(GROUP, f"stereo row error, {left}+{right}, true rays, +-60 mm, RMS", rms, "px",
                           goal="<= 0.01 px" if central else "", ok=rms <= 0.01 if central else None))
    return figs


def evm_triangulation(quick: bool) -> list[Figure]:
    """3D error of points exactly 50 mm in front of / behind the plane, non-central lenses."""
    size = (320, 256) if quick else (1280, 1024)
    figs = []
    for left, right in (("noncentral", "noncentral"), ("noncentral", "brown")):
        lenses, prvms = _pair(left, right, *size)
        rig = build_rig(*prvms)
        x = _volume(rig, POINTS // 4 if quick else POINTS, 50.0, exact=True)
        pl, pr = (_seen(rig, ln, p, x) for ln, p in zip(lenses, prvms))
        ok = _inside(rig, pl, pr)
        err = {}
        for corrected in (True, False):
            t = triangulate(rig, pl[ok, 0], pr[ok, 0], pl[ok, 1], row_right=pr[ok, 1], corrected=corrected)
            err[corrected] = float(np.sqrt(np.mean(np.sum((t.points - x[ok]) ** 2, axis=1))))
        figs.append(Figure(GROUP, f"3D error +-50 mm, {left}+{right}, EVM-corrected rays, RMS", err[True] * 1e3,
                           "um", "pinhole rays (Q matrix)", err[False] * 1e3, "<= 1/10 of pinhole",
                           err[True] <= err[False] / 10))
    return figs


def export_exactness(quick: bool) -> list[Figure]:
    """cv2.triangulatePoints with the exported P1, P2 against our plane points."""
    from stereodic.stereo.export import stereo_matrices
    lenses, prvms = _pair("brown", "freeform", *((320, 256) if quick else (1280, 1024)))
    rig = build_rig(*prvms)
    m = stereo_matrices(rig)
    rng = np.random.default_rng(0)
    x, r = rng.uniform(0, rig.sensor.width - 1, 10_000), rng.uniform(0, rig.sensor.height - 1, 10_000)
    h = cv2.triangulatePoints(m["P1"], m["P2"], np.stack([x, r]), np.stack([x, r]))
    wcs = ((h[:3] / h[3]).T - m["T_wcs"].ravel()) @ m["R_wcs"]
    ours = triangulate(rig, x, x, r, corrected=False).points
    rel = float(np.abs(wcs - ours).max() / rig.working_distance_mm)
    return [Figure(GROUP, "export: cv2.triangulatePoints(P1, P2) vs ours on the plane, max / working distance",
                   rel, "", goal="<= 1e-6", ok=rel <= 1e-6)]


def rectify_speed(quick: bool) -> list[Figure]:
    """Rectifying one 8-bit pair (IMM only, float maps)."""
    from stereodic.bench import best_time
    from stereodic.stereo.rectify import rectify_pair
    size = (640, 512) if quick else (1280, 1024)
    lenses, prvms = _pair("brown", "brown", *size)
    t0 = time.perf_counter()
    rig = build_rig(*prvms)
    build = time.perf_counter() - t0
    img = (np.random.default_rng(0).random(size[::-1]) * 255).astype(np.uint8)
    pair_time = best_time(lambda: rectify_pair(rig, img, img), repeat=5)
    mp = size[0] * size[1] / 1e6
    return [Figure(GROUP, f"rig build, 2 x {mp:.1f} MP", build, "s"),
            Figure(GROUP, f"rectify a {mp:.1f} MP 8-bit pair", pair_time * 1e3, "ms")]


def _import_pair(path: str, out: str) -> tuple[float, int]:
    """What `stereodic import PATH -o OUT` does, in this process: (CPU seconds, the rig file's bytes)."""
    from stereodic.formats import import_calibration
    from stereodic.stereo.rig import save_rig
    t0 = time.process_time()
    save_rig(out, import_calibration([path]).result)
    return time.process_time() - t0, Path(out).stat().st_size


def _use_rig(out: str) -> float:
    """`load_rig(OUT)` and both cameras' maps and rays (what rectify, dic and scan read): CPU seconds."""
    from stereodic.stereo.rig import SIDES, load_rig
    t0 = time.process_time()
    rig = load_rig(out)
    for side in SIDES:
        rig.camera(side).imm, rig.camera(side).direction
    return time.process_time() - t0


def import_speed(quick: bool) -> list[Figure]:
    """`stereodic import` of an OpenCV stereo calibration of a 6016 x 4016 (24 MP) pair (1504 x 1004 with
    --quick): 5 coefficients, cameras 300 mm apart converging by 15 degrees; time, CPU and peak memory of
    the fresh process that imports it, the rig file against the two 8-bit images it describes, and the
    first use of the rig (its maps and rays computed from the models) in another fresh process."""
    from stereodic.bench import run_isolated
    w, h = (1504, 1004) if quick else (6016, 4016)
    f = 12000.0 * w / 6016
    K = np.array([[f, 0, (w - 1) / 2 + 0.5], [0, f, (h - 1) / 2 + 0.5], [0, 0, 1]])
    R = cv2.Rodrigues(np.array([0.0, -0.26, 0.0]))[0]
    with tempfile.TemporaryDirectory() as tmp:
        path = str(Path(tmp) / "stereo.yml")
        fs = cv2.FileStorage(path, cv2.FILE_STORAGE_WRITE)
        for key, value in (("M1", K), ("D1", np.array([[-0.12, 0.3, 5e-4, -3e-4, -0.5]])), ("M2", K),
                           ("D2", np.array([[-0.11, 0.25, -2e-4, 4e-4, -0.4]])), ("R", R),
                           ("T", (-R @ [300.0, 0, 0]).reshape(3, 1)), ("image_width", w), ("image_height", h)):
            fs.write(key, value)
        fs.release()
        wall, peak, (cpu, size) = run_isolated(_import_pair, path, str(Path(tmp) / "rig.npz"))
        use_wall, use_peak, use_cpu = run_isolated(_use_rig, str(Path(tmp) / "rig.npz"))
    mp = w * h / 1e6
    return [Figure(GROUP, f"import a {mp:.0f} MP OpenCV pair, wall (fresh process)", wall, "s", goal="<= 60 s",
                   ok=wall <= 60 or quick),
            Figure(GROUP, f"import a {mp:.0f} MP OpenCV pair, CPU", cpu, "s"),
            Figure(GROUP, f"import a {mp:.0f} MP OpenCV pair, peak memory", peak / 2 ** 30, "GiB", goal="<= 4 GiB",
                   ok=peak <= 4 * 2 ** 30),
            Figure(GROUP, f"import a {mp:.0f} MP OpenCV pair, rig file", size / 1e6, "MB",
                   "the two 8-bit images", 2 * w * h / 1e6, "<= the images", size <= 2 * w * h),
            Figure(GROUP, "its rig's first use (maps and rays of both cameras), wall", use_wall, "s"),
            Figure(GROUP, "its rig's first use, CPU", use_cpu, "s"),
            Figure(GROUP, "its rig's first use, peak memory", use_peak / 2 ** 30, "GiB", goal="<= 4 GiB",
                   ok=use_peak <= 4 * 2 ** 30)]


# ------------------------------------------------------------------------------- OpenCV comparison

def _boards(lenses, capture, seed: int, supersample: int, squares=(9, 7)):
    """Chessboard images of both cameras, same placements (in the common display field) at every stage
    position of `capture`: list of (nominal z, WCS corners (K, 3), [left image, right image])."""
    from calib.capture import Pattern
    from calib.opencv_baseline import chessboard_display_corners
    from scanners.sim.camera import SimCamera
    from scanners.sim.display import SimDisplay
    from scanners.sim.screens import screen_image
    from scanners.sim.sensor import Sensor
    from scanners.sim.stage import SimStage
    display = SimDisplay()
    z_nominal = capture.z_positions("cam0")
    stage = SimStage(tuple(z_nominal), 3.0, (0.0, 0.0, 1.0), seed)   # simulate_calibration's stage
    lo, hi = np.full(2, -np.inf), np.full(2, np.inf)
    for lens in lenses:
        o, d = lens.rays(*lens.pixel_grid())
        for pose in stage.poses:
            cr = np.stack(display.hit(o, d, pose), axis=-1).reshape(-1, 2)
            lo, hi = np.maximum(lo, np.percentile(cr, 3, 0)), np.minimum(hi, np.percentile(cr, 97, 0))
    field = hi - lo
    size = int(0.6 * min(field[0] / squares[0], field[1] / squares[1]))
    board = np.array(squares) * size
    slack = (field - board) / 2 * 0.8
    cams = []
    for k, lens in enumerate(lenses):
        cam = SimCamera(lens, sensor=Sensor(), supersample=supersample, seed=seed + 17 * k)
        cam.set_exposure(display, 240, stage.poses[0])
        cams.append(cam)
    out = []
    for zn, pose in zip(z_nominal, stage.poses):
        for dx, dy in ((0, 0), (-1, -1), (1, -1), (-1, 1), (1, 1)):
            origin = [int(round((lo + hi)[0] / 2 - board[0] / 2 + dx * slack[0])),
                      int(round((lo + hi)[1] / 2 - board[1] / 2 + dy * slack[1]))]
            pattern = Pattern("chessboard", {"squares": list(squares), "square_px": size, "origin_px": origin,
                                             "low": 20, "high": 240})
            image = screen_image(pattern, display.width_px, display.height_px)
            cr = chessboard_display_corners(squares, size, origin)
            out.append((zn, capture.display_to_wcs(cr[:, 0], cr[:, 1], zn),
                        [cam.render(image, display, pose) for cam in cams]))
    return out


def _opencv_stereo(boards, width: int, height: int):
    """OpenCV's pipeline on the boards: (M1, D1, R1, P1, M2, D2, R2, P2)."""
    from calib.opencv_baseline import calibrate_opencv, chessboard_corners
    views = []
    for _, obj, images in boards:
        corners = [chessboard_corners(img, (9, 7)) for img in images]
        if all(c is not None for c in corners):
            views.append((obj.astype(np.float32), [c.astype(np.float32) for c in corners]))
    if len(views) < 4:
        raise RuntimeError(f"OpenCV found the chessboard in both cameras in only {len(views)} views")
    cams = [calibrate_opencv(np.concatenate([v[0] for v in views]), np.concatenate([v[1][k] for v in views]),
                             width, height, flags=0) for k in range(2)]
    (k1, d1), (k2, d2) = [(c.camera_matrix, c.dist[:5]) for c in cams]
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-12)
    _, k1, d1, k2, d2, rot, t, _, _ = cv2.stereoCalibrate(
        [v[0] for v in views], [v[1][0] for v in views], [v[1][1] for v in views], k1, d1, k2, d2,
        (width, height), None, None, flags=cv2.CALIB_USE_INTRINSIC_GUESS,
        criteria=crit)
    r1, r2, p1, p2, _, _, _ = cv2.stereoRectify(k1, d1, k2, d2, (width, height), rot, t, alpha=0)
    return (k1, d1, r1, p1), (k2, d2, r2, p2)


def opencv_comparison(quick: bool) -> list[Figure]:
    """Row error of our calibrated rig against OpenCV's stereo pipeline, same rig (module docstring)."""
    from calib.calibration import calibrate_camera
    from calib.capture import load_capture
    width, height = (320, 256) if quick else (640, 512)
    figs = []
    for left, right in (("brown", "brown"), ("freeform", "freeform")):
        with tempfile.TemporaryDirectory(prefix="bench_rig_") as root:
            supersample = max(3, -(-1280 // width))
            out = simulate_stereo(Path(root) / "st", left=left, right=right, width=width, height=height, seed=3,
                                  lens_options={"pixel_mm": 0.0053 * 1280 / width}, supersample=supersample)
            capture = load_capture(out)
            prvms = [calibrate_camera(capture, camera=cam).prvm for cam in ("cam0", "cam1")]
            lenses = stereo_lenses(left, right, width, height, 3, pixel_mm=0.0053 * 1280 / width)
            rig = build_rig(*prvms)
            x = _volume(rig, POINTS // 4, 60.0)
            uv = [project_true(lens, x) for lens in lenses]
            ours = [_seen(rig, lens, p, x, q) for lens, p, q in zip(lenses, prvms, uv)]
            ok = _inside(rig, *ours) & np.isfinite(uv[0]).all(1) & np.isfinite(uv[1]).all(1)
            scale = lenses[0].params["fx"] * rig.sensor.pitch_mm[1] / rig.working_distance_mm
            ours_rms = float(np.sqrt(np.mean((ours[0][ok, 1] - ours[1][ok, 1]) ** 2))) * scale
            cv_cams = _opencv_stereo(_boards(lenses, capture, 3, supersample), width, height)
            rect = [cv2.undistortPoints(q[ok].reshape(-1, 1, 2), k, d, R=r, P=p).reshape(-1, 2)
                    for q, (k, d, r, p) in zip(uv, cv_cams)]
            cv_scale = lenses[0].params["fx"] / cv_cams[0][3][1, 1]
            cv_rms = float(np.sqrt(np.mean((rect[0][:, 1] - rect[1][:, 1]) ** 2))) * cv_scale
        goal, good = ("<= OpenCV", ours_rms <= cv_rms) if left == "brown" else ("10x lower", ours_rms * 10 <= cv_rms)
        figs.append(Figure(GROUP, f"stereo row error vs OpenCV, {left}+{right}, calibrated, {width}x{height}, RMS",
                           ours_rms, "real px", "OpenCV stereoCalibrate + stereoRectify (chessboards)", cv_rms,
                           goal, good))
    return figs


SECTIONS = [row_error, evm_triangulation, export_exactness, rectify_speed, import_speed, opencv_comparison]


"""Benchmark of the PRVM calibration (issue 3): accuracy per lens family against the simulator's truth
(unregularised and regularised, the phase-noise bound, OpenCV's 14-coefficient model fed dense
correspondences and chessboards), and the speed and peak memory of decoding and fitting a 5 MP camera.

Data: `scanners.sim.calibration.simulate_calibration` with its defaults (1280x1024, periods 60/360/1920,
3 steps, 2 stage positions, 9 flats, gamma 2.2, noise), plus chessboards; the 5 MP speed data is simulated
at 2592x2048 (2.6 um pixels, so the display still covers the field) with supersample=1.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from stereodic.bench import Figure, run_isolated

LENSES = ("brown", "freeform", "noncentral", "telecentric", "scheimpflug")


def phase_noise_bound_px(capture, cal, truth) -> float:
    """RMS over valid pixels of the ray error (camera px, working plane = first stage position) that the
    phase noise alone causes: sigma_c = sqrt(2/N) * sigma_I / B * P / (2 pi) display px per axis, with
    sigma_I from the simulated sensor's shot and read noise at the pixel's mean signal."""
    from calib.evaluate import footprint_mm, working_plane
    from calib.phase import phase_sigma
    s = truth.meta["sensor"]
    gain_e = s["full_well_e"] / (2 ** s["bit_depth"] - 1)            # electrons per DN
    p = cal.positions[0]
    im = cal.intensity
    var = 0.0
    for a in range(2):
        mean_dn = im.offset + im.gain * p.mean[a]
        mod_dn = im.gain * p.modulation[a]
        sigma_i = np.sqrt(np.maximum(mean_dn, 0) * gain_e + s["read_noise_e"] ** 2) / gain_e
        sigma_i = np.sqrt(sigma_i ** 2 + 1 / 12)                       # quantisation
        sig_c = phase_sigma(p.steps[a], sigma_i, mod_dn) * p.period_px[a] / (2 * np.pi)
        var = var + (sig_c * capture.display.pitch_mm[a]) ** 2
    fp = footprint_mm(truth, working_plane(truth))
    ok = cal.prvm.valid & np.isfinite(var)
    return float(np.sqrt(np.mean(var[ok])) / fp)


def _opencv_chessboard(capture, camera, width, height):
    import cv2

    from calib.opencv_baseline import calibrate_opencv, chessboard_corners, chessboard_display_corners
    obj, img = [], []
    for f in capture.select(camera, type="chessboard"):
        corners = chessboard_corners(capture.read(f), tuple(f.pattern.squares))
        if corners is None:
            continue
        cr = chessboard_display_corners(tuple(f.pattern.squares), f.pattern.square_px,
                                        f.pattern.params.get("origin_px", [0, 0]))
        obj.append(capture.display_to_wcs(cr[:, 0], cr[:, 1], f.z_mm))
        img.append(corners)
    if len({round(o[0, 2], 6) for o in obj}) < 2:
        return None
    try:
        return calibrate_opencv(np.concatenate(obj), np.concatenate(img), width, height)
    except cv2.error:
        return None


def accuracy(lens: str, width: int, height: int, root: str, chessboard: bool = True) -> dict:
    """Simulate one lens family and measure every method against its truth; errors in camera pixels."""
    from calib.calibration import calibrate_camera
    from calib.capture import load_capture
    from calib.evaluate import ErrorStats, ray_error_px
    from calib.opencv_baseline import calibrate_opencv, dense_correspondences
    from calib.prvm_file import PRVM, load_prvm
    from scanners.sim.calibration import simulate_calibration
    out = Path(root) / lens
    simulate_calibration(out, lens=lens, width=width, height=height, chessboard=chessboard)
    capture, truth = load_capture(out), load_prvm(out / "truth.npz")
    cal = calibrate_camera(capture)
    raw = PRVM(cal.raw.origin(), cal.raw.direction(), cal.raw.valid)
    res = {"raw": ErrorStats.of(ray_error_px(raw, truth)), "reg": ErrorStats.of(ray_error_px(cal.prvm, truth)),
           "bound": phase_noise_bound_px(capture, cal, truth)}
    pts = [capture.display_to_wcs(p.coord[0], p.coord[1], p.z_mm) for p in cal.positions]
    obj, img = dense_correspondences(pts, [p.valid for p in cal.positions], step=8)
    ocv = calibrate_opencv(obj, img, width, height)
    o, d = ocv.rays(width, height)
    res["opencv_dense"] = ErrorStats.of(ray_error_px(PRVM(o, d, np.ones((height, width), bool)), truth))
    board = _opencv_chessboard(capture, "cam0", width, height)
    if board is not None:
        o, d = board.rays(width, height)
        res["opencv_chess"] = ErrorStats.of(ray_error_px(PRVM(o, d, np.ones((height, width), bool)), truth))
    return res


def decode_and_fit(path: str) -> dict:
    """Calibrate the dataset at `path` (run in a fresh process for the timing and peak memory)."""
    from calib.calibration import calibrate_camera
    from calib.capture import load_capture
    cal = calibrate_camera(load_capture(path))
    return {"valid": float(cal.prvm.valid.mean())}


def run(quick: bool = False) -> list[Figure]:
    from scanners.sim.calibration import simulate_calibration
    width, height = (320, 256) if quick else (1280, 1024)
    figs: list[Figure] = []
    with tempfile.TemporaryDirectory(prefix="bench_calib_") as root:
        for lens in LENSES:
            r = accuracy(lens, width, height, root, chessboard=not quick)
            reg, raw = r["reg"], r["raw"]
            g = f"calib/{lens}"
            figs.append(Figure(g, "ray error RMS, regularised", reg.rms, "px", goal="<= 0.02", ok=reg.rms <= 0.02))
            figs.append(Figure(g, "ray error p99, regularised", reg.p99, "px", goal="<= 0.06", ok=reg.p99 <= 0.06))
            figs.append(Figure(g, "ray error RMS, unregularised", raw.rms, "px", "phase-noise bound", r["bound"],
                               "<= 1.2x bound", raw.rms <= 1.2 * r["bound"]))
            cv = r["opencv_dense"].rms
            ratio_goal = (reg.rms <= 1.5 * cv) if lens == "brown" else (cv >= 10 * reg.rms)
            figs.append(Figure(g, "ray error RMS vs OpenCV dense", reg.rms, "px", "OpenCV 14-coef, dense", cv,
                               "<= 1.5x OpenCV" if lens == "brown" else "10x lower", ratio_goal))
            if "opencv_chess" in r:
                figs.append(Figure(g, "ray error RMS vs OpenCV chessboard", reg.rms, "px",
                                   "OpenCV 14-coef, chessboard", r["opencv_chess"].rms))
        w5, h5 = (640, 512) if quick else (2592, 2048)
        path = Path(root) / "speed"
        # a 5 MP sensor of 2.6 um pixels: the field of the 1.3 MP default, covered by the display
        simulate_calibration(path, lens="brown", width=w5, height=h5, supersample=1,
                             lens_options={"pixel_mm": 0.0053 * 1280 / w5})
        seconds, peak, _ = run_isolated(decode_and_fit, str(path))
        mp = w5 * h5 / 1e6
        figs.append(Figure("calib/speed", f"decode + fit {mp:.1f} MP, 2 positions, 3x3x2 fringes + 9 flats",
                           seconds, "s", goal="<= 10 s" if not quick else "", ok=seconds <= 10 if not quick else None))
        figs.append(Figure("calib/speed", f"peak memory {mp:.1f} MP", peak / 2 ** 30, "GiB",
                           goal="<= 2 GiB" if not quick else "", ok=peak <= 2 * 2 ** 30 if not quick else None))
    return figs

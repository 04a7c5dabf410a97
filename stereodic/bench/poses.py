"""Benchmark rows of `stereodic bench calib` for issue 14: calibration without a stage (a hand-held
display), pose refinement below the stage floor, Bayer cameras, and the speed of a 5 MP hand-held
calibration.

Every ray error is in camera pixels of the working plane, against the simulator's truth in the frame of
the estimate: a staged calibration's WCS is the display at its first position and a hand-held one's the
display at pose 0, so the truth (in the simulator's nominal frame) is moved there by the known TRUE pose
of that display (never by a fit of the estimate to the truth). Hand-held and staged results are then
compared in one frame, the simulator's: both moved there by that true pose, on the planes z = 0 (the
working plane, ~400 mm from the camera) and -25 ... 75 mm (the working volume of the 0-50 mm stage).

- Hand-held: 8 poses at 300-600 mm tilted up to 35 degrees (`scanners.sim.handheld`), on the
  brown, non-central and free-form lenses, against a staged calibration with the same number of fringe
  frames (8 positions over 0-50 mm, 3 um stage errors); the estimated poses against the true ones (the
  translation of the centre of the display area the camera saw, and the rotation); a display moved
  (0.2 mm, 0.1 degree) halfway through one pose's fringes.
- Staged, realistic stage errors (3 um along the axis, 0.01 degree tilt, 5 um lateral per position),
  3 positions 0/25/50 mm, every lens family: the stage floor (the true rays' display points fitted at
  the nominal poses, and at the refined ones), the calibration with and without refinement, and for the
  Scheimpflug lens OpenCV on the same decoded points.
- Bayer: an RGGB camera (per-colour response, lateral chromatic aberration), each colour's photosites
  against the truth, beside a monochrome camera of the same lens on the same bench.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from stereodic.bench import PERIODS, Figure, run_isolated

HANDHELD_LENSES = ("brown", "noncentral", "freeform")
STAGE_LENSES = ("brown", "freeform", "noncentral", "telecentric", "scheimpflug")
POSES = 8
REALISTIC = dict(stage_error_um=3.0, stage_tilt_deg=0.01, stage_lateral_um=5.0)
PLANES = np.linspace(-25.0, 75.0, 11)


def _stats(prvm, truth) -> dict:
    """Plane (z = 0) and volume (`PLANES`) error statistics (camera px) of a PRVM against a truth in
    the same frame."""
    from calib.evaluate import ErrorStats, ray_error_px, volume_error_px
    return {"plane": ErrorStats.of(ray_error_px(prvm, truth, z_mm=0.0)),
            "volume": ErrorStats.of(volume_error_px(prvm, truth, PLANES))}


def _staged_truth(truth):
    """The truth of a staged simulation in the estimate's WCS: the display's frame at the first
    position (its true pose)."""
    r, t = truth.extra["display_rotation"][0], truth.extra["display_translation_mm"][0]
    return truth.transformed(r.T, -r.T @ t)


def _rays(lines):
    from calib.prvm_file import PRVM
    return PRVM(lines.origin(), lines.direction(), lines.valid, meta={"reference_z_mm": lines.z_ref})


def _floor(truth, rotation, translation, pitch) -> dict:
    """`_stats` of the true rays' display points (`display_cr`) fitted at the given display poses (in
    the frame of the first position's display; pitch: the display's, mm), against the truth in that
    frame."""
    from calib.prvm import fit_posed_lines
    cr = truth.extra["display_cr"].astype(np.float64)
    lines = fit_posed_lines([c.transpose(2, 0, 1) for c in cr], [np.ones(cr.shape[1:3], np.float32)] * len(cr),
                            rotation, translation, pitch).lines
    return _stats(_rays(lines), _staged_truth(truth))


def handheld_errors(cal, truth) -> tuple[float, float, float, float]:
    """(largest translation error (um) of the centre of the seen display area, largest rotation error
    (degrees), largest reported 1-sigma of each) over the poses used, against the truth's poses."""
    from calib.poses import log_so3
    rep = cal.poses
    rt, tt = truth.extra["display_rotation"], truth.extra["display_translation_mm"]
    dt, dr, st, sr = [], [], [], []
    for k in np.flatnonzero(rep.used):
        c = rep.centre_mm[k]
        q = rep.rotation[k].T @ (c - rep.translation[k])
        dt.append(1000 * np.linalg.norm(c - (rt[k] @ q + tt[k])))
        dr.append(np.degrees(np.linalg.norm(log_so3(rep.rotation[k] @ rt[k].T))))
        st.append(np.linalg.norm(rep.sd_translation_um[k]))
        sr.append(np.linalg.norm(rep.sd_rotation_deg[k]))
    return max(dt), max(dr), max(st), max(sr)


def _field(width: int) -> dict:
    """simulate_calibration's lens and sampling options for a width-pixel sensor with the field of the
    default 1280-pixel one (a hand-held calibration's conditioning depends on the field of view)."""
    return {"lens_options": {"pixel_mm": 0.0053 * 1280 / width}, "supersample": max(3, -(-1280 // width))}


def handheld_accuracy(lens: str, width: int, height: int, root: Path, poses: int = POSES,
                      disturbed: int | None = None) -> dict:
    """Simulate a hand-held capture and calibrate it: `_stats` in the simulator's frame, the pose
    errors, and the poses left out."""
    from calib.calibration import calibrate_camera
    from calib.capture import load_capture
    from calib.prvm_file import load_prvm
    from scanners.sim.calibration import simulate_calibration
    from scanners.sim.handheld import HandHeld
    out = root / f"handheld_{lens}{'' if disturbed is None else '_disturbed'}"
    simulate_calibration(out, lens=lens, width=width, height=height,
                         handheld=HandHeld(poses=poses, disturbed=disturbed), **_field(width))
    cal = calibrate_camera(load_capture(out))
    truth = load_prvm(out / "truth.npz")
    r, t = truth.extra["sim_rotation"], truth.extra["sim_translation_mm"]
    return {"stats": _stats(cal.prvm.transformed(r, t), truth.transformed(r, t)),
            "poses": handheld_errors(cal, truth), "left_out": list(np.flatnonzero(~cal.poses.used)),
            "chi": cal.poses.chi}


def staged_accuracy(lens: str, width: int, height: int, root: Path, positions, stage: dict, name: str,
                    refine_too: bool = False) -> dict:
    """Simulate a staged capture and calibrate it (refinement as by default; with `refine_too` also
    without): `_stats` in the first display's frame, the floors, and the OpenCV comparison."""
    from calib.calibration import calibrate_camera
    from calib.capture import load_capture
    from calib.opencv_baseline import calibrate_opencv, dense_correspondences
    from calib.prvm_file import PRVM, load_prvm
    from scanners.sim.calibration import simulate_calibration
    out = root / name
    simulate_calibration(out, lens=lens, width=width, height=height, z_positions=positions, **stage,
                         **({"periods": PERIODS[lens]} if lens in PERIODS else {}), **_field(width))
    capture, truth = load_capture(out), load_prvm(out / "truth.npz")
    moved = _staged_truth(truth)
    cal = calibrate_camera(capture)
    res = {"refined": _stats(cal.prvm, moved), "used": cal.poses is not None and cal.poses.used}
    if refine_too:
        res["nominal"] = _stats(calibrate_camera(capture, refine=False).prvm, moved)
        zn = truth.extra["stage_nominal_z_mm"]
        rotation = np.broadcast_to(np.eye(3), (len(zn), 3, 3))
        pitch = capture.display.pitch_mm
        res["floor_nominal"] = _floor(truth, rotation, np.stack([0 * zn, 0 * zn, zn], axis=1), pitch)
        res["floor_refined"] = _floor(truth, *cal.poses.poses, pitch)
        pts = [capture.display_to_wcs(p.coord[0], p.coord[1], p.z_mm) for p in cal.positions]
        obj, img = dense_correspondences(pts, [p.valid for p in cal.positions])
        o, d = calibrate_opencv(obj, img, width, height).rays(width, height)
        res["opencv"] = _stats(PRVM(o, d, np.ones((height, width), bool)), moved)
    return res


def bayer_accuracy(lens: str, width: int, height: int, root: Path) -> dict:
    """Per-colour plane error RMS of a Bayer camera and the RMS of a monochrome one (same lens, bench)."""
    from calib.bayer import colour_map
    from calib.calibration import calibrate_camera
    from calib.capture import load_capture
    from calib.evaluate import ErrorStats, ray_error_px
    from calib.prvm_file import load_prvm
    from scanners.sim.bayer import BayerSensor
    from scanners.sim.calibration import simulate_calibration
    res = {}
    for name, bayer in (("bayer", BayerSensor()), ("mono", None)):
        out = root / f"{name}_{lens}"
        simulate_calibration(out, lens=lens, width=width, height=height, bayer=bayer, **_field(width))
        cal, truth = calibrate_camera(load_capture(out)), load_prvm(out / "truth.npz")
        err = ray_error_px(cal.prvm, _staged_truth(truth), z_mm=0.0)
        if bayer is None:
            res["mono"] = ErrorStats.of(err).rms
        else:
            colour = colour_map(bayer.pattern, height, width)
            res.update({c: ErrorStats.of(np.where(colour == c, err, np.nan)).rms for c in "RGB"})
    return res


def calibrate_path(path: str) -> dict:
    """Calibrate the dataset at `path` (run in a fresh process for the timing and peak memory)."""
    from calib.calibration import calibrate_camera
    from calib.capture import load_capture
    cal = calibrate_camera(load_capture(path))
    return {"valid": float(cal.prvm.valid.mean())}


def run(quick: bool = False, floors: dict | None = None) -> list[Figure]:
    """The rows (module docstring). floors: the stage floor (plane RMS, camera px) that `stereodic
    bench calib` measures per lens on its standard bench, the reference of the refined floors."""
    from scanners.sim.calibration import simulate_calibration
    from scanners.sim.handheld import HandHeld
    floors = floors or {}
    # --quick: 320 x 256 sensors of the default field (their stage floor then differs from `floors`)
    width, height = (320, 256) if quick else (1280, 1024)
    figs: list[Figure] = []
    with tempfile.TemporaryDirectory(prefix="bench_poses_") as tmp:
        root = Path(tmp)
        for lens in HANDHELD_LENSES[:1] if quick else HANDHELD_LENSES:
            g = f"calib/handheld/{lens}"
            hh = handheld_accuracy(lens, width, height, root)
            st = staged_accuracy(lens, width, height, root, list(np.linspace(0, 50, POSES)), {},
                                 f"staged8_{lens}")
            for where in ("plane", "volume"):
                ours, ref = hh["stats"][where].rms, st["refined"][where].rms
                figs.append(Figure(g, f"ray error RMS, {POSES} hand-held poses ({where}), {ours / ref:.2f}x staged",
                                   ours, "px", f"staged, {POSES} positions, same fringe frames", ref, "<= 2x staged",
                                   ours <= 2 * ref))
            dt, dr, st_, sr = hh["poses"]
            figs.append(Figure(g, "pose error, largest translation (centre of the seen area)", dt, "um",
                               "its reported 1-sigma", st_, "<= 5 um", dt <= 5))
            figs.append(Figure(g, "pose error, largest rotation", dr, "deg", "its reported 1-sigma", sr,
                               "<= 0.002 deg", dr <= 0.002))
        g = "calib/handheld/brown"
        dist = handheld_accuracy("brown", width, height, root, disturbed=3)
        flagged = dist["left_out"] == [3]
        figs.append(Figure(g, "display moved 0.2 mm / 0.1 deg during pose 3's fringes: its out-of-family "
                              "statistic", float(dist["chi"][3]), "", "threshold", 5.0, "flagged, alone",
                           flagged))
        figs.append(Figure(g, "ray error RMS with the moved pose left out (plane)", dist["stats"]["plane"].rms, "px"))

        for lens in STAGE_LENSES[:1] if quick else STAGE_LENSES:
            g = f"calib/stage/{lens}"
            r = staged_accuracy(lens, width, height, root, [0.0, 25.0, 50.0], REALISTIC, f"staged3_{lens}",
                                refine_too=True)
            today = floors.get(lens)
            plane = r["floor_refined"]["plane"].rms
            figs.append(Figure(g, "stage floor, 3 positions, realistic errors, nominal poses (plane)",
                               r["floor_nominal"]["plane"].rms, "px"))
            figs.append(Figure(g, "stage floor, refined poses (plane)", plane, "px",
                               *(("stage floor today (2 positions, 3 um)", today, "<= 1/3 of today's",
                                  plane <= today / 3) if today is not None else ())))
            figs.append(Figure(g, "stage floor, nominal / refined poses (volume)", r["floor_refined"]["volume"].rms,
                               "px", "nominal poses", r["floor_nominal"]["volume"].rms))
            for where in ("plane", "volume"):
                figs.append(Figure(g, f"ray error RMS, refined poses {'used' if r['used'] else 'NOT used'} ({where})",
                                   r["refined"][where].rms, "px", "--no-refine-poses", r["nominal"][where].rms))
            if lens == "scheimpflug":
                ratio = r["opencv"]["plane"].rms / r["refined"]["plane"].rms
                figs.append(Figure(g, f"ray error RMS vs OpenCV dense (plane), OpenCV/ours {ratio:.2f}",
                                   r["refined"]["plane"].rms, "px", "OpenCV 14-coef, dense, nominal positions",
                                   r["opencv"]["plane"].rms))

        b = bayer_accuracy("brown", width, height, root)
        for c in "RGB":
            figs.append(Figure("calib/bayer/brown", f"ray error RMS, {c} photosites of an RGGB camera (plane)", b[c],
                               "px", "monochrome camera, same lens and bench", b["mono"]))

        w5, h5 = (640, 512) if quick else (2592, 2048)
        path = root / "speed5"
        simulate_calibration(path, lens="brown", width=w5, height=h5, supersample=2 if quick else 1,
                             lens_options={"pixel_mm": 0.0053 * 1280 / w5}, handheld=HandHeld(poses=POSES))
        seconds, peak, _ = run_isolated(calibrate_path, str(path))
        mp = w5 * h5 / 1e6
        figs.append(Figure("calib/speed", f"hand-held calibration {mp:.1f} MP, {POSES} poses, 3x3x2 fringes + 9 flats",
                           seconds, "s", goal="" if quick else "<= 60 s", ok=None if quick else seconds <= 60))
        figs.append(Figure("calib/speed", f"peak memory, hand-held {mp:.1f} MP", peak / 2 ** 30, "GiB",
                           goal="" if quick else "<= 4 GiB", ok=None if quick else peak <= 4 * 2 ** 30))
    return figs

"""The end-to-end demo on the built-in simulated rig: every step is a real `stereodic` command, printed
before it runs so that a user can repeat it by hand, and every command says what it wrote.

Each step is a function that takes the output folder; its docstring's first line, one sentence, is the
step's heading. A figure of merit against the simulator's ground truth is printed after the steps that
have one.
"""

from __future__ import annotations

import shlex
import sys
import time
from pathlib import Path

import numpy as np


DEMO_LENS = "freeform"            # the lens OpenCV's models cannot follow
DEMO_SIZE = ("640", "512")
STEREO_SIZE = ("480", "384")     # two cameras to render and calibrate: smaller, to keep the demo short


def _run(*argv: str) -> None:
    """Run one `stereodic` command in-process; a non-zero status stops the demo."""
    from stereodic.cli import main
    print(f"$ stereodic {shlex.join(argv)}", flush=True)
    t0 = time.perf_counter()
    status = main(list(argv))
    if status:
        raise SystemExit(status)
    print(f"  ({time.perf_counter() - t0:.1f} s)", flush=True)


def calibration(out: Path) -> None:
    """Calibrate a free-form lens from simulated fringes and hold its rays against the simulator's truth."""
    from calib.evaluate import ErrorStats, ray_error_px
    from calib.prvm_file import load_prvm
    data = out / "calibration"
    _run("simulate", "calibration", "--lens", DEMO_LENS, "--width", DEMO_SIZE[0], "--height", DEMO_SIZE[1],
         "-o", str(data))
    _run("calibrate", str(data), "-o", str(out / "cam0.npz"), "--report", str(out / "report"))
    truth = load_prvm(data / "truth.npz")
    stats = ErrorStats.of(ray_error_px(load_prvm(out / "cam0.npz"), truth))
    print(f"  ray error against the truth: RMS {stats.rms:.4f} px, 99th percentile {stats.p99:.4f} px, "
          f"{stats.valid:.1%} of pixels calibrated")
    _run("show", str(out / "cam0.npz"), "--truth", str(data / "truth.npz"), "-o", str(out / "report"))


def virtual_camera(out: Path) -> None:
    """Undistort one captured frame with the camera's virtual pinhole model, and export the model."""
    frame = sorted((out / "calibration").glob("z*/cam0_flat_*.png"))[0].parent / "cam0_x_P60_s0.png"
    _run("undistort", str(out / "cam0.npz"), str(frame), "-o", str(out / "undistorted"))
    _run("export", str(out / "cam0.npz"), "--format", "opencv", "-o", str(out / "cam0_pinhole.yaml"))


def stereo(out: Path) -> None:
    """Calibrate a stereo pair, build its rectified virtual rig and export the rig for OpenCV.

    The pair: Brown-Conrady lens left, free-form right."""
    data = out / "stereo"
    _run("simulate", "stereo", "--left", "brown", "--right", DEMO_LENS, "--width", STEREO_SIZE[0],
         "--height", STEREO_SIZE[1], "-o", str(data))
    for cam in ("cam0", "cam1"):
        _run("calibrate", str(data), "--camera", cam, "-o", str(out / f"stereo_{cam}.npz"))
    _run("rig", str(out / "stereo_cam0.npz"), str(out / "stereo_cam1.npz"), "-o", str(out / "rig.npz"))
    _run("export", str(out / "rig.npz"), "--format", "opencv", "-o", str(out / "rig_opencv.yaml"))


def scan(out: Path) -> None:
    """Scan a simulated sphere with the fringe-projection scanner and check its fitted diameter."""
    from scanners.sim.scan import load_truth
    from scanners.sim.scan_scene import Sphere, surface_from_dict
    import open3d as o3d

    from stereodic.scan.fit import fit_sphere
    data = out / "scan"
    _run("simulate", "scan", "--objects", "sphere", "--width", DEMO_SIZE[0], "--height", DEMO_SIZE[1],
         "-o", str(data))
    _run("scan", str(data / "rig.npz"), str(data), "--state", "0", "-o", str(out / "sphere.ply"))
    sphere = next(s for s in map(surface_from_dict, load_truth(data)["states"][0]["surfaces"])
                  if isinstance(s, Sphere))
    pts = np.asarray(o3d.io.read_point_cloud(str(out / "sphere.ply")).points)
    near = pts[np.abs(sphere.distance(pts)) < 1.0]
    fit = fit_sphere(near)
    print(f"  sphere: {len(near)} of the cloud's {len(pts)} points lie within 1 mm of the true sphere (the "
          f"rest: the wall behind it)")
    print(f"  sphere: fitted diameter {2 * fit.radius_mm:.4f} mm, true "
          f"{2 * sphere.radius_mm:.4f} mm, form error (range) {1000 * np.ptp(fit.residuals):.1f} um")


def dic2d(out: Path) -> None:
    """Measure a known sub-pixel translation of a speckle image with 2D DIC."""
    import csv

    shift = (0.35, -0.20)
    _run("simulate", "dic2d", "--shift", f"{shift[0]},{shift[1]}", "-o", str(out / "dic"))
    _run("dic2d", str(out / "dic" / "reference.png"), str(out / "dic" / "moved.png"), "--subset", "21",
         "--step", "8", "-o", str(out / "dic" / "displacements.csv"))
    with open(out / "dic" / "displacements.csv") as f:
        rows = [r for r in csv.DictReader(f) if r["converged"] == "1"]
    u = np.array([float(r["u"]) for r in rows])
    v = np.array([float(r["v"]) for r in rows])
    print(f"  {len(rows)} points: mean u {u.mean():+.4f} px (true {shift[0]:+.2f}), mean v {v.mean():+.4f} px "
          f"(true {shift[1]:+.2f}), std {u.std():.4f} / {v.std():.4f} px")


def dic3d(out: Path) -> None:
    """Rectify a speckled plate's image pair, then measure its shape, 3D displacement and strain with stereo DIC.

    The rectified pair's overlay shows the row alignment (speckle has the texture it needs). States:
    translation, rotation, 1 % tension, bulge; the tension state's strain is held against the truth."""
    from scanners.sim.dic import load_dic_truth, truth_at_pixels
    from stereodic.stereo.rig import load_rig
    data = out / "dic3d"
    _run("simulate", "dic", "-o", str(data))
    _run("rectify", str(data / "rig.npz"), str(data / "s000" / "cam0.png"), str(data / "s000" / "cam1.png"), "-o",
         str(out / "rectified"))
    _run("dic", str(data / "rig.npz"), str(data), "-o", str(out / "dic3d_result"))
    truth = load_dic_truth(data)
    tension = next(k for k, st in enumerate(truth.states) if st.name == "tension")
    rows = np.genfromtxt(out / "dic3d_result" / "dic.csv", delimiter=",", names=True, dtype=None,
                         encoding="utf-8")
    rows = rows[(rows["state"] == tension) & (rows["strain_valid"] == 1)]
    # the material point of each row: the one the left camera sees where the rig's IMM puts the row's grid
    # point in the original image; its truth from the simulator's own lens and plate
    true = truth_at_pixels(truth, load_rig(data / "rig.npz").left.imm.real_position(rows["x"], rows["y"]))
    for c in ("exx", "eyy"):
        print(f"  tension, {c}: measured mean {rows[c].mean() * 1e6:.0f}, true {true[c][tension].mean() * 1e6:.0f} "
              f"microstrain, mean error {(rows[c] - true[c][tension]).mean() * 1e6:+.1f} microstrain "
              f"over {len(rows)} points")


STEPS = [calibration, virtual_camera, stereo, scan, dic2d, dic3d]


def run_demo(output: str) -> int:
    out = Path(output)
    out.mkdir(parents=True, exist_ok=True)
    np.seterr(all="ignore")
    t0 = time.perf_counter()
    for k, step in enumerate(STEPS, 1):
        print(f"\n== {k}/{len(STEPS)}. {step.__doc__.splitlines()[0]}", flush=True)
        step(out)
    print(f"\ndemo finished in {time.perf_counter() - t0:.0f} s; everything it wrote is in {out}/. Pictures "
          f"to look at: {out}/report/error_xy.png (ray error), {out}/rectified/overlay.png (row alignment), "
          f"{out}/dic3d_result/maps/ (strain), {out}/sphere.ply (open it in CloudCompare or MeshLab)",
          file=sys.stderr)
    return 0

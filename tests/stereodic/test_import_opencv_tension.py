"""A lab's workflow on the simulated rig: chessboards rendered by the simulated stereo rig
(scanners.sim.stereo, chessboard=True), OpenCV's calibrateCamera and stereoCalibrate on them, the
stereo_calib YAML written, `stereodic import` of it, then the simulated 1 % tension test
(scanners.sim.dic, the same two cameras) correlated with that rig: the existing strain goal holds.

OpenCV's stereo file has camera 1's frame as its world; the boards' object points are given in the
simulator's WCS (display pixels at the stage position), so the pose of camera 1 in that WCS (solvePnP on
all its corners, written as R_wcs / T_wcs) puts the imported rig in the truth's frame."""

import cv2
import numpy as np
import pytest

from calib.capture import load_capture
from calib.opencv_baseline import calibrate_opencv, chessboard_corners, chessboard_display_corners
from scanners.sim.dic import DicState, simulate_dic
from scanners.sim.stereo import simulate_stereo
from stereodic.cli import main
from stereodic.dic import DicSettings, make_grid
from stereodic.dic3d.dataset import load_states
from stereodic.dic3d.stereo import StereoDic, StereoSettings
from stereodic.stereo.rig import load_rig

pytestmark = pytest.mark.slow
W, H, SEED = 640, 512, 0


def _corners(capture):
    """Per camera, the WCS points (N, 3) and image corners (N, 2) of every board found in both cameras."""
    obj, img = [], [[], []]
    boards = [f for f in capture.frames if f.pattern.type == "chessboard" and f.camera == "cam0"]
    for f0 in boards:
        f1 = next(f for f in capture.frames if f.camera == "cam1" and f.pattern == f0.pattern and f.z_mm == f0.z_mm)
        p = f0.pattern.params
        found = [chessboard_corners(capture.read(f), tuple(p["squares"])) for f in (f0, f1)]
        if any(c is None for c in found):
            continue
        cr = chessboard_display_corners(tuple(p["squares"]), p["square_px"], p["origin_px"])
        obj.append(capture.display_to_wcs(cr[:, 0], cr[:, 1], f0.z_mm))
        for k in range(2):
            img[k].append(found[k])
    return np.concatenate(obj), [np.concatenate(i) for i in img], len(obj)


def test_tension_with_an_imported_opencv_calibration(tmp_path):
    # the chessboards on the same two cameras as the DIC experiment (scanners.sim.dic.dic_lenses)
    cal = simulate_stereo(tmp_path / "cal", left="brown", right="brown", width=W, height=H, seed=SEED,
                          periods=(1920,), steps=3,
                          z_positions=(0.0, 40.0, 80.0), supersample=2, chessboard=True,
                          lens_options={"pixel_mm": 0.0053 * 1280 / W, "focus_mm": 410.0})
    obj, img, views = _corners(load_capture(cal))
    assert views >= 10
    cams = [calibrate_opencv(obj, img[k], W, H, flags=0) for k in range(2)]
    o32, i32 = [obj.astype(np.float32)], [[i.astype(np.float32)] for i in img]
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-12)
    rms, m1, d1, m2, d2, R, T, _, _ = cv2.stereoCalibrate(o32, i32[0], i32[1], cams[0].camera_matrix,
                                                          cams[0].dist[:5], cams[1].camera_matrix,
                                                          cams[1].dist[:5], (W, H), flags=cv2.CALIB_FIX_INTRINSIC,
                                                          criteria=crit)
    assert rms < 0.3
    _, rvec, tvec = cv2.solvePnP(obj, img[0], m1, d1, cams[0].rvec, cams[0].tvec, useExtrinsicGuess=True,
                                 flags=cv2.SOLVEPNP_ITERATIVE)
    fs = cv2.FileStorage(str(tmp_path / "stereo.yml"), cv2.FILE_STORAGE_WRITE)
    for key, value in (("M1", m1), ("D1", d1), ("M2", m2), ("D2", d2), ("R", R), ("T", T),
                       ("R_wcs", cv2.Rodrigues(rvec)[0]), ("T_wcs", tvec)):
        fs.write(key, np.asarray(value, np.float64))
    fs.write("image_width", W)
    fs.write("image_height", H)
    fs.release()
    assert main(["import", str(tmp_path / "stereo.yml"), "-o", str(tmp_path / "rig.npz")]) == 0

    strain = 0.01
    states = [DicState("reference"), DicState("tension", stretch=(1.0 + strain, 1.0 - 0.3 * strain))]
    simulate_dic(tmp_path / "dic", states, width=W, height=H, seed=SEED, supersample=2)
    rig = load_rig(tmp_path / "rig.npz")
    data = load_states(tmp_path / "dic", rig)
    grid = make_grid(rig.sensor.width, rig.sensor.height, subset=21, step=5,
                     roi=(15, 15, rig.sensor.width - 16, rig.sensor.height - 16))
    result = list(StereoDic(rig, grid, settings=StereoSettings(DicSettings(subset=21), strain_window=9)).run(
        list(data.rectified(rig))))
    # uniform tension: the same Green-Lagrange strain everywhere, in the plate's frame (e1 in the WCS x-z
    # plane, which is the x axis our strain uses, the rig being in the WCS)
    truth = {"exx": ((1 + strain) ** 2 - 1) / 2, "eyy": ((1 - 0.3 * strain) ** 2 - 1) / 2, "exy": 0.0}
    st = result[1]
    sv = st.strain.valid
    assert st.converged[grid.active].mean() > 0.85 and sv[grid.active].mean() > 0.5
    errors = {e: float(np.mean(getattr(st.strain, e)[sv]) - truth[e]) for e in truth}
    print(f"OpenCV stereoCalibrate RMS {rms:.3f} px over {views} boards; mean strain errors {errors}")
    assert all(abs(v) <= 50e-6 for v in errors.values())

"""Stereo without a stage: two cameras that see the same hand-held display poses are calibrated each on
its own into one WCS (the display at pose 0) and make a rig directly, without a registration."""

import numpy as np
import pytest

from calib.calibration import calibrate_camera
from calib.capture import load_capture
from calib.evaluate import ErrorStats, ray_error_px
from calib.prvm_file import load_prvm
from scanners.sim.handheld import HandHeld
from scanners.sim.stereo import simulate_stereo
from stereodic.cli import main
from stereodic.stereo.rig import build_rig


@pytest.mark.slow
def test_two_cameras_of_one_hand_held_capture_share_the_wcs(tmp_path):
    out = simulate_stereo(tmp_path / "stereo", left="brown", right="noncentral", width=320, height=256,
                          lens_options={"pixel_mm": 0.0212},
                          handheld=HandHeld(poses=6), supersample=6, flat_levels=(0, 64, 128, 192, 255))
    capture = load_capture(out)
    assert capture.posed and set(capture.cameras) == {"cam0", "cam1"}
    prvms = []
    for name in ("cam0", "cam1"):
        cal = calibrate_camera(capture, camera=name)
        truth = load_prvm(out / f"truth_{name}.npz")          # in the display's frame at pose 0
        for z in (0.0, 80.0):
            assert ErrorStats.of(ray_error_px(cal.prvm, truth, z_mm=z)).rms < 0.02
        prvms.append(cal.prvm)
        cal.prvm.save(tmp_path / f"{name}.npz")
    # both truths are one frame: the same display point lies on both cameras' true rays
    t0, t1 = (load_prvm(out / f"truth_{n}.npz") for n in ("cam0", "cam1"))
    assert np.allclose(t0.extra["display_translation_mm"], t1.extra["display_translation_mm"])
    rig = build_rig(prvms[0], prvms[1], width=160, height=128)
    assert np.linalg.norm(rig.left.centre - rig.right.centre) == pytest.approx(200.0, rel=0.01)   # the true baseline
    assert main(["rig", str(tmp_path / "cam0.npz"), str(tmp_path / "cam1.npz"), "-o", str(tmp_path / "rig.npz")]) == 0

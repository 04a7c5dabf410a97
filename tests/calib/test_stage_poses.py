"""Pose refinement on a stage (calib.stage_poses): a stage whose display tilts and runs out at each
position, from the independent synthetic generator, and the simulated rig."""

import numpy as np
import pytest

from calib.calibration import calibrate_camera
from calib.capture import load_capture
from calib.evaluate import ErrorStats, ray_error_px
from calib.prvm_file import PRVM
from stereodic.cli import main
from synth_capture import DISPLAY, make_capture


def _rotation(axis, deg):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    a = np.radians(deg)
    return np.eye(3) + np.sin(a) * k + (1 - np.cos(a)) * k @ k


ZS = (0.0, 15.0, 30.0, 45.0)
CENTRE = np.array([DISPLAY.width_px * DISPLAY.pitch_mm[0] / 2, DISPLAY.height_px * DISPLAY.pitch_mm[1] / 2, 0.0])
# each position's true pose: tilted about the display's centre, shifted along and across the axis (mm)
ERRORS = [((1, 0, 0), 0.0, (0, 0, 0)), ((1, 2, 0), 0.05, (0.010, -0.008, 0.006)),
          ((-2, 1, 0), 0.06, (-0.006, 0.012, -0.010)), ((1, -1, 0.2), 0.04, (0.008, 0.004, 0.008))]


def _true_poses():
    out = []
    for z, (axis, deg, shift) in zip(ZS, ERRORS):
        r = _rotation(axis, deg)
        out.append((r, np.array([0.0, 0.0, z]) + np.array(shift) + CENTRE - r @ CENTRE))
    return out


@pytest.fixture(scope="module")
def tilted_stage(tmp_path_factory):
    root = tmp_path_factory.mktemp("stage")
    _, truth = make_capture(root, zs=ZS, stage_poses=_true_poses(), noise=0.2)
    return root, truth


def test_refined_poses_lower_the_ray_error_below_the_nominal_floor(tilted_stage):
    """With the display tilted by 0.04-0.06 degrees at the stage positions, the refined calibration's
    rays on the working plane are 3x closer to the truth than the nominal one's; the refinement is used
    and the estimated tilts approach the true ones."""
    root, truth = tilted_stage
    cap = load_capture(root)
    refined, nominal = calibrate_camera(cap), calibrate_camera(cap, refine=False)
    assert refined.poses.used and nominal.poses is None
    err_r = ErrorStats.of(ray_error_px(refined.prvm, truth, z_mm=0.0)).rms
    err_n = ErrorStats.of(ray_error_px(nominal.prvm, truth, z_mm=0.0)).rms
    assert err_r < err_n / 3, (err_r, err_n)
    meta = refined.prvm.meta["stage_poses"]
    assert meta["used"] and len(meta["positions"]) == 4 and meta["cost_refined"] < meta["cost_nominal"]


def test_calibrate_prints_the_stage_errors_and_no_refine_poses_keeps_the_nominal(tilted_stage, tmp_path, capsys):
    root, _ = tilted_stage
    assert main(["calibrate", str(root), "-o", str(tmp_path / "a.npz")]) == 0
    text = capsys.readouterr().out
    assert "stage poses: refined poses used" in text and text.count("  z = ") == 3
    assert main(["calibrate", str(root), "--no-refine-poses", "-o", str(tmp_path / "b.npz")]) == 0
    assert "stage poses" not in capsys.readouterr().out


def test_a_perfect_stage_is_not_refined(tmp_path):
    """Without stage errors the refinement does not lower the residual significantly: nominal poses kept."""
    make_capture(tmp_path, zs=ZS, noise=0.2)
    cal = calibrate_camera(load_capture(tmp_path))
    assert cal.poses is not None and not cal.poses.used


@pytest.mark.slow
def test_simulated_stage_with_realistic_errors(tmp_path):
    """The simulated rig (640 x 512, 3 positions, z 3 um, tilt 0.01 deg, lateral 5 um): the true rays'
    display points fitted at the refined poses are 10x closer to the truth (on the working plane, in the
    first display's frame) than at the nominal ones."""
    from calib.prvm import fit_posed_lines
    from calib.prvm_file import load_prvm
    from scanners.sim.calibration import simulate_calibration
    simulate_calibration(tmp_path, lens="brown", width=640, height=512, z_positions=(0, 25, 50), stage_error_um=3,
                         stage_tilt_deg=0.01, stage_lateral_um=5)
    cap = load_capture(tmp_path)
    cal = calibrate_camera(cap)
    truth = load_prvm(tmp_path / "truth.npz")
    r0, t0 = truth.extra["display_rotation"][0], truth.extra["display_translation_mm"][0]
    moved = truth.transformed(r0.T, -r0.T @ t0)
    cr = [c.transpose(2, 0, 1).astype(float) for c in truth.extra["display_cr"]]
    ones = [np.ones((512, 640), np.float32)] * 3

    def floor(rotation, translation):
        lines = fit_posed_lines(cr, ones, rotation, translation, cap.display.pitch_mm).lines
        return ErrorStats.of(ray_error_px(PRVM(lines.origin(), lines.direction(), lines.valid), moved,
                                          z_mm=0.0)).rms

    nominal = floor(np.broadcast_to(np.eye(3), (3, 3, 3)), np.array([[0, 0, 0], [0, 0, 25.0], [0, 0, 50.0]]))
    assert cal.poses.used and floor(*cal.poses.poses) < nominal / 10

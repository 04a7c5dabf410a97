"""The simulator's hand-held display (scanners.sim.handheld) and Bayer sensor (scanners.sim.bayer)."""

import numpy as np
import pytest

from calib.capture import load_capture
from calib.prvm_file import load_prvm
from scanners.sim.bayer import BayerCamera, BayerSensor, colour_index
from scanners.sim.calibration import simulate_calibration
from scanners.sim.display import SimDisplay
from scanners.sim.handheld import HandHeld, coverage, disturbed_pose, handheld_poses
from scanners.sim.lenses import make_lens
from scanners.sim.pose import DisplayPose
from scanners.sim.sensor import Sensor
from stereodic.cli import main

SMALL = dict(width=160, height=128, lens_options={"pixel_mm": 0.0053 * 8}, supersample=8,
             flat_levels=(0, 128, 255))


def _angle_deg(r):
    return np.degrees(np.arccos(np.clip((np.trace(r) - 1) / 2, -1, 1)))


def test_poses_cover_the_field_within_the_reach():
    lens, display = make_lens("brown"), SimDisplay()
    held = HandHeld(poses=8)
    poses = handheld_poses(lens, display, held, seed=4)
    axis = lens.rotation[:, 2]
    centre = np.array([display.size_mm[0] - display.pitch_mm[0], display.size_mm[1] - display.pitch_mm[1], 0]) / 2
    tilts = []
    for k, pose in enumerate(poses):
        cover, incidence = coverage(lens, display, pose)
        assert cover >= (1.0 if k == 0 else held.min_cover) and incidence <= 60.0
        depth = (pose.to_wcs(centre) - lens.centre_mm) @ axis
        assert 300.0 <= depth <= 600.0
        tilt = np.degrees(np.arccos(pose.normal @ axis))
        assert tilt <= held.max_tilt_deg + 1e-9
        tilts.append(tilt)
    assert min(tilts) >= 0.3 * held.max_tilt_deg - 1e-9 and max(tilts) > 25.0
    # the tilt axes go round: the normals spread in every direction across the line of sight
    normals = np.array([p.normal - (p.normal @ axis) * axis for p in poses])
    assert np.linalg.svd(normals, compute_uv=False)[1] > 0.3 * np.sqrt(len(poses)) * np.sin(np.radians(10))


def test_as_held_poses_are_about_the_focus_tipped_about_x_or_y():
    """`as_held`: pose 0's centre 420 mm along the axis, the others 375-445 mm; each display tipped 4-15
    degrees about the camera's x or y axis in turn (the roll of up to 2 degrees is about its normal);
    the lens focused at 420 mm
    behind a 0.5 mm glass, 90 % fill."""
    from scanners.sim.handheld import as_held
    options = as_held(poses=7)
    lens, display = make_lens("noncentral", **options["lens_options"]), options["display"]
    assert lens.focus_mm == 420.0 and options["cover_glass"] == (0.5, 1.52) and display.fill_factor == (0.9, 0.9)
    poses = handheld_poses(lens, display, options["handheld"], seed=0)
    axis = lens.rotation[:, 2]
    centre = np.array([display.size_mm[0] - display.pitch_mm[0], display.size_mm[1] - display.pitch_mm[1], 0]) / 2
    depths = [(pose.to_wcs(centre) - lens.centre_mm) @ axis for pose in poses]
    assert depths[0] == pytest.approx(420.0, abs=1e-6) and all(375.0 <= d <= 445.0 for d in depths)
    for k, pose in enumerate(poses):
        tilt = np.degrees(np.arccos(pose.normal @ axis))
        assert 4.0 - 1e-9 <= tilt <= 15.0 + 1e-9
        # about x (k even: the normal leans along the camera's y only) or y (k odd: along its x only)
        lean = lens.rotation.T @ pose.normal
        assert abs(lean[k % 2]) < 1e-9 and abs(lean[1 - k % 2]) > np.sin(np.radians(4.0)) - 1e-9


def test_disturbed_pose_moves_by_the_stated_amounts():
    display = SimDisplay()
    held = HandHeld(disturbance_mm=0.2, disturbance_deg=0.1)
    pose = DisplayPose(np.eye(3), (10.0, 20.0, 400.0))
    moved = disturbed_pose(pose, display, held, seed=0)
    assert _angle_deg(moved.R @ pose.R.T) == pytest.approx(0.1, rel=1e-6)
    centre = np.array([display.size_mm[0] / 2, display.size_mm[1] / 2, 0.0])
    assert np.linalg.norm(moved.to_wcs(centre) - pose.to_wcs(centre)) == pytest.approx(0.2, rel=1e-6)


@pytest.fixture(scope="module")
def handheld_dataset(tmp_path_factory):
    out = tmp_path_factory.mktemp("hh")
    simulate_calibration(out, lens="noncentral", handheld=HandHeld(poses=4, disturbed=2), **SMALL)
    return out


def test_handheld_dataset_and_its_truth(handheld_dataset):
    """Frames carry poses (flats at pose 0 only); the truth is in the display's frame at pose 0: each
    true ray meets the display of every pose where `display_cr` says (an ideal decoder's answer)."""
    cap = load_capture(handheld_dataset)
    assert cap.posed and cap.positions("cam0") == [0, 1, 2, 3]
    assert {f.pose for f in cap.select("cam0", type="flat")} == {0}
    assert cap.select("cam0", pose=1, type="fringe")[0].file == "pose01/cam0_x_P60_s0.png"
    truth = load_prvm(handheld_dataset / "truth.npz")
    rot, trans, cr = truth.extra["display_rotation"], truth.extra["display_translation_mm"], truth.extra["display_cr"]
    assert np.allclose(rot[0], np.eye(3)) and np.allclose(trans[0], 0)
    pitch = np.array(cap.display.pitch_mm)
    for k in range(4):
        n = rot[k][:, 2]
        s = ((trans[k] - truth.origin) @ n) / (truth.direction @ n)
        q = (truth.origin + s[..., None] * truth.direction - trans[k]) @ rot[k]
        assert np.abs(q[..., :2] / pitch - cr[k]).max() < 1e-3
    # pose 2's display moved halfway through its fringes, by the stated 0.2 mm and 0.1 degree
    assert _angle_deg(truth.extra["disturbed_rotation"] @ rot[2].T) == pytest.approx(0.1, rel=1e-6)
    assert truth.meta["handheld"]["disturbed"] == 2


def test_the_moved_display_shows_in_the_second_half_of_its_frames(handheld_dataset):
    """Pose 2's x fringes (its first half) match an undisturbed rendering; its y fringes do not."""
    cap = load_capture(handheld_dataset)
    again = handheld_dataset.parent / "again"
    simulate_calibration(again, lens="noncentral", handheld=HandHeld(poses=4), noise=True, **SMALL)
    other = load_capture(again)
    for axis, same in (("x", True), ("y", False)):
        f = cap.select("cam0", pose=2, axis=axis, period_px=60)[0]
        g = other.select("cam0", pose=2, axis=axis, period_px=60)[0]
        assert (cap.read(f) == other.read(g)).all() == same


def test_simulate_command_writes_a_handheld_bayer_dataset(tmp_path, capsys):
    out = tmp_path / "d"
    assert main(["simulate", "calibration", "--handheld", "3", "--bayer", "GRBG", "--width", "160", "--height",
                 "128", "--periods", "1920", "--flat-levels", "128", "-o", str(out)]) == 0
    cap = load_capture(out)
    assert cap.posed and cap.bayer == {"cam0": "GRBG"} and len(cap.positions("cam0")) == 3


def test_bad_handheld_options(tmp_path, capsys):
    assert main(["simulate", "calibration", "--handheld", "2", "-o", str(tmp_path / "d")]) == 2
    assert "--handheld" in capsys.readouterr().err
    assert main(["simulate", "calibration", "--disturb", "1", "-o", str(tmp_path / "d")]) == 2
    assert "--disturb" in capsys.readouterr().err


def test_bayer_colours_have_their_own_rays_and_sensitivity():
    """A red photosite's true ray is the lens's ray at its point scaled about the centre by the red
    magnification; a flat at full white lights the colours in the ratio of their gains."""
    bayer = BayerSensor("RGGB", gain=(0.5, 1.0, 0.8), lateral_colour=(1e-3, 0.0, -1e-3))
    base = make_lens("brown", width=160, height=128, pixel_mm=0.0424)
    lens = base.__class__(**{**base.__dict__, "colour": bayer.colour(160, 128)})
    u, v = np.array([0.0, 1.0, 1.0]), np.array([0.0, 0.0, 1.0])             # R, G, B photosites
    cu, cv = 79.5, 63.5
    o, d = lens.rays(u, v)
    for i, m in enumerate((1e-3, 0.0, -1e-3)):
        eo, ed = base.rays(cu + (u[i] - cu) * (1 + m), cv + (v[i] - cv) * (1 + m))
        assert np.allclose(o[i], eo) and np.allclose(d[i], ed)
    cam = BayerCamera(lens, sensor=Sensor(), supersample=8, bayer=bayer, seed=0)
    pose = DisplayPose.staged(0.0)
    e = cam.irradiance(np.full((1080, 1920), 255, np.uint8), SimDisplay(), pose) / cam.vignetting
    colour = colour_index("RGGB", *np.mgrid[0:128, 0:160])
    means = [e[8:-8, 8:-8][colour[8:-8, 8:-8] == i].mean() for i in range(3)]
    assert means[0] / means[1] == pytest.approx(0.5, rel=0.01) and means[2] / means[1] == pytest.approx(0.8, rel=0.01)

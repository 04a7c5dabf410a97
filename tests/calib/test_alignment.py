"""The alignment readings' geometry (calib.alignment) against the simulator's exact rays and poses: the
display pose through a PRVM's rays is exact for any lens (central or not), the readings equal the
simulator's own (scanners.sim.aim), the stage axis comes back from two poses, and the pattern-alone
focal length from a homography of a known pinhole."""

import numpy as np
import pytest

from calib.alignment import (PatternIntrinsics, PinholeRays, PrvmRays, fit_display_pose, read_alignment,
                             stage_axis)
from scanners.sim.aim import aim, true_alignment
from scanners.sim.display import SimDisplay
from scanners.sim.lenses import make_lens
from scanners.sim.optics import rotation
from scanners.sim.pose import DisplayPose, about_point
from stereodic.virtual.camera import fit_optical_centre

W, H = 96, 80
PIXEL_MM = 0.0053 * 1280 / W              # the field of the default 1280x1024 camera
DISPLAY = SimDisplay()


def seen(lens, pose):
    """(2, H, W) display pixels each pixel's TRUE ray meets (the simulator's own ray tracing)."""
    o, d = lens.rays(*lens.pixel_grid())
    return np.stack(DISPLAY.hit(o, d, pose))


def tilted(z_mm, tx_deg, ty_deg):
    """The display at stage position z, turned about its centre by tx about x and ty about y."""
    centre = np.array([*DISPLAY.size_mm, 0.0]) / 2
    return about_point(rotation("y", np.radians(ty_deg)) @ rotation("x", np.radians(tx_deg)), centre,
                       (0.0, 0.0, z_mm))


@pytest.mark.parametrize("family", ["brown", "freeform", "noncentral"])
def test_pose_through_prvm_rays_is_exact(family):
    lens = make_lens(family, width=W, height=H, seed=2, pixel_mm=PIXEL_MM)
    prvm = lens.true_prvm()
    model = PrvmRays(prvm, fit_optical_centre(prvm)[0])
    pose = tilted(30.0, 1.7, -2.4)
    fit = fit_display_pose(model, seen(lens, pose), np.ones((H, W), bool), DISPLAY.pitch_mm)
    assert fit.rms_px < 1e-6
    assert np.allclose(fit.rotation, pose.R, atol=1e-9) and np.allclose(fit.translation, pose.t, atol=1e-6)
    if family != "noncentral":            # a central lens: the readings are the simulator's
        truth = true_alignment(lens, DISPLAY, pose)
        got = read_alignment(model, fit, DISPLAY.pitch_mm).to_json()
        # the image centre lies between pixel centres: its ray is interpolated (bilinear) from theirs
        for key in ("tilt_x_deg", "tilt_y_deg", "roll_deg"):
            assert got[key] == pytest.approx(truth[key], abs=2e-4), key
        assert got["distance_mm"] == pytest.approx(truth["distance_mm"], abs=1e-6)
        assert np.allclose(got["line_of_sight_px"], truth["line_of_sight_px"], atol=1e-3)
        assert np.allclose(got["foot_px"], truth["foot_px"], atol=1e-4)


def test_pinhole_rays_are_the_brown_lens_rays():
    lens = make_lens("brown", width=W, height=H, seed=3, pixel_mm=PIXEL_MM)
    p = lens.params
    K = [[p["fx"], 0, p["cx"]], [0, p["fy"], p["cy"]], [0, 0, 1]]
    k, tan = p["distortion"]["k"], p["distortion"]["p"]
    model = PinholeRays(K, [k[0], k[1], tan[0], tan[1], k[2]], W, H)
    u, v = lens.pixel_grid()
    _, d = model.rays(u, v)
    _, want = lens._camera_rays(u, v)                         # the simulator's camera frame
    assert np.abs(d - want).max() < 1e-12


@pytest.mark.parametrize("axis_deg", [(0.0, 0.0), (0.6, -0.35), (-2.0, 1.0)])
def test_stage_axis_from_two_poses(axis_deg):
    lens = aim(make_lens("freeform", width=W, height=H, seed=1, pixel_mm=PIXEL_MM), 1.2, -0.7, 0.4)
    prvm = make_lens("freeform", width=W, height=H, seed=1,
                     pixel_mm=PIXEL_MM).true_prvm()   # calibrated in another pose
    model = PrvmRays(prvm, fit_optical_centre(prvm)[0])
    a = np.array([np.tan(np.radians(axis_deg[0])), np.tan(np.radians(axis_deg[1])), 1.0])
    a /= np.linalg.norm(a)
    fits = [fit_display_pose(model, seen(lens, DisplayPose.staged(z, axis=a)), np.ones((H, W), bool),
                             DISPLAY.pitch_mm)
            for z in (0.0, 40.0)]
    got = stage_axis(fits[0], fits[1], 40.0)
    assert np.allclose(got.axis, a, atol=1e-9)
    assert got.angle_x_deg == pytest.approx(axis_deg[0], abs=1e-7)
    assert got.angle_y_deg == pytest.approx(axis_deg[1], abs=1e-7)
    assert got.travel_mm == pytest.approx(40.0 / a[2], abs=1e-6) and got.rotation_deg < 1e-7
    assert np.allclose(got.drift, a[:2] / a[2], atol=1e-12)


def test_pattern_focal_length_from_an_oblique_view():
    f = 1234.5
    K = np.array([[f, 0, (W - 1) / 2], [0, f, (H - 1) / 2], [0, 0, 1]])
    pitch = np.array(DISPLAY.pitch_mm)

    def homography(tx, ty):       # display px -> image px of a distortion-free pinhole 400 mm away
        r = rotation("y", np.radians(ty)) @ rotation("x", np.radians(tx))
        t = np.array([-130.0, -75.0, 400.0])
        return K @ np.column_stack([r[:, 0] * pitch[0], r[:, 1] * pitch[1], t])

    est = PatternIntrinsics(W, H)
    est.update(homography(0.4, 0.3), pitch)            # too square: the focal length stays unknown
    assert not est.focal_measured and est.focal_px == pytest.approx(np.hypot(W, H))
    model = est.update(homography(6.0, -4.0), pitch)
    assert est.focal_measured and est.focal_px == pytest.approx(f, rel=1e-9)
    assert np.allclose(model.K, K)
    est.update(homography(3.5, 0.0), pitch / 1.0001)   # a less oblique view does not replace it
    assert est.focal_px == pytest.approx(f, rel=1e-9)
    assert PatternIntrinsics(W, H, focal_px=800.0).update(homography(6.0, -4.0), pitch).K[0, 0] == 800.0

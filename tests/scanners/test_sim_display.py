"""The simulated display: gamma, pixel grid with gaps, cover-glass refraction, stage axis; its images."""

import numpy as np
import pytest

from calib.capture import CoverGlass, Pattern
from scanners.sim.display import SimDisplay
from scanners.sim.screens import fringe_shifts, screen_image
from scanners.sim.optics import rotation
from scanners.sim.pose import DisplayPose
from scanners.sim.stage import SimStage


def test_luminance_follows_gamma_above_the_black_level():
    d = SimDisplay(gamma=2.4, black_level=0.002)
    lum = d.luminance(np.array([0, 64, 128, 255], np.uint8))
    assert lum[0] == pytest.approx(0.002)
    assert lum[3] == pytest.approx(1.0)
    assert (lum[2] - 0.002) / (1 - 0.002) == pytest.approx((128 / 255) ** 2.4, rel=1e-6)


def test_a_whole_pixel_window_sees_the_fill_factor_and_a_point_in_the_gap_sees_black():
    d = SimDisplay(width_px=40, height_px=30, fill_factor=(0.7, 0.8), stripes=3)
    img = np.full((30, 40), 200, np.uint8)
    rng = np.random.default_rng(0)
    c, r = rng.uniform(5, 35, 500), rng.uniform(5, 25, 500)
    mean = d.luminance_at(img, c, r, window=(1.0, 1.0))
    assert np.allclose(mean, 0.7 * 0.8 * d.luminance(np.uint8(200)), rtol=1e-5)
    # Point samples: the middle of the (unlit) gap between rows is black; the centre stripe is lit.
    assert d.luminance_at(img, np.array([10.0]), np.array([10.5]))[0] == 0
    assert d.luminance_at(img, np.array([10.0]), np.array([10.0]))[0] == pytest.approx(d.luminance(np.uint8(200)))
    # Between two stripes of one pixel (1/6 pixel from its centre) is black too.
    assert d.luminance_at(img, np.array([10.0 + 1 / 6]), np.array([10.0]))[0] == 0


def test_a_window_mixes_the_two_neighbouring_display_pixels_by_their_lit_areas():
    d = SimDisplay(width_px=4, height_px=4, fill_factor=(1.0, 1.0), stripes=1)
    img = np.zeros((4, 4), np.uint8)
    img[:, 2] = 255                       # column 2 lit, lit area from c = 1.5 to 2.5
    got = d.luminance_at(img, np.array([1.25, 1.5, 2.0, 1.0]), np.full(4, 1.0), window=(0.5, 0.5))
    lo = d.black_level
    assert np.allclose(got, [lo, 0.5 + 0.5 * lo, 1.0, lo], atol=1e-6)


def test_outside_the_display_is_its_bezel_and_a_window_across_the_edge_sees_both():
    img = np.full((4, 4), 255, np.uint8)
    assert SimDisplay(width_px=4, height_px=4, bezel=0.0).luminance_at(
        img, np.array([-2.0, 7.0]), np.array([1.0, 1.0])).max() == 0
    d = SimDisplay(width_px=4, height_px=4, fill_factor=(1.0, 1.0), stripes=1, bezel=0.03)
    got = d.luminance_at(img, np.array([-2.0, 7.0, -0.5, 3.5]), np.array([1.0, 1.0, 1.0, 1.0]), window=(0.5, 0.5))
    np.testing.assert_allclose(got, [0.03, 0.03, 0.5 + 0.5 * 0.03, 0.5 + 0.5 * 0.03], rtol=1e-6)
    assert SimDisplay().bezel > 0                      # a real bezel reflects some room light


def test_a_bowed_display_is_hit_on_its_curved_surface():
    """The hit lies on the ray and on the paraboloid z = bow (1 - rho^2) of the display frame (an
    independent evaluation of the surface), with and without cover glass; its sagitta is the bow."""
    bowed = SimDisplay(bow_mm=0.1)
    w, h = (1920 - 1) * 0.2745, (1080 - 1) * 0.2745
    surface = lambda x, y: 0.1 * (1 - ((x - w / 2) ** 2 + (y - h / 2) ** 2) / ((w / 2) ** 2 + (h / 2) ** 2))  # noqa
    assert surface(w / 2, h / 2) == pytest.approx(0.1) and surface(0.0, 0.0) == pytest.approx(0.0)
    rng = np.random.default_rng(3)
    o = np.c_[rng.uniform(0, 500, (50, 2)), np.full(50, -400.0)]
    d = np.c_[rng.uniform(-0.4, 0.4, (50, 2)), np.ones(50)]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    pose = DisplayPose(rotation("x", 0.05), (2.0, -1.0, 30.0))
    c, r = bowed.hit(o, d, pose)
    x, y = c * 0.2745, r * 0.2745
    local_o, local_d = pose.to_display(o, d)
    t = (x - local_o[:, 0]) / local_d[:, 0]
    on_ray = local_o + t[:, None] * local_d
    assert np.allclose(on_ray[:, 1], y, atol=1e-9) and np.allclose(on_ray[:, 2], surface(x, y), atol=1e-9)
    flat_c, _ = SimDisplay().hit(o, d, pose)
    assert 0.01 < np.abs(c - flat_c).max() * 0.2745 < 0.1       # ~slope x bow: tens of micrometres
    # with glass lying on the bowed pixels: the flat display's refraction, the whole slab deeper by the
    # bow, which the ray crosses in air first (the faces' ~1e-3 slope changes the refraction by a few
    # tenths of a micrometre)
    glass = CoverGlass(0.7, 1.5)
    cg, rg = SimDisplay(bow_mm=0.1, cover_glass=glass).hit(o, d, pose)
    c0, r0 = SimDisplay(cover_glass=glass).hit(o, d, pose)
    depth = surface(cg * 0.2745, rg * 0.2745)
    shift = np.stack([cg - c0, rg - r0], axis=1) * 0.2745
    np.testing.assert_allclose(shift, depth[:, None] * local_d[:, :2] / local_d[:, 2:], atol=5e-4)


def test_a_pitch_error_scales_the_display_but_not_its_record():
    d = SimDisplay(pitch_error=1e-4)
    assert d.record().pitch_mm == (0.2745, 0.2745)
    o, dirn = np.array([[100.0, 80.0, -400.0]]), np.array([[0.1, -0.05, 1.0]])
    c, r = d.hit(o, dirn, DisplayPose.staged(0.0))
    c0, r0 = SimDisplay().hit(o, dirn, DisplayPose.staged(0.0))
    assert c[0] == pytest.approx(c0[0] / (1 + 1e-4), rel=1e-12) and r[0] == pytest.approx(r0[0] / (1 + 1e-4), rel=1e-12)


def test_viewing_angle_lowers_the_luminance_and_changes_the_gamma():
    d = SimDisplay(width_px=4, height_px=4, fill_factor=(1.0, 1.0), stripes=1, bezel=0.0, falloff=0.4,
                   gamma_tilt=-0.2, black_level=0.002)
    img = np.full((4, 4), 128, np.uint8)
    sin2 = np.array([0.0, 0.1, 0.3])
    got = d.luminance_at(img, np.full(3, 1.0), np.full(3, 1.0), sin2=sin2)
    gamma = 2.2 * (1 - 0.2 * sin2)
    expected = (1 - 0.4 * sin2) * (0.002 + 0.998 * (128 / 255) ** gamma)
    np.testing.assert_allclose(got, expected, rtol=1e-5)
    with pytest.raises(ValueError, match="sin2"):
        d.luminance_at(img, np.full(3, 1.0), np.full(3, 1.0))
    dirn = np.array([[np.sin(0.3), 0.0, np.cos(0.3)]])
    assert d.sin2_view(dirn, DisplayPose(rotation("y", 0.1))) == pytest.approx(np.sin(0.2) ** 2)


@pytest.mark.parametrize("angle_deg", [0.0, 10.0, 25.0, 40.0])
def test_cover_glass_shifts_the_seen_point_as_a_refracting_plate(angle_deg):
    t, n, z = 1.2, 1.52, 30.0
    plain = SimDisplay()
    glass = SimDisplay(cover_glass=CoverGlass(t, n))
    a = np.radians(angle_deg)
    d = np.array([[np.sin(a) * np.cos(0.3), np.sin(a) * np.sin(0.3), np.cos(a)]])
    o = np.array([[100.0, 80.0, 0.0]])
    c0, r0 = plain.hit(o, d, DisplayPose.staged(z))
    c1, r1 = glass.hit(o, d, DisplayPose.staged(z))
    shift = np.hypot(c1 - c0, r1 - r0)[0] * plain.pitch_mm[0]        # along the display plane, mm
    theta_t = np.arcsin(np.sin(a) / n)
    lateral = t * np.sin(a - theta_t) / np.cos(theta_t)             # perpendicular to the ray
    assert shift * np.cos(a) == pytest.approx(lateral, abs=1e-12)
    if angle_deg > 0:                                             # the point moves back towards the axis
        assert np.hypot(c1 - 100 / 0.2745, r1 - 80 / 0.2745) < np.hypot(c0 - 100 / 0.2745, r0 - 80 / 0.2745)


def test_stage_axis_moves_the_display_sideways():
    d = SimDisplay()
    o, dirn = np.array([[50.0, 40.0, 0.0]]), np.array([[0.0, 0.0, 1.0]])
    c0, r0 = d.hit(o, dirn, DisplayPose.staged(100.0))
    c1, r1 = d.hit(o, dirn, DisplayPose.staged(100.0, axis=(0.01, -0.02, 1.0)))
    assert (c1 - c0)[0] * d.pitch_mm[0] == pytest.approx(-1.0)
    assert (r1 - r0)[0] * d.pitch_mm[1] == pytest.approx(2.0)


def test_stage_true_positions_differ_by_micrometres():
    s = SimStage((0.0, 25.0, 50.0), error_um=3.0, seed=4)
    err = np.array(s.true_mm) - np.array(s.nominal_mm)
    assert 0 < np.abs(err).max() < 0.02
    assert s.true_pose(25.0).translation == (0.0, 0.0, s.true_mm[1])
    assert SimStage((0.0, 50.0), error_um=0.0).true_mm == (0.0, 50.0)


def test_tilted_display_is_hit_where_the_tilted_plane_is():
    # an independent plane intersection: the plane through the pose's origin, normal R @ z
    rot = rotation("y", 0.2) @ rotation("x", -0.1)
    pose = DisplayPose(rot, (3.0, -2.0, 120.0))
    rng = np.random.default_rng(1)
    o = np.c_[rng.uniform(-50, 50, (20, 2)), np.zeros(20)]
    d = np.c_[rng.uniform(-0.3, 0.3, (20, 2)), np.ones(20)]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    display = SimDisplay()
    c, r = display.hit(o, d, pose)
    n, t0 = rot[:, 2], np.array(pose.translation)
    p = o + (((t0 - o) @ n) / (d @ n))[:, None] * d
    local = (p - t0) @ rot                      # R^T (p - t)
    assert np.allclose(local[:, 2], 0, atol=1e-9)
    assert np.allclose(c * display.pitch_mm[0], local[:, 0], atol=1e-9)
    assert np.allclose(r * display.pitch_mm[1], local[:, 1], atol=1e-9)


def test_stage_tilt_and_lateral_errors_have_their_stated_size():
    nominal = tuple(np.linspace(0, 100, 400))
    s = SimStage(nominal, error_um=3.0, seed=2, tilt_deg=0.01, lateral_um=5.0, pivot_mm=(260.0, 150.0))
    assert np.std(s.tilts_deg) == pytest.approx(0.01, rel=0.1)
    assert np.std(s.lateral_mm) * 1e3 == pytest.approx(5.0, rel=0.1)
    # each pose rotates about the pivot: the pivot lands at its nominal place plus the lateral shift
    for pose, z, (lx, ly), (ax, ay) in zip(s.poses, s.true_mm, s.lateral_mm, np.radians(s.tilts_deg)):
        assert np.allclose(pose.to_wcs([260.0, 150.0, 0.0]), [260.0 + lx, 150.0 + ly, z], atol=1e-12)
        assert np.allclose(pose.R, rotation("y", ay) @ rotation("x", ax), atol=1e-15)
    # the z errors are the same draws as without tilt (datasets keep their stage positions)
    assert SimStage(nominal, error_um=3.0, seed=2).true_mm == s.true_mm


def test_fringe_image_is_the_design_formula_rounded():
    p = Pattern("fringe", {"axis": "y", "period_px": 60, "shift_rad": 2 * np.pi / 3, "low": 20, "high": 240})
    img = screen_image(p, 8, 120)
    assert img.dtype == np.uint8 and img.shape == (120, 8)
    assert (img == img[:, :1]).all()                   # constant along rows for axis y
    assert img[20, 0] == 240                           # 2*pi*20/60 - 2*pi/3 = 0: the crest
    assert img[50, 0] == 20                            # half a period later: the trough
    assert img[0, 0] == round(20 + 110 * (1 + np.cos(-2 * np.pi / 3)))


def test_shifts_follow_the_design_convention():
    assert np.allclose(fringe_shifts(3), [0, 2 * np.pi / 3, -2 * np.pi / 3])
    assert np.allclose(fringe_shifts(4), [0, np.pi / 2, np.pi, -np.pi / 2])


def test_chessboard_image_places_the_squares():
    p = Pattern("chessboard", {"squares": [4, 3], "square_px": 10, "origin_px": [5, 7], "low": 20, "high": 240})
    img = screen_image(p, 60, 50)
    assert img[7, 5] == 20 and img[7, 15] == 240 and img[17, 15] == 20     # alternating from the corner
    assert img[6, 5] == 240 and img[36, 44] == 240                          # outside the board: high
    assert (img == 20).sum() == 6 * 100

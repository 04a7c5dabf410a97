import numpy as np

from calib.capture import CoverGlass
from calib.prvm import Lines, fit_lines, glass_offset


def test_line_fit_exact_and_residual():
    rng = np.random.default_rng(0)
    start = rng.normal(0, 10, (4, 5, 2))
    slope = rng.normal(0, 0.2, (4, 5, 2))
    z = np.array([0.0, 30.0, 70.0])
    pts = np.stack([start + zi * slope for zi in z])
    lines = fit_lines(z, pts, np.ones((3, 4, 5)))
    np.testing.assert_allclose(lines.start, start, atol=1e-9)
    np.testing.assert_allclose(lines.slope, slope, atol=1e-12)
    assert lines.valid.all() and np.nanmax(lines.residual_mm) < 1e-6
    pts[1, 0, 0, 0] += 0.3                     # one point off the line: a residual
    lines = fit_lines(z, pts, np.ones((3, 4, 5)))
    assert lines.residual_mm[0, 0] > 0.05
    two = fit_lines(z[:2], pts[:2], np.ones((2, 4, 5)))
    assert np.isnan(two.residual_mm).all()
    w = np.ones((3, 4, 5))
    w[1:, 2, 2] = 0                            # one position only: not valid
    assert not fit_lines(z, pts, w).valid[2, 2]


def test_glass_offset_matches_snell():
    glass = CoverGlass(1.5, 1.52)
    for angle in (0.0, 0.2, 0.6):
        slope = np.array([[np.tan(angle), 0.0]])
        a_glass = np.arcsin(np.sin(angle) / 1.52)
        want = 1.5 * (np.tan(angle) - np.tan(a_glass))
        np.testing.assert_allclose(glass_offset(slope, glass)[0, 0], want, atol=1e-12)


def test_lines_moved_to_another_frame_pass_through_the_moved_points():
    # two points of each line, moved by a rigid motion by hand: the moved lines pass through both
    rng = np.random.default_rng(1)
    a_pts = np.concatenate([rng.normal(0, 20, (3, 4, 2)), np.full((3, 4, 1), 5.0)], axis=-1)
    b_pts = a_pts + np.concatenate([rng.normal(0, 0.3, (3, 4, 2)), np.ones((3, 4, 1))], axis=-1) * 80
    lines = Lines.through(5.0, a_pts[..., :2], 85.0, b_pts[..., :2], np.ones((3, 4), bool),
                          np.zeros((3, 4), np.float32), np.ones((3, 4), np.int16), z_ref=-10.0)
    c, s = np.cos(0.3), np.sin(0.3)
    rotation = np.array([[1.0, 0, 0], [0, c, -s], [0, s, c]])
    translation = np.array([3.0, -7.0, 40.0])
    moved = lines.moved(rotation, translation, z_ref=12.0)
    for p in (a_pts, b_pts):
        q = p @ rotation.T + translation
        on_line = moved.start + (q[..., 2:] - 12.0) * moved.slope
        np.testing.assert_allclose(on_line, q[..., :2], atol=1e-9)
    assert moved.valid.all() and moved.z_ref == 12.0
    back = lines.moved(np.diag([1.0, -1.0, -1.0]), np.zeros(3))         # the lines now run towards -z
    assert not back.valid.any() and np.isnan(back.start).all()

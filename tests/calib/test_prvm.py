import numpy as np

from calib.capture import CoverGlass
from calib.prvm import fit_lines, glass_offset


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

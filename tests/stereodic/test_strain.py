"""Strain by local least squares (virtual strain gauge) against analytic fields."""

import numpy as np
import pytest

from stereodic.strain.fit import strain_2d, strain_3d


def _green_lagrange(ux, uy, vx, vy):
    return (ux + 0.5 * (ux ** 2 + vx ** 2), vy + 0.5 * (uy ** 2 + vy ** 2),
            0.5 * (uy + vx + ux * uy + vx * vy))


@pytest.fixture
def grid():
    xs = np.arange(0.0, 300.0, 5.0)
    ys = np.arange(0.0, 200.0, 5.0)
    X, Y = np.meshgrid(xs, ys)
    return xs, ys, X, Y


def test_homogeneous_large_deformation_is_exact(grid):
    xs, ys, X, Y = grid
    ux, uy, vx, vy = 0.05, 0.02, -0.03, 0.04
    u = 1.5 + ux * X + uy * Y
    v = -2.0 + vx * X + vy * Y
    s = strain_2d(xs, ys, u, v, window=5)
    exx, eyy, exy = _green_lagrange(ux, uy, vx, vy)
    assert s.valid[2:-2, 2:-2].all()
    assert np.allclose(s.exx[s.valid], exx, atol=1e-12)
    assert np.allclose(s.eyy[s.valid], eyy, atol=1e-12)
    assert np.allclose(s.exy[s.valid], exy, atol=1e-12)
    assert np.allclose(s.grad[s.valid][:, :2], [[ux, uy], [vx, vy]], atol=1e-12)


def test_missing_points_and_sparse_windows(grid):
    xs, ys, X, Y = grid
    u = 0.01 * X
    v = 0.0 * Y
    u[10, 10] = np.nan  # one lost point: its window neighbours still fit
    u[20:30, 30:40] = np.nan  # a lost patch
    s = strain_2d(xs, ys, u, v, window=5, min_fraction=0.6)
    assert not s.valid[10, 10] and np.isnan(s.exx[10, 10])  # no strain at a point without displacement
    assert s.valid[10, 11] and abs(s.exx[10, 11] - (0.01 + 0.5e-4)) < 1e-12
    assert not s.valid[25, 35]
    assert s.valid[2:-2, 2:-2].sum() > 0.8 * s.valid[2:-2, 2:-2].size
    assert (np.isnan(s.exx) == ~s.valid).all()
    # the corner's window holds 9 of 25 points, below 60 %
    assert not s.valid[0, 0]


def test_a_window_with_exactly_the_least_fraction_fits(grid):
    """Row 0's windows (5 x 5) hold 3 x 5 = 15 points, exactly 60 %: fitted, whatever the sums' rounding."""
    xs, ys, X, Y = grid
    u, v = 0.01 * X, -0.02 * Y
    s = strain_2d(xs, ys, u, v, window=5, min_fraction=0.6)
    assert s.valid[0, 2:-2].all() and not s.valid[0, :2].any()     # the corners hold 9 and 12
    assert np.allclose(s.exx[0, 2:-2], 0.01 + 0.5e-4, atol=1e-12)
    assert np.allclose(s.eyy[0, 2:-2], -0.02 + 0.5 * 0.02 ** 2, atol=1e-12)


def test_quadratic_field_gives_the_slope_at_the_centre(grid):
    xs, ys, X, Y = grid
    u = 1e-4 * (X - 150) ** 2
    v = 2e-4 * (Y - 100) ** 2
    s = strain_2d(xs, ys, u, v, window=7)
    ux = 2e-4 * (X - 150)
    vy = 4e-4 * (Y - 100)
    ok = np.zeros_like(s.valid)
    ok[3:-3, 3:-3] = True  # full, symmetric windows (truncated ones at the edges fit off-centre)
    assert s.valid[ok].all()
    assert np.allclose(s.exx[ok], ux[ok] + 0.5 * ux[ok] ** 2, atol=1e-10)
    assert np.allclose(s.eyy[ok], vy[ok] + 0.5 * vy[ok] ** 2, atol=1e-10)
    assert np.allclose(s.exy[ok], 0.0, atol=1e-10)


def _rotation(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def test_3d_tilted_plane_matches_2d(grid):
    xs, ys, X, Y = grid
    u = 0.02 * X - 0.01 * Y
    v = 0.005 * X + 0.03 * Y
    flat = strain_2d(xs, ys, u, v, window=5)
    R = _rotation([1.0, 0.3, 0.0], 0.5)  # tilt, keeping x roughly in the plane
    P = np.stack([X, Y, np.zeros_like(X)], -1) @ R.T + [10.0, -5.0, 400.0]
    D = np.stack([u, v, np.zeros_like(u)], -1) @ R.T
    s = strain_3d(P, D, window=5)
    assert np.allclose(s.normal[s.valid], R @ [0, 0, 1], atol=1e-9)
    # the tangent frame's e1 is the projection of x: compare invariants, then components in that frame
    tr2 = flat.exx + flat.eyy
    assert np.allclose((s.exx + s.eyy)[s.valid], tr2[s.valid], atol=1e-10)
    det2 = flat.exx * flat.eyy - flat.exy ** 2
    assert np.allclose((s.exx * s.eyy - s.exy ** 2)[s.valid], det2[s.valid], atol=1e-10)


def test_3d_rigid_motion_has_no_strain(grid):
    _, _, X, Y = grid
    P = np.stack([X, Y, 0.001 * (X - 150) ** 2], -1)  # a curved surface
    R = _rotation([0.2, 1.0, 0.4], 0.7)
    D = P @ R.T + [3.0, 1.0, -2.0] - P
    s = strain_3d(P, D, window=5)
    assert s.valid[2:-2, 2:-2].all()
    for c in (s.exx, s.eyy, s.exy):
        assert np.abs(c[s.valid]).max() < 1e-10


def test_3d_cylinder_under_inflation_and_stretch():
    """Cylinder of radius r (axis y): radius grows by a, length by b: hoop strain a + a^2/2 along the
    circumference (e1), axial strain b + b^2/2 along y (e2), no shear."""
    r, a, b = 100.0, 0.02, 0.01
    theta = np.linspace(-0.6, 0.6, 61)
    y = np.linspace(0, 100, 41)
    T, Yg = np.meshgrid(theta, y)
    P = np.stack([r * np.sin(T), Yg, 500.0 - r * np.cos(T)], -1)
    Q = np.stack([(1 + a) * r * np.sin(T), (1 + b) * Yg, 500.0 - (1 + a) * r * np.cos(T)], -1)
    s = strain_3d(P, Q - P, window=5)
    ok = s.valid
    # window 5 spans 0.08 rad: the plane fit on a curved surface is good to ~(0.04)^2
    assert np.abs(s.exx[ok] - (a + a * a / 2)).max() < 2e-4 * (1 + a)
    assert np.abs(s.eyy[ok] - (b + b * b / 2)).max() < 1e-9
    assert np.abs(s.exy[ok]).max() < 1e-9
    # normal along +z at the apex
    assert np.allclose(s.normal[20, 30], [0, 0, 1], atol=1e-9)


def test_bad_window():
    with pytest.raises(ValueError):
        strain_2d(np.arange(5.0), np.arange(5.0), np.zeros((5, 5)), np.zeros((5, 5)), window=4)


def test_the_compiled_fit_refuses_arrays_of_the_wrong_shape_or_type():
    """The strain kernel checks its arrays (stereodic/src/buffers.h) instead of reading past them."""
    from stereodic.strain._kernels import fit_all
    shape = (6, 7)
    X, D = np.zeros(shape + (3,)), np.zeros(shape + (3,))
    out = [np.empty(shape) for _ in range(3)] + [np.empty(shape, bool), np.empty(shape + (3, 2)),
                                                  np.empty(shape + (3,)), np.empty(shape + (3,))]
    fit_all(X, D, 3, 5.0, *out)
    with pytest.raises(ValueError, match="D"):
        fit_all(X, np.zeros((6, 6, 3)), 3, 5.0, *out)
    with pytest.raises(TypeError, match="X"):
        fit_all(X.astype(np.float32), D, 3, 5.0, *out)
    with pytest.raises(ValueError, match="window"):
        fit_all(X, D, 4, 5.0, *out)
    with pytest.raises(ValueError, match="grad"):
        fit_all(X, D, 3, 5.0, *out[:4], np.empty(shape + (3, 3)), *out[5:])

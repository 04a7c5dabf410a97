"""Triangulation of rectified matches against the simulator's true 3D points."""

import numpy as np
import pytest

from stereodic.stereo.triangulate import closest_points, triangulate
from tests.stereodic.rig_cases import inside, pair, seen_at, volume_points


def _errors(families, depth_mm, corrected):
    ll, lr, pl, pr, rig = pair(*families)
    rng = np.random.default_rng(3)
    x = volume_points(rig, 2000, 1.0, seed=4)
    x += (rng.choice([-1.0, 1.0], len(x)) * depth_mm)[:, None] * rig.sensor.normal   # +-depth from the plane
    left, right = seen_at(rig, ll, pl, x), seen_at(rig, lr, pr, x)
    ok = inside(rig, left, right)
    t = triangulate(rig, left[ok, 0], right[ok, 0], left[ok, 1], row_right=right[ok, 1], corrected=corrected)
    return np.linalg.norm(t.points - x[ok], axis=1), t.gap_mm


@pytest.mark.parametrize("families", [("noncentral", "noncentral"), ("noncentral", "brown")])
def test_evm_corrected_rays_beat_the_pinhole_tenfold_off_the_plane(families):
    """Non-central lenses, points 50 mm in front of and behind the common plane."""
    evm, evm_gap = _errors(families, 50.0, True)
    pin, _ = _errors(families, 50.0, False)
    rms_evm, rms_pin = np.sqrt(np.mean(evm ** 2)), np.sqrt(np.mean(pin ** 2))
    assert rms_pin > 2e-3                                  # the pinhole model really is wrong here
    assert rms_evm <= rms_pin / 10
    assert np.median(evm_gap) < 1e-4                       # the real rays meet


def test_central_rig_triangulates_to_interpolation_accuracy():
    err, gap = _errors(("brown", "freeform"), 50.0, True)
    assert np.sqrt(np.mean(err ** 2)) < 2e-3               # mm, at 400 mm with 0.65 mm virtual pixels
    assert np.max(gap) < 1e-3


def test_points_on_the_plane_are_the_plane_points():
    *_, rig = pair()
    rng = np.random.default_rng(0)
    x, r = rng.uniform(0, 319, 1000), rng.uniform(0, 255, 1000)
    for corrected in (True, False):
        t = triangulate(rig, x, x, r, corrected=corrected)
        assert np.abs(t.points - rig.sensor.points(x, r)).max() < 1e-6
        assert t.gap_mm.max() < 1e-6


def test_shapes_and_disparity_sign():
    *_, rig = pair()
    x = np.full((4, 5), 160.0)
    t = triangulate(rig, x + 3, x, np.full((4, 5), 128.0))
    assert t.points.shape == (4, 5, 3) and t.gap_mm.shape == (4, 5)
    # positive disparity (x_left > x_right) = in front of the plane, towards the cameras
    assert np.all((t.points - rig.sensor.centre) @ rig.sensor.normal < 0)


def test_closest_points_of_known_lines():
    o1, d1 = np.array([[0.0, 0, 0]]), np.array([[1.0, 0, 0]])
    o2, d2 = np.array([[0.0, 2, 5]]), np.array([[0.0, 1, 0]])
    t = closest_points(o1, d1, o2, d2)
    assert np.allclose(t.points, [[0, 0, 2.5]]) and np.allclose(t.gap_mm, 5)
    parallel = closest_points(o1, d1, o2, d1)
    assert np.isnan(parallel.points).all()


@pytest.mark.parametrize("corrected", [True, False])
def test_numba_kernel_equals_the_numpy_statement(corrected):
    """triangulate (fused numba kernel) == closest_points(*rays_at(left), *rays_at(right)), blank rays too."""
    from stereodic.stereo.triangulate import rays_at
    *_, rig = pair("noncentral", "brown")
    rng = np.random.default_rng(5)
    n = 5000
    xl, rl = rng.uniform(-2, rig.sensor.width + 1, n), rng.uniform(-2, rig.sensor.height + 1, n)
    xr, rr = xl - rng.uniform(-20, 20, n), rl + rng.normal(0, 0.5, n)
    xl[:10] = np.nan
    got = triangulate(rig, xl, xr, rl, row_right=rr, corrected=corrected)
    ref = closest_points(*rays_at(rig, "left", xl, rl, corrected=corrected),
                         *rays_at(rig, "right", xr, rr, corrected=corrected))
    assert np.array_equal(np.isnan(got.points), np.isnan(ref.points)) and np.isnan(got.points[:10]).all()
    ok = np.isfinite(ref.points).all(axis=1)
    assert ok.sum() > n // 2
    assert np.abs(got.points[ok] - ref.points[ok]).max() < 1e-9
    assert np.abs(got.gap_mm[ok] - ref.gap_mm[ok]).max() < 1e-9


def test_ray_distances_are_the_signed_gap_of_the_triangulation():
    """The signed distance between the two rays (the compiled kernel): numpy's statement of it from
    `rays_at` (o_r - o_l) . n / |n|, n = d_l x d_r; its size is triangulate's gap (the same rays, another
    kernel), zero for the simulator's true matches, and it changes sign across the epipolar row."""
    from stereodic.stereo.triangulate import ray_distances, rays_at
    ll, lr, pl, pr, rig = pair("noncentral", "brown")
    x = volume_points(rig, 500, 1.0, seed=5)
    left, right = seen_at(rig, ll, pl, x), seen_at(rig, lr, pr, x)
    ok = inside(rig, left, right)
    (xl, yl), (xr, yr) = left[ok].T, right[ok].T
    assert np.abs(ray_distances(rig, xl, yl, xr, yr)).max() < 1e-4          # mm: true matches meet
    for dy in (0.7, -0.7):
        d = ray_distances(rig, xl, yl, xr, yr + dy)
        gap = triangulate(rig, xl, xr, yl, row_right=yr + dy).gap_mm
        assert np.allclose(np.abs(d), gap, rtol=1e-9, atol=1e-9)
        assert np.all(np.sign(d) == np.sign(d[0])) and np.abs(d).min() > 0.05
    assert np.sign(ray_distances(rig, xl[:1], yl[:1], xr[:1], yr[:1] + 0.7)) != \
        np.sign(ray_distances(rig, xl[:1], yl[:1], xr[:1], yr[:1] - 0.7))
    (o1, d1), (o2, d2) = rays_at(rig, "left", xl, yl), rays_at(rig, "right", xr, yr + 0.7)
    n = np.cross(d1, d2)
    assert np.allclose(ray_distances(rig, xl, yl, xr, yr + 0.7),
                       np.einsum("ij,ij->i", o2 - o1, n) / np.linalg.norm(n, axis=1), rtol=1e-9, atol=1e-12)
    blank = ray_distances(rig, np.array([np.nan, xl[0]]), yl[:2], xr[:2], yr[:2])
    assert np.isnan(blank[0]) and np.isfinite(blank[1])


def test_the_compiled_kernels_refuse_arrays_of_the_wrong_shape():
    """The triangulation's kernels check their arrays (stereodic/src/buffers.h) instead of reading past
    them: matches of unequal lengths, direction fields of different sizes, an output too short."""
    from stereodic.stereo._kernels import distances_all, triangulate_all
    x = np.zeros(5)
    v3, field = np.zeros(3), np.zeros((4, 6, 3))
    distances_all(x, x, x, x, v3, v3, v3, field, field, np.empty(5))
    with pytest.raises(ValueError, match="rr"):
        distances_all(x, x, x, np.zeros(4), v3, v3, v3, field, field, np.empty(5))
    with pytest.raises(ValueError, match="dir_r"):
        distances_all(x, x, x, x, v3, v3, v3, field, np.zeros((4, 5, 3)), np.empty(5))
    with pytest.raises(ValueError, match="points"):
        triangulate_all(x, x, x, x, v3, v3, v3, field, field, v3, v3, True, np.empty((4, 3)), np.empty(5))

import numpy as np
import pytest

from calib.evaluate import ErrorStats, footprint_mm, ray_error_px, volume_error_px, volume_planes
from calib.prvm_file import PRVM

H, W = 48, 64
CENTRE = np.array([5.0, 3.0, -400.0])            # a central camera 400 mm before the working plane


def _truth(stage=(0.0, 50.0)) -> PRVM:
    """Rays of a pinhole camera at CENTRE, 0.2 mm apart on the plane z = 0."""
    v, u = np.mgrid[0:H, 0:W].astype(float)
    target = np.stack([0.2 * u, 0.2 * v, np.zeros_like(u)], axis=-1)
    d = target - CENTRE
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    return PRVM(target, d, np.ones((H, W), bool), extra={"stage_true_z_mm": np.array(stage)})


def _tilted(truth: PRVM, slope: float) -> PRVM:
    """The truth's rays, each turned about its point on z = 0 by `slope` (dx/dz)."""
    d = truth.direction / truth.direction[..., 2:3]
    d = d + np.array([slope, 0.0, 0.0])
    return PRVM(truth.origin.copy(), d / np.linalg.norm(d, axis=-1, keepdims=True), truth.valid.copy())


def test_plane_error_reads_in_pixels():
    truth = _truth()
    shifted = PRVM(truth.origin + [0.05, 0.0, 0.0], truth.direction, truth.valid)     # a quarter pixel
    assert footprint_mm(truth, 0.0) == pytest.approx(0.2)
    np.testing.assert_allclose(ray_error_px(shifted, truth), 0.25, rtol=1e-9)
    np.testing.assert_allclose(ray_error_px(truth, truth), 0.0, atol=1e-12)


def test_volume_error_sees_a_wrong_direction_the_plane_misses():
    truth = _truth()
    planes = volume_planes(truth)
    np.testing.assert_allclose(planes[[0, -1]], [-25.0, 75.0])          # the stage range and half again
    est = _tilted(truth, 1e-3)
    assert ErrorStats.of(ray_error_px(est, truth)).rms < 1e-9           # right on the working plane
    # wrong by slope * z on the plane z: RMS over the planes / footprint on the working plane
    expected = np.sqrt(np.mean((1e-3 * planes) ** 2)) / 0.2
    np.testing.assert_allclose(volume_error_px(est, truth), expected, rtol=1e-3)


def test_volume_error_equals_plane_error_for_a_parallel_shift():
    truth = _truth()
    shifted = PRVM(truth.origin + [0.0, 0.02, 0.0], truth.direction, truth.valid)
    np.testing.assert_allclose(volume_error_px(shifted, truth), 0.1, rtol=1e-3)   # the lines stay 0.02 mm apart


def test_invalid_pixels_and_missing_stage_range():
    truth = _truth(stage=(0.0,))
    assert len(volume_planes(truth)) == 1
    est = PRVM(truth.origin.copy(), truth.direction.copy(), truth.valid.copy())
    est.valid[:5] = False
    err = volume_error_px(est, truth)
    assert np.isnan(err[:5]).all() and np.isfinite(err[5:]).all()
    assert ErrorStats.of(err).valid == pytest.approx(1 - 5 / H)

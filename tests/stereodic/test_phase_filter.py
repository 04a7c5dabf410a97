"""The masked local-quadratic phase filter: exact on smooth phase, noise reduced by the predicted factor,
no smearing across a step edge or into holes."""

import numpy as np
import pytest

from stereodic.scan.phase_filter import continuous, kernel, noise_gain, radius, smooth_phase

H, W = 200, 300


def _smooth_truth():
    y, x = np.mgrid[0:H, 0:W].astype(np.float64)
    return 400 + 0.6 * x + 0.03 * y + 2e-4 * (x - 150) ** 2 + 1e-4 * (y - 90) ** 2 - 5e-5 * (x - 150) * (y - 90)


def test_kernel_sums_to_one_and_reproduces_quadratics():
    k = kernel(3.0)
    r = radius(3.0)
    x = np.arange(-r, r + 1.0)
    xx, yy = np.meshgrid(x, x)
    assert k.sum() == pytest.approx(1.0, abs=1e-12)
    for f in (xx, yy, xx * xx, xx * yy, yy * yy):
        assert abs((k * f).sum()) < 1e-9          # the centre value of a quadratic is its constant term


def test_quadratic_phase_is_unchanged_and_noise_drops_by_the_predicted_factor():
    truth = _smooth_truth()
    clean = smooth_phase(truth.astype(np.float32), sigma_px=2.5)
    inner = np.isfinite(clean)
    r = radius(2.5)
    assert inner[r:-r, r:-r].all() and not inner[:r].any() and not inner[:, -r:].any()
    assert np.abs(clean[inner] - truth[inner]).max() < 2e-4             # float32 rounding only
    rng = np.random.default_rng(1)
    sigma = 0.02
    noisy = smooth_phase((truth + sigma * rng.standard_normal(truth.shape)).astype(np.float32), sigma_px=2.5)
    err = noisy[inner] - truth[inner]
    assert abs(err.mean()) < 0.1 * sigma * noise_gain(2.5)
    assert err.std() == pytest.approx(sigma * noise_gain(2.5), rel=0.05)
    assert 1 / noise_gain(2.5) == pytest.approx(5.4, abs=0.1) and 1 / noise_gain(3.0) == pytest.approx(6.4, abs=0.1)


def test_step_edge_is_kept_within_the_window_radius_and_never_smeared():
    """An occlusion edge: the phase jumps by 40 units at x = 150, a blurred (mixed) pixel between."""
    truth = _smooth_truth()
    truth[:, 150:] += 40.0
    truth[:, 150] -= 20.0                                      # a mixed pixel, half way
    rng = np.random.default_rng(2)
    sigma = 0.02
    out = smooth_phase((truth + sigma * rng.standard_normal(truth.shape)).astype(np.float32), sigma_px=3.0)
    r = radius(3.0)
    ok = np.isfinite(out)
    cols = np.flatnonzero(ok[H // 2])
    # pixels 149-151 make bad pairs (149|150, 150|151); the window of a measured pixel holds none of them
    assert cols[cols < 150].max() == 148 - r and cols[cols > 150].min() == 152 + r
    err = np.abs(out[ok] - truth[ok])
    assert err.max() < 6 * sigma * noise_gain(3.0)             # nothing pulled towards the other side


def test_holes_grow_by_the_window_radius_and_decreasing_phase_works():
    truth = _smooth_truth()
    ph = truth.astype(np.float32)
    ph[100, 200] = np.nan
    out = smooth_phase(ph, sigma_px=2.0)
    r = radius(2.0)
    bad = ~np.isfinite(out)
    assert bad[100 - r:100 + r + 1, 200 - r:200 + r + 1].all()
    assert not bad[100 - r - 1, 200] and not bad[100, 200 + r + 1]
    flipped = smooth_phase(-ph, sigma_px=2.0)
    assert np.allclose(flipped[~bad], -out[~bad], atol=2e-4)
    assert continuous(ph).sum() == ph.size - 1                 # the hole only: a NaN is no edge
    assert np.array_equal(smooth_phase(ph, sigma_px=0.0), ph, equal_nan=True)

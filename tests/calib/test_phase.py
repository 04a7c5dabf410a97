import numpy as np
import pytest

from calib.phase import (DARK, LOW_MODULATION, SATURATED, FringeSums, WaveformCorrection, correct_phase,
                         decode_frames, unwrap_temporal)
from calib.patterns import step_shifts


def _frames(theta, shifts, a=100.0, b=60.0):
    return [a + b * np.cos(theta - d) for d in shifts]


@pytest.mark.parametrize("shifts", [step_shifts(3), step_shifts(4), step_shifts(7), [0.0, 1.0, 2.5, 4.0]])
def test_wrapped_phase_any_known_shifts(shifts):
    theta = np.linspace(-3.1, 3.1, 50).reshape(5, 10)
    s = FringeSums(theta.shape)
    for img, d in zip(_frames(theta, shifts), shifts):
        s.add(img.astype(np.float32), d)
    r = s.solve(255, 1, 1)
    np.testing.assert_allclose(np.angle(np.exp(1j * (r.phase - theta))), 0, atol=1e-4)
    np.testing.assert_allclose(r.modulation, 60, rtol=1e-4)
    assert (r.quality == 0).all()


def test_noise_estimate_and_phase_sigma():
    rng = np.random.default_rng(1)
    theta = rng.uniform(-np.pi, np.pi, (200, 200))
    shifts = step_shifts(6)
    s = FringeSums(theta.shape)
    for img, d in zip(_frames(theta, shifts), shifts):
        s.add((img + rng.normal(0, 2.0, img.shape)).astype(np.float32), d)
    r = s.solve(1e9, 0, 0)
    assert abs(np.median(r.noise) - 2.0 * np.sqrt(6 / 3) / np.sqrt(6 / 3)) < 0.3
    err = np.angle(np.exp(1j * (r.phase - theta)))
    assert abs(err.std() / (np.sqrt(2 / 6) * 2.0 / 60) - 1) < 0.05


def test_quality_flags():
    theta = np.zeros((3, 3))
    s = FringeSums(theta.shape)
    frames = _frames(theta, step_shifts(3))
    for img, d in zip(frames, step_shifts(3)):
        img = img.copy()
        img[0, 0] = 255          # saturated
        img[1, 1] = 1            # dark, no modulation
        s.add(img.astype(np.float32), d)
    r = s.solve(255, 5, 10)
    assert r.quality[0, 0] & SATURATED
    assert r.quality[1, 1] & DARK and r.quality[1, 1] & LOW_MODULATION
    assert r.quality[2, 2] == 0


def test_temporal_unwrapping_recovers_the_display_coordinate():
    coord = np.linspace(20, 1900, 5000)      # (pixels within 5 sigma of the wrap are flagged)
    periods = [1920, 360, 60, 12]
    rng = np.random.default_rng(0)
    phases = [np.angle(np.exp(1j * (2 * np.pi * coord / p + rng.normal(0, 0.01, coord.shape)))) for p in periods]
    un = unwrap_temporal(periods[::-1], phases[::-1], 1920)
    assert un.consistent.all()
    assert np.abs(un.coord - coord).max() < 0.1
    assert max(un.mismatch_sigma) < 0.05


def test_unwrapping_flags_inconsistent_pixels_and_short_longest_period():
    coord = np.linspace(0, 999, 1000)
    phases = [np.angle(np.exp(1j * 2 * np.pi * coord / p)) for p in (1000, 50)]
    phases[1][500] += 2.5              # a corrupted short-period phase
    un = unwrap_temporal([1000, 50], phases, 1000)
    assert not un.consistent[500] and un.consistent.sum() == 999
    with pytest.raises(ValueError, match="ambiguous"):
        unwrap_temporal([500, 50], phases, 1000)


def test_waveform_correction_removes_the_gamma_error():
    shifts = step_shifts(3)
    phi = 2 * np.pi * np.arange(1024) / 1024
    gamma_wave = lambda x: (20 + 110 * (1 + np.cos(x))) ** 2.2  # noqa: E731
    corr = WaveformCorrection(gamma_wave(phi), shifts)
    theta = np.linspace(-3, 3, 101)
    s = FringeSums(theta.shape)
    for d in shifts:
        s.add(gamma_wave(theta - d).astype(np.float32), d)
    raw = s.solve(1e12, 0, 0).phase
    assert np.abs(raw - theta).max() > 0.1                  # gamma's periodic error
    assert np.abs(corr(raw) - theta).max() < 1e-3


@pytest.mark.parametrize("steps", [3, 4, 16])
def test_decode_frames_equals_fringe_sums_and_correction(steps):
    h, w = 60, 400
    rng = np.random.default_rng(steps)
    coord = np.linspace(0, 1279, w)[None, :] + np.linspace(0, 30, h)[:, None]
    shifts = [float(np.angle(np.exp(2j * np.pi * k / steps))) for k in range(steps)]
    frames = []
    for d in shifts:
        lum = ((10 + 120 * (1 + np.cos(2 * np.pi * coord / 32 - d))) / 255.0) ** 2.2
        img = 20 + 200 * lum * np.linspace(0.2, 1.0, w)[None, :] + rng.normal(0, 1.5, coord.shape)
        img[:5] = 3                                          # a dark band
        img[5:8] = 255                                       # saturated
        frames.append(np.clip(np.rint(img), 0, 255).astype(np.uint8))
    fix = WaveformCorrection(((10 + 120 * (1 + np.cos(2 * np.pi * np.arange(1024) / 1024))) / 255.0) ** 2.2, shifts)
    sums = FringeSums((h, w), full_scale=255)
    for f, d in zip(frames, shifts):
        sums.add(f, d)
    ref = sums.solve(255, 5.1, 5.1)
    correct_phase(ref, fix)
    got = decode_frames(frames, shifts, 255, 5.1, 5.1, fix)
    assert np.array_equal(got.quality, ref.quality) and (ref.quality != 0).any()
    ok = ref.quality == 0
    assert np.abs(np.angle(np.exp(1j * (got.phase - ref.phase)))[ok]).max() < 2e-4
    np.testing.assert_allclose(got.modulation, ref.modulation, atol=1e-3)
    np.testing.assert_allclose(got.offset, ref.offset, atol=1e-3)
    np.testing.assert_allclose(got.noise, ref.noise, rtol=1e-3, atol=1e-3, equal_nan=True)
    assert np.isnan(got.noise).all() == (steps == 3)
    with pytest.raises(ValueError, match="3 or more distinct shifts"):
        decode_frames(frames[:2], shifts[:2], 255, 5.1, 5.1)


def test_clipped_samples_are_left_out_and_the_phase_solved_from_the_rest():
    """Samples at full scale (or 0) carry no phase: with 5 steps a pixel keeps its exact phase from the
    unclipped ones while 3 remain, and is SATURATED with fewer."""
    shifts = step_shifts(5)
    theta = np.linspace(-3.1, 3.1, 400).reshape(20, 20)
    bright = np.linspace(0.6, 2.5, 20)[:, None]               # rows clip more the brighter they are
    frames = [np.clip(np.rint(255 * bright * (0.5 + 0.4 * np.cos(theta - d))), 0, 255).astype(np.uint8) for d in shifts]
    clipped = np.sum([f == 255 for f in frames], axis=0)
    assert (clipped == 1).any() and (clipped == 2).any() and (clipped >= 3).any()
    sums = FringeSums(theta.shape, full_scale=255)
    for f, d in zip(frames, shifts):
        sums.add(f, d)
    r = sums.solve(255, 1, 1)
    solved = clipped <= 2
    err = np.angle(np.exp(1j * (r.phase - theta)))
    assert np.abs(err[solved]).max() < 0.02                      # the 8-bit rounding of 2-3 samples
    assert ((r.quality & SATURATED) != 0).tolist() == (clipped >= 3).tolist()
    counts = np.bitwise_count(r.clipped[0]) if hasattr(np, "bitwise_count") else None
    if counts is not None:
        assert (counts == clipped).all()
    # the same in one pass (decode_frames) and the whole pixel lost without clip tracking
    got = decode_frames(frames, shifts, 255, 1, 1)
    assert np.array_equal(got.quality, r.quality)
    assert np.abs(np.angle(np.exp(1j * (got.phase - r.phase)))[solved]).max() < 1e-5
    old = FringeSums(theta.shape)
    for f, d in zip(frames, shifts):
        old.add(f, d)
    assert ((old.solve(255, 1, 1).quality & SATURATED) != 0).tolist() == (clipped >= 1).tolist()


def test_a_clipped_pixel_gets_the_gamma_correction_of_the_shifts_it_kept():
    """Through a gamma, the periodic phase error depends on which shifts a pixel was decoded from: the
    correction of its own subset removes it, the whole set's would not."""
    shifts = step_shifts(4)
    phi = 2 * np.pi * np.arange(1024) / 1024
    wave = lambda x: ((20 + 110 * (1 + np.cos(x))) / 255) ** 2.2  # noqa: E731
    theta = np.linspace(-3, 3, 301)
    scale = 300.0
    frames = [wave(theta - d) * scale for d in shifts]
    frames[0] = np.where(np.abs(theta) < 1.0, 300.0, frames[0])   # the crest of the first frame clips
    sums = FringeSums(theta.shape, full_scale=300.0)
    for f, d in zip(frames, shifts):
        sums.add(f.astype(np.float32), d)
    r = sums.solve(300.0, 0, 0)
    fix = WaveformCorrection(wave(phi), shifts)
    whole = fix(r.phase)
    correct_phase(r, fix)
    clip = np.abs(theta) < 1.0
    assert np.abs(np.angle(np.exp(1j * (r.phase - theta)))).max() < 2e-3
    assert np.abs(np.angle(np.exp(1j * (whole - theta)))[clip]).max() > 0.02

"""The scan's fast decoding equals calib.phase's (FringeSums.solve, WaveformCorrection, unwrap_temporal)."""

import numpy as np
import pytest

from calib.phase import FringeSums, WaveformCorrection, unwrap_temporal
from scanners.scan_decode import decode_set, unwrap

H, W, WIDTH = 60, 400, 1280
PERIODS = (1280.0, 160.0, 32.0, 8.0)


def _frames(period, steps, coord, rng, gamma=2.2):
    shifts = [float(np.angle(np.exp(2j * np.pi * k / steps))) for k in range(steps)]
    frames = []
    for d in shifts:
        code = 10 + 120 * (1 + np.cos(2 * np.pi * coord / period - d))
        lum = (code / 255.0) ** gamma
        img = 20 + 200 * lum * np.linspace(0.2, 1.0, W)[None, :] + rng.normal(0, 1.5, coord.shape)
        img[:5] = 3                                          # a dark band
        img[5:8] = 255                                       # saturated
        frames.append(np.clip(np.rint(img), 0, 255).astype(np.uint8))
    wave = (10 + 120 * (1 + np.cos(2 * np.pi * np.arange(1024) / 1024))) / 255.0
    return frames, shifts, WaveformCorrection(wave ** gamma, shifts)


@pytest.mark.parametrize("steps", [3, 4, 16])
def test_decode_set_equals_fringe_sums(steps):
    rng = np.random.default_rng(steps)
    coord = np.linspace(0, WIDTH - 1, W)[None, :] + np.linspace(0, 30, H)[:, None]
    frames, shifts, fix = _frames(32.0, steps, coord, rng)
    sums = FringeSums((H, W))
    for f, d in zip(frames, shifts):
        sums.add(f.astype(np.float32), d, f)
    ref = sums.solve(255, 5.1, 5.1)
    ref_phase = fix(ref.phase)
    got = decode_set(frames, shifts, 255, 5.1, 5.1, fix)
    assert np.array_equal(got.quality, ref.quality) and (ref.quality != 0).any()
    ok = ref.quality == 0
    assert np.abs(np.angle(np.exp(1j * (got.phase - ref_phase)))[ok]).max() < 2e-4
    assert np.allclose(got.modulation, ref.modulation, atol=1e-3) and np.allclose(got.offset, ref.offset, atol=1e-3)
    with pytest.raises(ValueError, match="3 or more distinct shifts"):
        decode_set(frames[:2], shifts[:2], 255, 5.1, 5.1)


def test_unwrap_equals_unwrap_temporal():
    rng = np.random.default_rng(0)
    coord = np.linspace(-5, WIDTH + 5, W)[None, :] + np.zeros((H, 1))
    noise = rng.normal(0, 0.02, (len(PERIODS), H, W))
    noise[:, 30, 100:110] += 2.5                              # an unwrapping failure
    phases = [np.angle(np.exp(1j * (2 * np.pi * coord / p + n))).astype(np.float32) for p, n in zip(PERIODS, noise)]
    valid = np.ones((H, W), bool)
    ref = unwrap_temporal(list(PERIODS), phases, WIDTH, valid)
    got = unwrap(list(PERIODS), phases, WIDTH, valid)
    assert np.array_equal(got.consistent, ref.consistent) and not ref.consistent.all()
    assert np.allclose(got.mismatch_sigma, ref.mismatch_sigma, rtol=1e-5)
    assert np.abs(got.coord - ref.coord)[ref.consistent].max() < 1e-3
    assert np.abs(got.coord - coord)[ref.consistent].max() < 0.2          # 5 sigma of 0.02 rad at 8 px
    with pytest.raises(ValueError, match="shorter than the display"):
        unwrap([160.0, 32.0], phases[1:3], WIDTH, valid)

"""Calibration on what real cameras and benches produce (issue 12), against the simulator's truth: a
display that does not fill the view, a 12-bit camera with clipped samples, any pattern set the format
allows, a lens with finer distortion than the simulator's families."""

import numpy as np
import pytest

from calib.calibration import calibrate_camera
from calib.capture import load_capture
from calib.errors import InputError
from calib.evaluate import ErrorStats, positions_seen, ray_error_px
from calib.prvm_file import PRVM, load_prvm

sim = pytest.importorskip("scanners.sim.calibration")


def seen_count(truth) -> np.ndarray:
    """(H, W) how many stage positions' displays (the default 1920 x 1080) each pixel centre's TRUE ray
    lands on."""
    return positions_seen(truth, 1920, 1080)


@pytest.mark.slow
def test_a_converging_pair_whose_display_misses_part_of_the_view_calibrates_both_cameras(tmp_path):
    """Both cameras of a converging pair with a 1.6x wider field than the default: the display misses
    2-3 % of each camera's pixels at stage position 0, 5-6 % at 25 mm and 9-10 % at 50 mm. Pixels that
    saw it at 2 positions are calibrated from those two; none that saw it at fewer has a valid ray."""
    from scanners.sim.stereo import simulate_stereo
    out = simulate_stereo(tmp_path / "st", left="brown", right="freeform", width=320, height=256,
                          lens_options={"pixel_mm": 0.0053 * 4 * 1.6},
                          supersample=5, flat_levels=(0, 128, 255), z_positions=(0.0, 25.0, 50.0))
    cap = load_capture(out)
    for cam in ("cam0", "cam1"):
        truth = load_prvm(out / f"truth_{cam}.npz")
        n = seen_count(truth)
        last = truth.extra["display_cr"][-1]
        unseen = 1 - np.mean((last[..., 0] >= -0.5) & (last[..., 0] <= 1919.5) & (last[..., 1] >= -0.5)
                             & (last[..., 1] <= 1079.5))
        assert 0.05 <= unseen <= 0.2
        cal = calibrate_camera(cap, camera=cam)
        valid, used = cal.prvm.valid, cal.prvm.extra["used_positions"]
        assert not (valid & (n == 0)).any()
        assert (valid & (n == 1)).sum() <= 1e-3 * n.size          # pixels straddling the edge by a hair
        assert valid[n >= 2].mean() >= 0.98
        band = valid & (n == 2)
        assert band.sum() > 0.02 * n.size and valid[n == 2].mean() > 0.6
        assert (used[band] == 2).mean() > 0.99                    # from the positions that saw them
        err = ray_error_px(cal.prvm, truth)
        inner = ErrorStats.of(np.where(n == 3, err, np.nan)).rms
        assert ErrorStats.of(np.where(band, err, np.nan)).rms < min(3 * inner, 0.02)
        assert any("not calibrated" in note for note in cal.notes)


def test_a_display_that_does_not_fill_the_view_leaves_its_edge_out(tmp_path):
    """One camera, the display missing 12 % of the rows at the last of three positions: the pixels
    next to the bezel are flagged (the display edge), and the rest of the view calibrates as well as
    where it is whole."""
    sim.simulate_calibration(tmp_path, lens="brown", width=320, height=256, unseen=0.12,
                             z_positions=(0.0, 25.0, 50.0), flat_levels=(0, 64, 128, 192, 255))
    truth = load_prvm(tmp_path / "truth.npz")
    n = seen_count(truth)
    cal = calibrate_camera(load_capture(tmp_path))
    from calib.phase import EDGE
    for i, p in enumerate(cal.positions):
        edge = (p.quality & EDGE) != 0
        assert edge.sum() >= 320 * 0.9                    # about a row of pixels along the bezel
        rows = np.nonzero(edge.any(axis=1))[0]
        bottom = truth.extra["display_cr"][i, :, 160, 1]
        assert np.all(np.abs(bottom[rows] - 1079.5) < 8 * 0.63 * 2)    # within a few pixels of the edge
    assert not (cal.prvm.valid & (n < 2)).any()
    err = ray_error_px(cal.prvm, truth)
    whole = ErrorStats.of(np.where(n == 3, err, np.nan)).rms
    assert ErrorStats.of(np.where(n == 2, err, np.nan)).rms < 3 * whole and whole < 0.01


def test_clipped_samples_of_a_12_bit_camera_are_solved_from_the_rest(tmp_path):
    """A 12-bit camera written LSB-aligned in 16-bit PNGs, over-exposed so that ~3 % of its pixels
    clip at a step of some fringe sets (4 steps): those are decoded from their unclipped samples, and
    the rays are as good as without clipping."""
    common = dict(lens="brown", width=320, height=256, bit_depth=12, steps=4)
    sim.simulate_calibration(tmp_path / "clean", **common)
    sim.simulate_calibration(tmp_path / "over", overexposure=0.03, **common)
    errors, covered = {}, {}
    for name in ("clean", "over"):
        cap = load_capture(tmp_path / name)
        img = cap.read(cap.select("cam0", type="fringe")[0])
        assert img.dtype == np.uint16 and img.max() <= 4095
        truth = load_prvm(tmp_path / name / "truth.npz")
        cal = calibrate_camera(cap)
        errors[name] = ErrorStats.of(ray_error_px(cal.prvm, truth)).rms
        covered[name] = cal.prvm.valid[seen_count(truth) >= 2].mean()
        if name == "over":
            solved = cal.positions[0].clipped[0]
            assert 0.015 * img.size < solved < 0.06 * img.size
            assert any("clipped samples" in note for note in cal.notes)
            assert cal.prvm.meta["clipped_pixels"][0][0] == solved
    assert errors["over"] < 1.3 * errors["clean"]
    assert covered["over"] >= 0.97


def test_values_beyond_the_declared_bit_depth_are_refused(tmp_path):
    """12-bit data written MSB-aligned (shifted up by 4) in a dataset declaring 12 bits: one line
    naming the file, not a calibration with a wrong full scale."""
    from calib.imageio import write_gray
    sim.simulate_calibration(tmp_path, lens="brown", width=64, height=48, bit_depth=12, periods=(20, 100, 1920),
                             flat_levels=(0, 128, 255))
    cap = load_capture(tmp_path)
    frame = cap.select("cam0", type="fringe")[0]
    write_gray(cap.path(frame), (cap.read(frame) << 4).astype(np.uint16))
    with pytest.raises(InputError, match="MSB-aligned") as err:
        calibrate_camera(load_capture(tmp_path))
    assert frame.file in str(err.value)


def test_a_lens_with_finer_distortion_than_the_simulators_families_is_followed(tmp_path):
    """A Brown-Conrady lens with a 0.3 px radial ripple of 15 px wavelength (finer than any of the
    families' distortion): the smallest window comes down to it, and the rays follow most of the
    ripple instead of smoothing it away (its RMS is what a window that ignores it leaves)."""
    sim.simulate_calibration(tmp_path, lens="brown", width=320, height=256, lens_options={"ripple": (0.3, 15.0)})
    truth = load_prvm(tmp_path / "truth.npz")
    cal = calibrate_camera(load_capture(tmp_path))
    ripple_rms = 0.3 / np.sqrt(2)
    assert cal.prvm.meta["regularisation"]["windows_px"][0] <= 11
    err = ErrorStats.of(ray_error_px(cal.prvm, truth), margin=8).rms
    raw = ErrorStats.of(ray_error_px(PRVM(cal.raw.origin(), cal.raw.direction(), cal.raw.valid), truth),
                        margin=8).rms
    assert err < 0.5 * ripple_rms and err < 0.5 * raw


def _random_pattern_set(rng: np.random.Generator) -> dict:
    """Periods, steps and stage positions drawn within the format's limits, for the 480 x 360 display
    of `synth_capture` (a camera pixel sees ~4 display pixels there): 2 to 4 periods, the longest
    covering the display up to twice over, each shorter one 3 to 8 times shorter than the last (not
    multiples of 6 nor of each other), the shortest 12 to 30 display px; 3 to 16 steps each, 9 to 24
    frames per axis (the default set's least; the test's time); 2 or 3 positions at uneven spacing
    over 25 to 60 mm."""
    while True:
        count = int(rng.integers(2, 5))
        periods = [float(rng.uniform(480, 960))]
        for _ in range(count - 1):
            periods.append(periods[-1] / rng.uniform(3, 8))
        steps = [int(s) for s in rng.integers(3, 17, count)]
        if 12 <= periods[-1] <= 30 and 9 <= sum(steps) <= 24:
            break
    m = int(rng.integers(2, 4))
    span = rng.uniform(25, 60)
    z = np.sort(np.concatenate([[0.0, span], rng.uniform(0, span, m - 2)]))
    return dict(periods=[round(p, 1) for p in periods], steps=steps, zs=tuple(round(v, 2) for v in z))


@pytest.mark.parametrize("draw", range(10))
def test_random_pattern_sets_calibrate_as_well_as_the_default_set(tmp_path, draw):
    """Each drawn set against the generator's default periods (480, 60, 12) with the same number of
    fringe frames per axis and position (spread evenly, the remainder to the shortest period) on the
    same bench (an independent generator, `synth_capture`: distorted pinhole camera, gamma 2.2 display
    with flats, sensor noise, the darkest fringe above the noise floor): the unregularised rays' error,
    over the phase noise each set's shortest period allows (period / sqrt(its steps)), and the
    coverage are as good."""
    from synth_capture import make_capture
    rng = np.random.default_rng(100 + draw)
    drawn = _random_pattern_set(rng)
    frames = sum(drawn["steps"])
    reference = dict(periods=(480, 60, 12), steps=[frames // 3 + (i < frames % 3) for i in range(3)][::-1],
                     zs=drawn["zs"])
    quality = {}
    for name, pattern in (("drawn", drawn), ("default", reference)):
        manifest, truth = make_capture(tmp_path / name, w=64, h=48, gamma=2.2, noise=2.0, seed=draw, low=60,
                                       flat_levels=(0, 64, 128, 192, 255), **pattern)
        cal = calibrate_camera(load_capture(manifest), smoother=None)
        err = ErrorStats.of(ray_error_px(cal.prvm, truth, z_mm=20.0))
        noise = pattern["periods"][-1] / np.sqrt(pattern["steps"][-1])
        quality[name] = (err.rms / noise, err.valid)
    assert quality["drawn"][1] >= quality["default"][1] - 0.01, drawn
    assert quality["drawn"][0] < 1.3 * quality["default"][0], drawn

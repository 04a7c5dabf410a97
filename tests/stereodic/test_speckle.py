"""`stereodic speckle`: the predicted displacement noise of a speckle (sqrt(2) sigma / sqrt(SSSIG)) against
the noise dic2d measures - on simulated speckle of known noise and on the real DIC Challenge sample 5."""

import json
from pathlib import Path

import numpy as np
import pytest

from calib.imageio import read_gray, write_gray
from scanners.sim.speckle import make_speckle, render
from stereodic.cli import main
from stereodic.dic import DicSettings, correlate_pair, make_grid
from stereodic.dic.speckle_quality import speckle_quality

SAMPLE5 = Path(__file__).resolve().parents[3] / "shared" / "data" / "dic-challenge-sample5"
N = 320


def _measured_std(ref, dfm, shift, subset, roi):
    grid = make_grid(ref.shape[1], ref.shape[0], subset=subset, step=subset, roi=roi)
    f = correlate_pair(ref, dfm, grid, settings=DicSettings(subset=subset))
    return float(np.std(f.u[f.ok] - shift)), grid


@pytest.mark.parametrize("noise", [2.0, 4.0])
def test_prediction_matches_dic2d_on_simulated_speckle(noise):
    sp = make_speckle(N, N, seed=5)
    ref = render(sp, noise_sigma=noise, bits=None, seed=1)
    dfm = render(sp, (0.3, 0.0), noise_sigma=noise, bits=None, seed=2)
    static = render(sp, noise_sigma=noise, bits=None, seed=3)
    roi = (20, 20, N - 21, N - 21)
    for subset in (15, 25):
        std, grid = _measured_std(ref, dfm, 0.3, subset, roi)
        q = speckle_quality(ref, subset=subset, roi=roi)
        assert q.sigma_source == "estimated" and q.sigma == pytest.approx(noise, rel=0.25)
        at = int(np.flatnonzero(q.sizes == subset)[0])
        assert 0.75 < std / q.median_px[at] < 1.35, (subset, std, q.median_px[at])
        known = speckle_quality(ref, subset=subset, roi=roi, second=static)
        assert known.sigma_source == "measured" and known.sigma == pytest.approx(noise, rel=0.05)
        assert 0.85 < std / known.median_px[at] < 1.35


@pytest.mark.skipif(not SAMPLE5.is_dir(), reason="needs ../shared/data/dic-challenge-sample5")
def test_prediction_matches_dic2d_on_sample5(tmp_path, capsys):
    """The real images: the noise measured from the reference and the zero-shift image, then the random
    error of dic2d's u on the 0.10 px image (std about its mean), 21 x 21 subsets."""
    ref = read_gray(SAMPLE5 / "reference.tif")
    dfm = read_gray(SAMPLE5 / "shift_x0.10_y0.10.tif")
    roi = (40, 40, 471, 471)
    grid = make_grid(512, 512, subset=21, step=10, roi=roi)
    f = correlate_pair(ref, dfm, grid, settings=DicSettings(subset=21))
    std = float(np.std(f.u[f.ok]))
    assert main(["speckle", str(SAMPLE5 / "reference.tif"), "--static", str(SAMPLE5 / "shift_x0.00_y0.00.tif"),
                 "--subset", "21", "--roi", "40,40,471,471", "-o", str(tmp_path)]) == 0
    rec = json.loads((tmp_path / "speckle.json").read_text())
    pred = rec["predicted_noise_median_px"][rec["subset_px"].index(21)]
    assert 0.85 < std / pred < 1.25, (std, pred)
    assert "noise 1.1" in capsys.readouterr().out
    assert (tmp_path / "speckle.png").stat().st_size > 10_000


def test_command_outputs_and_smallest_subset(tmp_path, capsys):
    sp = make_speckle(200, 160, seed=2)
    write_gray(tmp_path / "sp.png", render(sp, noise_sigma=3.0, seed=1))
    assert main(["speckle", str(tmp_path / "sp.png"), "--subset", "25", "--target", "0.008", "-o",
                 str(tmp_path / "out")]) == 0
    rec = json.loads((tmp_path / "out" / "speckle.json").read_text())
    med = np.array(rec["predicted_noise_median_px"])
    sizes = rec["subset_px"]
    assert np.all(np.diff(med) < 0)                               # more pixels, less noise
    k = sizes.index(rec["smallest_subset_px"])
    assert med[k] <= 0.008 < med[k - 1]
    with np.load(tmp_path / "out" / "noise_map.npz") as z:
        m = z["noise_px"]
        assert m.shape == (160, 200) and np.isnan(m[:12]).all() and np.isfinite(m[12:-12, 12:-12]).all()
        assert np.nanmedian(m) == pytest.approx(med[sizes.index(25)], rel=0.02)
    assert main(["speckle", str(tmp_path / "sp.png"), "--subset", "24", "-o", str(tmp_path / "o2")]) == 2
    assert "--subset" in capsys.readouterr().err

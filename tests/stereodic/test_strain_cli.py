"""`stereodic strain`: strain recomputed from saved results, without correlating again - the run's own
strains with the run's window, the simulator's truth in another measure, and 2-D results."""

import csv

import numpy as np
import pytest

from calib.imageio import write_gray
from scanners.sim.dic import load_dic_truth, truth_at_pixels
from scanners.sim.speckle import make_speckle, render
from stereodic.cli import main
from stereodic.stereo.rig import load_rig


@pytest.fixture(scope="module")
def result(dic_sim, tmp_path_factory):
    out = tmp_path_factory.mktemp("strain") / "dic"
    assert main(["dic", str(dic_sim / "rig.npz"), str(dic_sim), "--step", "6", "--strain-window", "5", "--no-vtk",
                 "--no-plot", "-o", str(out)]) == 0
    return out


def test_same_window_and_measure_give_the_runs_strains(result, tmp_path):
    assert main(["strain", str(result), "--no-plot", "-o", str(tmp_path / "s")]) == 0
    with np.load(result / "dic.npz") as a, np.load(tmp_path / "s" / "strain.npz") as b:
        for k in ("exx", "eyy", "exy", "e_major", "e_vm", "strain_valid"):
            assert np.array_equal(a[k], b[k], equal_nan=True), k
    with open(tmp_path / "s" / "strain.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert list(rows[0])[:4] == ["state", "x", "y", "exx"] and {r["state"] for r in rows} == {"0", "1", "2"}


def test_log_strain_of_the_tension_against_the_truth(dic_sim, result, tmp_path):
    """1 % tension (stretches 1.01, 0.997): log strains ln(1.01), ln(0.997) on the plate's axes."""
    assert main(["strain", str(result / "dic.npz"), "--strain-window", "9", "--measure", "log", "-o", str(tmp_path / "s")]) == 0
    rig = load_rig(dic_sim / "rig.npz")
    with np.load(tmp_path / "s" / "strain.npz") as z, np.load(result / "dic.npz") as d:
        ok = z["strain_valid"][2]
        assert ok.sum() > 200
        assert np.mean(z["exx"][2][ok]) == pytest.approx(np.log(1.01), abs=100e-6)
        assert np.mean(z["eyy"][2][ok]) == pytest.approx(np.log(0.997), abs=100e-6)
        assert np.mean(z["e_angle"][2][ok]) == pytest.approx(0.0, abs=2.0)
        X, Y = np.meshgrid(d["x"], d["y"])
        truth = truth_at_pixels(load_dic_truth(dic_sim), rig.left.imm.real_position(X.ravel(), Y.ravel()))
    # the truth's Green-Lagrange E11 turned into the log measure: ln(sqrt(2 E + 1))
    true_log = 0.5 * np.log(2 * truth["exx"][2] + 1).reshape(ok.shape)
    assert np.abs(np.mean(true_log[ok]) - np.log(1.01)) < 1e-9
    assert (tmp_path / "s" / "maps" / "state2_exx.png").stat().st_size > 1000


def test_2d_results(tmp_path):
    sp = make_speckle(160, 128, seed=4)
    write_gray(tmp_path / "ref.png", render(sp, noise_sigma=1.0, seed=1))
    write_gray(tmp_path / "st.png", render(sp, lambda x, y: (0.02 * (x - 80), -0.006 * (y - 64)), noise_sigma=1.0,
                                           seed=3, supersample=4))
    assert main(["dic2d", str(tmp_path / "ref.png"), str(tmp_path / "st.png"), "--step", "6", "--strain-window", "7",
                 "--measure", "engineering", "--npz", str(tmp_path / "f.npz"), "-o", str(tmp_path / "f.csv")]) == 0
    assert main(["strain", str(tmp_path / "f.npz"), "--strain-window", "7", "--measure", "engineering", "--no-plot",
                 "-o", str(tmp_path / "s")]) == 0
    with np.load(tmp_path / "f.npz") as a, np.load(tmp_path / "s" / "strain.npz") as b:
        assert np.array_equal(a["exx"], b["exx"], equal_nan=True)
        ok = b["strain_valid"][0]
        assert np.median(b["exx"][0][ok]) == pytest.approx(0.02, abs=1e-3)   # engineering: stretch - 1
        assert np.median(b["eyy"][0][ok]) == pytest.approx(-0.006, abs=1e-3)
    with open(tmp_path / "s" / "strain.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert list(rows[0])[0] == "image"


def test_not_a_result(tmp_path, capsys):
    np.savez(tmp_path / "x.npz", meta=np.array('{"format": "stereodic.rig/1"}'))
    assert main(["strain", str(tmp_path / "x.npz"), "-o", str(tmp_path / "s")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "x.npz" in err and "stereodic.dic/1" in err
    assert main(["strain", str(tmp_path), "-o", str(tmp_path / "s")]) == 2
    assert "dic.npz" in capsys.readouterr().err

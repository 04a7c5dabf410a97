"""`stereodic dic2d` end to end: the CSV contract, options, and bad input (exit status 2, file named)."""

import csv
from pathlib import Path

import numpy as np
import pytest

from calib.imageio import write_gray
from scanners.sim.speckle import make_speckle, render
from stereodic.cli import main

DATA = Path(__file__).resolve().parents[3] / "shared" / "data" / "dic-challenge-sample5"


@pytest.fixture(scope="module")
def images(tmp_path_factory):
    """Reference, a translated image and a stretched one (8-bit PNG, 160x128) with their truth."""
    d = tmp_path_factory.mktemp("dic2d")
    sp = make_speckle(160, 128, seed=4)
    write_gray(d / "ref.png", render(sp, noise_sigma=1.0, seed=1))
    write_gray(d / "shift.png", render(sp, (1.3, -0.6), noise_sigma=1.0, seed=2))
    stretch = lambda x, y: (0.01 * (x - 80), 0.0 * y)  # noqa: E731  exx = 0.01 + 0.01^2/2
    write_gray(d / "stretch.png", render(sp, stretch, noise_sigma=1.0, seed=3, supersample=4))
    return d


def _rows(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def test_csv_columns_values_and_strain(images, tmp_path):
    out = tmp_path / "out.csv"
    assert main(["dic2d", str(images / "ref.png"), str(images / "shift.png"), str(images / "stretch.png"),
                 "--subset", "21", "--step", "6", "--roi", "12,12,146,114", "--strain-window", "5", "-o", str(out),
                 "--npz", str(tmp_path / "f.npz"), "--plot", str(tmp_path / "maps")]) == 0
    rows = _rows(out)
    assert list(rows[0])[:7] == ["image", "x", "y", "u", "v", "zncc", "converged"]
    assert {"exx", "eyy", "exy", "strain_valid", "status"} <= set(rows[0])
    shift = [r for r in rows if r["image"] == "0" and r["converged"] == "1"]
    stretch = [r for r in rows if r["image"] == "1" and r["converged"] == "1"]
    n_points = sum(r["image"] == "0" for r in rows)
    assert len(shift) == n_points and len(stretch) == n_points  # the ROI keeps the subsets inside
    assert abs(np.mean([float(r["u"]) for r in shift]) - 1.3) < 0.01
    assert abs(np.mean([float(r["v"]) for r in shift]) + 0.6) < 0.01
    for r in stretch:
        assert abs(float(r["u"]) - 0.01 * (float(r["x"]) - 80)) < 0.05
    exx = [float(r["exx"]) for r in stretch if r["strain_valid"] == "1"]
    assert abs(np.median(exx) - (0.01 + 0.5 * 0.01 ** 2)) < 1e-3
    # never a silent NaN: NaN displacements only where not converged, NaN strains only where not valid
    for r in rows:
        assert (r["converged"] == "1") == np.isfinite(float(r["u"])) == np.isfinite(float(r["v"]))
        assert (r["strain_valid"] == "1") == np.isfinite(float(r["exx"]))
    npz = np.load(tmp_path / "f.npz")
    assert npz["u"].shape == (2,) + npz["active"].shape
    assert sorted(p.name for p in (tmp_path / "maps").iterdir())[:3] == ["image0_exx.png", "image0_exy.png",
                                                                         "image0_eyy.png"]


@pytest.mark.skipif(not DATA.is_dir(), reason="DIC challenge sample 5 images not present")
def test_real_images_through_the_command_line(tmp_path):
    out = tmp_path / "out.csv"
    assert main(["dic2d", str(DATA / "reference.tif"), str(DATA / "shift_x0.10_y0.10.tif"), "--subset", "35",
                 "--roi", "100,100,400,400", "--start-point", "250,250", "-o", str(out)]) == 0
    rows = _rows(out)
    assert all(r["converged"] == "1" for r in rows)
    assert abs(np.mean([float(r["u"]) for r in rows]) - 0.10) < 0.0015
    assert abs(np.mean([float(r["v"]) for r in rows]) - 0.10) < 0.0015


def _fails(argv, capsys, *words):
    assert main(["dic2d"] + argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    for w in words:
        assert w in err
    return err


def test_images_of_different_sizes(images, tmp_path, capsys):
    small = tmp_path / "small.png"
    write_gray(small, np.zeros((100, 120), np.uint8))
    _fails([str(images / "ref.png"), str(images / "shift.png"), str(small), "-o", str(tmp_path / "o.csv")],
           capsys, str(small), "120x100", "160x128")
    assert not (tmp_path / "o.csv").exists()


def test_missing_state_in_a_sequence(images, tmp_path, capsys):
    missing = images / "state_002.png"
    _fails([str(images / "ref.png"), str(images / "shift.png"), str(missing), "-o", str(tmp_path / "o.csv")],
           capsys, str(missing), "missing")
    assert not (tmp_path / "o.csv").exists()


@pytest.mark.parametrize("seed", ["500,20", "-3,40", "20"])
def test_seed_outside_the_image(images, tmp_path, capsys, seed):
    _fails([str(images / "ref.png"), str(images / "shift.png"), f"--start-point={seed}", "-o", str(tmp_path / "o.csv")],
           capsys, "--start-point")


def test_bad_options(images, tmp_path, capsys):
    base = [str(images / "ref.png"), str(images / "shift.png"), "-o", str(tmp_path / "o.csv")]
    _fails(base + ["--subset", "20"], capsys, "--subset", "odd")
    _fails(base + ["--roi", "10,10,400,50"], capsys, "--roi")
    _fails(base + ["--roi", "50,50,100,100", "--start-point", "20,20"], capsys, "--start-point", "region of interest")
    mask = tmp_path / "mask.png"
    write_gray(mask, np.full((10, 10), 255, np.uint8))
    _fails(base + ["--mask", str(mask)], capsys, str(mask), "mask")


def test_textureless_region_is_flagged(images, tmp_path):
    ref = np.array(render(make_speckle(160, 128, seed=4), noise_sigma=1.0, seed=1))
    ref[:, :70] = 128
    dfm = ref.copy()
    write_gray(tmp_path / "ref.png", ref)
    write_gray(tmp_path / "def.png", dfm)
    out = tmp_path / "out.csv"
    # by default the points are placed where the reference has speckle: none on the blank part
    assert main(["dic2d", str(tmp_path / "ref.png"), str(tmp_path / "def.png"), "--step", "8", "-o", str(out)]) == 0
    rows = _rows(out)
    assert rows and all(float(r["x"]) + 10 >= 70 - 3 for r in rows)
    assert all(r["converged"] == "1" and abs(float(r["u"])) < 0.02 for r in rows if float(r["x"]) - 10 > 72)
    # a region that takes it in: its points are flagged
    assert main(["dic2d", str(tmp_path / "ref.png"), str(tmp_path / "def.png"), "--step", "8", "--roi",
                 "0,0,159,127", "-o", str(out)]) == 0
    rows = _rows(out)
    blank = [r for r in rows if float(r["x"]) + 10 < 70 - 3]  # 3 px: the low-pass and B-spline reach
    textured = [r for r in rows if float(r["x"]) - 10 > 72]
    assert blank and all(r["converged"] == "0" and r["status"] == "no_texture" for r in blank)
    assert all(r["u"] == "nan" for r in blank)
    assert all(r["converged"] == "1" and abs(float(r["u"])) < 0.02 for r in textured)


def test_mask_and_incremental(images, tmp_path):
    mask = np.zeros((128, 160), np.uint8)
    mask[:, 80:] = 255
    write_gray(tmp_path / "mask.png", mask)
    out = tmp_path / "out.csv"
    assert main(["dic2d", str(images / "ref.png"), str(images / "shift.png"), "--mask", str(tmp_path / "mask.png"),
                 "--roi", "12,12,146,114", "--incremental", "-o", str(out)]) == 0
    rows = _rows(out)
    assert rows and all(float(r["x"]) >= 80 for r in rows)
    assert all(r["converged"] == "1" and abs(float(r["u"]) - 1.3) < 0.03 for r in rows)

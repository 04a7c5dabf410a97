"""`--columns dice`: DICe's solution-file layout and column names, read by the reader a DICe script uses
(skip the '***' block, one line of names, rows of %.4E values) - checked on DICe's own committed files
first - and holding the same numbers as our own CSV and NPZ."""

import csv
import re
from pathlib import Path

import numpy as np
import pytest

from calib.imageio import write_gray
from scanners.sim.speckle import make_speckle, render
from stereodic.cli import main

GOLD = Path(__file__).resolve().parents[3] / "shared" / "data" / "dice-stereo-list" / "dice-gold"
NUMBER = re.compile(r"^-?\d\.\d{4}E[+-]\d{2}$")


def read_dice(path):
    """(names, rows) of a DICe solution file, the way DICe users' scripts read them."""
    lines = [ln for ln in Path(path).read_text().splitlines() if not ln.startswith("***")]
    names = lines[0].split(",")
    return names, np.array([[float(v) for v in ln.split(",")] for ln in lines[1:]])


@pytest.mark.skipif(not GOLD.is_dir(), reason="needs ../shared/data/dice-stereo-list")
def test_the_reader_reads_dices_own_files():
    names, rows = read_dice(GOLD / "DICe_solution_list_5.txt")
    assert names[:2] == ["COORDINATE_X", "COORDINATE_Y"] and rows.shape[1] == len(names) and len(rows) > 10
    assert all(NUMBER.match(v) for v in (GOLD / "DICe_solution_list_5.txt").read_text().splitlines()[-1].strip().split(","))


def test_dic2d(tmp_path):
    sp = make_speckle(160, 128, seed=4)
    write_gray(tmp_path / "ref.png", render(sp, noise_sigma=1.0, seed=1))
    for k, shift in enumerate(((1.3, -0.6), (2.0, 0.5))):
        write_gray(tmp_path / f"d{k}.png", render(sp, shift, noise_sigma=1.0, seed=k + 2))
    common = [str(tmp_path / "ref.png"), str(tmp_path / "d*.png"), "--step", "8", "--strain-window", "5"]
    assert main(["dic2d", *common, "-o", str(tmp_path / "ours.csv")]) == 0
    assert main(["dic2d", *common, "--columns", "dice", "-o", str(tmp_path / "DICe_solution.txt")]) == 0
    with open(tmp_path / "ours.csv", newline="") as f:
        ours = list(csv.DictReader(f))
    failed = 0
    for k in (0, 1):
        path = tmp_path / f"DICe_solution_{k}.txt"
        assert path.read_text().startswith("***")
        names, rows = read_dice(path)
        assert names == ["SUBSET_ID", "COORDINATE_X", "COORDINATE_Y", "DISPLACEMENT_X", "DISPLACEMENT_Y", "SIGMA",
                         "GAMMA", "VSG_STRAIN_XX", "VSG_STRAIN_YY", "VSG_STRAIN_XY"]
        mine = [r for r in ours if r["image"] == str(k)]
        assert len(rows) == len(mine)
        col = {n: rows[:, i] for i, n in enumerate(names)}
        for ours_name, dice_name in (("x", "COORDINATE_X"), ("u", "DISPLACEMENT_X"), ("v", "DISPLACEMENT_Y"),
                                     ("exx", "VSG_STRAIN_XX")):
            want = np.array([float(r[ours_name]) for r in mine])
            assert np.allclose(col[dice_name], want, rtol=1e-4, atol=1e-7, equal_nan=True), dice_name  # %.7f ours
        converged = np.array([r["converged"] == "1" for r in mine])
        failed += (~converged).sum()
        assert np.all(col["SIGMA"][~converged] == -1)              # DICe's mark of a failure
        noise = np.array([float(r["noise_px"]) for r in mine])
        assert np.allclose(col["SIGMA"][converged], noise[converged], atol=1e-5)
        zncc = np.array([float(r["zncc"]) for r in mine])
        assert np.allclose(col["GAMMA"], 2 * (1 - zncc), rtol=1e-3, atol=2e-6, equal_nan=True)  # zncc: %.6f
    assert failed > 0                                           # border points of the first image


def test_dic(dic_sim, tmp_path):
    rig = str(dic_sim / "rig.npz")
    common = [rig, str(dic_sim), "--step", "12", "--no-vtk", "--no-plot"]
    assert main(["dic", *common, "-o", str(tmp_path / "ours")]) == 0
    assert main(["dic", *common, "--columns", "dice", "-o", str(tmp_path / "dice")]) == 0
    assert not (tmp_path / "dice" / "dic.csv").exists()
    with np.load(tmp_path / "ours" / "dic.npz") as z:
        act = z["active"]
        ref_l = np.stack([z["left_x0"][0][act], z["left_y0"][0][act]], -1)
        for k in range(3):
            names, rows = read_dice(tmp_path / "dice" / f"DICe_solution_{k}.txt")
            col = {n: rows[:, i] for i, n in enumerate(names)}
            assert {"MODEL_COORDINATES_X", "MODEL_DISPLACEMENT_Z", "STEREO_COORDINATES_X", "SIGMA"} <= set(names)
            close = lambda a, b: np.allclose(a, b, rtol=1e-4, atol=1e-9, equal_nan=True)  # noqa: E731
            assert close(col["COORDINATE_X"], ref_l[:, 0]) and close(col["COORDINATE_Y"], ref_l[:, 1])
            assert close(col["DISPLACEMENT_X"], z["left_x0"][k][act] - ref_l[:, 0])
            assert close(col["MODEL_COORDINATES_Z"], z["points"][0][act][:, 2])
            assert close(col["MODEL_DISPLACEMENT_X"], z["displacement"][k][act][:, 0])
            assert close(col["VSG_STRAIN_YY"], z["eyy"][k][act])
            assert np.all((col["SIGMA"] == -1) == ~z["converged"][k][act])
            names, rows = read_dice(tmp_path / "dice" / f"DICe_solution_stereo_{k}.txt")
            col = {n: rows[:, i] for i, n in enumerate(names)}
            assert close(col["COORDINATE_X"] + col["DISPLACEMENT_X"], z["right_x0"][k][act])

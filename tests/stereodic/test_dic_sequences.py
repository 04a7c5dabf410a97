"""`stereodic dic` on image sequences without a manifest: two patterns, or a folder of pairs (DICe's and
VIC-3D's naming), 8- and 16-bit; every bad input found before any work, in one line naming the file."""

import shutil

import numpy as np
import pytest
from PIL import Image

from calib.imageio import read_gray
from stereodic.cli import main

OPTS = ["--step", "12", "--no-vtk", "--no-plot"]


@pytest.fixture(scope="module")
def sim(dic_sim):
    return dic_sim


def _pairs(sim, folder, suffix=(".png", ".png"), convert=None):
    """The dataset's images as img_000k_0 / img_000k_1 in `folder` (DICe's naming)."""
    folder.mkdir()
    for k in range(3):
        for cam, ext in zip((0, 1), suffix):
            img = read_gray(sim / f"s{k:03d}" / f"cam{cam}.png")
            out = folder / f"img_{k:04d}_{cam}{ext}"
            if convert:
                convert(img, out)
            else:
                shutil.copy(sim / f"s{k:03d}" / f"cam{cam}.png", out)
    return folder


def test_patterns_and_folder_give_the_datasets_result(sim, tmp_path):
    rig = str(sim / "rig.npz")
    assert main(["dic", rig, str(sim), *OPTS, "-o", str(tmp_path / "a")]) == 0
    assert main(["dic", rig, "--left", str(sim / "s*" / "cam0.png"), "--right", str(sim / "s*" / "cam1.png"),
                 *OPTS, "-o", str(tmp_path / "b")]) == 0
    folder = _pairs(sim, tmp_path / "pairs")
    assert main(["dic", rig, "--images", str(folder), *OPTS, "-o", str(tmp_path / "c")]) == 0
    ref = (tmp_path / "a" / "dic.csv").read_bytes()
    assert ref.count(b"\n") > 300
    assert (tmp_path / "b" / "dic.csv").read_bytes() == ref
    assert (tmp_path / "c" / "dic.csv").read_bytes() == ref
    with np.load(tmp_path / "a" / "dic.npz") as a, np.load(tmp_path / "c" / "dic.npz") as c:
        assert all(np.array_equal(a[k], c[k], equal_nan=True) for k in a.files if k != "meta")


def test_natural_order_and_16_bit_tiff(sim, tmp_path):
    """16-bit TIFFs (the 8-bit values times 257: the same speckle on another scale) named so that an
    alphabetical sort would put state 10 before state 2 - here states 0, 1, 2 as 8, 9, 10."""
    def tif16(img, out):
        k = int(out.stem.split("_")[1])
        Image.fromarray(img.astype(np.uint16) * 257).save(out.with_name(f"img_{k + 8}_{out.stem[-1]}.tif"))

    folder = tmp_path / "t16"
    _pairs(sim, folder, convert=tif16)
    assert sorted(p.name for p in folder.iterdir())[:2] == ["img_10_0.tif", "img_10_1.tif"]
    rig = str(sim / "rig.npz")
    assert main(["dic", rig, str(sim), *OPTS, "-o", str(tmp_path / "a")]) == 0
    assert main(["dic", rig, "--images", str(folder), *OPTS, "-o", str(tmp_path / "b")]) == 0
    with np.load(tmp_path / "a" / "dic.npz") as a, np.load(tmp_path / "b" / "dic.npz") as b:
        both = a["converged"] & b["converged"]
        assert both.sum() > 0.95 * a["converged"].sum()
        # ZNSSD does not see the scale; only the 8-bit rounding of the rectified images differs
        assert np.abs(a["displacement"][both] - b["displacement"][both]).max() < 0.01
        assert np.abs(b["displacement"][2][both[2]].mean(0) - a["displacement"][2][both[2]].mean(0)).max() < 1e-3


def _bad(args, capsys, *names):
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and all(n in err for n in names), err
    return err


def test_bad_inputs_are_one_line_before_any_work(sim, tmp_path, capsys):
    rig = str(sim / "rig.npz")
    out = tmp_path / "out"
    folder = _pairs(sim, tmp_path / "pairs")
    (folder / "img_0001_1.png").unlink()
    _bad(["dic", rig, "--images", str(folder), "-o", str(out)], capsys, "img_0001_0.png", "img_0001_1.png", "partner")
    folder = _pairs(sim, tmp_path / "sizes")
    Image.fromarray(np.zeros((100, 120), np.uint8)).save(folder / "img_0002_1.png")
    _bad(["dic", rig, "--images", str(folder), "-o", str(out)], capsys, "img_0002_1.png", "120x100")
    folder = _pairs(sim, tmp_path / "cut")
    data = (folder / "img_0002_0.png").read_bytes()
    (folder / "img_0002_0.png").write_bytes(data[: len(data) // 2])
    _bad(["dic", rig, "--images", str(folder), "-o", str(out)], capsys, "img_0002_0.png", "not a readable image")
    _bad(["dic", rig, "--left", str(sim / "s*" / "cam7.png"), "--right", str(sim / "s*" / "cam1.png"), "-o", str(out)],
         capsys, "cam7.png", "matches no file")
    _bad(["dic", rig, "--left", str(sim / "s00[01]" / "cam0.png"), "--right", str(sim / "s*" / "cam1.png"),
          "-o", str(out)], capsys, "cam1.png", "matches 3 images", "2")
    _bad(["dic", rig, str(sim), "--images", str(folder), "-o", str(out)], capsys, "exactly one")
    _bad(["dic", rig, "--left", str(sim / "s*" / "cam0.png"), "-o", str(out)], capsys, "--right")
    assert not out.exists()                                   # nothing was started


def test_dic2d_expands_patterns_in_natural_order(sim, tmp_path):
    folder = _pairs(sim, tmp_path / "pairs")
    for k in range(3):
        (folder / f"img_{k:04d}_0.png").rename(folder / f"left_{(k + 1) * 5}.png")   # 5, 10, 15
    ref = str(folder / "left_5.png")
    assert main(["dic2d", ref, str(folder / "left_*.png"), "--step", "12", "-o", str(tmp_path / "a.csv")]) == 0
    assert main(["dic2d", ref, ref, str(folder / "left_10.png"), str(folder / "left_15.png"), "--step", "12",
                 "-o", str(tmp_path / "b.csv")]) == 0
    assert (tmp_path / "a.csv").read_bytes() == (tmp_path / "b.csv").read_bytes()

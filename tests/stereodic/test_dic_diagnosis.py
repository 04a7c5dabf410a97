"""A run that measures little says why: a state with under half of its points measured gets a line naming
the likely cause and what changes it; a reference that measures nothing stops the run (exit status 2,
one line) without writing maps."""

import shutil

import numpy as np

from calib.imageio import read_gray, write_gray
from stereodic.cli import main

ARGS = ["--step", "12", "--no-vtk", "--strain-window", "0"]


def _pairs(folder, dic_sim, states):
    """A folder of image pairs (DICe's naming) from (left, right) image arrays or dic_sim state numbers."""
    folder.mkdir()
    for k, state in enumerate(states):
        for cam, image in enumerate(state if isinstance(state, tuple) else (None, None)):
            path = folder / f"img_{k:04d}_{cam}.png"
            if image is None:
                shutil.copy(dic_sim / f"s{state:03d}" / f"cam{cam}.png", path)
            else:
                write_gray(path, image)
    return folder


def test_images_out_of_order_are_named(dic_sim, tmp_path, capsys):
    """State 1 is another scene (the reference turned upside down): its left matches fail, and the line
    names motion beyond the search or images out of order; the state's maps are not written blank."""
    left, right = (read_gray(dic_sim / "s000" / f"cam{c}.png") for c in (0, 1))
    pairs = _pairs(tmp_path / "pairs", dic_sim, [0, (left[::-1].copy(), right[::-1].copy()), 1])
    assert main(["dic", str(dic_sim / "rig.npz"), "--images", str(pairs), *ARGS, "-o", str(tmp_path / "out")]) == 0
    out = capsys.readouterr().out
    line = next(ln for ln in out.splitlines() if ln.startswith("state 1: only"))
    assert "left:" in line and "motion beyond what was searched" in line and "out of order" in line
    assert "--search" in line
    assert not any(ln.startswith(("state 0: only", "state 2: only")) for ln in out.splitlines())
    with np.load(tmp_path / "out" / "dic.npz") as z:
        assert 2 * z["converged"][1].sum() < z["active"].sum() <= 2 * z["converged"][2].sum()
    maps = {p.name for p in (tmp_path / "out" / "maps").iterdir()}
    assert "state0_Z.png" in maps and "state2_dZ.png" in maps
    assert ("state1_dZ.png" in maps) == bool(np.load(tmp_path / "out" / "dic.npz")["converged"][1].any())


def test_a_reference_that_measures_nothing_stops_the_run(dic_sim, tmp_path, capsys):
    """The right camera's reference image blank (a lens cap): nothing is measured in the reference; the
    run stops with exit status 2 and one line naming the images and the right camera's failure."""
    left = read_gray(dic_sim / "s000" / "cam0.png")
    pairs = _pairs(tmp_path / "pairs", dic_sim, [(left, np.full_like(left, 40)), 1])
    assert main(["dic", str(dic_sim / "rig.npz"), "--images", str(pairs), *ARGS, "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(pairs) in err[0] and "no point measured in the reference pair" in err[0]
    assert "right:" in err[0] and "the right camera does not find the left one's speckle" in err[0]
    assert not (tmp_path / "out" / "maps").exists() and not (tmp_path / "out" / "dic.npz").exists()


def test_swapped_cameras_are_warned_about(dic_sim, tmp_path, capsys):
    """The two cameras' images given the wrong way round: the rows are 8-20 px off and the turn that
    would explain them is far beyond a bump: the run warns that the cameras may be swapped."""
    args = [str(dic_sim / "rig.npz"), "--left", str(dic_sim / "s*" / "cam1.png"), "--right",
            str(dic_sim / "s*" / "cam0.png"), *ARGS, "--no-plot", "-o", str(tmp_path / "out")]
    assert main(["dic", *args]) == 0
    err = capsys.readouterr().err
    assert "swapped" in err and "--left-suffix" in err


def test_dic2d_names_the_cause_of_an_image_that_measures_little(dic_sim, tmp_path, capsys):
    """dic2d: the deformed image another scene (the reference turned upside down): the line says why."""
    ref = read_gray(dic_sim / "s000" / "cam0.png")
    write_gray(tmp_path / "ref.png", ref)
    write_gray(tmp_path / "other.png", ref[::-1].copy())
    write_gray(tmp_path / "same.png", ref)
    assert main(["dic2d", str(tmp_path / "ref.png"), str(tmp_path / "other.png"), str(tmp_path / "same.png"),
                 "--step", "12", "-o", str(tmp_path / "out.csv")]) == 0
    lines = capsys.readouterr().out.splitlines()
    line = next(ln for ln in lines if ln.startswith("image 0: only"))
    assert "motion beyond what was searched" in line and "--search" in line
    assert not any(ln.startswith("image 1: only") for ln in lines)

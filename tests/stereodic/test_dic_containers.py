"""DIC of the same frames from a PNG folder, a multi-page TIFF, a lossless video (FFV1) and a lossy MP4:
the same results (the lossy one within its own noise); bad sequence files refused in one line."""

from __future__ import annotations

import csv

import cv2
import numpy as np
import pytest
import tifffile

from calib.imageio import write_gray
from stereodic.cli import main

SHIFTS = [(0.0, 0.0), (0.4, -0.3), (1.2, 0.5), (2.1, 1.4)]


def _speckle_frames(w=96, h=72):
    """A speckle shifted by SHIFTS (px, along x and y), quintic spline shifts of a band-limited pattern."""
    from scipy import ndimage
    rng = np.random.default_rng(3)
    base = ndimage.gaussian_filter(rng.random((h, w)), 2.0, mode="wrap")
    base = 20 + 215 * (base - base.min()) / np.ptp(base)
    return [ndimage.shift(base, (dy, dx), order=5, mode="wrap").round().clip(0, 255).astype(np.uint8)
            for dx, dy in SHIFTS]


def _video(path, frames, fourcc):
    h, w = frames[0].shape
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), 10, (w, h), isColor=False)
    assert writer.isOpened()
    for f in frames:
        writer.write(f)
    writer.release()


def _uv(path):
    with open(path) as f:
        rows = list(csv.DictReader(f))
    return np.array([[float(r["u"]), float(r["v"])] for r in rows])


def test_png_tiff_and_videos_give_the_same_results(tmp_path):
    frames = _speckle_frames()
    for k, f in enumerate(frames):
        write_gray(tmp_path / f"f{k}.png", f)
    tifffile.imwrite(tmp_path / "stack.tif", np.stack(frames), photometric="minisblack")
    _video(tmp_path / "lossless.avi", frames, "FFV1")
    _video(tmp_path / "lossy.mp4", frames, "mp4v")
    opts = ["--subset", "21", "--step", "12"]
    assert main(["dic2d", str(tmp_path / "f0.png"), str(tmp_path / "f*.png"), *opts, "-o", str(tmp_path / "png.csv")]) == 0
    for name in ("stack.tif", "lossless.avi", "lossy.mp4"):
        assert main(["dic2d", f"{tmp_path / name}::0", str(tmp_path / name), *opts, "-o",
                     str(tmp_path / f"{name}.csv")]) == 0
    png = (tmp_path / "png.csv").read_text()
    assert (tmp_path / "stack.tif.csv").read_text() == png
    assert (tmp_path / "lossless.avi.csv").read_text() == png
    truth = np.repeat(np.array(SHIFTS), len(_uv(tmp_path / "png.csv")) // len(SHIFTS), axis=0)
    assert np.abs(_uv(tmp_path / "png.csv") - truth).max() < 0.05
    lossy = np.abs(_uv(tmp_path / "lossy.mp4.csv") - truth)
    assert np.nanmedian(lossy) < 0.1                     # within the codec's own noise


@pytest.mark.parametrize("case", ["undecodable video", "pages of different sizes"])
def test_bad_sequence_files_are_one_line(tmp_path, capsys, case):
    write_gray(tmp_path / "ref.png", _speckle_frames()[0])
    if case == "undecodable video":
        bad = tmp_path / "broken.avi"
        bad.write_bytes(np.random.default_rng(2).bytes(20000))
        name = "broken.avi"
    else:
        bad = tmp_path / "mixed.tif"
        with tifffile.TiffWriter(bad) as tw:
            tw.write(np.zeros((72, 96), np.uint8))
            tw.write(np.zeros((60, 80), np.uint8))
        name = "mixed.tif::1"
    assert main(["dic2d", str(tmp_path / "ref.png"), str(bad), "-o", str(tmp_path / "out.csv")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and name in err[0] and "Traceback" not in err[0]
    assert not (tmp_path / "out.csv").exists()


def test_dic2d_mat_holds_the_npz_arrays(tmp_path):
    from scipy.io import loadmat
    frames = _speckle_frames()
    tifffile.imwrite(tmp_path / "stack.tif", np.stack(frames), photometric="minisblack")
    assert main(["dic2d", f"{tmp_path / 'stack.tif'}::0", str(tmp_path / "stack.tif"), "--subset", "21", "--step",
                 "12", "--strain-window", "3", "-o", str(tmp_path / "r.csv"), "--npz", str(tmp_path / "r.npz"),
                 "--mat", str(tmp_path / "r.mat")]) == 0
    mat, npz = loadmat(tmp_path / "r.mat"), np.load(tmp_path / "r.npz")
    for key in npz.files:
        if key != "meta":
            a, b = mat[key], npz[key]
            assert np.array_equal(a.reshape(b.shape), b, equal_nan=b.dtype.kind == "f"), key
    assert "stereodic.dic2d/1" in str(mat["meta"][0])
    assert np.allclose(np.nanmedian(mat["u"], axis=(1, 2)), [s[0] for s in SHIFTS], atol=0.05)


@pytest.mark.slow
def test_stereo_dic_from_two_videos_and_a_side_by_side_stream(dic_sim, tmp_path):
    """The simulated stereo states as two lossless videos, and as one side-by-side stream: the same
    results as the dataset's PNG files, and the frames' timestamps recorded for the load."""
    import json

    from calib.imageio import read_gray
    states = sorted(dic_sim.glob("s0*"))
    pairs = [(read_gray(s / "cam0.png"), read_gray(s / "cam1.png")) for s in states]
    _video(tmp_path / "left.avi", [p[0] for p in pairs], "FFV1")
    _video(tmp_path / "right.avi", [p[1] for p in pairs], "FFV1")
    _video(tmp_path / "both.avi", [np.hstack(p) for p in pairs], "FFV1")
    rig, opts = str(dic_sim / "rig.npz"), ["--no-vtk", "--no-plot", "--subset", "21", "--step", "10"]
    assert main(["dic", rig, str(dic_sim), *opts, "-o", str(tmp_path / "png")]) == 0
    assert main(["dic", rig, "--left", str(tmp_path / "left.avi"), "--right", str(tmp_path / "right.avi"), *opts,
                 "-o", str(tmp_path / "two")]) == 0
    assert main(["dic", rig, "--left", f"{tmp_path / 'both.avi'}:left", "--right", f"{tmp_path / 'both.avi'}:right",
                 *opts, "-o", str(tmp_path / "sbs")]) == 0
    with np.load(tmp_path / "png" / "dic.npz") as ref:
        for run in ("two", "sbs"):
            with np.load(tmp_path / run / "dic.npz") as z:
                assert np.array_equal(z["points"], ref["points"], equal_nan=True), run
                meta = json.loads(str(z["meta"]))
                assert np.allclose(meta["state_times_s"], np.arange(len(states)) / 10)


def test_dic2d_of_a_cine_keeps_its_timestamps_for_the_load(tmp_path):
    """A .cine's frame times go into the dic2d NPZ; `gauge --join time` joins a load logged on the same
    clock without being told the frame rate."""
    from tests.calib.sequence_files import write_cine
    frames = np.stack(_speckle_frames()).astype(np.uint16) * 16
    times = 1_750_000_000.0 + 0.5 * np.arange(len(frames))
    write_cine(tmp_path / "a.cine", frames, times)
    assert main(["dic2d", f"{tmp_path / 'a.cine'}::0", str(tmp_path / "a.cine"), "--subset", "21", "--step", "12",
                 "-o", str(tmp_path / "r.csv"), "--npz", str(tmp_path / "r.npz")]) == 0
    log = "time,force\n" + "".join(f"{t:.3f},{100 * (t - times[0]):.3f}\n" for t in times[0] + np.arange(0, 3, 0.1))
    (tmp_path / "load.csv").write_text(log)
    assert main(["gauge", str(tmp_path / "r.npz"), "--point", "48,36", "--load", str(tmp_path / "load.csv"),
                 "--join", "time", "--no-plot", "-o", str(tmp_path / "g")]) == 0
    with open(tmp_path / "g" / "load.csv") as f:
        force = [float(r["force_n"]) for r in csv.DictReader(f)]
    assert np.allclose(force, [0, 0, 50, 100, 150], atol=1e-3)     # the reference, then frames 0..3

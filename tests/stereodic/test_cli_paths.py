"""Paths checked before any work (stereodic.cli.common.check_paths), wrong truths refused, and the words
for files that are not what they claim: one line on stderr, exit status 2, nothing written."""

import os

import numpy as np
import pytest

import stereodic.dic
from calib.imageio import write_gray
from calib.prvm_file import PRVM
from stereodic.cli import main


def _run(argv, capsys):
    status = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return status, err.strip(), out


def _refused(argv, capsys, *words):
    status, err, _ = _run(argv, capsys)
    assert status == 2 and len(err.splitlines()) == 1 and "Traceback" not in err, err
    for w in words:
        assert w in err, err
    return err


@pytest.fixture
def pair(tmp_path):
    rng = np.random.default_rng(1)
    img = (rng.random((48, 48)) * 255).astype(np.uint8)
    write_gray(tmp_path / "a.png", img)
    write_gray(tmp_path / "b.png", img)
    return tmp_path / "a.png", tmp_path / "b.png"


@pytest.fixture
def no_work(monkeypatch):
    """Fail the test if the correlation starts: the path checks come first."""
    def work(*args, **kwargs):
        raise AssertionError("the command started its work")
    monkeypatch.setattr(stereodic.dic, "correlate_sequence", work)


def _prvm(width=24, height=16, camera="cam0", shift_mm=0.0) -> PRVM:
    v, u = np.mgrid[0:height, 0:width].astype(float)
    origin = np.stack([u * 0.1 + shift_mm, v * 0.1, np.zeros_like(u)], -1)
    direction = np.stack([(u - width / 2) * 1e-3, (v - height / 2) * 1e-3, np.ones_like(u)], -1)
    direction /= np.linalg.norm(direction, axis=-1, keepdims=True)
    return PRVM(origin, direction, np.ones((height, width), bool), meta={"camera": camera})


def test_output_that_is_a_directory(tmp_path, pair, no_work, capsys):
    (tmp_path / "somedir").mkdir()
    _refused(["dic2d", *pair, "-o", tmp_path / "somedir"], capsys, "somedir", "is a directory", "-o/--output")
    _refused(["export", tmp_path / "cam.npz", "--format", "opencv", "-o", tmp_path / "somedir"], capsys,
             "cam.npz", "missing")
    _prvm().save(tmp_path / "cam.npz")
    _refused(["export", tmp_path / "cam.npz", "--format", "opencv", "-o", tmp_path / "somedir"], capsys,
             "somedir", "is a directory")


def test_output_under_a_regular_file(tmp_path, pair, no_work, capsys):
    (tmp_path / "notes.txt").write_text("my notes\n")
    _refused(["dic2d", *pair, "-o", tmp_path / "notes.txt" / "r.csv"], capsys, "notes.txt is a file, not a folder")
    _refused(["dic2d", *pair, "-o", tmp_path / "r.csv", "--plot", tmp_path / "notes.txt" / "maps"], capsys,
             "not a folder")
    _prvm().save(tmp_path / "cam.npz")
    _refused(["show", tmp_path / "cam.npz", "-o", tmp_path / "notes.txt"], capsys, "notes.txt",
             "is a file; -o/--output expects a folder")
    assert (tmp_path / "notes.txt").read_text() == "my notes\n" and not (tmp_path / "r.csv").exists()


def test_output_without_write_permission(tmp_path, pair, no_work, capsys, monkeypatch):
    locked = tmp_path / "locked"
    locked.mkdir()
    real = os.access
    monkeypatch.setattr(os, "access", lambda p, mode: False if (os.fspath(p) == str(locked) and mode & os.W_OK)
                        else real(p, mode))
    _refused(["dic2d", *pair, "-o", locked / "sub" / "r.csv"], capsys, "no permission to write in", "locked")


def test_output_that_would_overwrite_an_input(pair, no_work, capsys):
    _refused(["dic2d", *pair, "-o", pair[1]], capsys, "b.png", "is also an input")


def test_a_directory_given_as_an_image_or_a_file(tmp_path, pair, no_work, capsys):
    (tmp_path / "frames").mkdir()
    _refused(["dic2d", tmp_path / "frames", pair[1], "-o", tmp_path / "r.csv"], capsys,
             "frames: is a directory; REF_IMG expects an image file")
    _refused(["dic2d", *pair, "--mask", tmp_path / "frames", "-o", tmp_path / "r.csv"], capsys,
             "is a directory; --mask expects a mask image file")
    _refused(["show", tmp_path / "frames", "-o", tmp_path / "pics"], capsys, "is a directory", "PRVM file")
    _refused(["calibrate", tmp_path / "nothing", "-o", tmp_path / "c.npz"], capsys, "nothing", "dataset is missing")


def test_a_truth_of_another_camera_is_refused(tmp_path, capsys):
    _prvm(camera="cam0").save(tmp_path / "cam0.npz")
    _prvm(camera="cam1").save(tmp_path / "truth_cam1.npz")
    _prvm(width=30).save(tmp_path / "truth_big.npz")
    _prvm(shift_mm=12.0).save(tmp_path / "truth_elsewhere.npz")   # 120 pixels away
    for truth, words in (("truth_cam1.npz", "camera 'cam1'"), ("truth_big.npz", "30x16"),
                         ("truth_elsewhere.npz", "median 120 camera pixels")):
        _refused(["show", tmp_path / "cam0.npz", "--truth", tmp_path / truth, "-o", tmp_path / "pics"], capsys,
                 truth, words)
    assert not (tmp_path / "pics").exists()
    _prvm(camera="cam0").save(tmp_path / "truth.npz")
    status, err, out = _run(["show", tmp_path / "cam0.npz", "--truth", tmp_path / "truth.npz", "-o",
                             tmp_path / "pics"], capsys)
    assert status == 0 and (tmp_path / "pics" / "error.png").exists()
    assert any(line.startswith(f"wrote {tmp_path / 'pics' / 'error.png'}: ray error map") for line in out.splitlines())


def test_an_npz_that_is_not_one_says_so_in_words(tmp_path, capsys):
    (tmp_path / "text.npz").write_text("not numpy\n")
    (tmp_path / "empty.npz").write_bytes(b"")
    (tmp_path / "broken.npz").write_bytes(b"PK\x03\x04" + bytes(100))
    for name, words in (("text.npz", "not an .npz (zip) archive"), ("empty.npz", "is empty"),
                        ("broken.npz", "damaged")):
        err = _refused(["show", tmp_path / name, "-o", tmp_path / "pics"], capsys, name, words)
        assert "Error" not in err and "(" + "BadZipFile" not in err


def test_the_mechanism_for_folders_and_either(tmp_path):
    """add_input(kind='dir') and add_output(kind='any'), which the next commands use (an image folder,
    an export that is a file or a folder by format)."""
    import argparse

    from calib.errors import InputError
    from stereodic.cli.common import add_input, add_output, check_paths
    p = argparse.ArgumentParser()
    add_input(p, "--images", kind="dir", what="image")
    add_output(p, kind="any")
    (tmp_path / "f.txt").write_text("x")
    (tmp_path / "d").mkdir()
    check_paths(p.parse_args(["--images", str(tmp_path / "d"), "-o", str(tmp_path / "d")]))   # both fine
    check_paths(p.parse_args(["--images", str(tmp_path / "d"), "-o", str(tmp_path / "f.txt")]))
    with pytest.raises(InputError, match="f.txt: is a file; --images expects a folder"):
        check_paths(p.parse_args(["--images", str(tmp_path / "f.txt"), "-o", str(tmp_path / "o")]))
    with pytest.raises(InputError, match="none: image folder is missing"):
        check_paths(p.parse_args(["--images", str(tmp_path / "none"), "-o", str(tmp_path / "o")]))
    with pytest.raises(InputError, match="f.txt is a file, not a folder"):
        check_paths(p.parse_args(["--images", str(tmp_path / "d"), "-o", str(tmp_path / "f.txt" / "o")]))

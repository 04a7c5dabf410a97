"""The capture dataset format: round trip, lazy reading and one test per kind of bad dataset."""

import json

import numpy as np
import pytest

from calib.capture import CaptureWriter, Display, Frame, Pattern, fringe_frame, load_capture
from calib.errors import InputError
from calib.imageio import write_gray
from stereodic.cli import main

W, H = 40, 30


def make_dataset(root, positions=(0.0, 50.0), dtype=np.uint8):
    """A small valid calibration dataset: for each position 3 x-fringes and one flat frame."""
    wr = CaptureWriter(root, "calibration", {"cam0": (W, H)},
                       Display(1920, 1080, (0.2745, 0.2745), gamma=2.2))
    rng = np.random.default_rng(0)
    for z in positions:
        for k, d in enumerate((0.0, 2 * np.pi / 3, -2 * np.pi / 3)):
            img = rng.integers(0, np.iinfo(dtype).max, (H, W), dtype=dtype)
            wr.add(fringe_frame("cam0", f"z{z:03.0f}/cam0_x_P60_s{k}.png", z, "x", 60, d), img)
        wr.add(Frame("cam0", f"z{z:03.0f}/cam0_flat_128.png", Pattern("flat", {"level": 128}), z_mm=z),
               np.full((H, W), 100, dtype))
    return wr.capture


def edit_manifest(root, fn):
    p = root / "capture.json"
    d = json.loads(p.read_text())
    fn(d)
    p.write_text(json.dumps(d))


def test_round_trip_and_lazy_read(tmp_path):
    cap = make_dataset(tmp_path)
    back = load_capture(tmp_path)
    assert back.to_json() == cap.to_json()
    assert back.z_positions("cam0") == [0.0, 50.0]
    fr = back.select("cam0", type="fringe", z_mm=50.0, period_px=60)
    assert len(fr) == 3
    img = back.read(fr[1])
    assert img.shape == (H, W) and img.dtype == np.uint8
    assert back.display.gamma == 2.2


def test_sixteen_bit_tiff_and_colour(tmp_path):
    img16 = (np.arange(W * H, dtype=np.uint16).reshape(H, W) * 50)
    write_gray(tmp_path / "a.tif", img16)
    from calib.imageio import read_gray
    assert np.array_equal(read_gray(tmp_path / "a.tif"), img16)
    import cv2
    colour = np.zeros((H, W, 3), np.uint8)
    colour[..., 1] = 200  # pure green
    cv2.imwrite(str(tmp_path / "c.png"), colour)
    grey = read_gray(tmp_path / "c.png")
    assert grey.shape == (H, W) and abs(int(grey[0, 0]) - round(0.587 * 200)) <= 1


def test_display_to_wcs_follows_stage_axis(tmp_path):
    make_dataset(tmp_path)
    edit_manifest(tmp_path, lambda d: d.update(stage={"axis": [0.01, -0.02, 1.0]}))
    cap = load_capture(tmp_path)
    p = cap.display_to_wcs(np.array([100.0]), np.array([200.0]), 50.0)[0]
    a = np.array([0.01, -0.02, 1.0])
    expect = np.array([100 * 0.2745, 200 * 0.2745, 0.0]) + 50.0 * a / a[2]
    assert np.allclose(p, expect)


def test_writer_resumes(tmp_path):
    make_dataset(tmp_path, positions=(0.0,))
    wr = CaptureWriter(tmp_path, "calibration", {"cam0": (W, H)}, Display(1920, 1080, (0.2745, 0.2745)))
    assert len(wr.capture.frames) == 4
    again = fringe_frame("cam0", "other.png", 0.0, "x", 60, 0.0)
    assert wr.has(again)


@pytest.mark.parametrize("case, expect", [
    ("missing_image", "image file is missing"),
    ("unreadable_image", "not a readable image"),
    ("wrong_size", "image is 41x30"),
    ("unknown_pattern", "unknown pattern type 'stripes'"),
    ("missing_period", "fringe pattern lacks 'period_px'"),
    ("missing_shift", "fringe pattern lacks 'shift_rad'"),
    ("one_position", "at least 2 are needed"),
    ("duplicate_frame", "duplicate frame"),
    ("duplicate_file", "duplicate frame: file"),
    ("bad_json", "not valid JSON"),
    ("wrong_format", "expected 'stereodic.capture/1'"),
])
def test_bad_dataset_is_rejected_in_one_line(tmp_path, case, expect):
    make_dataset(tmp_path)
    bad_file = "capture.json"
    if case == "missing_image":
        (tmp_path / "z050/cam0_x_P60_s1.png").unlink()
        bad_file = "cam0_x_P60_s1.png"
    elif case == "unreadable_image":
        (tmp_path / "z050/cam0_x_P60_s1.png").write_bytes(b"not a png")
        bad_file = "cam0_x_P60_s1.png"
    elif case == "wrong_size":
        write_gray(tmp_path / "z000/cam0_x_P60_s2.png", np.zeros((H, W + 1), np.uint8))
        bad_file = "cam0_x_P60_s2.png"
    elif case == "unknown_pattern":
        edit_manifest(tmp_path, lambda d: d["frames"][0]["pattern"].update(type="stripes"))
    elif case == "missing_period":
        edit_manifest(tmp_path, lambda d: d["frames"][0]["pattern"].pop("period_px"))
    elif case == "missing_shift":
        edit_manifest(tmp_path, lambda d: d["frames"][0]["pattern"].pop("shift_rad"))
    elif case == "one_position":
        edit_manifest(tmp_path, lambda d: d.update(frames=[f for f in d["frames"] if f["z_mm"] == 0.0]))
    elif case == "duplicate_frame":
        def dup(d):
            f = dict(d["frames"][0])
            f["file"] = "z050/cam0_x_P60_s1.png"
            d["frames"][1] = f
        edit_manifest(tmp_path, dup)
    elif case == "duplicate_file":
        edit_manifest(tmp_path, lambda d: d["frames"][1].update(file=d["frames"][0]["file"]))
    elif case == "bad_json":
        (tmp_path / "capture.json").write_text("{ not json")
    elif case == "wrong_format":
        edit_manifest(tmp_path, lambda d: d.update(format="other/2"))

    with pytest.raises(InputError) as err:
        load_capture(tmp_path)
    assert expect in str(err.value)
    assert bad_file in str(err.value)
    assert "\n" not in str(err.value)


def test_cli_reports_bad_dataset_with_status_2(tmp_path, capsys, monkeypatch):
    """InputError from any command -> `stereodic: <file>: <problem>`, one line, exit 2."""
    import stereodic.cli as cli

    def fake_register(sub):
        p = sub.add_parser("probe")
        p.add_argument("dataset")
        p.set_defaults(func=lambda a: load_capture(a.dataset) and 0)

    make_dataset(tmp_path)
    (tmp_path / "z000/cam0_flat_128.png").unlink()
    monkeypatch.setattr(cli, "COMMANDS", cli.COMMANDS + ["probe"])
    import sys
    import types
    monkeypatch.setitem(sys.modules, "stereodic.cli.probe", types.SimpleNamespace(register=fake_register))
    assert main(["probe", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cam0_flat_128.png" in err[0] and "missing" in err[0]

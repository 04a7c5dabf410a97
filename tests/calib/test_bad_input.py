"""Bad calibration input is reported (exit 2, one line naming the file) and never gives a silent PRVM."""

import json

import numpy as np

from calib.prvm_file import load_prvm
from stereodic.cli import main
from synth_capture import make_capture


def _run(tmp_path, capsys, dataset):
    out = tmp_path / "cam.npz"
    status = main(["calibrate", str(dataset), "-o", str(out)])
    err = capsys.readouterr().err
    return status, err, out


def test_missing_frame(tmp_path, capsys):
    manifest, _ = make_capture(tmp_path / "d")
    (tmp_path / "d" / "z1" / "x_P60_s1.png").unlink()
    status, err, out = _run(tmp_path, capsys, tmp_path / "d")
    assert status == 2 and "x_P60_s1.png" in err and "missing" in err and not out.exists()


def test_inconsistent_frames(tmp_path, capsys):
    manifest, _ = make_capture(tmp_path / "d")
    d = json.loads(manifest.read_text())
    d["frames"] = [f for f in d["frames"] if not f["file"].startswith("z0/y_P12_s")] + \
        [f for f in d["frames"] if f["file"] == "z0/y_P12_s0.png"]
    manifest.write_text(json.dumps(d))
    status, err, out = _run(tmp_path, capsys, tmp_path / "d")
    assert status == 2 and "capture.json" in err and "fewer than 3 distinct shifts" in err and not out.exists()


def test_only_one_stage_position(tmp_path, capsys):
    manifest, _ = make_capture(tmp_path / "d", zs=(0.0,))
    status, err, out = _run(tmp_path, capsys, tmp_path / "d")
    assert status == 2 and "capture.json" in err and "stage position" in err and not out.exists()


def test_all_dark(tmp_path, capsys):
    make_capture(tmp_path / "d", gain=0.005)
    status, err, out = _run(tmp_path, capsys, tmp_path / "d")
    assert status == 2 and ".png" in err and "dark" in err and not out.exists()


def test_saturated(tmp_path, capsys):
    make_capture(tmp_path / "d", gain=3.0)
    status, err, out = _run(tmp_path, capsys, tmp_path / "d")
    assert status == 2 and ".png" in err and "saturated" in err and not out.exists()


def test_display_does_not_cover_the_field_of_view(tmp_path, capsys):
    """The part of the image outside the display is masked, named in a warning, and drawn by --report."""
    make_capture(tmp_path / "d", cover=(0, 300, 0, 359))       # the display's right part shows nothing
    out = tmp_path / "cam.npz"
    assert main(["calibrate", str(tmp_path / "d"), "--report", str(tmp_path / "rep"), "-o", str(out)]) == 0
    err = capsys.readouterr().err
    assert "warning" in err and "not calibrated" in err and "field of view" in err
    prvm = load_prvm(out)
    assert 0.1 < (~prvm.valid).mean() < 0.9
    assert not prvm.valid[:, -1].any() and prvm.valid[:, 0].all()
    assert np.isnan(prvm.origin[~prvm.valid]).all()
    assert (tmp_path / "rep" / "mask.png").is_file()


def test_unsafe_period_ratio(tmp_path, capsys):
    make_capture(tmp_path / "d", periods=(480, 8), noise=6.0)
    status, err, out = _run(tmp_path, capsys, tmp_path / "d")
    assert status == 2 and "period ratio" in err and not out.exists()


def _posed(tmp_path):
    """A small stage-free capture (3 poses of a tilted display) and its manifest as a dict."""
    from test_handheld import BIG, PERIODS, synthetic_poses
    manifest, _ = make_capture(tmp_path / "d", periods=PERIODS, display=BIG, poses=synthetic_poses(3))
    return manifest, json.loads(manifest.read_text())


def test_capture_mixing_poses_and_stage_positions(tmp_path, capsys):
    manifest, d = _posed(tmp_path)
    del d["frames"][5]["pose"]
    d["frames"][5]["z_mm"] = 0.0
    manifest.write_text(json.dumps(d))
    status, err, out = _run(tmp_path, capsys, tmp_path / "d")
    assert status == 2 and "capture.json" in err and "mixes stage positions and display poses" in err
    assert len(err.strip().splitlines()) == 1 and not out.exists()


def test_pose_with_a_missing_fringe_set(tmp_path, capsys):
    manifest, d = _posed(tmp_path)
    d["frames"] = [f for f in d["frames"] if not (f["pose"] == 2 and f["file"].startswith("z2/y_P15_"))]
    manifest.write_text(json.dumps(d))
    status, err, out = _run(tmp_path, capsys, tmp_path / "d")
    assert status == 2 and "capture.json" in err and "pose 2" in err and "y fringe set of period 15" in err
    assert not out.exists()


def test_fewer_poses_than_the_model_needs(tmp_path, capsys):
    manifest, d = _posed(tmp_path)
    d["frames"] = [f for f in d["frames"] if f["pose"] != 2]
    manifest.write_text(json.dumps(d))
    status, err, out = _run(tmp_path, capsys, tmp_path / "d")
    assert status == 2 and "capture.json" in err and "2 display pose(s); at least 3" in err and not out.exists()


def test_frame_with_both_a_pose_and_a_stage_position(tmp_path, capsys):
    manifest, d = _posed(tmp_path)
    d["frames"][0]["z_mm"] = 0.0
    manifest.write_text(json.dumps(d))
    status, err, out = _run(tmp_path, capsys, tmp_path / "d")
    assert status == 2 and "frame 0" in err and "both 'z_mm' and 'pose'" in err and not out.exists()

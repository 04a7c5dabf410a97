"""Bad input to `stereodic rig` / `rectify`: one line naming the file, exit status 2."""

import numpy as np
import pytest

from calib.prvm_file import PRVM
from scanners.sim.lenses import DEFAULT_TARGET_MM, make_lens
from stereodic.cli import main
from tests.stereodic.rig_cases import H, PIXEL_MM, W, pair


def _save(path, prvm: PRVM, **meta):
    PRVM(prvm.origin, prvm.direction, prvm.valid, prvm.residual_mm, {**prvm.meta, **meta}).save(path)
    return str(path)


def _run(argv, capsys):
    status = main(argv)
    err = capsys.readouterr().err.strip()
    return status, err


def test_prvms_from_different_datasets_do_not_share_a_wcs(tmp_path, capsys):
    _, _, pl, pr, _ = pair()
    left = _save(tmp_path / "L.npz", pl, dataset="/data/left_calibration")
    right = _save(tmp_path / "R.npz", pr, dataset="/data/right_calibration")
    status, err = _run(["rig", left, right, "-o", str(tmp_path / "rig.npz")], capsys)
    assert status == 2 and len(err.splitlines()) == 1
    assert "R.npz" in err and "WCS" in err
    assert not (tmp_path / "rig.npz").exists()


def test_registered_and_unregistered_do_not_mix(tmp_path, capsys):
    _, _, pl, pr, _ = pair()
    left = _save(tmp_path / "L.npz", pl, wcs="registration A")
    right = _save(tmp_path / "R.npz", pr, wcs="registration B")
    status, err = _run(["rig", left, right, "-o", str(tmp_path / "rig.npz")], capsys)
    assert status == 2 and "R.npz" in err and "registered" in err


def test_fields_that_do_not_overlap(tmp_path, capsys):
    _, _, pl, _, _ = pair()
    away = make_lens("brown", width=W, height=H, seed=5, pixel_mm=PIXEL_MM, offset_mm=(100.0, 0.0),
                     target_mm=(DEFAULT_TARGET_MM[0] + 400, DEFAULT_TARGET_MM[1], 0.0))
    left = _save(tmp_path / "L.npz", pl)
    right = _save(tmp_path / "R.npz", away.true_prvm(dataset=pl.meta["dataset"]))
    status, err = _run(["rig", left, right, "-o", str(tmp_path / "rig.npz")], capsys)
    assert status == 2 and "R.npz" in err and "overlap" in err


def test_identical_optical_centres(tmp_path, capsys):
    _, _, pl, _, _ = pair()
    left = _save(tmp_path / "L.npz", pl)
    right = _save(tmp_path / "R.npz", pl)
    status, err = _run(["rig", left, right, "-o", str(tmp_path / "rig.npz")], capsys)
    assert status == 2 and "R.npz" in err and "coincides" in err


def test_telecentric_model_is_not_offered(tmp_path, capsys):
    """A telecentric pair has no common pinhole geometry to rectify to: --model does not offer it."""
    _, _, pl, pr, _ = pair()
    with pytest.raises(SystemExit) as stop:
        main(["rig", _save(tmp_path / "L.npz", pl), _save(tmp_path / "R.npz", pr), "--model", "telecentric",
              "-o", str(tmp_path / "rig.npz")])
    assert stop.value.code == 2
    assert "invalid choice: 'telecentric'" in capsys.readouterr().err
    assert not (tmp_path / "rig.npz").exists()


def test_rectify_with_a_camera_file_or_wrong_images(tmp_path, capsys):
    _, _, pl, pr, _ = pair()
    cam = _save(tmp_path / "L.npz", pl)
    from calib.imageio import write_gray
    write_gray(tmp_path / "a.png", np.zeros((H, W), np.uint8))
    write_gray(tmp_path / "small.png", np.zeros((10, 10), np.uint8))
    status, err = _run(["rectify", cam, str(tmp_path / "a.png"), str(tmp_path / "a.png"), "-o",
                        str(tmp_path / "out")], capsys)
    assert status == 2 and "L.npz" in err and "rig" in err
    assert main(["rig", cam, _save(tmp_path / "R.npz", pr), "-o", str(tmp_path / "rig.npz")]) == 0
    capsys.readouterr()
    status, err = _run(["rectify", str(tmp_path / "rig.npz"), str(tmp_path / "a.png"), str(tmp_path / "small.png"),
                        "-o", str(tmp_path / "out")], capsys)
    assert status == 2 and "small.png" in err
    status, err = _run(["rectify", str(tmp_path / "missing.npz"), str(tmp_path / "a.png"),
                        str(tmp_path / "a.png"), "-o", str(tmp_path / "out")], capsys)
    assert status == 2 and "missing.npz" in err

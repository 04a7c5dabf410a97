import json

import numpy as np
import pytest

from calib.imageio import read_gray
from calib.patterns import (DisplayResponse, calibration_sequence, fringe_image, fringe_profile, step_shifts)
from stereodic.cli import main


def test_three_step_shifts_are_the_seeds():
    np.testing.assert_allclose(step_shifts(3), [0, 2 * np.pi / 3, -2 * np.pi / 3])
    assert len(step_shifts(5)) == 5
    with pytest.raises(ValueError):
        step_shifts(2)


def test_fringe_follows_the_design_formula():
    img = fringe_image(200, 30, axis="x", period_px=60, shift_rad=2 * np.pi / 3, low=20, high=240)
    c = np.arange(200)
    want = 20 + 220 / 2 * (1 + np.cos(2 * np.pi * c / 60 - 2 * np.pi / 3))
    assert img.shape == (30, 200) and img.dtype == np.uint8
    assert np.abs(img[7].astype(float) - want).max() <= 0.5
    assert (img == img[0]).all()
    imy = fringe_image(50, 80, axis="y", period_px=40, shift_rad=0, low=20, high=240)
    assert (imy[:, 3] == imy[:, 0]).all() and imy.min() >= 20 and imy.max() <= 240


def test_precompensated_fringe_emits_a_cosine():
    levels = np.linspace(0, 255, 256)
    resp = DisplayResponse(levels, 0.002 + (levels / 255) ** 2.2)
    code = fringe_profile(600, 60, 0.3, 20, 240, resp)
    lum = resp(code)
    c = np.arange(600)
    want = resp(20) + (resp(240) - resp(20)) / 2 * (1 + np.cos(2 * np.pi * c / 60 - 0.3))
    assert np.abs(lum - want).max() < 1e-4


def test_sequence_and_cli_write_exact_resolution(tmp_path):
    seq = calibration_sequence(64, 48, periods=[64, 16], steps=4, flat_levels=[0, 128])
    assert len(seq) == 2 + 2 * 2 * 4
    assert main(["patterns", "--display", "64x48", "--periods", "64,16", "--steps", "4",
                 "--flat-levels", "0,128,255", "-o", str(tmp_path)]) == 0
    manifest = json.loads((tmp_path / "patterns.json").read_text())
    assert manifest["format"] == "stereodic.patterns/1" and len(manifest["patterns"]) == 3 + 16
    for entry in manifest["patterns"]:
        assert read_gray(tmp_path / entry["file"]).shape == (48, 64)
    fr = [e for e in manifest["patterns"] if e["pattern"]["type"] == "fringe"][0]
    img = read_gray(tmp_path / fr["file"])
    p = fr["pattern"]
    np.testing.assert_array_equal(img, fringe_image(64, 48, axis=p["axis"], period_px=p["period_px"],
                                                    shift_rad=p["shift_rad"], low=p["low"], high=p["high"]))


def test_cli_rejects_periods_that_do_not_cover_the_display(tmp_path, capsys):
    assert main(["patterns", "--display", "1920x1080", "--periods", "60,360", "-o", str(tmp_path)]) == 2
    assert "--periods" in capsys.readouterr().err

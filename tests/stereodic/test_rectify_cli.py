"""`stereodic rig` + `stereodic rectify` on images of a textured plane: a surface on the common plane
appears at the same virtual pixels in both rectified images."""

import cv2
import numpy as np
import pytest

from calib.imageio import read_gray, write_gray
from scanners.sim.speckle import make_speckle, render
from stereodic.cli import main
from stereodic.stereo.rectify import row_alignment
from tests.stereodic.dice_gold import DATA as DICE
from tests.stereodic.rig_cases import pair


def _texture(rig, points):
    """A smooth 16-bit texture on the common plane (WCS points (..., 3) on it)."""
    p = points - rig.sensor.origin
    a, b = p @ rig.sensor.axis_u, p @ rig.sensor.axis_v
    return 30000 + 20000 * np.sin(2 * np.pi * a / 40.0) * np.cos(2 * np.pi * b / 30.0)


def _photo(rig, lens):
    """The camera's image of the textured common plane (point-sampled at the true rays)."""
    o, d = lens.rays(*lens.pixel_grid())
    n = rig.sensor.normal
    t = ((rig.sensor.origin - o) @ n) / (d @ n)
    return np.rint(_texture(rig, o + t[..., None] * d)).astype(np.uint16)


def test_rig_and_rectify_commands(tmp_path, capsys):
    ll, lr, pl, pr, rig = pair("brown", "freeform")
    pl.save(tmp_path / "L.npz")
    pr.save(tmp_path / "R.npz")
    assert main(["rig", str(tmp_path / "L.npz"), str(tmp_path / "R.npz"), "-o", str(tmp_path / "rig.npz")]) == 0
    write_gray(tmp_path / "l_000.png", _photo(rig, ll))
    write_gray(tmp_path / "r_000.png", _photo(rig, lr))
    out = tmp_path / "rect"
    assert main(["rectify", str(tmp_path / "rig.npz"), str(tmp_path / "l_000.png"), str(tmp_path / "r_000.png"),
                 "-o", str(out)]) == 0
    written = [line.split(":")[0] for line in capsys.readouterr().out.splitlines() if line.startswith("wrote")]
    assert written[-3:] == [f"wrote {out / 'left' / 'l_000.png'}", f"wrote {out / 'right' / 'r_000.png'}",
                            f"wrote {out / 'overlay.png'}"]
    left, right = read_gray(out / "left" / "l_000.png"), read_gray(out / "right" / "r_000.png")
    assert left.shape == right.shape == (rig.sensor.height, rig.sensor.width) and left.dtype == np.uint16
    truth = _texture(rig, rig.sensor.grid())
    for img in (left, right):
        assert np.sqrt(np.mean((img - truth) ** 2)) < 100          # of 20000: bilinear resampling only
    assert np.sqrt(np.mean((left.astype(float) - right) ** 2)) < 100
    overlay = cv2.imread(str(out / "overlay.png"))
    assert overlay.shape[0] > 300 and overlay.shape[1] > 600


def test_row_alignment_measures_a_known_vertical_disparity():
    """Features of a speckle pair whose right image is the left moved by (-23, dy) pixels, up to tens of
    rows: the measured vertical disparity is dy (the renderer integrates the dots analytically: an exact
    sub-pixel shift)."""
    sp = make_speckle(320, 240, seed=7)
    left = render(sp, noise_sigma=1.0, seed=1)
    for dy in (0.0, 0.35, -1.6, 22.4):          # 22.4: a rig whose calibration no longer fits its images
        right = render(sp, (-23.0, dy), noise_sigma=1.0, seed=2)
        m = row_alignment(left, right)
        assert m.dy.size >= 30
        assert abs(np.mean(m.dy) - dy) < 0.01 and m.rms == np.sqrt(np.mean(m.dy ** 2))
        assert np.abs(m.dy - dy).max() < 0.05 and np.abs(m.x_right - m.x + 23).max() < 0.05


def test_row_alignment_of_stripes_finds_nothing():
    """Vertical stripes carry no row information: no feature may be reported."""
    x = np.arange(320)
    stripes = np.tile((128 + 100 * np.sin(2 * np.pi * x / 17)).astype(np.uint8), (240, 1))
    assert row_alignment(stripes, np.roll(stripes, 5, axis=1)).dy.size == 0


@pytest.mark.slow
@pytest.mark.skipif(not DICE.is_dir(), reason="dice-stereo-list not present")
def test_rectify_names_the_rows_offset_of_a_rig_that_no_longer_fits(tmp_path, capsys):
    """The dice-stereo-list pair through its imported VIC-3D calibration: the rectified rows are 12-39 px
    apart (the calibration does not fit these images); the speckle is matched and the message says so."""
    assert main(["import", str(DICE / "cal.xml"), "-o", str(tmp_path / "rig.npz")]) == 0
    images = DICE / "images"
    assert main(["rectify", str(tmp_path / "rig.npz"), str(images / "img_0000_0.tif"), str(images / "img_0000_1.tif"),
                 "-o", str(tmp_path / "out")]) == 0
    line = next(ln for ln in capsys.readouterr().out.splitlines() if "overlay.png" in ln)
    count = int(line.split(" over ")[1].split(" matched")[0])
    low, high = (float(v) for v in line.split("the rows are ")[1].split(" px apart")[0].split(" to "))
    assert count >= 50 and -45 < low < -30 and -20 < high < -5 and "no longer fits" in line

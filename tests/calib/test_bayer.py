"""Bayer cameras (calib.bayer): the mosaic's layout, colour images, and a calibration whose colours see
the display with their own gain and response (the independent synthetic generator of synth_capture)."""

import cv2
import numpy as np
import pytest

from calib.bayer import colour_map, colours, read_mosaic
from calib.calibration import calibrate_camera
from calib.capture import load_capture
from calib.evaluate import ErrorStats, ray_error_px
from calib.imageio import read_gray
from synth_capture import make_capture


@pytest.mark.parametrize("pattern", ["RGGB", "BGGR", "GRBG", "GBRG"])
def test_colours_follow_the_pattern(pattern):
    m = colour_map(pattern, 4, 6)
    assert "".join(m[:2, :2].ravel()) == pattern
    assert (m[2:4, 4:6] == m[:2, :2]).all()
    assert colours(pattern)[(1, 0)] == pattern[2]


def test_a_colour_image_of_a_bayer_camera_is_re_mosaicked(tmp_path):
    """Each photosite takes its own colour's channel of a colour (BGR-stored) image."""
    rng = np.random.default_rng(0)
    bgr = rng.integers(0, 65535, (6, 8, 3), dtype=np.uint16)
    cv2.imwrite(str(tmp_path / "c.png"), bgr)
    mosaic = read_mosaic(tmp_path / "c.png", "GRBG")
    assert mosaic[0, 0] == bgr[0, 0, 1] and mosaic[0, 1] == bgr[0, 1, 2]          # G, R
    assert mosaic[1, 0] == bgr[1, 0, 0] and mosaic[1, 1] == bgr[1, 1, 1]          # B, G
    assert mosaic[5, 7] == bgr[5, 7, 1]
    cv2.imwrite(str(tmp_path / "raw.png"), bgr[..., 0])
    assert (read_mosaic(tmp_path / "raw.png", "GRBG") == bgr[..., 0]).all()       # raw: as it is


def test_a_colour_image_of_a_monochrome_camera_is_converted_with_documented_weights(tmp_path):
    """Y = 0.299 R + 0.587 G + 0.114 B (docs/calibration.md), rounded."""
    rng = np.random.default_rng(1)
    bgr = rng.integers(0, 256, (5, 7, 3), dtype=np.uint8)
    cv2.imwrite(str(tmp_path / "c.png"), bgr)
    expect = 0.299 * bgr[..., 2] + 0.587 * bgr[..., 1] + 0.114 * bgr[..., 0]
    assert np.abs(read_gray(tmp_path / "c.png").astype(float) - expect).max() <= 0.5 + 1e-9


COLOURS = {"R": (0.55, 1.8), "G": (1.0, 2.2), "B": (0.7, 2.6)}


@pytest.fixture(scope="module")
def bayer_calibration(tmp_path_factory):
    root = tmp_path_factory.mktemp("bayer")
    _, truth = make_capture(root, w=96, h=72, noise=0.3, flat_levels=(0, 48, 96, 144, 192, 255),
                            bayer=("RGGB", COLOURS), zs=(0.0, 40.0))
    return calibrate_camera(load_capture(root)), truth


def test_each_colour_is_decoded_with_its_own_response(bayer_calibration):
    """Every photosite's ray matches the truth as well as with one common response (RMS < 0.03 px,
    each colour); each sub-lattice's measured display response follows its own gamma."""
    cal, truth = bayer_calibration
    err = ray_error_px(cal.prvm, truth, z_mm=0.0)
    colour = colour_map("RGGB", 72, 96)
    for c in "RGB":
        assert ErrorStats.of(np.where(colour == c, err, np.nan)).rms < 0.03, c
    levels, lum = cal.prvm.extra["im_bayer_levels"], cal.prvm.extra["im_bayer_luminance"]
    for k, (dy, dx) in enumerate(((0, 0), (0, 1), (1, 0), (1, 1))):
        gamma = COLOURS["RGGB"[2 * dy + dx]][1]
        y = (levels[k] / 255) ** gamma
        # relative luminance from the darkest to the brightest unsaturated flat
        assert np.abs(lum[k] - (y - y[0]) / (y[-1] - y[0])).max() < 0.01
    assert cal.prvm.meta["bayer"] == "RGGB" and cal.prvm.extra["im_gain"].shape == (72, 96)

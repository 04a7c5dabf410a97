"""Pattern display: the file sink, the simulated screen and, on a virtual X screen (Xvfb), the real
full-screen window read back pixel for pixel through the X server."""

import cv2
import numpy as np
import pytest

from calib.errors import InputError
from calib.imageio import read_gray
from calib.patterns import fringe_image
from scanners.display import FileScreen, SimScreen, open_screen
from scanners.errors import HardwareError
from tests.scanners.xvfb import read_back, virtual_screen

W, H = 320, 200


def test_file_screen_writes_what_it_shows(tmp_path):
    screen = open_screen(f"file:{tmp_path}/shown?size=64x48")
    assert isinstance(screen, FileScreen) and screen.size == (64, 48)
    a = fringe_image(64, 48, axis="x", period_px=16, shift_rad=0.0)
    b = fringe_image(64, 48, axis="y", period_px=12, shift_rad=2.0)
    screen.show(a)
    screen.show(b)
    assert sorted(p.name for p in (tmp_path / "shown").iterdir()) == ["00000.png", "00001.png"]
    assert np.array_equal(read_gray(tmp_path / "shown" / "00001.png"), b)
    assert FileScreen(tmp_path / "shown", (64, 48))._next == 2     # a second run continues the numbering


def test_colour_pictures(tmp_path):
    picture = np.random.default_rng(2).integers(0, 256, (48, 64, 3), dtype=np.uint8)
    screen = FileScreen(tmp_path, (64, 48))
    screen.show(picture)
    assert np.array_equal(cv2.imread(str(tmp_path / "00000.png"))[:, :, ::-1], picture)
    sim = SimScreen()
    rgb = np.zeros((1080, 1920, 3), np.uint8)
    rgb[..., 0], rgb[..., 1], rgb[..., 2] = 200, 100, 50
    sim.show(rgb)
    assert sim.image.shape == (1080, 1920) and (sim.image == round(0.299 * 200 + 0.587 * 100 + 0.114 * 50)).all()
    with pytest.raises(ValueError, match="needs uint8 64x48"):
        screen.show(np.zeros((48, 64, 4), np.uint8))
    assert screen.pressed() == []


def test_wrong_pattern_size_is_refused(tmp_path):
    screen = FileScreen(tmp_path, (64, 48))
    with pytest.raises(ValueError, match="needs uint8 64x48"):
        screen.show(np.zeros((64, 48), np.uint8))


def test_sim_screen_holds_the_image():
    screen = open_screen("sim")
    assert isinstance(screen, SimScreen) and screen.size == (1920, 1080) and screen.pitch_mm == (0.2745, 0.2745)
    img = fringe_image(1920, 1080, axis="x", period_px=60, shift_rad=0.0)
    screen.show(img)
    assert np.array_equal(screen.image, img) and screen.serial == 1


@pytest.mark.parametrize("spec, says", [
    ("projector", "unknown display"), ("screen:one", "monitor number"), ("file:/tmp/x", "size=1920x1080"),
    ("file:/tmp/x?size=big", "size=1920x1080"),
])
def test_bad_display_specs(spec, says):
    with pytest.raises(InputError, match=says):
        open_screen(spec)


# ----------------------------------------------------------------------------------------- Xvfb

@pytest.fixture(scope="module")
def xvfb():
    """A virtual X screen of W x H pixels for this module."""
    with virtual_screen(W, H) as display:
        yield display


@pytest.mark.display
@pytest.mark.parametrize("vsync", [False, True])
def test_full_screen_pixel_for_pixel(xvfb, vsync):
    screen = open_screen("screen:0", settle_s=0.05, vsync=vsync)
    try:
        assert screen.size == (W, H)
        rng = np.random.default_rng(1)
        for image in (fringe_image(W, H, axis="x", period_px=60, shift_rad=0.0),
                      fringe_image(W, H, axis="y", period_px=36, shift_rad=-2.0944),
                      rng.integers(0, 256, (H, W), dtype=np.uint8)):   # noise: any scaling or filter shows
            screen.show(image)
            got = read_back(xvfb)
            for ch in range(3):                                       # grey on R, G and B alike
                assert np.array_equal(got[:, :, ch], image)
    finally:
        screen.close()


@pytest.mark.display
def test_missing_monitor(xvfb):
    with pytest.raises(HardwareError, match=r"screen:3: there are 1 monitor\(s\)"):
        open_screen("screen:3")


def test_no_monitor_is_refused_not_faked(monkeypatch):
    """Without an X display SDL falls back to an off-screen driver (a 1024x768 'desktop' nobody sees):
    patterns shown there would be lost, so the screen refuses to open."""
    pytest.importorskip("pygame")
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    with pytest.raises(HardwareError, match="screen:0: "):
        open_screen("screen:0")

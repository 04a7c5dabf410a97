"""Cameras: averaging and the saturation check, the folder camera, the simulated camera, specs."""

import threading
import time

import numpy as np
import pytest

from calib.errors import InputError
from calib.imageio import write_gray
from calib.patterns import fringe_image
from scanners.camera import Camera, FolderCamera, SaturatedError, SimulatedCamera, capture, open_camera
from scanners.display import SimScreen
from scanners.errors import HardwareError
from scanners.sim.aim import true_alignment
from scanners.sim.lenses import make_lens


class Scripted(Camera):
    """Returns the given frames in turn."""

    def __init__(self, frames, bit_depth=8):
        self.name, self.frames, self.bit_depth = "cam0", list(frames), bit_depth
        self.size = (frames[0].shape[1], frames[0].shape[0])

    def grab(self):
        return self.frames.pop(0)


def test_average_is_the_rounded_mean():
    frames = [np.full((2, 3), v, np.uint16) for v in (100, 101, 101, 103)]
    out = capture(Scripted(frames, bit_depth=12), average=4)
    assert out.dtype == np.uint16 and np.all(out == 101)     # 405 / 4 = 101.25


def test_saturation_limit():
    img = np.full((10, 100), 200, np.uint8)
    img[0, :2] = 255                                          # 2 of 1000 pixels at full scale
    assert capture(Scripted([img]), max_saturated=0.002) is img
    with pytest.raises(SaturatedError, match=r"cam0: 0.20% of the pixels are saturated"):
        capture(Scripted([img]), max_saturated=0.001)
    assert capture(Scripted([img]), max_saturated=None) is img
    # 12-bit camera in uint16: full scale is 4095, not 65535
    img12 = np.full((10, 10), 4095, np.uint16)
    with pytest.raises(SaturatedError):
        capture(Scripted([img12], bit_depth=12))


def test_wrong_frame_size_is_a_hardware_error():
    cam = Scripted([np.zeros((4, 4), np.uint8), np.zeros((4, 5), np.uint8)])
    capture(cam)
    with pytest.raises(HardwareError, match="frame is 5x4, expected 4x4"):
        capture(cam)


def test_folder_camera_takes_photos_in_name_order(tmp_path):
    (tmp_path / "notes.txt").write_text("not a photo")
    write_gray(tmp_path / "IMG_0001.png", np.full((30, 40), 1, np.uint8))
    import cv2
    cv2.imwrite(str(tmp_path / "IMG_0002.jpg"), np.full((30, 40, 3), 200, np.uint8))   # colour JPEG
    cam = open_camera(f"folder:{tmp_path}?timeout=0.2", "cam0")
    assert isinstance(cam, FolderCamera) and cam.size == (40, 30)
    assert cam.grab().max() == 1 and cam.source == "IMG_0001.png"
    second = cam.grab()
    assert second.ndim == 2 and abs(int(second.mean()) - 200) <= 2 and cam.source == "IMG_0002.jpg"
    with pytest.raises(HardwareError, match="no new photo"):
        cam.grab()


def test_folder_camera_waits_for_the_next_photo(tmp_path, capsys):
    cam = FolderCamera(tmp_path, "cam0", size=(8, 6), timeout_s=5, poll_s=0.02)
    threading.Timer(0.2, write_gray, (tmp_path / "a.png", np.full((6, 8), 7, np.uint8))).start()
    t0 = time.monotonic()
    assert cam.grab().max() == 7
    assert time.monotonic() - t0 >= 0.2
    assert "Take a photo with cam0 now" in capsys.readouterr().err


def test_folder_camera_needs_a_size(tmp_path):
    with pytest.raises(InputError, match="size=WIDTHxHEIGHT"):
        FolderCamera(tmp_path, "cam0")


def test_simulated_camera_noise_depends_only_on_what_it_sees():
    z = [0.0]
    screen = SimScreen()
    cams = [SimulatedCamera("cam0", screen, lambda: z[0], size=(48, 40), seed=5) for _ in range(2)]
    for c in cams:
        c.set_exposure(240, 0.0)
    a = fringe_image(1920, 1080, axis="x", period_px=60, shift_rad=0.0)
    screen.show(a)
    first = cams[0].grab()
    again = cams[0].grab()                     # a second grab of the same image: new noise
    assert not np.array_equal(first, again)
    assert np.array_equal(cams[1].grab(), first)      # same history of this image -> same frame
    screen.show(a)                             # shown anew (as after a resume): the count restarts
    assert np.array_equal(cams[0].grab(), first)
    z[0] = 50.0
    assert not np.array_equal(cams[0].grab(), first)  # elsewhere: another image


def test_simulated_camera_aimed_at_known_tilts_on_a_tilted_stage():
    screen = SimScreen()
    axis = (0.01, -0.02, 1.0)
    cam = open_camera("sim:freeform?size=64x48&pixel_um=106&tilt=1.5,-2.5&roll=0.7", "cam0", screen, lambda: 20.0,
                      axis)
    assert cam.sim.lens.pixel_mm == pytest.approx(0.106)
    truth = true_alignment(cam.sim.lens, screen.sim, cam.true_pose())
    assert (truth["tilt_x_deg"], truth["tilt_y_deg"], truth["roll_deg"]) == pytest.approx((1.5, -2.5, 0.7))
    assert np.allclose(cam.true_pose().t, [0.2, -0.4, 20.0]) and cam.true_pose().is_staged()
    plain = open_camera("sim:freeform?size=64x48&pixel_um=106", "cam0", screen, lambda: 20.0)
    assert np.allclose(plain.sim.lens.rotation,
                       make_lens("freeform", width=64, height=48, seed=0, pixel_mm=0.106).rotation)  # seeded


def test_simulated_camera_sees_a_colour_picture_as_its_grey():
    screen = SimScreen()
    cam = SimulatedCamera("cam0", screen, lambda: 0.0, size=(48, 40), noise=False)
    cam.set_exposure(240, 0.0)
    grey = fringe_image(1920, 1080, axis="x", period_px=60, shift_rad=0.0)
    screen.show(grey)
    want = cam.grab()
    screen.show(np.repeat(grey[:, :, None], 3, axis=2))        # the same grey as an RGB picture
    assert np.array_equal(screen.image, grey) and np.array_equal(cam.grab(), want)


def test_simulated_camera_needs_the_simulated_rig():
    with pytest.raises(InputError, match="needs --display sim"):
        open_camera("sim", "cam0", screen=None, true_z_mm=None)


@pytest.mark.parametrize("spec, says", [
    ("usb:0", "unknown camera"), ("cv:first", "cv:INDEX"), ("cv:0?fps=30", "unknown option"),
    ("folder:/tmp?size=4k", "WIDTHxHEIGHT"), ("cv:0?exposure_ms=long", "exposure_ms must be a number"),
    ("sim?tilt=1,2,3", "tilt must be 2 comma-separated"), ("sim?roll=up", "roll must be 1 comma-separated"),
    ("sim?pixel_um=0", "pixel_um must be positive"), ("sim?tilt=40,0", r"within \+-30 degrees"),
])
def test_bad_camera_specs(spec, says):
    with pytest.raises(InputError, match=says):
        open_camera(spec, "cam0", SimScreen(), lambda: 0.0)


def test_missing_opencv_device():
    with pytest.raises(HardwareError, match="cannot open camera cv:97"):
        open_camera("cv:97", "cam0")


def test_bit_depth_is_declared_reported_or_the_frames_own(tmp_path):
    from scanners.camera import frame_bit_depth
    lsb12 = np.array([[0, 4095]], np.uint16)
    assert frame_bit_depth(np.zeros((2, 2), np.uint8), "cam0") == 8
    assert frame_bit_depth(lsb12, "cam0") == 16                       # unknown: the frame's own
    assert frame_bit_depth(lsb12, "cam0", reported=12) == 12          # what the driver reports (XIMEA)
    assert frame_bit_depth(lsb12, "cam0", declared=12, reported=14) == 12
    with pytest.raises(InputError, match="MSB-aligned"):
        frame_bit_depth(lsb12 << 4, "cam0", declared=12)              # 12 bits in the top of 16
    with pytest.raises(InputError, match="does not fit"):
        frame_bit_depth(np.zeros((2, 2), np.uint8), "cam0", declared=12)
    # a folder camera declares it in its spec; the full scale it checks saturation against follows
    write_gray(tmp_path / "a.png", np.full((6, 8), 4095, np.uint16))
    cam = open_camera(f"folder:{tmp_path}?bit_depth=12&timeout=0.2", "cam0")
    assert cam.bit_depth == 12
    with pytest.raises(SaturatedError):
        capture(cam)
    with pytest.raises(InputError, match="bit_depth"):
        open_camera(f"folder:{tmp_path}?bit_depth=20", "cam0")
    assert open_camera(f"folder:{tmp_path / 'none'}?size=8x6", "cam1").bit_depth is None

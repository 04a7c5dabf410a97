"""Decoding a fringe set held in memory (calib.live_decode) against the simulated camera's true display
coordinates: the display's gamma must be measured from flats for a period ratio of 16 to unwrap."""

import numpy as np
import pytest

from calib.live_decode import decode_display, flat_correction
from calib.patterns import flat_image, fringe_image, step_shifts
from scanners.sim.camera import SimCamera
from scanners.sim.display import SimDisplay
from scanners.sim.lenses import make_lens
from scanners.sim.pose import DisplayPose
from scanners.sim.sensor import Sensor

W, H = 160, 128
DISPLAY = SimDisplay()                        # gamma 2.2
POSE = DisplayPose.staged(20.0)
PERIODS = (1920.0, 120.0)
SHIFTS = step_shifts(3)


@pytest.fixture(scope="module")
def camera():
    cam = SimCamera(make_lens("brown", width=W, height=H, seed=0, pixel_mm=0.0212), sensor=Sensor(bit_depth=8),
                    supersample=3, seed=1)
    cam.set_exposure(DISPLAY, 240, POSE)
    return cam


def fringes(cam):
    return {(axis, p): [cam.render(fringe_image(1920, 1080, axis=axis, period_px=p, shift_rad=d), DISPLAY, POSE)
                        for d in SHIFTS]
            for axis in "xy" for p in PERIODS}


def test_decodes_the_true_display_points(camera):
    levels = (20, 130, 240)
    correction = flat_correction(levels, [camera.render(flat_image(1920, 1080, v), DISPLAY, POSE) for v in levels],
                                 255, 20, 240, SHIFTS)
    assert correction.max_error > 0.2                  # gamma 2.2 bends a 3-step fringe by 0.25 rad
    got = decode_display(fringes(camera), SHIFTS, (1920, 1080), 255, correction=correction)
    truth = np.moveaxis(camera.view(DISPLAY, POSE).display_cr, -1, 0)
    err = np.linalg.norm(got.coord - truth, axis=0)[got.valid]
    assert got.valid_fraction > 0.99
    assert err.max() < 2.0 and np.sqrt(np.mean(err ** 2)) < 0.4      # display pixels, no wrong fringe order
    assert max(max(s) for s in got.mismatch_sigma.values()) < 0.05
    assert got.mean.shape == (H, W) and np.median(got.mean[got.valid]) > 50


def test_without_the_response_the_periods_disagree(camera):
    with pytest.raises(ValueError, match="disagree by 0.2"):
        decode_display(fringes(camera), SHIFTS, (1920, 1080), 255)


def test_a_camera_that_sees_nothing_decodes_nothing():
    rng = np.random.default_rng(0)
    frames = {(a, p): [rng.integers(0, 6, (H, W)).astype(np.uint8) for _ in SHIFTS] for a in "xy" for p in PERIODS}
    assert decode_display(frames, SHIFTS, (1920, 1080), 255).valid_fraction == 0.0
    with pytest.raises(ValueError, match="no pixel responds"):
        flat_correction((20, 130, 240), [np.full((H, W), 3, np.uint8)] * 3, 255, 20, 240, SHIFTS)

"""The simulated camera: what it renders is what the true rays, display and sensor physics say."""

import dataclasses

import numpy as np
import pytest
from scipy.special import j1

from calib.capture import CoverGlass
from calib.errors import InputError
from scanners.sim.camera import SimCamera
from scanners.sim.display import SimDisplay
from scanners.sim.lenses import make_lens
from scanners.sim.pose import DisplayPose
from scanners.sim.sensor import Sensor

staged = DisplayPose.staged

W, H = 160, 128
SMOOTH = SimDisplay(fill_factor=(1.0, 1.0), stripes=1)      # no pixel gaps: a flat is uniform


def flat(level):
    return np.full((1080, 1920), level, np.uint8)


def test_flat_frame_shows_the_vignetting_and_gain_that_were_set():
    cam = SimCamera(make_lens("brown", width=W, height=H, vignetting=-0.2),
                    sensor=Sensor(bit_depth=16, prnu=0.02), seed=5)
    cam.set_exposure(SMOOTH, 255, staged(0.0), fraction=0.8)
    n = 16
    mean = np.mean([cam.render(flat(255), SMOOTH, staged(0.0)).astype(float) for _ in range(n)], axis=0)
    conv = cam.sensor.full_well_e / cam.sensor.max_dn
    electrons = (mean - cam.sensor.dark_offset * cam.sensor.max_dn) * conv
    product = electrons / cam.exposure_e                        # = vignetting * gain (flat luminance 1)
    # The smooth part is the vignetting: a quadratic surface fits it.
    u, v = cam.lens.pixel_grid()
    a = np.column_stack([np.ones(u.size), u.ravel(), v.ravel(), u.ravel() ** 2, (u * v).ravel(), v.ravel() ** 2])
    smooth = (a @ np.linalg.lstsq(a, product.ravel(), rcond=None)[0]).reshape(u.shape)
    assert np.abs(smooth - cam.vignetting * cam.gain.mean()).max() < 2e-3
    assert cam.vignetting.min() < 0.97                          # there is vignetting to find
    # The rest is the gain, recovered to within the shot and read noise of the mean of n frames.
    gain = product / smooth
    predicted = np.sqrt(electrons + cam.sensor.read_noise_e ** 2) / electrons / np.sqrt(n)
    err = gain - cam.gain / cam.gain.mean()
    assert np.std(err) < 1.2 * np.sqrt(np.mean(predicted ** 2))
    assert np.corrcoef(gain.ravel(), cam.gain.ravel())[0, 1] > 0.9


def test_noise_variance_is_shot_plus_read_noise():
    cam = SimCamera(make_lens("brown", width=W, height=H), sensor=Sensor(bit_depth=16, read_noise_e=20.0), seed=1)
    cam.set_exposure(SMOOTH, 200, staged(0.0), fraction=0.5)
    clean = cam.render(flat(200), SMOOTH, staged(0.0), noise=False).astype(float)
    a, b = (cam.render(flat(200), SMOOTH, staged(0.0)).astype(float) for _ in range(2))
    conv = cam.sensor.full_well_e / cam.sensor.max_dn
    electrons = (clean - cam.sensor.dark_offset * cam.sensor.max_dn) * conv
    predicted = np.mean(electrons + 20.0 ** 2) / conv ** 2
    assert np.var(a - b) / 2 == pytest.approx(predicted, rel=0.05)


def test_mean_of_noisy_renders_converges_to_the_noise_free_render():
    cam = SimCamera(make_lens("freeform", width=W, height=H), sensor=Sensor(bit_depth=16), seed=2)
    img = np.tile(np.uint8(20 + 220 * (np.arange(1920) % 37 > 18)), (1080, 1))
    cam.set_exposure(SimDisplay(), 240, staged(20.0))
    clean = cam.render(img, SimDisplay(), staged(20.0), noise=False).astype(float)
    frames = np.array([cam.render(img, SimDisplay(), staged(20.0)).astype(float) for _ in range(64)])
    err = {n: np.sqrt(np.mean((frames[:n].mean(axis=0) - clean) ** 2)) for n in (4, 16, 64)}
    assert err[4] / err[16] == pytest.approx(2.0, rel=0.15)
    assert err[4] / err[64] == pytest.approx(4.0, rel=0.15)


def test_bit_depth_and_saturation():
    for bits, dtype in ((8, np.uint8), (12, np.uint16)):
        cam = SimCamera(make_lens("brown", width=W, height=H), sensor=Sensor(bit_depth=bits), seed=0)
        cam.set_exposure(SMOOTH, 128, staged(0.0), fraction=0.9)
        img = cam.render(flat(255), SMOOTH, staged(0.0))
        assert img.dtype == dtype
        assert img.max() == 2 ** bits - 1                       # 255 is ~4.5x as bright as 128: saturated
        assert (img == 2 ** bits - 1).mean() > 0.9
        # Black: the ADC's dark offset plus the display's black level (1/1000 of white) through the optics.
        dark = cam.render(flat(0), SMOOTH, staged(0.0), noise=False)
        e = cam.exposure_e * SMOOTH.black_level * cam.vignetting * cam.gain
        expected = 0.01 * (2 ** bits - 1) + e * (2 ** bits - 1) / cam.sensor.full_well_e
        assert np.abs(dark - expected).max() <= 0.51


def test_default_exposure_puts_the_brightest_fringe_near_full_scale():
    cam = SimCamera(make_lens("brown", width=W, height=H))
    cam.set_exposure(SimDisplay(), 240, staged(0.0))
    img = cam.render(flat(240), SimDisplay(), staged(0.0), noise=False)
    assert 0.85 * 255 <= img.max() <= 0.9 * 255


def column_hit(lens, display, z, c0, rows):
    """For each row (pixel centres), the sensor column u whose true ray reaches display column c0."""
    u = np.linspace(0, lens.width - 1, 4 * lens.width)
    out = []
    for v in rows:
        o, d = lens.rays(u, np.full_like(u, v))
        c, _ = display.hit(o, d, staged(z))
        out.append(np.interp(c0, c, u) if c[-1] > c[0] else np.interp(c0, c[::-1], u[::-1]))
    return np.array(out)


@pytest.mark.parametrize("glass", [None, CoverGlass(4.0, 1.5)])
def test_a_bright_display_column_appears_where_the_true_rays_meet_it(glass):
    lens = make_lens("brown", width=W, height=H, seed=4, offset_mm=(40.0, 0.0))   # oblique view: the glass matters
    cam = SimCamera(lens, sensor=Sensor(bit_depth=16), seed=0)
    display = SimDisplay(fill_factor=(1.0, 1.0), stripes=1, cover_glass=glass)
    z = 25.0
    o, d = lens.rays(np.array([W / 2]), np.array([H / 2]))
    c0 = int(round(SMOOTH.hit(o, d, staged(z))[0][0]))
    img = flat(0)
    img[:, c0] = 255
    cam.set_exposure(display, 255, staged(z), fraction=0.5)
    render = cam.render(img, display, staged(z), noise=False).astype(float)
    rows = np.arange(10, H - 10, 9)
    signal = render[rows] - np.median(render)
    uu = np.arange(W)
    peak = np.array([np.sum(uu * np.clip(s, 0, None) * (np.abs(uu - np.argmax(s)) < 6))
                     / np.sum(np.clip(s, 0, None) * (np.abs(uu - np.argmax(s)) < 6)) for s in signal])
    # Where the line is expected: straight rays to the pixel plane, then (with glass) moved by the
    # plate's in-plane shift t (tan(theta) - tan(theta')) back towards where the ray entered the glass.
    expected = column_hit(lens, SMOOTH, z, c0, rows)
    if glass is not None:
        o, d = lens.rays(expected, rows.astype(float))
        theta = np.arccos(d[:, 2])
        shift = glass.thickness_mm * (np.tan(theta) - np.tan(np.arcsin(np.sin(theta) / 1.5)))
        dc = -shift * d[:, 0] / np.hypot(d[:, 0], d[:, 1]) / display.pitch_mm[0]     # display px
        c_pair = SMOOTH.hit(*lens.rays(np.array([W / 2 - 1, W / 2 + 1]), np.full(2, H / 2)), staged(z))[0]
        du = dc / ((c_pair[1] - c_pair[0]) / 2)                     # camera px
        assert np.abs(du).min() > 0.5                             # the glass moves the line visibly
        expected = expected - du
    assert np.abs(peak - expected).max() < 0.05


def test_defocus_lowers_fringe_contrast_as_the_thin_lens_blur_circle_says():
    lens = make_lens("brown", width=W, height=H, f_number=2.0, focus_mm=400.0, offset_mm=(0, 0), roll_deg=0.0)
    cam = SimCamera(lens, sensor=Sensor(bit_depth=16), diffraction=False)
    period = 12                                                  # display pixels, ~18 camera pixels
    img = np.tile(np.uint8(np.rint(127.5 + 127.5 * np.cos(2 * np.pi * np.arange(1920) / period))), (1080, 1))
    linear = SimDisplay(gamma=1.0, black_level=0.0, fill_factor=(1.0, 1.0), stripes=1)
    contrast = {}
    for z in (0.0, 40.0):
        view = cam.view(linear, staged(z))
        row = cam.irradiance(img, linear, staged(z))[H // 2, 20:-20]
        contrast[z] = (row.max() - row.min()) / (row.max() + row.min())
        blur = float(np.median(view.blur_px))
        cam_period = period / np.median(np.diff(view.c, axis=1)) / cam.supersample   # camera px
        contrast[z, "blur"] = blur
        contrast[z, "f"] = 1 / cam_period
    assert contrast[0.0, "blur"] < 0.05 and contrast[40.0, "blur"] > 3.0
    x = np.pi * contrast[40.0, "blur"] * contrast[40.0, "f"]
    pixel_mtf = lambda f: np.sinc(f)                                 # noqa: E731 - pixel area integration
    predicted = abs(2 * j1(x) / x) * pixel_mtf(contrast[40.0, "f"]) / pixel_mtf(contrast[0.0, "f"])
    assert contrast[40.0] / contrast[0.0] == pytest.approx(predicted, abs=0.05)


def test_a_border_pixel_of_a_defocused_view_sees_what_a_larger_sensor_sees_there():
    # the blur mixes into a border pixel the light the lens images beyond the sensor's edge (not a mirror
    # image of the sensor's own): the same lens on a sensor 10 pixels larger all round (the same rays,
    # shifted principal point) records the same irradiance at the shared pixels, border rows included
    lens = make_lens("brown", width=W, height=H, f_number=2.0, focus_mm=400.0, offset_mm=(0, 0), roll_deg=0.0)
    k = 10
    larger = dataclasses.replace(lens, width=W + 2 * k, height=H + 2 * k, cx=lens.cx + k, cy=lens.cy + k)
    period = 12
    wave = lambda n: np.cos(2 * np.pi * np.arange(n) / period)      # noqa: E731 - fringes along both axes
    img = np.uint8(np.rint(127.5 + 63.75 * (wave(1920)[None, :] + wave(1080)[:, None])))
    display = SimDisplay(gamma=1.0, black_level=0.0, fill_factor=(1.0, 1.0), stripes=1)
    small_cam, large_cam = SimCamera(lens), SimCamera(larger)
    small = small_cam.irradiance(img, display, staged(40.0))
    large = large_cam.irradiance(img, display, staged(40.0))[k:-k, k:-k]
    assert float(np.median(small_cam.view(display, staged(40.0)).blur_px)) > 3.0        # a wide blur
    assert small_cam.view(display, staged(40.0)).margin >= 3
    swing = float(small.max() - small.min())
    assert np.abs(small - large).max() < 1e-4 * swing
    # the pattern changes within the blur's reach of the border (a mirror image there would differ)
    assert np.abs(small[:, 0] - small[:, 4]).max() > 0.05 * swing and np.abs(small[0] - small[4]).max() > 0.05 * swing


def test_the_default_bench_display_covers_the_camera_field():
    lens = make_lens("brown")                               # 1280 x 1024 at ~400 mm
    display = SimDisplay()
    u = np.concatenate([np.arange(1280.0), np.arange(1280.0), np.zeros(1024), np.full(1024, 1279.0)])
    v = np.concatenate([np.zeros(1280), np.full(1280, 1023.0), np.arange(1024.0), np.arange(1024.0)])
    for z in (0.0, 50.0):
        c, r = display.hit(*lens.rays(u, v), staged(z))
        assert c.min() > 0 and r.min() > 0 and c.max() < 1919 and r.max() < 1079


def test_a_display_that_does_not_fill_the_field_shows_its_bezel_beyond_it():
    """Aimed at the display's corner, the camera sees the display in one quadrant, the bezel elsewhere,
    and a blend of the two within the blur of the edge."""
    display = SimDisplay(fill_factor=(1.0, 1.0), stripes=1, bezel=0.02)     # no pixel gaps: uniform
    cam = SimCamera(make_lens("brown", width=W, height=H, target_mm=(0.0, 0.0, 0.0)))
    view = cam.view(display, staged(0.0))
    irr = cam.irradiance(flat(255), display, staged(0.0))
    c, r = view.display_cr[..., 0], view.display_cr[..., 1]
    # the edge distance of each pixel in camera pixels (display px per camera px from the view)
    scale = np.median(np.abs(np.diff(c, axis=1)))
    depth = np.minimum(c + 0.5, r + 0.5) / scale                  # > 0 on the display
    lit = display.fill_factor[0] * display.fill_factor[1] * display.luminance(np.uint8(255))
    reach = 2 + float(view.blur_px.max())                         # blur radius and the pixel, generously
    np.testing.assert_allclose(irr[depth < -reach], 0.02, rtol=1e-4)
    np.testing.assert_allclose(irr[depth > reach], lit, rtol=0.02)
    edge = np.abs(depth) < 0.5
    assert (irr[edge] > 0.02 * 1.5).all() and (irr[edge] < 0.9 * lit).all()
    assert 0.1 < view.seen.mean() < 0.5 and (view.seen == (depth > 0)).mean() > 0.99


def test_a_camera_that_does_not_see_the_display_is_an_input_error():
    cam = SimCamera(make_lens("brown", width=W, height=H, target_mm=(-300.0, -300.0, 0.0)))
    with pytest.raises(InputError, match="does not see the display"):
        cam.view(SimDisplay(), staged(0.0))


def test_ambient_light_and_hot_pixels_add_their_recorded_signal():
    lens = make_lens("brown", width=W, height=H)
    plain = SimCamera(lens, sensor=Sensor(bit_depth=16), seed=2)
    flawed = SimCamera(lens, sensor=Sensor(bit_depth=16, hot_pixels=0.01), seed=2, ambient=0.05,
                       ambient_variation=0.3)
    for cam in (plain, flawed):
        cam.exposure_e = 5000.0
    hot = flawed.hot_e > 0
    assert 0.005 < hot.mean() < 0.015 and flawed.hot_e.max() > flawed.sensor.full_well_e
    assert flawed.ambient.min() == pytest.approx(0.05 * 0.7, rel=0.02)
    assert flawed.ambient.max() == pytest.approx(0.05 * 1.3, rel=0.02)
    black = flat(0)
    e0 = plain.electrons(black, SMOOTH, staged(0.0))
    e1 = flawed.electrons(black, SMOOTH, staged(0.0))
    expected = e0 + flawed.ambient * flawed.vignetting * flawed.gain * 5000.0 + flawed.hot_e
    np.testing.assert_allclose(e1, expected, rtol=1e-5)
    img = flawed.render(black, SMOOTH, staged(0.0), noise=False)
    assert (img[flawed.hot_e >= flawed.sensor.full_well_e] == flawed.sensor.max_dn).all()


def test_overexposure_clips_the_stated_share_of_the_pixels_that_see_the_display():
    display = SimDisplay()
    cam = SimCamera(make_lens("brown", width=W, height=H, target_mm=(0.0, 0.0, 0.0)),
                    sensor=Sensor(bit_depth=12), seed=1)
    cam.set_exposure(display, 240, staged(0.0), clipped=0.05)
    img = cam.render(flat(240), display, staged(0.0), noise=False)
    seen = cam.view(display, staged(0.0)).seen
    assert 0.1 < seen.mean() < 0.9
    assert np.mean(img[seen] == 4095) == pytest.approx(0.05, abs=0.005)

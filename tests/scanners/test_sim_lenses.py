"""The simulated lenses: true rays with the geometry each family must have."""

import numpy as np
import pytest

from calib.errors import InputError
from scanners.sim.distortion import Distortion
from scanners.sim.lenses import LENS_FAMILIES, make_lens

W, H = 160, 128


def grid(step=7):
    return np.meshgrid(np.arange(0, W, step, dtype=float), np.arange(0, H, step, dtype=float))


def closest_point(origin, direction):
    """Least-squares point nearest to all lines; returns (point, RMS distance of the lines from it)."""
    o, d = origin.reshape(-1, 3), direction.reshape(-1, 3)
    proj = np.eye(3)[None] - d[:, :, None] * d[:, None, :]
    p = np.linalg.solve(proj.sum(0), np.einsum("nij,nj->i", proj, o))
    dist = np.linalg.norm(np.einsum("nij,nj->ni", proj, o - p), axis=1)
    return p, np.sqrt(np.mean(dist ** 2))


@pytest.mark.parametrize("family", LENS_FAMILIES)
def test_rays_are_unit_towards_display_with_origin_on_reference_plane(family):
    o, d = make_lens(family, width=W, height=H, seed=3).rays(*grid())
    assert np.allclose(np.linalg.norm(d, axis=-1), 1, atol=1e-14)
    assert (d[..., 2] > 0).all()
    assert np.abs(o[..., 2]).max() < 1e-9


@pytest.mark.parametrize("family", ["brown", "freeform", "scheimpflug"])
def test_central_lens_rays_meet_at_the_projection_centre(family):
    lens = make_lens(family, width=W, height=H, seed=1)
    p, rms = closest_point(*lens.rays(*grid()))
    assert rms < 1e-9
    assert np.allclose(p, lens.centre_mm, atol=1e-8)
    assert -600 < p[2] < -200                     # the camera sits some 400 mm in front of the display


def test_telecentric_rays_are_parallel_and_spread_over_the_field():
    lens = make_lens("telecentric", width=W, height=H)
    o, d = lens.rays(*grid())
    d = d.reshape(-1, 3)
    assert np.abs(d - d[0]).max() < 1e-14
    assert np.allclose(d[0], lens.rotation[:, 2], atol=1e-14)   # along the optical axis
    # object field = sensor field / magnification
    o = o.reshape(-1, 3) - (o.reshape(-1, 3) @ d[0])[:, None] * d[0]
    width = np.ptp(o @ lens.rotation[:, 0])
    assert width == pytest.approx((W - 1 - (W - 1) % 7) * 0.0053 / lens.magnification, rel=0.01)


@pytest.mark.parametrize("family", LENS_FAMILIES)
def test_a_pixel_sees_less_than_a_display_pixel_but_does_not_resolve_it(family):
    """The seed's physical interpolation: a camera pixel's footprint on the display is 0.3-1 display
    pixel (0.2745 mm), so the display's reference points are about as dense as the camera's pixels
    (a much smaller footprint resolves the display's pixel grid and the decoded phase becomes a
    staircase); and the display (527 x 296 mm) covers the field at both default stage positions."""
    lens = make_lens(family, width=1280, height=1024)
    u, v = np.meshgrid(np.arange(0, 1280, 8.0), np.arange(0, 1024, 8.0))
    o, d = lens.rays(u, v)
    for z in (0.0, 50.0):
        p = o + (z / d[..., 2])[..., None] * d
        step = 0.5 * (np.linalg.norm(np.diff(p, axis=1), axis=-1).mean()
                      + np.linalg.norm(np.diff(p, axis=0), axis=-1).mean()) / 8
        assert 0.3 <= step / 0.2745 <= 1.0
        assert (p[..., 0] > 0).all() and (p[..., 0] < 1919 * 0.2745).all()
        assert (p[..., 1] > 0).all() and (p[..., 1] < 1079 * 0.2745).all()


def test_noncentral_rays_do_not_meet_and_follow_snells_law_through_the_window():
    lens = make_lens("noncentral", seed=2)          # full 1280 x 1024 sensor, sampled sparsely
    u, v = np.meshgrid(np.arange(0, 1280, 64.0), np.arange(0, 1024, 64.0))
    o, d = lens.rays(u, v)
    _, rms = closest_point(o, d)
    assert rms > 0.1                                # mm (a pinhole: 1e-9): the window makes it non-central
    # Each ray leaves the window parallel to the chief ray through the centre, shifted sideways by
    # t sin(theta - theta') / cos(theta') (plane-parallel plate).
    chief = lens.chief_directions(u, v) @ lens.rotation.T
    assert np.abs(d - chief).max() < 1e-12
    w = lens.window
    theta = np.arccos(chief @ (lens.rotation @ w.normal))
    theta_t = np.arcsin(np.sin(theta) / w.index)
    expected = w.thickness_mm * np.sin(theta - theta_t) / np.cos(theta_t)
    rel = o - lens.centre_mm
    shift = np.linalg.norm(rel - np.sum(rel * d, axis=-1)[..., None] * d, axis=-1)
    assert np.abs(shift - expected).max() < 1e-9
    assert expected.max() - expected.min() > 0.3


def pixel_displacement(lens):
    """Distorted minus ideal pixel positions of the central lens (pixels), on the pixel grid."""
    u, v = lens.pixel_grid()
    d = lens.chief_directions(u, v)
    return (lens.fx * d[..., 0] / d[..., 2] + lens.cx - u, lens.fy * d[..., 1] / d[..., 2] + lens.cy - v)


def test_brown_lens_distorts_several_pixels_at_the_corners():
    lens = make_lens("brown")
    u = np.array([0.0, 1279.0, 0.0, 1279.0, 640.0])
    v = np.array([0.0, 0.0, 1023.0, 1023.0, 512.0])
    d = lens.chief_directions(u, v)
    du = lens.fx * d[:, 0] / d[:, 2] + lens.cx - u
    dv = lens.fy * d[:, 1] / d[:, 2] + lens.cy - v
    corner = np.hypot(du, dv)
    assert (2 < corner[:4]).all() and (corner[:4] < 20).all()
    assert corner[4] < 0.1


def fit_polynomial_model(lens):
    """RMS and max residual (pixels) of a least-squares fit of the OpenCV polynomial model (radial to
    r^12, tangential, thin prism) to the lens's distortion, with its own principal point."""
    u, v = lens.pixel_grid()
    d = lens.chief_directions(u, v)
    x, y = (d[..., 0] / d[..., 2]).ravel(), (d[..., 1] / d[..., 2]).ravel()
    xd, yd = ((u - lens.cx) / lens.fx).ravel(), ((v - lens.cy) / lens.fy).ravel()
    r2 = x * x + y * y
    zero = np.zeros_like(x)
    cols_x = [x * r2 ** k for k in range(1, 7)] + [2 * x * y, r2 + 2 * x * x, r2, r2 * r2, zero, zero]
    cols_y = [y * r2 ** k for k in range(1, 7)] + [r2 + 2 * y * y, 2 * x * y, zero, zero, r2, r2 * r2]
    a = np.vstack([np.column_stack(cols_x), np.column_stack(cols_y)])
    b = np.concatenate([xd - x, yd - y])
    coef, *_ = np.linalg.lstsq(a, b, rcond=None)
    res = (a @ coef - b) * lens.fx
    return np.sqrt(np.mean(res ** 2)), np.abs(res).max()


def test_freeform_lens_defeats_the_polynomial_model_that_fits_brown_exactly():
    assert fit_polynomial_model(make_lens("brown", width=320, height=256))[1] < 1e-6
    rms, worst = fit_polynomial_model(make_lens("freeform", width=320, height=256))
    assert rms > 0.2 and worst > 1.0


def test_freeform_distortion_is_smooth_at_ten_pixels():
    du, dv = pixel_displacement(make_lens("freeform", width=320, height=256))
    for f in (du, dv):
        second = f[:, 20:] - 2 * f[:, 10:-10] + f[:, :-20]
        assert np.abs(second).max() < 0.2          # px over a 10 px step: bumps are >= 20 px wide


def scheimpflug_blur(lens, z_mm=25.0):
    """Defocus blur diameters (pixels) over the sensor for the display plane z = z_mm."""
    u, v = np.meshgrid(np.linspace(0, lens.width - 1, 17), np.linspace(0, lens.height - 1, 13))
    o, d = lens.rays(u, v)
    return lens.blur_diameter_px(u, v, o + (z_mm / d[..., 2])[..., None] * d)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_scheimpflug_views_the_display_obliquely_with_its_plane_in_focus(seed):
    lens = make_lens("scheimpflug", width=1280, height=1024, seed=seed)
    view = np.degrees(np.arccos(lens.rotation[2, 2]))            # axis vs display normal
    assert 25 <= view <= 35
    # the sensor is tilted (about the axis perpendicular to the viewing plane) by the Scheimpflug rule
    # tan(tilt) = m tan(object tilt), m = v / F the magnification on the axis
    p = lens.sensor_points(np.array([0.0, 1279.0]), np.array([512.0, 512.0]))
    tilt = np.degrees(np.arctan2(p[1, 2] - p[0, 2], p[1, 0] - p[0, 0]))
    assert abs(tilt) == pytest.approx(abs(lens.sensor_tilt_deg), abs=1e-9)
    m = lens.focal_mm / (lens.focus_mm - lens.focal_mm)
    assert abs(np.tan(np.radians(tilt))) == pytest.approx(m * np.tan(np.radians(view)), rel=0.03)
    assert 1 < abs(tilt) < 4
    # the plane of sharp focus is the display plane at the middle of the stage travel: the blur circle
    # is far below a pixel over the whole field; without the tilt its edges would be blurred
    assert scheimpflug_blur(lens).max() < 0.1
    untilted = make_lens("scheimpflug", width=1280, height=1024, seed=seed, sensor_tilt_deg=0.0)
    assert scheimpflug_blur(untilted).max() > 2.0
    # at the default stage positions (+-25 mm) the blur is even across the field (a ~2 px disk, the
    # optics' interpolation of the display's pixels)
    for z in (0.0, 50.0):
        b = scheimpflug_blur(lens, z)
        assert 1.0 < b.min() and b.max() < 1.3 * b.min()


def test_distortion_inverse_round_trips():
    dist = Distortion(k=(-0.2, 0.1, 0.01), p=(1e-3, -2e-3), bumps=np.array([[0.05, 0.0, 0.02, 1e-3, -5e-4]]))
    x, y = np.meshgrid(np.linspace(-0.3, 0.3, 31), np.linspace(-0.25, 0.25, 27))
    xd, yd = dist.apply(x, y)
    assert np.abs(xd - x).max() > 1e-3
    xi, yi = dist.invert(xd, yd)
    assert max(np.abs(xi - x).max(), np.abs(yi - y).max()) < 1e-14


def test_true_prvm_is_the_ray_of_each_pixel_centre():
    lens = make_lens("noncentral", width=40, height=30)
    prvm = lens.true_prvm(camera="cam0")
    o, d = lens.rays(np.array([17.0]), np.array([11.0]))
    assert np.allclose(prvm.origin[11, 17], o[0]) and np.allclose(prvm.direction[11, 17], d[0])
    assert prvm.valid.all() and prvm.reference_z_mm == 0.0


def test_bad_lens_arguments_are_input_errors():
    with pytest.raises(InputError, match="unknown lens family"):
        make_lens("fisheye")
    with pytest.raises(InputError, match="no parameter"):
        make_lens("brown", magnification=0.5)
    with pytest.raises(InputError, match="positive"):
        make_lens("brown", focal_mm=-3)

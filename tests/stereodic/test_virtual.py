"""Fitting the ray models (optical centre, telecentric direction, non-centrality) and the virtual sensor."""

import numpy as np
import pytest

from calib.errors import InputError
from scanners.sim.lenses import make_lens
from stereodic.virtual.imm import build_imm
from stereodic.virtual.camera import (VirtualSensor, default_camera, fit_optical_centre, fit_telecentric_direction,
                               largest_field, miss_in_pixels)
from virtual_cases import CENTRE, opencv_camera

SMALL = dict(width=160, height=120, pixel_mm=0.0053 * 8)  # the full lens field on a small sensor


def test_optical_centre_is_robust_to_bad_pixels():
    prvm = opencv_camera()[-1]
    rng = np.random.default_rng(3)
    bad = rng.random(prvm.valid.shape) < 0.03
    d = prvm.direction.copy()
    d[bad] += rng.normal(0, 0.05, (bad.sum(), 3))
    d[bad] /= np.linalg.norm(d[bad], axis=-1, keepdims=True)
    prvm.direction = d
    robust, miss = fit_optical_centre(prvm)
    plain, _ = fit_optical_centre(prvm, iterations=1)  # unweighted least squares
    assert np.linalg.norm(robust - CENTRE) < 0.02
    assert np.linalg.norm(plain - CENTRE) > 10 * np.linalg.norm(robust - CENTRE)
    assert np.nanmedian(miss[~bad]) < 1e-3 and np.nanmedian(miss[bad]) > 1.0


def test_central_lens_has_no_miss_and_the_window_lens_has_some():
    brown = make_lens("brown", seed=2, **SMALL)
    centre, miss = fit_optical_centre(brown.true_prvm())
    assert np.linalg.norm(centre - brown.centre_mm) < 1e-6 and np.nanmax(miss) < 1e-6
    window = make_lens("noncentral", seed=2, **SMALL)
    prvm = window.true_prvm()
    centre, miss = fit_optical_centre(prvm)
    px = miss_in_pixels(prvm, centre, miss, 0.0)
    assert np.nanmax(miss) > 0.05  # a 10 mm glass plate tilted 25 degrees is not central
    assert np.nanmax(px) > 0.05 and np.all(np.isfinite(px))


def test_telecentric_direction_is_the_optical_axis():
    lens = make_lens("telecentric", seed=2, **SMALL)
    direction, deviation = fit_telecentric_direction(lens.true_prvm())
    assert np.allclose(direction, lens.rotation[:, 2], atol=1e-12)
    assert np.nanmax(deviation) < 1e-9


def test_sensor_points_and_intersections_agree():
    a = np.array([1.0, 0.1, 0.0]) / np.linalg.norm([1.0, 0.1, 0.0])
    b = np.cross([0.1, -0.2, 1.0], a)
    s = VirtualSensor([1.0, 2, 3], a, b / np.linalg.norm(b), (0.05, 0.06), 40, 30)
    u, v = np.array([0.0, 12.3, 39.0]), np.array([0.0, 7.7, 29.0])
    p = s.points(u, v)
    d = np.array([0.1, -0.2, 1.0]) / np.linalg.norm([0.1, -0.2, 1.0])
    uv = s.intersect(p - 100 * d, np.broadcast_to(d, p.shape))
    assert np.allclose(uv, np.stack([u, v], -1), atol=1e-9)


@pytest.mark.parametrize("model", ["pinhole", "telecentric"])
def test_default_camera_is_the_largest_without_blank_pixels(model):
    lens = make_lens("brown" if model == "pinhole" else "telecentric", seed=4, **SMALL)
    prvm = lens.true_prvm()
    cam = default_camera(prvm, model=model)
    s = cam.sensor
    assert (s.width, s.height) == (prvm.width, prvm.height)
    assert build_imm(prvm, s).valid.all()
    bigger = s.with_field(((s.centre - s.origin) @ s.axis_u, (s.centre - s.origin) @ s.axis_v),
                          np.array(s.pitch_mm) * 1.01, s.width, s.height)
    assert not build_imm(prvm, bigger).valid.all()
    if model == "telecentric":
        assert np.allclose(s.normal, lens.rotation[:, 2], atol=1e-9)


def test_too_large_a_pitch_is_refused():
    prvm = make_lens("brown", seed=4, **SMALL).true_prvm()
    cam = default_camera(prvm)
    with pytest.raises(InputError, match="larger than the real field"):
        largest_field(prvm, cam.sensor, 160, 120, pitch_mm=cam.sensor.pitch_mm[0] * 1.05)
    ok = largest_field(prvm, cam.sensor, 160, 120, pitch_mm=cam.sensor.pitch_mm[0] * 0.9)
    assert build_imm(prvm, ok).valid.all()

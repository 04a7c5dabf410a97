"""The IMM: round-trip closure against the true rays, straight lines through every lens family, the
seed's 4-pixel form, and the two map kinds."""

import numpy as np
import pytest

from calib.errors import InputError
from scanners.sim.lenses import make_lens
from stereodic.bench.lines import line_centres, render_lines, straightness_rms
from stereodic.virtual.imm import apply_imm, build_imm
from stereodic.virtual.sampling import bilinear
from stereodic.virtual.camera import default_camera
from virtual_cases import smooth_texture

W, H = 240, 180
LENS = dict(width=W, height=H, pixel_mm=0.0053 * 1280 / W)  # the full lens field on a small sensor


def _setup(family, seed=1):
    lens = make_lens(family, seed=seed, **LENS)
    prvm = lens.true_prvm()
    cam = default_camera(prvm, model="telecentric" if family == "telecentric" else "pinhole")
    return lens, prvm, cam, build_imm(prvm, cam.sensor)


@pytest.mark.parametrize("family", ["brown", "freeform", "scheimpflug", "telecentric"])
def test_round_trip_closes(family):
    """virtual pixel -> IMM real pixel -> TRUE ray of the lens there -> virtual plane -> virtual pixel."""
    lens, prvm, cam, imm = _setup(family)
    assert imm.valid.all()
    o, d = lens.rays(imm.map_x.astype(np.float64), imm.map_y.astype(np.float64))
    uv = cam.sensor.intersect(o, d)
    v, u = np.mgrid[0:H, 0:W]
    err = np.hypot(uv[..., 0] - u, uv[..., 1] - v)
    assert np.sqrt(np.mean(err ** 2)) <= 0.005


@pytest.mark.parametrize("family", ["brown", "freeform", "scheimpflug", "telecentric"])
def test_lines_come_out_straight(family):
    """A line grid on the plane z = 60 mm (not the virtual plane), rendered through the true rays."""
    lens, prvm, cam, imm = _setup(family)
    pitch = cam.sensor.pitch_mm[0]
    for axis in "xy":
        img = render_lines(lens.rays, W, H, 60.0, spacing_mm=pitch * W / 6, sigma_mm=2 * pitch, axis=axis)
        lines = line_centres(apply_imm(img, imm), imm.valid, axis, sigma_px=2.0)
        assert len(lines) >= 4
        assert straightness_rms(lines) <= 0.02
        # the same lines in the real image are bent more than twice the bound (the test can fail)
        if family in ("brown", "freeform"):
            assert straightness_rms(line_centres(img, prvm.valid, axis, sigma_px=2.0)) > 0.04


def test_taps_are_what_remap_computes():
    *_, imm = _setup("brown")
    img = smooth_texture(h=H, w=W).astype(np.float32)
    index, weights = imm.taps()
    assert index.shape == (H, W, 4) and np.allclose(weights.sum(-1), 1)
    by_taps = (img.ravel()[index] * weights).sum(-1)
    assert np.abs(by_taps - apply_imm(img, imm)).max() < 1e-3


def test_float_maps_are_exact_and_fixed_point_rounds_to_a_32nd():
    *_, imm = _setup("brown")
    img = smooth_texture(h=H, w=W, blur=1.5).astype(np.float32)
    exact = bilinear(img, imm.map_x, imm.map_y)
    err_float = np.abs(apply_imm(img, imm) - exact)
    err_fixed = np.abs(apply_imm(img, imm, fixed_point=True) - exact)
    assert err_float.max() < 1e-3
    assert err_fixed.max() > 10 * err_float.max()
    # positions off by <= 1/64 pixel per axis: the error stays within the cell's value range / 32
    index, _ = imm.taps()
    taps = img.ravel()[index]
    assert (err_fixed <= (taps.max(-1) - taps.min(-1)) / 32 + 1e-3).all()


def test_image_of_another_size_is_refused():
    *_, imm = _setup("brown")
    with pytest.raises(InputError, match="camera is 240x180"):
        apply_imm(np.zeros((H, W + 1), np.uint8), imm)

"""Parts of the 2D DIC engine: the B-spline interpolant, the speckle renderer it is tested with, and the
integer searches (square window for seeds, rows for rectified stereo)."""

import numpy as np
import pytest
from scipy import ndimage

from scanners.sim.speckle import make_speckle, render
from stereodic.dic import BSplineImage, row_search, search_integer
from stereodic.dic.interpolation import gaussian_lowpass


@pytest.mark.parametrize("order", [3, 5])
def test_bspline_matches_scipy_and_its_own_derivative(order):
    rng = np.random.default_rng(1)
    img = ndimage.gaussian_filter(rng.random((40, 50)) * 255, 1.2)
    b = BSplineImage.from_image(img, order=order)
    x, y = rng.uniform(0, 49, 500), rng.uniform(0, 39, 500)
    expected = ndimage.map_coordinates(img, [y, x], order=order, mode="mirror")
    assert np.abs(b.sample(x, y) - expected).max() < 1e-3  # float32 coefficients
    gx, gy = b.gradient(x, y)
    e = 1e-2
    assert np.abs(gx - (b.sample(x + e, y) - b.sample(x - e, y)) / (2 * e)).max() < 1e-2
    assert np.abs(gy - (b.sample(x, y + e) - b.sample(x, y - e)) / (2 * e)).max() < 1e-2
    pix = b.pixel_gradients()
    assert np.abs(pix[0] - img).max() < 1e-3  # the interpolant passes through the pixels
    assert np.isnan(b.sample(np.array([-1.0]), np.array([5.0]))).all()


def test_prefilter_is_scipys_gaussian():
    img = np.random.default_rng(2).random((30, 41)) * 255
    for sigma in (0.5, 0.7, 1.3):
        expected = ndimage.gaussian_filter(img, sigma, mode="mirror", truncate=3.0)
        assert np.abs(gaussian_lowpass(img, sigma) - expected).max() < 1e-9
    b = BSplineImage.from_image(img, order=3, prefilter_sigma=0.7)
    assert np.abs(b.pixel_gradients()[0] - ndimage.gaussian_filter(img, 0.7, mode="mirror", truncate=3.0)).max() < 1e-3


def test_speckle_translation_is_exact():
    sp = make_speckle(64, 64, seed=1)
    ref = render(sp, bits=None)
    moved = render(sp, (3.0, -2.0), bits=None)
    # an integer translation moves pixel values exactly: the renderer integrates analytically
    assert np.abs(moved[10:50, 13:53] - ref[12:52, 10:50]).max() < 1e-9
    # the general path (deformed dots, supersampled) agrees with the analytic one
    general = render(sp, lambda x, y: (0 * x + 0.3, 0 * y - 0.2), bits=None, supersample=8)
    assert np.abs(general - render(sp, (0.3, -0.2), bits=None)).max() < 0.5
    assert ref.std() > 40  # a contrasted pattern


def test_search_integer_and_row_search():
    sp = make_speckle(128, 96, seed=2)
    ref = render(sp)
    dfm = render(sp, (7.0, -4.0))
    assert search_integer(ref, dfm, 60, 50, 10, 12)[:2] == (7, -4)
    assert search_integer(ref, dfm, 60, 50, 10, 5, centre=(5, -5))[:2] == (7, -4)
    d, z = row_search(ref, render(sp, (-9.0, 0.0)), np.array([40, 70, 100]), np.array([30, 50, 60]), half=10,
                      dmin=-20, dmax=0)
    assert d.tolist() == [-9, -9, -9] and (z > 0.95).all()
    flat = np.full_like(ref, 100)
    assert search_integer(flat, dfm, 60, 50, 10, 12)[2] == -1.0


@pytest.mark.parametrize("order", [3, 5])
@pytest.mark.parametrize("shape", [(40, 50), (7, 300), (300, 6)])
def test_bspline_coefficients_are_scipys(order, shape):
    # the compiled prefilter (stereodic/dic/src/bspline.c) against scipy's, mirrored borders, float32 out
    img = np.random.default_rng(3).random(shape) * 255
    coef = BSplineImage.from_image(img, order=order).coef
    expected = np.pad(ndimage.spline_filter(img, order=order, mode="mirror", output=np.float32), 4, mode="reflect")
    assert np.abs(coef - expected).max() <= 1e-6 * np.abs(expected).max()  # equal but for a few float32 ulps

import numpy as np

from calib.intensity import IntensityMatrix, fit_intensity, smooth_response


def test_intensity_matrix_linearises_each_pixel():
    rng = np.random.default_rng(0)
    h, w = 40, 50
    gain = rng.uniform(100, 200, (h, w))
    offset = rng.uniform(2, 6, (h, w))
    levels = [0, 32, 64, 96, 128, 160, 192, 224, 255]
    lum = lambda L: 0.001 + (np.asarray(L) / 255) ** 2.2   # noqa: E731
    images = [offset + gain * lum(L) for L in levels]
    im = fit_intensity(levels, images, full_scale=1e6, min_range=5)
    y = im.luminance(offset + gain * lum(150))
    # one common scale for all pixels: the normalised luminance of code 150
    want = (lum(150) - lum(0)) / (lum(255) - lum(0))
    np.testing.assert_allclose(y, want, rtol=2e-3)
    codes = np.linspace(20, 240, 50)
    np.testing.assert_allclose(im.response.inverse(im.response(codes)), codes, atol=0.05)
    back = IntensityMatrix.from_arrays(im.to_arrays())        # as stored in the PRVM file
    np.testing.assert_array_equal(back.gain, im.gain)
    np.testing.assert_allclose(back.response(codes), im.response(codes))


def test_smooth_response_follows_a_gamma_from_few_levels():
    levels = np.array([0, 64, 128, 192, 255.0])
    r = smooth_response(levels, (levels / 255) ** 2.2)
    codes = np.linspace(20, 240, 200)
    np.testing.assert_allclose(r.inverse((codes / 255) ** 2.2), codes, atol=0.01)

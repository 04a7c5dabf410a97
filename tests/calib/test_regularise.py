import numpy as np
import pytest

from scipy import ndimage

from calib.regularise import Adaptive, Smoother, _base, deepest_half, finest_scale, smooth_fields

H, W = 256, 320
SIGMA = 0.3                     # white noise of the raw field
BUMPS = [(90.0, 80.0, 12.0, 2.0), (230.0, 170.0, 18.0, -1.5)]      # u, v, sigma (px), amplitude


def _truth() -> tuple[np.ndarray, np.ndarray]:
    """A smooth field (cubic plus a long wave) with two local Gaussian bumps; and the mask of the pixels
    farther than 4 sigma from every bump (the smooth region)."""
    v, u = np.mgrid[0:H, 0:W].astype(float)
    un, vn = u / W - 0.5, v / H - 0.5
    field = 40 * un + 25 * vn + 30 * un ** 2 * vn - 20 * vn ** 3 + 3 * np.sin(un * 5.0 + 1.0) * np.cos(vn * 4.0)
    smooth = np.ones((H, W), bool)
    for bu, bv, s, a in BUMPS:
        r2 = (u - bu) ** 2 + (v - bv) ** 2
        field += a * np.exp(-r2 / (2 * s * s))
        smooth &= r2 > (4 * s) ** 2
    return field, smooth


def _interior(margin: int) -> np.ndarray:
    m = np.zeros((H, W), bool)
    m[margin:-margin, margin:-margin] = True
    return m


def test_local_fit_reproduces_cubics_everywhere():
    v, u = np.mgrid[0:H, 0:W].astype(float)
    cubic = 1e-6 * (u ** 3 - 2 * v ** 3) + 1e-4 * u * v - 0.01 * u + 3.0
    for smoother in (Smoother(10), Smoother(15, 3, 2), Adaptive(half_window=10)):
        out = smooth_fields(cubic[None], np.ones((H, W), bool), smoother).fields[0]
        np.testing.assert_allclose(out, cubic, atol=1e-9)


def test_fixed_window_noise_factor_matches_monte_carlo():
    rng = np.random.default_rng(1)
    sm = Smoother(8)
    runs = np.stack([smooth_fields(rng.normal(0, SIGMA, (1, 120, 140)), np.ones((120, 140), bool), sm).fields[0]
                     for _ in range(40)])
    reg = smooth_fields(rng.normal(0, SIGMA, (1, 120, 140)), np.ones((120, 140), bool), sm)
    # the predicted noise after smoothing (noise estimate x gain) against the spread over runs,
    # in the interior and at the border (one-sided windows)
    predicted = reg.noise[0] * reg.gain[0]
    measured = runs.std(axis=0)
    for sel in (np.s_[30:90, 30:110], np.s_[0:4, :], np.s_[:, -4:]):
        assert np.median(predicted[sel]) == pytest.approx(np.median(measured[sel]), rel=0.15)
    assert np.median(reg.noise[0]) == pytest.approx(SIGMA, rel=0.05)


@pytest.fixture(scope="module")
def adaptive_runs():
    """Eight noisy realisations of the field, each regularised with the adaptive and the smallest fixed
    window."""
    field, smooth = _truth()
    rng = np.random.default_rng(0)
    valid = np.ones((H, W), bool)
    ada, fix, last = [], [], None
    for _ in range(8):
        raw = field + rng.normal(0, SIGMA, (H, W))
        last = smooth_fields(raw[None], valid, Adaptive(half_window=10))
        ada.append(last.fields[0])
        fix.append(smooth_fields(raw[None], valid, Smoother(10)).fields[0])
    return field, smooth, np.stack(ada), np.stack(fix), last


def test_adaptive_lowers_noise_by_the_predicted_factor_where_smooth(adaptive_runs):
    field, smooth, ada, fix, last = adaptive_runs
    sel = smooth & _interior(40)
    err_ada = np.sqrt(np.mean((ada - field)[:, sel] ** 2))
    err_fix = np.sqrt(np.mean((fix - field)[:, sel] ** 2))
    predicted = np.sqrt(np.mean((SIGMA * last.gain[0][sel]) ** 2))
    assert err_ada == pytest.approx(predicted, rel=0.25)
    # there windows between 41 and 81 px are chosen (a 161-px window bends the long wave): 2.5x less
    # error than 21 px
    assert np.median(last.window[sel]) > 60
    assert err_ada < err_fix / 2.5


def test_adaptive_does_not_bias_local_bumps(adaptive_runs):
    """Near a bump the bias the larger windows could bring stays below the noise of the smallest window
    (the one that follows the bump), so the error there is no worse than with that window alone."""
    field, smooth, ada, fix, last = adaptive_runs
    v, u = np.mgrid[0:H, 0:W]
    for bu, bv, s, a in BUMPS:
        near = (u - bu) ** 2 + (v - bv) ** 2 < (2 * s) ** 2
        noise_ada = np.mean((ada - ada.mean(axis=0))[:, near] ** 2)
        # the mean of the runs still holds 1/n of their noise variance
        bias = np.sqrt(np.mean((ada.mean(axis=0) - field)[near] ** 2) - noise_ada / (len(ada) - 1))
        noise_small = np.sqrt(np.mean((fix - fix.mean(axis=0))[:, near] ** 2))
        assert bias < noise_small
        err_ada = np.sqrt(np.mean((ada - field)[:, near] ** 2))
        err_fix = np.sqrt(np.mean((fix - field)[:, near] ** 2))
        assert err_ada < 1.15 * err_fix
        assert np.median(last.window[near]) <= 41                          # small windows chosen there


def test_adaptive_uncertainty_covers_the_error(adaptive_runs):
    """The reported error of the adaptive fit (the noise after smoothing) against its RMS error over the
    eight realisations and the whole field: it covers 96 % of it, the bias the windows of least risk let
    through being a small part (below). (Lepski's choice alone, before 2026-12-07: 73 %.)"""
    field, smooth, ada, fix, last = adaptive_runs
    err = np.sqrt(np.mean((ada - field) ** 2))
    noise = np.sqrt(np.mean((last.noise[0] * last.gain[0]) ** 2))
    assert noise == pytest.approx(err, rel=0.1)


def test_adaptive_keeps_the_bias_below_half_the_error(adaptive_runs):
    """The window of least risk counts the squared bias twice (`Adaptive.bias_weight`), so the error
    common to all eight realisations (the bias) is well below half the RMS error (Lepski's method alone
    at 3 sigma, the choice before 2026-12-07: 68 %, above the noise)."""
    field, smooth, ada, fix, last = adaptive_runs
    err = ada - field
    common = err.mean(axis=0)
    spread = np.mean((err - common) ** 2)
    bias = np.sqrt(np.mean(common ** 2) - spread / (len(ada) - 1))   # the mean keeps 1/n of the noise
    assert bias < 0.5 * np.sqrt(np.mean(err ** 2))


def test_a_field_the_windows_follow_exactly_errs_by_its_noise():
    """A cubic with white noise: every window follows it, the largest are chosen, and the error is the
    noise after smoothing, to 15 %."""
    v, u = np.mgrid[0:H, 0:W].astype(float)
    cubic = 1e-6 * (u ** 3 - 2 * v ** 3) + 1e-4 * u * v - 0.01 * u + 3.0
    reg = smooth_fields((cubic + np.random.default_rng(2).normal(0, SIGMA, (H, W)))[None], np.ones((H, W), bool),
                        Adaptive(half_window=10))
    noise = np.sqrt(np.mean((reg.noise[0] * reg.gain[0]) ** 2))
    assert np.sqrt(np.mean((reg.fields[0] - cubic) ** 2)) == pytest.approx(noise, rel=0.15)


def _lstsq_polynomial(field: np.ndarray, valid: np.ndarray, degree: int) -> np.ndarray:
    """The least-squares polynomial of total degree `degree` over the valid pixels (numpy's lstsq on a
    monomial design matrix): the independent reference for `_base`."""
    v, u = np.mgrid[0:H, 0:W].astype(float)
    un, vn = 2 * u / (W - 1) - 1, 2 * v / (H - 1) - 1
    design = np.stack([un ** i * vn ** j for i in range(degree + 1) for j in range(degree + 1 - i)], axis=-1)
    coef, *_ = np.linalg.lstsq(design[valid], field[valid], rcond=None)
    return design @ coef


def _radial_field() -> np.ndarray:
    """x of a Brown-Conrady lens in pixels: degree 5 in (u, v), centre off the image's."""
    v, u = np.mgrid[0:H, 0:W].astype(float)
    x, y = (u - 150) / 200, (v - 130) / 200
    r2 = x * x + y * y
    return 200 * x * (1 - 0.3 * r2 + 0.25 * r2 * r2)


def test_base_degree_rises_only_where_the_polynomial_models_the_field():
    rng = np.random.default_rng(4)
    valid = np.ones((H, W), bool)
    valid[40:90, 200:260] = False
    v, u = np.mgrid[0:H, 0:W].astype(float)
    cubic = 1e-6 * (u ** 3 - 2 * v ** 3) + 1e-4 * u * v - 0.01 * u + 3.0
    # local bumps on the radial field: no global polynomial models it, the local fits must (degree 3)
    bumpy = _radial_field().copy()
    for bu, bv in rng.uniform((0, 0), (W, H), (20, 2)):
        bumpy += 2.0 * np.exp(-((u - bu) ** 2 + (v - bv) ** 2) / (2 * 10.0 ** 2))
    for field, degree in ((cubic, 3), (_radial_field(), 5), (bumpy, 3)):
        raw = field + rng.normal(0, SIGMA, (H, W))
        np.testing.assert_allclose(_base(raw, valid), _lstsq_polynomial(raw, valid, degree), atol=1e-8)


def test_adaptive_follows_radial_distortion_to_the_border():
    """A Brown-Conrady field is degree 5: after the global polynomial the large windows are unbiased up
    to the border, where the one-sided line fits keep the noise low."""
    field = _radial_field()
    rng = np.random.default_rng(5)
    border = np.ones((H, W), bool)
    border[16:-16, 16:-16] = False
    err = np.stack([smooth_fields((field + rng.normal(0, SIGMA, (H, W)))[None], np.ones((H, W), bool),
                                  Adaptive(half_window=10)).fields[0] - field for _ in range(4)])
    assert np.sqrt(np.mean(err[:, _interior(60)] ** 2)) < SIGMA / 50
    assert np.sqrt(np.mean(err[:, border] ** 2)) < SIGMA / 25


def test_adaptive_handles_masked_pixels():
    field, _ = _truth()
    rng = np.random.default_rng(3)
    valid = np.ones((H, W), bool)
    valid[100:140, 150:200] = False                      # a hole
    valid[:, :12] = False                                # a strip the display did not cover
    raw = np.where(valid, field + rng.normal(0, SIGMA, (H, W)), np.nan)
    reg = smooth_fields(np.stack([raw, 2 * raw]), valid, Adaptive(half_window=10))
    assert np.isnan(reg.fields[:, ~valid]).all() and np.isfinite(reg.fields[:, valid]).all()
    err = np.abs(reg.fields[0] - field)[valid]
    assert np.sqrt(np.mean(err ** 2)) < 0.5 * SIGMA * 0.3 and err.max() < 5 * SIGMA * 0.3
    np.testing.assert_allclose(reg.noise[1][valid], 2 * reg.noise[0][valid], rtol=1e-4)


def test_too_small_image_is_refused():
    with pytest.raises(ValueError, match="too small"):
        smooth_fields(np.zeros((1, 30, 30)), np.ones((30, 30), bool), Adaptive(half_window=20))


def test_windows_stop_at_the_border_of_the_data():
    """A band the display did not cover (its boundary a slanted line): the windows end there, one-sided
    as at the image border, so the pixels next to it are as accurate as those next to the image's own
    border, and a cubic is still reproduced exactly."""
    field = _radial_field()
    v, u = np.mgrid[0:H, 0:W].astype(float)
    valid = v < 190 + 0.2 * (u - W / 2)
    rng = np.random.default_rng(6)
    errs = []
    for _ in range(4):
        raw = np.where(valid, field + rng.normal(0, SIGMA, (H, W)), np.nan)
        errs.append(smooth_fields(raw[None], valid, Adaptive(half_window=10)).fields[0] - field)
    err = np.stack(errs)
    dist = ndimage.distance_transform_edt(valid)
    near_band = valid & (dist <= 16) & (u > 20) & (u < W - 20)
    near_border = valid & (v < 16) & (u > 20) & (u < W - 20)
    rms = lambda sel: np.sqrt(np.mean(err[:, sel] ** 2))  # noqa: E731
    assert rms(near_band) < 1.5 * rms(near_border) and rms(near_band) < SIGMA / 15
    cubic = 1e-6 * (u ** 3 - 2 * v ** 3) + 1e-4 * u * v - 0.01 * u + 3.0
    out = smooth_fields(np.where(valid, cubic, np.nan)[None], valid, Adaptive(half_window=10)).fields[0]
    np.testing.assert_allclose(out[valid], cubic[valid], atol=1e-8)


def _planes(rng, common=None, own=None):
    """The decoded points of two stage planes (display px, (2, H, W) each): one Brown-Conrady field seen
    on both (the second 1.1x larger, as from farther away), white noise, plus `common(u, v)` (lens
    structure: the same ray displacement on both planes) or `own(u, v, plane)` (the display's own
    systematic error: different on each plane)."""
    v, u = np.mgrid[0:H, 0:W].astype(float)
    out = []
    for k, scale in enumerate((1.0, 1.1)):
        f = np.stack([_radial_field(), 0.8 * _radial_field()]) * scale
        if common is not None:
            f = f + scale * common(u, v)
        if own is not None:
            f = f + own(u, v, k)
        out.append(f + rng.normal(0, SIGMA, (2, H, W)))
    return out


def test_the_smallest_window_follows_lens_structure_common_to_both_planes_not_the_displays_own():
    """`finest_scale` goes below the deepest default window only for structure the two stage planes
    share (the lens's): a 15 px ripple of the rays takes it to the smallest windows; the same ripple
    differing between the planes (what the display's pixel grid does) leaves it where a smooth lens is."""
    rng = np.random.default_rng(7)
    valid = np.ones((H, W), bool)
    ripple = lambda u, v: 0.6 * np.sin(2 * np.pi * np.hypot(u - 150, v - 120) / 15.0)  # noqa: E731
    smooth = finest_scale(*_planes(rng), valid)
    assert smooth == deepest_half(H, W)
    assert finest_scale(*_planes(rng, common=ripple), valid) <= 5
    own = lambda u, v, k: ripple(u + 7.5 * k, v)  # noqa: E731 - other phase on the other plane
    assert finest_scale(*_planes(rng, own=own), valid) == smooth


def _finer_rung_errors(field: np.ndarray, near: np.ndarray, seed: int) -> tuple[float, float]:
    """The RMS error over `near` of the adaptive fit (finest scale 41 px) without and with the finer rung
    (21 px), over six noise realisations."""
    rng = np.random.default_rng(seed)
    fits = {0: [], 1: []}
    for _ in range(6):
        raw = (field + rng.normal(0, SIGMA, (H, W)))[None]
        for rungs in fits:
            fits[rungs].append(smooth_fields(raw, np.ones((H, W), bool),
                                             Adaptive(half_window=20, finer_rungs=rungs)).fields[0])
    return tuple(float(np.sqrt(np.mean((np.stack(fits[k]) - field)[:, near] ** 2))) for k in (0, 1))


def test_a_bump_at_the_border_is_followed_by_the_finer_window():
    """A lens bump (16 px) on the image's left border: there the finest scale's window (41 px) is
    one-sided and 82 px long, and bends the bump away; the ladder's finer rung, half its size
    (`Adaptive.finer_rungs`), follows it, 3x closer to the truth."""
    field, _ = _truth()
    v, u = np.mgrid[0:H, 0:W].astype(float)
    field = field + 2.0 * np.exp(-((u - 3) ** 2 + (v - 130) ** 2) / (2 * 16.0 ** 2))
    without, with_ = _finer_rung_errors(field, (u < 25) & (np.abs(v - 130) < 25), seed=3)
    assert with_ < without / 3


def test_a_bump_narrower_than_the_finest_scale_is_followed_inside_the_image():
    """A bump of 8 px inside the image, narrower than the finest scale the ladder was given (41 px):
    over the region where Lepski's test rejects the finest scale's window against the finer one, the
    finer rung may be chosen there too, 0.05 against 0.21 without it (Lepski's choice before 2026-12-07,
    the finer rung at the border only: 0.21; at the rejecting pixels only, until 2026-12-08: 0.15)."""
    field, _ = _truth()
    v, u = np.mgrid[0:H, 0:W].astype(float)
    field = field + 2.0 * np.exp(-((u - 160) ** 2 + (v - 60) ** 2) / (2 * 8.0 ** 2))
    without, with_ = _finer_rung_errors(field, (u - 160) ** 2 + (v - 60) ** 2 < 16 ** 2, seed=3)
    assert with_ < 0.8 * without


def _gate_errors(field: np.ndarray, masks: list[np.ndarray], monkeypatch, pixelwise: bool) -> list[float]:
    """RMS errors over `masks` of the adaptive fit (finest scale 41 px, the finer rung 21 px) over six
    noise realisations; `pixelwise`: the finer rung gated by the rejecting pixels themselves, not their
    region (`_rejected_region`)."""
    import calib.regularise as reg
    if pixelwise:
        monkeypatch.setattr(reg, "_rejected_region", lambda rejected, half: rejected)
    rng = np.random.default_rng(3)
    err = np.stack([smooth_fields((field + rng.normal(0, SIGMA, (H, W)))[None], np.ones((H, W), bool),
                                  Adaptive(half_window=20, finer_rungs=1)).fields[0] - field for _ in range(6)])
    monkeypatch.undo()
    return [float(np.sqrt(np.mean(err[:, m] ** 2))) for m in masks]


def test_the_finer_rung_serves_the_region_of_a_bump_and_not_the_noises_isolated_rejections(monkeypatch):
    """The finer rung inside the image is opened over the regions where Lepski's test rejects the finest
    scale's window (`_rejected_region`: their opening drops the noise's isolated rejections, a margin of
    the window's half size takes in the bump's flanks), not at the rejecting pixels alone: on an 8-px bump
    the error within two widths of its centre falls 3x (0.15 -> 0.05), and over the whole of a smooth
    field without a bump it does not grow (0.0205 -> 0.0180: fewer of the noise's false alarms choose the
    noisier window)."""
    field, _ = _truth()
    v, u = np.mgrid[0:H, 0:W].astype(float)
    bump = field + 2.0 * np.exp(-((u - 160) ** 2 + (v - 60) ** 2) / (2 * 8.0 ** 2))
    near = (u - 160) ** 2 + (v - 60) ** 2 < 16 ** 2
    everywhere = np.ones((H, W), bool)
    (region_near,) = _gate_errors(bump, [near], monkeypatch, pixelwise=False)
    (pixel_near,) = _gate_errors(bump, [near], monkeypatch, pixelwise=True)
    assert region_near < pixel_near / 2.5
    (region_smooth,) = _gate_errors(field, [everywhere], monkeypatch, pixelwise=False)
    (pixel_smooth,) = _gate_errors(field, [everywhere], monkeypatch, pixelwise=True)
    assert region_smooth <= pixel_smooth

"""Gray code: the patterns against OpenCV's GrayCodePattern, the per-pixel decoding against a known
camera-to-projector mapping (blur and noise), the Gray-ordered phase against the true column."""

import cv2
import numpy as np
import pytest

from calib.graycode import GRAY_TOLERANCE, decode_gray, gray, gray_to_binary, unwrap_with_gray
from calib.patterns import gray_sequence
from calib.phase import DARK, UNDECIDED


def test_sequence_is_opencvs_graycodepattern():
    ok, reference = cv2.structured_light.GrayCodePattern.create(1280, 800).generate()
    ours = gray_sequence(1280, 800, axes=("x", "y"))
    assert ok and len(ours) == len(reference) + 2                       # + white and black
    for (pattern, image), ref in zip(ours, reference):
        assert pattern.type == "gray" and np.array_equal(image, ref), pattern
    assert [p.params["level"] for p, _ in ours[-2:]] == [255, 0]


def test_gray_to_binary_inverts_gray():
    n = np.arange(1 << 16)
    assert np.array_equal(gray_to_binary(gray(n)), n)
    assert np.all(np.bitwise_count(gray(n[1:]) ^ gray(n[:-1])) == 1)     # neighbours differ in one bit


def _camera(width_px: int, cols: np.ndarray, low_bit: int, blur_px: float, noise: float, rng):
    """Frames of a camera row set that sees panel column cols[x] at pixel x (oversampled 8x, blurred,
    8-bit noisy): patterns, inverses, white, black (rows identical but for the noise)."""
    seq = gray_sequence(width_px, 1, period_px=None if low_bit == 0 else 2 ** (low_bit + 1))
    fine = np.linspace(cols[0], cols[-1], 8 * len(cols))

    def render(line):
        v = np.interp(fine, np.arange(width_px), line.astype(float))
        v = cv2.GaussianBlur(v[None, :], (0, 0), 8 * blur_px)[0].reshape(len(cols), 8).mean(axis=1)
        v = 30 + 0.8 * v + rng.normal(0, noise, (40, len(cols)))
        return np.clip(np.rint(v), 0, 255).astype(np.uint8)

    frames = {p.key(): render(img[0]) for p, img in seq if p.type != "fringe"}
    bits = sorted({p.params["bit"] for p, _ in seq if p.type == "gray"})
    pick = lambda inv: [frames[p.key()] for b in bits for p, _ in seq  # noqa: E731
                        if p.type == "gray" and p.params["bit"] == b and p.params["inverse"] == inv]
    flats = [frames[p.key()] for p, _ in seq if p.type == "flat"]
    return pick(False), pick(True), flats[0], flats[1]


@pytest.mark.parametrize("low_bit", [0, 2])
def test_decoding_finds_the_true_column(low_bit):
    rng = np.random.default_rng(3)
    cols = np.linspace(-0.4, 1279.4, 2400)               # ~1.9 camera pixels per column, as the statue's
    pats, invs, white, black = _camera(1280, cols, low_bit, blur_px=0.7, noise=2.0, rng=rng)
    dec = decode_gray(pats, invs, white, black, low_bit=low_bit, extent_px=1280, min_contrast=20,
                      min_difference=3)
    w = 2 ** low_bit
    ok = np.isfinite(dec.coord)
    assert ok.mean() > 0.97                                # undecided only on a few stripe boundaries
    err = dec.coord - np.broadcast_to(cols, dec.coord.shape)
    # a decided pixel lies in its stripe (centre +- w/2), a boundary pixel next to the boundary
    assert np.abs(err[ok]).max() <= w / 2 + 0.5
    assert np.abs(np.median(err[ok])) < 0.05 * w + 0.02
    assert np.all(dec.quality[~ok] & UNDECIDED)
    # without inverses (thresholds from white and black) the same columns
    alone = decode_gray(pats, None, white, black, low_bit=low_bit, extent_px=1280, min_contrast=20,
                        min_difference=3)
    both = ok & np.isfinite(alone.coord)
    assert both.mean() > 0.9 and np.abs(alone.coord[both] - dec.coord[both]).max() <= w


def test_undecided_bits_are_flagged_not_guessed():
    rng = np.random.default_rng(4)
    cols = np.linspace(100, 300, 400)
    pats, invs, white, black = _camera(1280, cols, 0, blur_px=0.7, noise=1.0, rng=rng)
    pats[3][:, 200:] = invs[3][:, 200:]                   # bit 3 of the right half: no contrast at all
    pats[5][:, 300:] = invs[5][:, 300:]                   # and bit 5 of the last quarter too
    black[:, :20] = white[:, :20]                          # an unlit strip
    dec = decode_gray(pats, invs, white, black, low_bit=0, extent_px=1280, min_contrast=20, min_difference=3)
    assert np.all(dec.quality[:, 300:] & UNDECIDED)       # two undecided bits: never a coordinate
    # one undecided bit is a coordinate only where its two codes are neighbours (on their boundary)
    one = dec.coord[:, 200:300]
    got = np.isfinite(one)
    assert got.mean() < 0.3
    assert np.abs(one[got] - np.broadcast_to(cols[200:300], one.shape)[got]).max() <= 1.0
    assert np.all(dec.quality[:, :20] & DARK) and np.all(np.isnan(dec.coord[:, :20]))


def test_gray_orders_the_phase_through_misaligned_stripe_edges():
    rng = np.random.default_rng(5)
    period, stripe = 8.0, 4
    c = rng.uniform(0, 1279, 100_000)
    phase = np.angle(np.exp(1j * (2 * np.pi * c / period + rng.normal(0, 0.05, c.size))))
    # the Gray code's stripe centre, with the blur moving half of the pixels within 0.8 px of a boundary
    # to the neighbouring stripe
    s = np.floor((c + 0.5) / stripe)
    inside = c + 0.5 - (s + 0.5) * stripe                                 # from the stripe's centre
    s += np.where((np.abs(inside) > stripe / 2 - 0.8) & (rng.random(c.size) < 0.5), np.sign(inside), 0)
    coord_gray = s * stripe + (stripe - 1) / 2
    out, consistent = unwrap_with_gray(coord_gray, phase, period, stripe)
    assert consistent.all()
    assert np.abs(out - c).max() < 0.05 * period                         # right period everywhere
    far = c + period * (GRAY_TOLERANCE + 0.5) / 2                       # a code 0.45 period off: flagged
    assert not unwrap_with_gray(far, phase, period, stripe)[1].any()
    with pytest.raises(ValueError, match="half the period"):
        unwrap_with_gray(coord_gray, phase, period, 8)

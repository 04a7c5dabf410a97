"""Spatial regularisation of the ray field (the seed's tip 1.5: "Gaussian filtering, NURBS").

Neighbouring pixels' rays differ smoothly, while the phase noise of each pixel is independent. Each ray
is represented by its points on two planes (x, y at the nearest and farthest stage positions) and each of
these four fields is fitted locally by a polynomial: a separable local polynomial regression of degree
`order` over a (2m+1) x (2m+1) window (a Savitzky-Golay filter inside the image). A local polynomial
reproduces any field of that degree exactly, so real distortion is not flattened the way a plain blur
would; the noise variance drops by the filter's centre weight.

How large a window? Noise falls as 1/window, but a window much wider than a local distortion bends it.
`Adaptive` lets the data decide per pixel by Lepski's method: it fits a ladder of windows, each doubling
the last, and keeps at each pixel the largest window whose fit differs from every smaller window's by at
most `threshold` standard deviations of that difference. The deviation is known: sigma (the raw field's
noise, measured locally from the smallest window's residual) times sqrt(v_i - v_j), v the filters'
variance factors (exact for nested local polynomial fits). Where the field is smooth on the large scale
(a Brown-Conrady or non-central lens) the largest window wins and the noise falls ~8x below one 43-pixel
window's; over a local bump the larger windows disagree with the smaller ones by more than their noise
and are rejected, so the bump keeps a small window. The bias this lets through is at most about the
noise of the smaller window (the balance that makes the method near-optimal). The chosen window index is
median-filtered (isolated false alarms of the test), eroded (never above the median) and blurred, and
the fit interpolated between the two neighbouring windows of the ladder, so the result has no seams.

A global polynomial (`_base`) is removed first and the local fits smooth the remainder: of degree 3,
or up to 6 where that models the field to within its noise (a Brown-Conrady lens's r^4 terms; not a
free-form lens's bumps), so that what is left for the local fits is small and the large windows fit it
without bias up to the border. Masked
pixels are filled with the remainder's nearest valid value; windows less than `coverage` valid are not
used beyond the smallest. At the image border a window becomes one-sided and `edge_span` times longer
(the off-centre evaluation of a polynomial is noisier), and the larger windows fit a line there
(`Adaptive.edge_order`), which the base has made enough; the smallest keeps the cubic, for a local
bump near the border. Window sums come from running sums (numba), so a window costs the same whatever
its size.
"""

from __future__ import annotations

from dataclasses import dataclass
from math import comb

import cv2
import numba
import numpy as np
from scipy import ndimage

# global polynomial removed before local smoothing (`_base`): its least and greatest total degree in u
# and v, and how much (in noise variances per term) a higher degree's terms must explain to be used
BASE_DEGREE = 3
BASE_DEGREE_MAX = 6
BASE_SIGNIFICANCE = 20.0
BASE_RESIDUAL = 1.5


@dataclass(frozen=True)
class Smoother:
    """One separable local polynomial fit: half_window m (pixels) and polynomial order; edge_order,
    edge_span: the order and the length (in windows) of the one-sided fit used for the m pixels nearest
    the image border (a longer window offsets the noise of an off-centre polynomial evaluation)."""

    half_window: int = 20
    order: int = 3
    edge_order: int = 3
    edge_span: int = 2

    @property
    def window(self) -> int:
        return 2 * self.half_window + 1

    def axis_weights(self, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """For an axis of n pixels: (lo (n,) int, hi (n,) int, coef (n, order+1), var (n,)) such that
        the fit at pixel i is sum_k coef[i, k] * sum_{lo[i] <= j < hi[i]} ((j - i) / m)^k a[j], and var[i]
        is that fit's noise variance over the raw one's for white noise.
        """
        m = self.half_window
        i = np.arange(n)
        ne = min(n, self.edge_span * self.window)
        lo = np.clip(i - m, 0, None)
        hi = np.minimum(i + m + 1, n)
        edge_lo, edge_hi = i < m, i >= n - m
        lo[edge_lo], hi[edge_lo] = 0, ne
        lo[edge_hi], hi[edge_hi] = n - ne, n
        coef = np.zeros((n, self.order + 1))
        var = np.empty(n)
        # sums of ((j - i) / m)^p over a window = differences of prefix sums over the offsets j - i
        offsets = np.arange(-n, n + 1) / m
        prefix = np.zeros((2 * self.order + 1, 2 * n + 2))
        for p in range(2 * self.order + 1):
            np.cumsum(offsets ** p, out=prefix[p, 1:])
        for deg, rows in ((self.order, ~(edge_lo | edge_hi)), (self.edge_order, edge_lo | edge_hi)):
            idx = np.flatnonzero(rows)
            if not len(idx):
                continue
            a0, a1 = lo[idx] - idx + n, hi[idx] - idx + n
            pw = (prefix[:2 * deg + 1, a1] - prefix[:2 * deg + 1, a0]).T        # (rows, 2 deg + 1)
            a = pw[:, np.add.outer(np.arange(deg + 1), np.arange(deg + 1))]
            e0 = np.zeros((len(idx), deg + 1, 1))
            e0[:, 0] = 1.0
            c = np.linalg.solve(a, e0)[..., 0]               # A^-1 e0: the fit's value at u = 0
            coef[idx, :deg + 1] = c
            var[idx] = c[:, 0]                              # e0^T A^-1 e0
        return lo, hi, coef, var



def _axis_weights(ladder: list[Smoother], n: int) -> tuple[np.ndarray, ...]:
    """Weights of each ladder window along an axis of n pixels, for the running-sum kernels: (lo, hi
    (J, n) int64, g (J, n, K) float64, var (J, n) float64, centre, scale) such that window j's fit at
    pixel i is sum_q g[j, i, q] * sum_{lo <= p < hi} ((p - centre) / scale)^q a[p]: each power of
    (p - i) / m is expanded binomially in (p - centre) / scale, so that one set of running sums serves
    every window and pixel."""
    centre, scale = n // 2, max(n / 2, 1.0)
    nk = max(s.order for s in ladder) + 1
    lo, hi = np.empty((len(ladder), n), np.int64), np.empty((len(ladder), n), np.int64)
    g, var = np.zeros((len(ladder), n, nk)), np.empty((len(ladder), n))
    i = np.arange(n)
    for j, s in enumerate(ladder):
        lo[j], hi[j], coef, var[j] = s.axis_weights(n)
        m = s.half_window
        d = (centre - i) / m                    # (p - i) / m = (scale / m) (p - centre) / scale + d
        for k in range(coef.shape[1]):
            for q in range(k + 1):
                g[j, :, q] += coef[:, k] * comb(k, q) * (scale / m) ** q * d ** (k - q)
    return lo, hi, g, var, float(centre), scale


@numba.njit(cache=True, parallel=True)
def _fit_axis0(a, lo, hi, g, centre, scale):
    """(J, N, C) float32 window fits along axis 0 of a (N, C): out[j, i, c] = sum_q g[j, i, q] *
    sum_{lo[j, i] <= p < hi[j, i]} ((p - centre) / scale)^q a[p, c], from float64 running sums over
    blocks of columns (float32 holds the fits of the small remainder to ~1e-7 of its size)."""
    n, ncol = a.shape
    nw, _, nk = g.shape
    out = np.empty((nw, n, ncol), np.float32)
    block = 32
    for b in numba.prange((ncol + block - 1) // block):
        c0 = b * block
        nc = min(ncol, c0 + block) - c0
        cs = np.zeros((n + 1, nk, block))
        for p in range(n):
            t = (p - centre) / scale
            tq = 1.0
            for q in range(nk):
                for c in range(nc):
                    cs[p + 1, q, c] = cs[p, q, c] + tq * a[p, c0 + c]
                tq *= t
        for j in range(nw):
            for i in range(n):
                l, h = lo[j, i], hi[j, i]
                for c in range(nc):
                    v = 0.0
                    for q in range(nk):
                        v += g[j, i, q] * (cs[h, q, c] - cs[l, q, c])
                    out[j, i, c0 + c] = v
    return out


@numba.njit(cache=True, parallel=True)
def _fit_axis1(a, lo, hi, g, centre, scale):
    """In place, along the last axis of a (J, R, N), window j for a[j]: as `_fit_axis0`."""
    nw, nrow, n = a.shape
    nk = g.shape[2]
    for jr in numba.prange(nw * nrow):
        j, r = jr // nrow, jr % nrow
        cs = np.zeros((n + 1, nk))
        for p in range(n):
            t = (p - centre) / scale
            v = a[j, r, p]
            for q in range(nk):
                cs[p + 1, q] = cs[p, q] + v
                v *= t
        for i in range(n):
            l, h = lo[j, i], hi[j, i]
            v = 0.0
            for q in range(nk):
                v += g[j, i, q] * (cs[h, q] - cs[l, q])
            a[j, r, i] = v


@numba.njit(cache=True, parallel=True)
def _lepski(fits, sigma, var_v, var_u, top, threshold):
    """(H, W) uint8 index of the largest window j <= top whose fit differs from every smaller window i's
    by at most threshold standard deviations of the difference, sigma * sqrt(var_i - var_j) (exact for
    nested local polynomial fits: the larger window's weights are a polynomial on the smaller window, so
    Cov(f_i, f_j) = Var(f_j))."""
    nw, h, w = fits.shape
    index = np.zeros((h, w), np.uint8)
    for r in numba.prange(h):
        for c in range(w):
            s2 = (threshold * sigma[r, c]) ** 2
            for j in range(1, min(nw, top[r, c] + 1)):
                vj = var_v[j, r] * var_u[j, c]
                ok = True
                for i in range(j):
                    d = fits[j, r, c] - fits[i, r, c]
                    if d * d > s2 * (var_v[i, r] * var_u[i, c] - vj):
                        ok = False
                        break
                if not ok:
                    break
                index[r, c] = j
    return index


@numba.njit(cache=True, parallel=True)
def _blend(fits, index, var_v, var_u, base, valid, windows):
    """At a fractional window index, linear between the two neighbouring windows: (base + fit (H, W)
    float64, the noise gain sqrt(variance factor) (H, W) float32, the window (H, W) float32); NaN
    outside valid."""
    nw, h, w = fits.shape
    value = np.full((h, w), np.nan)
    gain = np.full((h, w), np.nan, np.float32)
    window = np.full((h, w), np.nan, np.float32)
    for r in numba.prange(h):
        for c in range(w):
            if not valid[r, c]:
                continue
            x = index[r, c]
            j0 = min(int(x), nw - 1)
            j1 = min(j0 + 1, nw - 1)
            f = x - j0
            value[r, c] = base[r, c] + (1 - f) * fits[j0, r, c] + f * fits[j1, r, c]
            gain[r, c] = np.sqrt((1 - f) * var_v[j0, r] * var_u[j0, c] + f * var_v[j1, r] * var_u[j1, c])
            window[r, c] = (1 - f) * windows[j0] + f * windows[j1]
    return value, gain, window


@numba.njit(cache=True, parallel=True)
def _residual2(rem, fit, var_v, var_u, valid):
    """(H, W) float32 (rem - fit)^2 / (1 - v), 0 outside valid: an unbiased estimate of the raw noise
    variance, E[(raw - fit)^2] = sigma^2 (1 - v) for a local polynomial fit of variance factor v."""
    h, w = rem.shape
    out = np.zeros((h, w), np.float32)
    for r in numba.prange(h):
        for c in range(w):
            if valid[r, c]:
                d = rem[r, c] - fit[r, c]
                out[r, c] = d * d / max(1.0 - var_v[r] * var_u[c], 1e-3)
    return out


@dataclass(frozen=True)
class Adaptive:
    """Window chosen per pixel (Lepski's method) over a ladder of windows doubling from the smallest.

    half_window: the smallest window's half size m (pixels); levels: the number of windows (those wider
    than the image are dropped); order: the local polynomial's; edge_order: that of the larger windows'
    one-sided fits at the image border (lower is less noisy there; the smallest window keeps `order`,
    so the test can fall back to it where the field bends); threshold: how many standard deviations
    of their difference a window's fit may differ from a smaller one's; coverage: the least fraction of
    valid pixels in a window for it to be used (beyond the smallest); blend: the half size (in smallest
    half windows) of the median, erosion and box filters applied to the chosen window index.
    """

    half_window: int = 20
    levels: int = 4
    order: int = 3
    edge_order: int = 1
    threshold: float = 3.0
    coverage: float = 0.995
    blend: float = 1.0

    @property
    def window(self) -> int:
        """The smallest window (pixels)."""
        return 2 * self.half_window + 1

    def ladder(self) -> list[Smoother]:
        return [Smoother(self.half_window * 2 ** j, self.order, self.order if j == 0 else self.edge_order)
                for j in range(self.levels)]


@dataclass
class Regularised:
    """Result of `smooth_fields`. fields: (K, H, W) float64 smoothed, NaN outside valid; noise: (K, H, W)
    float32 estimated 1-sigma noise of the raw fields; gain: (K, H, W) float32 the noise after / before
    at each pixel; window: (H, W) float32 the effective window (pixels) used, averaged over the fields."""

    fields: np.ndarray
    noise: np.ndarray
    gain: np.ndarray
    window: np.ndarray


def _base(field: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """The global polynomial removed before local smoothing, least-squares over every valid pixel, in
    Legendre polynomials of the normalised pixel coordinates: of total degree `BASE_DEGREE`, or higher
    (up to `BASE_DEGREE_MAX`) where the polynomial is the field's model. A higher degree's terms must
    lower the residual sum of squares by `BASE_SIGNIFICANCE` times the noise variance per term (the
    decoded fields' noise is correlated over a few pixels, so terms fitted to noise alone reach a few
    units): a degree too high for the field only adds its fit's noise, which grows towards the border.
    And what that degree leaves must be noise, within `BASE_RESIDUAL` times the pixel-to-pixel noise
    variance: where the field has local structure (a free-form lens's bumps), the local fits are its
    model, and a high-degree polynomial chasing the bumps only makes the remainder harder for them.
    The normal equations separate into products of the (H, W) arrays with small per-axis tables, so no
    design matrix of one row per pixel is built."""
    h, w = field.shape
    pu = np.polynomial.legendre.legvander(np.linspace(-1, 1, w), BASE_DEGREE_MAX)    # (W, D)
    pv = np.polynomial.legendre.legvander(np.linspace(-1, 1, h), BASE_DEGREE_MAX)    # (H, D)
    d = BASE_DEGREE_MAX + 1
    pairs_u = (pu[:, :, None] * pu[:, None, :]).reshape(w, d * d)
    pairs_v = (pv[:, :, None] * pv[:, None, :]).reshape(h, d * d)
    # gram[j, l, i, k] = sum over valid pixels of P_i(u) P_k(u) P_j(v) P_l(v); rhs[j, i] of P_i(u) P_j(v) f
    gram = (pairs_v.T @ (valid.astype(np.float64) @ pairs_u)).reshape(d, d, d, d)
    sample = field[::8, ::8][valid[::8, ::8]]
    mean = float(np.mean(sample if sample.size else field[valid]))
    f0 = _masked(field - mean, valid)                     # ~centred: the residual sums stay exact
    rhs = pv.T @ f0 @ pu
    total = float(np.dot(f0.ravel(), f0.ravel()))
    fits = []                                                     # (terms, coefficients, residual SS)
    for degree in range(BASE_DEGREE, BASE_DEGREE_MAX + 1):
        terms = [(i, j) for i in range(degree + 1) for j in range(degree + 1 - i)]
        a = np.array([[gram[j, l, i, k] for (k, l) in terms] for (i, j) in terms])
        b = np.array([rhs[j, i] for (i, j) in terms])
        coef = np.linalg.lstsq(a, b, rcond=None)[0]          # a small or masked image may leave it singular
        fits.append((terms, coef, total - coef @ b))
    n = int(valid.sum())
    noise_var = fits[-1][2] / max(n - len(fits[-1][0]), 1)
    fine_var = _white_noise_variance(f0, valid)
    chosen = 0
    for k in range(1, len(fits)):
        drop = (fits[k - 1][2] - fits[k][2]) / (len(fits[k][0]) - len(fits[k - 1][0]))
        if drop > BASE_SIGNIFICANCE * noise_var and fits[k][2] <= BASE_RESIDUAL * n * fine_var:
            chosen = k
    c = np.zeros((d, d))                      # c[j, i]: the coefficient of P_j(v) P_i(u)
    for value, (i, j) in zip(fits[chosen][1], fits[chosen][0]):
        c[j, i] = value
    return pv @ c @ pu.T + mean


def _masked(values: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """`values` (a new array, changed in place) with 0 outside valid (NaN there included)."""
    np.putmask(values, ~valid, 0.0)
    return values


def _white_noise_variance(field: np.ndarray, valid: np.ndarray, stride: int = 4) -> float:
    """The variance of a field's pixel-to-pixel noise, from its second differences along every
    `stride`-th row and column (over valid triples; a smooth field's second differences are negligible
    beside the noise's, whose variance they hold 6 times)."""
    out = []
    for a, v in ((field[:, ::stride], valid[:, ::stride]), (field[::stride].T, valid[::stride].T)):
        ok = v[:-2] & v[1:-1] & v[2:]
        if ok.any():
            out.append(np.mean((a[:-2] - 2 * a[1:-1] + a[2:])[ok] ** 2) / 6)
    return float(np.mean(out)) if out else 0.0


def _box_median(index: np.ndarray, levels: int, size: int) -> np.ndarray:
    """Median over a size x size box of an index map with values 0 .. levels-1: the median is >= j
    where at least half the box is >= j."""
    out = np.zeros(index.shape, np.float32)
    for j in range(1, levels):
        share = cv2.blur((index >= j).astype(np.float32), (size, size), borderType=cv2.BORDER_REPLICATE)
        out += share >= 0.5
    return out


def _smooth_index(index: np.ndarray, levels: int, size: int) -> np.ndarray:
    """The chosen window index made smooth: median (drops the test's isolated false alarms), eroded
    (so that it nowhere exceeds the median) and box-blurred over size x size pixels."""
    med = _box_median(index, levels, size)
    ero = cv2.erode(med, np.ones((size, size), np.uint8), borderType=cv2.BORDER_REPLICATE)
    return cv2.blur(ero, (size, size), borderType=cv2.BORDER_REPLICATE)


def smooth_fields(fields: np.ndarray, valid: np.ndarray, smoother: Smoother | Adaptive) -> Regularised:
    """Smooth (K, H, W) fields over the valid pixels with one window (`Smoother`) or a window chosen
    per pixel (`Adaptive`)."""
    k, h, w = fields.shape
    if min(h, w) <= smoother.window:
        raise ValueError(f"image ({w}x{h}) is too small for a {smoother.window}-pixel smoothing window")
    ladder = smoother.ladder() if isinstance(smoother, Adaptive) else [smoother]
    ladder = [s for s in ladder if s.window < min(h, w)]
    lo_v, hi_v, g_v, var_v, centre_v, scale_v = _axis_weights(ladder, h)
    lo_u, hi_u, g_u, var_u, centre_u, scale_u = _axis_weights(ladder, w)
    vf = valid.astype(np.float32)
    fill_idx = None
    if not valid.all():
        fill_idx = ndimage.distance_transform_edt(~valid, return_distances=False, return_indices=True)
    box = ladder[0].window
    count = cv2.blur(vf, (box, box), borderType=cv2.BORDER_REPLICATE)
    # the largest window allowed at each pixel: one whose valid fraction reaches `coverage`
    top = np.zeros((h, w), np.uint8)
    for j, s in enumerate(ladder[1:], 1):
        top[cv2.blur(vf, (s.window, s.window), borderType=cv2.BORDER_REPLICATE) >= smoother.coverage] = j
    windows = np.array([s.window for s in ladder], np.float32)
    out = np.empty((k, h, w))
    noise = np.empty((k, h, w), np.float32)
    gain = np.empty((k, h, w), np.float32)
    window = np.zeros((h, w), np.float32)
    for i in range(k):
        base = _base(fields[i], valid)
        rem = _masked(fields[i] - base, valid)
        if fill_idx is not None:
            rem = rem[fill_idx[0], fill_idx[1]]
        fits = _fit_axis0(rem, lo_v, hi_v, g_v, centre_v, scale_v)
        _fit_axis1(fits, lo_u, hi_u, g_u, centre_u, scale_u)
        e2 = cv2.blur(_residual2(rem, fits[0], var_v[0], var_u[0], valid), (box, box), borderType=cv2.BORDER_REPLICATE)
        sigma = np.sqrt(np.maximum(e2, 0) / np.maximum(count, 1e-6))
        index = np.zeros((h, w), np.float32)
        if len(ladder) > 1:
            index = _lepski(fits, sigma, var_v, var_u, top, smoother.threshold)
            size = 2 * int(round(smoother.blend * ladder[0].half_window)) + 1
            index = _smooth_index(index, len(ladder), size)
        out[i], gain[i], win = _blend(fits, index, var_v, var_u, base, valid, windows)
        noise[i] = np.where(valid, sigma, np.nan)
        window += win / k
    return Regularised(out, noise, gain, window)

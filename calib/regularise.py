"""Spatial regularisation of the ray field (the seed's tip 1.5: "Gaussian filtering, NURBS").

Neighbouring pixels' rays differ smoothly, while the phase noise of each pixel is independent. Each ray
is represented by its points on two planes (x, y at the nearest and farthest stage positions) and each of
these four fields is fitted locally by a polynomial: a separable local polynomial regression of degree
`order` over a (2m+1) x (2m+1) window (a Savitzky-Golay filter inside the image). A local polynomial
reproduces any field of that degree exactly, so real distortion is not flattened the way a plain blur
would; the noise variance drops by the filter's centre weight.

How large a window? Noise falls as 1/window, but a window much wider than a local distortion bends it.
`Adaptive` lets the data decide per pixel: it fits a ladder of windows, each doubling the last, and
keeps at each pixel the window of least estimated risk, its noise variance plus its squared bias
(`_least_risk`). The noise is known: sigma^2 v_j (sigma the raw field's noise, measured locally from the
residual of the data's finest window; v_j the filter's variance factor). The bias is measured from the
step to the next smaller window: a local cubic's bias grows as its window's fourth power, so the step
is 15/16 of the larger window's bias plus noise of a known variance, sigma^2 (v_{j-1} - v_j) (nested
fits); the step squared less that noise, averaged over the smaller window's box, estimates the bias
squared (at the border, where the larger windows fit lines, with the growth of a line's bias). A
structure finer than two neighbouring windows bends both alike and leaves their step small (a 15-px
ripple), so the risk chooses among the windows Lepski's test lets through: up to the largest whose fit
differs from every smaller window's by at most `threshold` (2.5) standard deviations of their
difference. From one stage position, which cannot tell lens structure from the display's own errors,
the risk's box-averaged bias estimate follows those errors, and the window is Lepski's alone
(`bias_weight` 0, `threshold` 3; `calib.ray_field.auto_smoother`). Where the field is smooth
on the large scale (a Brown-Conrady or non-central lens) the largest window wins and the noise falls
~8x below one 43-pixel window's; over a local bump the larger windows' bias outweighs their lower
noise, so the bump keeps a small window, down to the ladder's finer rungs (`Adaptive.finer_rungs`)
within a window of the border, or over a region where Lepski's test rejects the finest scale's window
(`_rejected_region`). The squared bias counts `Adaptive.bias_weight` (2) times: a bias is common to every
capture of the same lens and poses and does not average out downstream as noise does. The chosen window
index is median-filtered (isolated choices of the noisy risk estimate) and blurred, and the fit
interpolated between the two neighbouring windows of the ladder, so the result has no seams.

Until 2026-12-07 the window was Lepski's alone, at 3 standard deviations, its index then eroded: it let
through a bias of up to about the noise of the smaller window (69-83 % of a free-form lens's as-held
ray error was common to two captures; 44-56 % now, docs/calibration.md). The finer rung serves the
border band, and inside it the regions where Lepski's test rejects the finest scale's window against it:
open to every pixel, the risk chose it where noise made the larger window's step look like bias, and a
hand-held calibration of the free-form lens at 1280 x 1024 erred by 28 % more; at the rejecting pixels
alone (until 2026-12-08) it left a bump's flanks to the larger window, and the median of the window index
overruled it over a small bump; over their regions grown by the half window, but with the noise's
isolated rejections kept (an opening drops them now), the same hand-held calibration erred by 23-26 %
more.

The uncertainty is the noise after smoothing. With the bias counted twice in the risk it is a small
part of the error: on a field with local bumps (`tests/calib/test_regularise.py`) the noise alone covers
96 % of the RMS error. (Until 2026-12-07 an estimate of the bias Lepski's choice let through was added:
the step from the chosen window to the next smaller one, less its noise, over the image. With the
risk's choice that step is small by selection and the estimate read 0, so it is gone.)

A global polynomial (`_base`) is removed first and the local fits smooth the remainder: of degree 3,
or up to 6 where that models the field to within its noise (a Brown-Conrady lens's r^4 terms; not a
free-form lens's bumps), so that what is left for the local fits is small and the large windows fit it
without bias up to the border. Small holes in the valid pixels are filled with the remainder's nearest
valid value; windows less than `coverage` valid (among their pixels inside the data) are not used
beyond the smallest. At the border of the data - the image's, or where a larger invalid area begins,
such as the band a display that does not fill the view leaves - a window becomes one-sided and
`edge_span` times longer (the off-centre evaluation of a polynomial is noisier), and the larger windows
fit a line there (`Adaptive.edge_order`), which the base has made enough; the smallest keeps the cubic,
for a local bump near the border; being one-sided and longer, a window reaches 2 x `edge_span` times
farther from a border pixel than from an interior one, and there the finer rungs serve. Window sums
come from running sums (numba), so a window costs the same whatever its size.

Where the ladder starts is measured (`finest_scale`): the finest scale of the structure the fields of
two stage planes share (the lens's), told from the noise and the display's own errors, which differ
between the planes.
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
# holes in the valid pixels up to this distance (pixels) from valid data are filled; larger invalid
# areas are outside the data, where the windows end (`_inside`)
FILL_PX = 2.0
# the smallest window (`finest_scale`): the analysis covers at most SCALE_REGION x SCALE_REGION pixels
# (the centre of a larger image) cut into blocks of a SCALE_BLOCKS-th of its smaller side; the ladder
# reaches below a window when more than SCALE_SHARE of the blocks are better served by a smaller one,
# and it keeps at least SCALE_LEVELS windows (doubling, narrower than the image: the risk has a
# choice everywhere, also for local features too small for a share of the blocks)
SCALE_REGION = 1024
SCALE_BLOCKS = 8
SCALE_SHARE = 0.2
SCALE_LEVELS = 3
# the radius of the opening (erosion, then dilation) of the pixels where Lepski's test rejects the finest
# scale's window, as a share of its half size: narrower regions of rejections are noise's (`_rejected_region`)
REJECTED_OPENING = 0.2


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
        i = np.arange(n)
        lo, hi, edge = self.bounds(i, np.zeros(n, np.int64), np.full(n, n, np.int64))
        coef, var = np.zeros((n, self.order + 1)), np.empty(n)
        for deg, rows in ((self.order, ~edge), (self.edge_order, edge)):
            coef[rows], var[rows] = _coefficients(self.half_window, deg, lo[rows] - i[rows], hi[rows] - i[rows],
                                                  self.order)
        return lo, hi, coef, var

    def bounds(self, i: np.ndarray, start: np.ndarray, end: np.ndarray) -> tuple[np.ndarray, ...]:
        """The windows [lo, hi) of pixels i within their runs [start, end) of an axis (arrays): centred,
        or, within a half window of a run's end, one-sided and `edge_span` windows long (the whole run
        if it is shorter); and whether each is such an edge window."""
        m = self.half_window
        ne = np.minimum(end - start, self.edge_span * self.window)
        edge_lo = i - start < m
        edge_hi = ~edge_lo & (end - 1 - i < m)
        lo = np.where(edge_lo, start, np.where(edge_hi, end - ne, i - m))
        hi = np.where(edge_lo, start + ne, np.where(edge_hi, end, i + m + 1))
        return lo, hi, edge_lo | edge_hi

    def run_tables(self, lengths: np.ndarray) -> tuple[np.ndarray, ...]:
        """Coefficients (as `axis_weights`'s, in (p - i) / m) of the windows a pixel can have inside a run
        of valid pixels (`_WindowTables`): interior (order+1,), edge (m, order+1) for the pixel k < m
        pixels from the lower end of a run at least edge_span windows long (the upper end mirrors it),
        and for each run shorter than that, of a length in `lengths`, the whole run's fit at each of
        its pixels: short (sum of lengths, order+1), with start (the row of each length's first
        pixel) ."""
        m, ne = self.half_window, self.edge_span * self.window
        interior = _coefficients(m, self.order, np.array([-m]), np.array([m + 1]), self.order)[0][0]
        k = np.arange(m)
        edge = _coefficients(m, self.edge_order, -k, ne - k, self.order)[0]
        lengths = np.asarray(lengths, np.int64)
        starts = np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.int64)
        k = np.concatenate([np.arange(n) for n in lengths]) if len(lengths) else np.zeros(0, np.int64)
        run = np.repeat(lengths, lengths)
        short = np.zeros((len(k), self.order + 1))
        for n in np.unique(lengths):         # a run too short for the degree: the degree its pixels allow
            rows = run == n
            short[rows] = _coefficients(m, min(self.edge_order, max(int(n) // 2 - 1, 0)), -k[rows], n - k[rows],
                                        self.order)[0]
        return interior, edge, short, starts


def _coefficients(m: int, degree: int, lo_off: np.ndarray, hi_off: np.ndarray, width: int) -> tuple[np.ndarray, ...]:
    """For windows lo_off <= p - i < hi_off (arrays of N offsets): (coef (N, width+1), var (N,)) of the
    least-squares polynomial of `degree` in t = (p - i) / m, evaluated at t = 0: its value is
    sum_k coef_k sum_p t^k a_p, and var = e0^T A^-1 e0 its variance factor (coef beyond the degree 0)."""
    lo_off, hi_off = np.asarray(lo_off, np.int64), np.asarray(hi_off, np.int64)
    coef = np.zeros((len(lo_off), width + 1))
    if not len(lo_off):
        return coef, np.zeros(0)
    first, last = int(lo_off.min()), int(hi_off.max())
    # sums of t^q over a window = differences of prefix sums over the offsets
    t = np.arange(first, last) / m
    prefix = np.zeros((2 * degree + 1, last - first + 1))
    for q in range(2 * degree + 1):
        np.cumsum(t ** q, out=prefix[q, 1:])
    pw = (prefix[:, hi_off - first] - prefix[:, lo_off - first]).T          # (N, 2 degree + 1)
    a = pw[:, np.add.outer(np.arange(degree + 1), np.arange(degree + 1))]
    e0 = np.zeros((len(lo_off), degree + 1, 1))
    e0[:, 0] = 1.0
    c = np.linalg.solve(a, e0)[..., 0]                   # A^-1 e0: the fit's value at t = 0
    coef[:, :degree + 1] = c
    return coef, c[:, 0].copy()                          # e0^T A^-1 e0


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


def _runs(inside: np.ndarray, axis: int) -> tuple[np.ndarray, np.ndarray]:
    """(start, end) int64 arrays of inside's shape: for each inside pixel, the run of inside pixels along
    `axis` (0: its column, 1: its row) that holds it, [start, end); 0, 0 outside."""
    a = inside if axis == 0 else inside.T
    n = a.shape[0]
    idx = np.arange(n)[:, None]
    before = np.zeros_like(a)
    before[1:] = a[:-1]
    after = np.zeros_like(a)
    after[:-1] = a[1:]
    start = np.maximum.accumulate(np.where(a & ~before, idx, -1), axis=0)
    end = np.minimum.accumulate(np.where(a & ~after, idx + 1, n + 1)[::-1], axis=0)[::-1]
    start, end = np.where(a, start, 0), np.where(a, end, 0)
    return (start, end) if axis == 0 else (np.ascontiguousarray(start.T), np.ascontiguousarray(end.T))


class _WindowTables:
    """The per-pixel windows of a ladder along one axis where runs of valid pixels are shorter than the
    axis (`Smoother.run_tables` of each level, flattened for the kernels): half (J,), span (J,) the edge
    window's length, interior (J, K), edge (J, max m, K), short (total, K) with short_index (J, n + 1)
    the row of a run length's first pixel (-1: absent), binom (K, K)."""

    def __init__(self, ladder: list[Smoother], start: np.ndarray, end: np.ndarray, n: int):
        nk = max(s.order for s in ladder) + 1
        self.half = np.array([s.half_window for s in ladder], np.int64)
        self.span = np.array([s.edge_span * s.window for s in ladder], np.int64)
        self.interior = np.zeros((len(ladder), nk))
        self.edge = np.zeros((len(ladder), int(self.half.max()), nk))
        self.short_index = np.full((len(ladder), n + 1), -1, np.int64)
        lengths = np.unique((end - start)[end > start])
        shorts = []
        offset = 0
        for j, s in enumerate(ladder):
            short_lengths = lengths[lengths < self.span[j]]
            interior, edge, short, starts = s.run_tables(short_lengths)
            self.interior[j, :interior.size] = interior
            self.edge[j, :len(edge), :edge.shape[1]] = edge
            self.short_index[j, short_lengths] = starts + offset
            shorts.append(np.pad(short, ((0, 0), (0, nk - short.shape[1]))))
            offset += len(short)
        self.short = np.concatenate(shorts) if shorts else np.zeros((0, nk))
        self.binom = np.array([[comb(k, q) for q in range(nk)] for k in range(nk)], np.float64)

    def args(self):
        return self.half, self.span, self.interior, self.edge, self.short, self.short_index, self.binom


_NO_RUNS = np.zeros((0, 0), np.int64)
_NO_VAR = np.zeros((0, 0, 0), np.float32)


@numba.njit(cache=True, inline="always")
def _run_window(i, s, e, j, half, span, interior, edge, short, short_index, binom, centre, scale, gq):
    """Pixel i of the run [s, e) at level j: fills gq with its coefficients in ((p - centre) / scale)^q
    (`_axis_weights`'s expansion) and returns (lo, hi, variance factor)."""
    m = half[j]
    k, kh = i - s, e - 1 - i
    sign = 1.0
    if k >= m and kh >= m:
        c = interior[j]
        lo, hi = i - m, i + m + 1
    elif e - s >= span[j]:
        if k < m:
            c = edge[j, k]
            lo, hi = s, s + span[j]
        else:
            c = edge[j, kh]
            lo, hi = e - span[j], e
            sign = -1.0                                 # the lower end's fit, mirrored
    else:
        c = short[short_index[j, e - s] + k]
        lo, hi = s, e
    d = (centre - i) / m
    r = scale / m
    nk = gq.size
    for q in range(nk):
        gq[q] = 0.0
    sk = 1.0
    for kk in range(nk):
        ck = c[kk] * sk
        sk *= sign
        dq = 1.0
        for q in range(kk, -1, -1):                     # d^(kk - q), q from kk down to 0
            gq[q] += ck * binom[kk, q] * r ** q * dq
            dq *= d
    return lo, hi, c[0]


@numba.njit(cache=True, parallel=True)
def _fit_axis0(a, lo, hi, g, centre, scale, start, end, half, span, interior, edge, short, short_index, binom,
               var):
    """(J, N, C) float32 window fits along axis 0 of a (N, C): out[j, i, c] = sum_q g[j, i, q] *
    sum_{lo[j, i] <= p < hi[j, i]} ((p - centre) / scale)^q a[p, c], from float64 running sums over
    blocks of columns (float32 holds the fits of the small remainder to ~1e-7 of its size). Where
    start/end (N, C) are given, a pixel whose run of valid pixels in its column is not the whole column
    has its own window inside the run (`_run_window`), its variance factor written to var (J, N, C)."""
    n, ncol = a.shape
    nw, _, nk = g.shape
    out = np.empty((nw, n, ncol), np.float32)
    runs = start.shape[0] > 0
    block = 32
    for b in numba.prange((ncol + block - 1) // block):
        c0 = b * block
        nc = min(ncol, c0 + block) - c0
        cs = np.zeros((n + 1, nk, block))
        gq = np.zeros(nk)
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
                    if runs and (start[i, c0 + c] != 0 or end[i, c0 + c] != n):
                        if end[i, c0 + c] == 0:                   # not in any run: outside the data
                            out[j, i, c0 + c] = 0.0
                            continue
                        l2, h2, v2 = _run_window(i, start[i, c0 + c], end[i, c0 + c], j, half, span, interior,
                                                 edge, short, short_index, binom, centre, scale, gq)
                        var[j, i, c0 + c] = v2
                        v = 0.0
                        for q in range(nk):
                            v += gq[q] * (cs[h2, q, c] - cs[l2, q, c])
                        out[j, i, c0 + c] = v
                        continue
                    v = 0.0
                    for q in range(nk):
                        v += g[j, i, q] * (cs[h, q, c] - cs[l, q, c])
                    out[j, i, c0 + c] = v
    return out


@numba.njit(cache=True, parallel=True)
def _fit_axis1(a, lo, hi, g, centre, scale, start, end, half, span, interior, edge, short, short_index, binom,
               var):
    """In place, along the last axis of a (J, R, N), window j for a[j]: as `_fit_axis0` (start/end
    (R, N): the runs along the rows)."""
    nw, nrow, n = a.shape
    nk = g.shape[2]
    runs = start.shape[0] > 0
    for jr in numba.prange(nw * nrow):
        j, r = jr // nrow, jr % nrow
        cs = np.zeros((n + 1, nk))
        gq = np.zeros(nk)
        for p in range(n):
            t = (p - centre) / scale
            v = a[j, r, p]
            for q in range(nk):
                cs[p + 1, q] = cs[p, q] + v
                v *= t
        for i in range(n):
            if runs and (start[r, i] != 0 or end[r, i] != n):
                if end[r, i] == 0:
                    a[j, r, i] = 0.0
                    continue
                l2, h2, v2 = _run_window(i, start[r, i], end[r, i], j, half, span, interior, edge, short,
                                         short_index, binom, centre, scale, gq)
                var[j, r, i] = v2
                v = 0.0
                for q in range(nk):
                    v += gq[q] * (cs[h2, q] - cs[l2, q])
                a[j, r, i] = v
                continue
            l, h = lo[j, i], hi[j, i]
            v = 0.0
            for q in range(nk):
                v += g[j, i, q] * (cs[h, q] - cs[l, q])
            a[j, r, i] = v


def _least_risk(fits: np.ndarray, sigma: np.ndarray, var_v: np.ndarray, var_u: np.ndarray, top: np.ndarray,
                ladder: list[Smoother], edge: np.ndarray, bias_weight: float) -> np.ndarray:
    """(H, W) uint8 index of the window j <= top of least estimated risk at each pixel: the window's noise
    sigma^2 v_j plus bias_weight times its squared bias b_j^2 (module docstring).

    The bias from the step to the next smaller window: a local polynomial of order p has a bias that
    grows as its window's (p + 1)-th power, g = 2^(p + 1) times per doubling (16 for a cubic), so
    fit_j - fit_{j-1} = b_j (1 - 1/g); the step squared, less its noise sigma^2 (v_{j-1} - v_j) (nested
    fits), averaged over window j - 1's box (what the step's noise is correlated over), over (1 - 1/g)^2
    estimates b_j^2 (clipped at 0). The order is each window's at the pixel:
    `Smoother.edge_order` within its half window of the border of the data (`edge`, pixels:
    `_edge_distance`); a window of a lower order than the smaller one has all their step's bias (g
    infinite). The smallest window's bias: the next one's over g."""
    index = np.zeros(sigma.shape, np.uint8)
    best = np.empty(sigma.shape, np.float32)
    step2 = np.empty(sigma.shape, np.float32)
    for j in range(1, len(fits)):
        small, large = ladder[j - 1], ladder[j]
        _step_squared(fits, j, sigma, var_v, var_u, step2)
        b2 = _box(step2, small.window)
        _risk_update(b2, j, sigma, var_v, var_u, edge, top, bias_weight, small.half_window, small.order,
                     small.edge_order, large.half_window, large.order, large.edge_order, best, index)
    return index


@numba.njit(cache=True, parallel=True)
def _step_squared(fits, j, sigma, var_v, var_u, out):
    """out (H, W) float32: the step from window j - 1's fit to window j's, squared, less its noise sigma^2
    (v_{j-1} - v_j) (`_least_risk`)."""
    nw, h, w = fits.shape
    for r in numba.prange(h):
        for c in range(w):
            d = fits[j, r, c] - fits[j - 1, r, c]
            s2 = sigma[r, c] * sigma[r, c]
            out[r, c] = d * d - s2 * (var_v[j - 1, r, c] * var_u[j - 1, r, c] - var_v[j, r, c] * var_u[j, r, c])


@numba.njit(cache=True, parallel=True)
def _risk_update(b2, j, sigma, var_v, var_u, edge, top, bias_weight, small_half, small_order, small_edge_order,
                 large_half, large_order, large_edge_order, best, index):
    """Window j's risk at each pixel from its box-averaged squared step `b2` (`_least_risk`); where it
    is below `best` (and j <= top) it becomes the best and `index` j. For j = 1, window 0's risk first."""
    h, w = b2.shape
    for r in numba.prange(h):
        for c in range(w):
            p_small = small_edge_order if edge[r, c] < small_half else small_order
            p_large = large_edge_order if edge[r, c] < large_half else large_order
            # the bias's growth per doubling, g = 2^(p + 1); a lower order than the smaller window's: all
            # the step is its own bias (g infinite)
            g = 2.0 ** (p_large + 1) if p_large == p_small else np.inf
            bias2 = max(b2[r, c], 0.0) / (1.0 - 1.0 / g) ** 2
            s2 = sigma[r, c] * sigma[r, c]
            if j == 1:
                best[r, c] = s2 * var_v[0, r, c] * var_u[0, r, c] + bias_weight * bias2 / (g * g)
                index[r, c] = 0
            risk = s2 * var_v[j, r, c] * var_u[j, r, c] + bias_weight * bias2
            if risk < best[r, c] and j <= top[r, c]:
                best[r, c] = risk
                index[r, c] = j


@numba.njit(cache=True, parallel=True)
def _lepski(fits, sigma, var_v, var_u, top, threshold):
    """(H, W) uint8 index of the largest window j <= top whose fit differs from every smaller window
    i's by at most threshold standard deviations of the difference, sigma * sqrt(var_i - var_j) (exact
    for nested local polynomial fits: the larger window's weights are a polynomial on the smaller
    window, so Cov(f_i, f_j) = Var(f_j)): Lepski's method, the cap on the window of least risk."""
    nw, h, w = fits.shape
    index = np.zeros((h, w), np.uint8)
    for r in numba.prange(h):
        for c in range(w):
            s2 = (threshold * sigma[r, c]) ** 2
            for j in range(1, min(nw, top[r, c] + 1)):
                vj = var_v[j, r, c] * var_u[j, r, c]
                ok = True
                for i in range(j):
                    d = fits[j, r, c] - fits[i, r, c]
                    if d * d > s2 * (var_v[i, r, c] * var_u[i, r, c] - vj):
                        ok = False
                        break
                if not ok:
                    break
                index[r, c] = j
    return index


def _edge_distance(inside: np.ndarray | None, h: int, w: int) -> np.ndarray:
    """(H, W) float32 the distance (pixels, along a row or column) of each pixel from the border of the
    data, the image's or where the pixels inside the data (`_inside`; None: all) end."""
    r, c = np.ogrid[:h, :w]
    dist = np.minimum(np.minimum(r, h - 1 - r), np.minimum(c, w - 1 - c)).astype(np.float32)
    if inside is not None:
        dist = np.minimum(dist, cv2.distanceTransform(inside.astype(np.uint8), cv2.DIST_C, 3) - 1)
    return dist


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
            gain[r, c] = np.sqrt((1 - f) * var_v[j0, r, c] * var_u[j0, r, c] + f * var_v[j1, r, c] * var_u[j1, r, c])
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
                out[r, c] = d * d / max(1.0 - var_v[r, c] * var_u[r, c], 1e-3)
    return out


@dataclass(frozen=True)
class Adaptive:
    """Window chosen per pixel, the one of least estimated risk (`_least_risk`) up to the largest that
    Lepski's test lets through (`_lepski`), over a ladder of windows doubling from the smallest.

    half_window: the smallest window's half size m (pixels) that the data need (`finest_scale`);
    finer_rungs: how many windows, each half the last, the ladder reaches below m (for a local feature
    narrower than the data's finest scale, or one near the border, where a window is one-sided and
    `Smoother.edge_span` times longer, so that it reaches that much farther from its pixel); levels: the
    number of windows from m up (those wider than the image are dropped); order: the local polynomial's;
    edge_order: that of the windows' above m one-sided fits at the border of the data (lower is less
    noisy there; the windows up to m keep `order`, for a local bump near the border); bias_weight: how
    much a window's squared bias counts against its noise variance in the risk; threshold: the cap, how
    many standard deviations of their difference the chosen window's fit may differ from any smaller
    one's; coverage: the least fraction of valid pixels among a window's pixels inside the data (the
    rest: filled holes) for it to be used (beyond the smallest); blend: the half size (in half windows
    m) of the median and box filters applied to the chosen window index.
    """

    half_window: int = 20
    levels: int = 4
    order: int = 3
    edge_order: int = 1
    finer_rungs: int = 1
    bias_weight: float = 2.0
    threshold: float = 2.5
    coverage: float = 0.9
    blend: float = 1.0

    @property
    def window(self) -> int:
        """The window of the data's finest scale, 2m + 1 (pixels); the ladder's `below` windows are finer."""
        return 2 * self.half_window + 1

    @property
    def below(self) -> int:
        """The windows of the ladder below `half_window`: as many of `finer_rungs` as keep a half window of
        at least 2 (a cubic's least)."""
        return sum(1 for k in range(1, self.finer_rungs + 1) if self.half_window >> k >= 2)

    def ladder(self) -> list[Smoother]:
        """The windows, smallest first: the `below` finer ones, then `levels` doubling from m."""
        lower = [Smoother(self.half_window >> k, self.order, self.order) for k in range(self.below, 0, -1)]
        return lower + [Smoother(self.half_window * 2 ** j, self.order, self.order if j == 0 else self.edge_order)
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


def window_halves(h: int, w: int) -> list[int]:
    """The candidate half windows of an h x w image, largest first: the window spanning a third of the
    smaller side, halved down to a half window of 2 (a cubic's least)."""
    halves = [max((min(h, w) // 3 - 1) // 2, 2)]
    while halves[-1] // 2 >= 2:
        halves.append(halves[-1] // 2)
    return halves


def deepest_half(h: int, w: int) -> int:
    """The largest candidate half window (`window_halves`) whose ladder keeps SCALE_LEVELS windows
    narrower than the image (or the smallest candidate)."""
    halves = window_halves(h, w)
    fits = [m for m in halves if 2 * m * 2 ** (SCALE_LEVELS - 1) + 1 < min(h, w)]
    return fits[0] if fits else halves[-1]


def finest_scale(first: np.ndarray, last: np.ndarray, valid: np.ndarray, order: int = 3) -> int:
    """The smallest window (half size, pixels) the fields need, from the data: what lens structure they
    have, and how fine, told from the noise and the display's own systematic errors (the pixel grid's
    staircase and moire) by their behaviour between two stage positions.

    first, last: (2, H, W) the points (x, y, any length unit) the pixels' rays reach on the first and
    last stage planes (their decoded display points); valid: (H, W) where both are. A ray's error from
    the lens is common to both planes (in pixels of each plane: the same displacement of the ray),
    while the noise and the display's systematic errors are not (other display pixels, another blur).
    With r_a, r_b each plane's remainder after the global polynomial (`_base`) in pixels (over each
    plane's mean pixel spacing), S = (r_a + r_b) / 2 holds the common structure and D = r_b - r_a none
    of it. For a window m, E[(S - S_m S)^2] - E[(D - S_m D)^2] / 4 is the common structure it fails to
    follow (bias^2) and E[(S_m D - S_top D)^2] / 2 the non-lens error it passes (variance, beyond the
    largest window's): their sum, averaged over blocks, is each block's risk, and each block has its
    best window. Candidates: `window_halves`; the smallest window is the largest candidate for which at
    most SCALE_SHARE of the blocks do better with a smaller one, and at most SCALE_DEPTH candidates
    below the top (ladders starting there keep four windows on a 1280 x 1024 image). Pixels outside `valid` are filled (`smooth_fields`'s windows) and left out."""
    h, w = valid.shape
    halves = window_halves(h, w)
    cap = deepest_half(h, w)
    r0, c0 = max((h - SCALE_REGION) // 2, 0), max((w - SCALE_REGION) // 2, 0)
    win = np.s_[r0:r0 + min(h, SCALE_REGION), c0:c0 + min(w, SCALE_REGION)]
    valid = valid[win]
    h, w = valid.shape
    halves = [m for m in halves if 2 * m + 1 < min(h, w)]
    if valid.mean() < 0.5 or len(halves) < 2:
        return cap
    rem = []
    for plane in (first, last):
        r = []
        for f in plane:
            f = np.asarray(f[win], np.float64)
            base = _base(f, valid, BASE_DEGREE)          # what finer windows follow, the cubic leaves
            spacing = np.median(np.hypot(*np.gradient(base[::4, ::4]))[valid[::4, ::4]]) / 4
            r.append(_masked(f - base, valid) / spacing)
        rem.append(np.stack(r))
    common, diff = (rem[0] + rem[1]) / 2, rem[1] - rem[0]
    fitter = _Fitter([Smoother(m, order, order) for m in halves], valid)
    fc = [fitter.fits(fitter.filled(f)) for f in common]          # (J, H, W) each
    fd = [fitter.fits(fitter.filled(f)) for f in diff]
    block = max(min(h, w) // SCALE_BLOCKS, 1)
    risk = _block_risk(common, diff, fc[0], fc[1], fd[0], fd[1], valid, block)
    best = np.asarray(halves)[np.argmin(risk, axis=0)]        # each block's best half window
    floor = halves[-1]
    for m in halves:
        if np.mean(best < m) <= SCALE_SHARE:
            floor = m
            break
    return min(floor, cap)


@numba.njit(cache=True, parallel=True)
def _block_risk(common, diff, fc0, fc1, fd0, fd1, valid, block):
    """(J, rows, columns) mean over the valid pixels of each block x block block of window j's risk:
    over the two components k, (common_k - its fit)^2 - (diff_k - its fit)^2 / 4 + (fit of diff_k -
    window 0's)^2 / 2 (fc, fd: (J, H, W) the windows' fits of each component of common and diff)."""
    nw = fc0.shape[0]
    h, w = valid.shape
    nbr, nbc = h // block, w // block
    out = np.zeros((nw, nbr, nbc))
    for b in numba.prange(nbr * nbc):
        br, bc = b // nbc, b % nbc
        n = 0
        acc = np.zeros(nw)
        for r in range(br * block, (br + 1) * block):
            for c in range(bc * block, (bc + 1) * block):
                if not valid[r, c]:
                    continue
                n += 1
                for j in range(nw):
                    e0, e1 = common[0, r, c] - fc0[j, r, c], common[1, r, c] - fc1[j, r, c]
                    d0, d1 = diff[0, r, c] - fd0[j, r, c], diff[1, r, c] - fd1[j, r, c]
                    p0, p1 = fd0[j, r, c] - fd0[0, r, c], fd1[j, r, c] - fd1[0, r, c]
                    acc[j] += e0 * e0 + e1 * e1 - (d0 * d0 + d1 * d1) / 4 + (p0 * p0 + p1 * p1) / 2
        for j in range(nw):
            out[j, br, bc] = acc[j] / max(n, 1)
    return out


def _base(field: np.ndarray, valid: np.ndarray, max_degree: int = BASE_DEGREE_MAX) -> np.ndarray:
    """The global polynomial removed before local smoothing, least-squares over every valid pixel, in
    Legendre polynomials of the normalised pixel coordinates: of total degree `BASE_DEGREE`, or higher
    (up to `BASE_DEGREE_MAX`) where the polynomial is the field's model. A higher degree's terms must
    lower the residual sum of squares by `BASE_SIGNIFICANCE` times the noise variance per term (the
    decoded fields' noise is correlated over a few pixels, so terms fitted to noise alone reach a few
    units): a degree too high for the field only adds its fit's noise, which grows towards the border.
    And what that degree leaves must be noise, within `BASE_RESIDUAL` times the pixel-to-pixel noise
    variance: where the field has local structure (a free-form lens's bumps), the local fits are its
    model, and a high-degree polynomial chasing the bumps only makes the remainder harder for them.
    max_degree = BASE_DEGREE: the cubic alone. The normal equations separate into products of the (H, W) arrays with small per-axis tables, so no
    design matrix of one row per pixel is built."""
    h, w = field.shape
    pu = np.polynomial.legendre.legvander(np.linspace(-1, 1, w), max_degree)    # (W, D)
    pv = np.polynomial.legendre.legvander(np.linspace(-1, 1, h), max_degree)    # (H, D)
    d = max_degree + 1
    pairs_u = (pu[:, :, None] * pu[:, None, :]).reshape(w, d * d)
    pairs_v = (pv[:, :, None] * pv[:, None, :]).reshape(h, d * d)
    # gram[j, l, i, k] = sum over valid pixels of P_i(u) P_k(u) P_j(v) P_l(v); rhs[j, i] of P_i(u) P_j(v) f
    gram = (pairs_v.T @ (valid.astype(np.float64) @ pairs_u)).reshape(d, d, d, d)
    sample = field[::8, ::8][valid[::8, ::8]]
    mean = float(np.mean(sample if sample.size else field[valid]))
    f0 = _masked(field - mean, valid)                     # ~centred: the residual sums stay exact
    rhs = pv.T @ (f0 @ pu)                 # (H, W) @ (W, D) first: 6x faster than (D, H) @ (H, W)
    total = float(np.dot(f0.ravel(), f0.ravel()))
    fits = []                                                     # (terms, coefficients, residual SS)
    for degree in range(BASE_DEGREE, max_degree + 1):
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


def _box_median(index: np.ndarray, levels: int, size: int, inside: np.ndarray | None) -> np.ndarray:
    """Median over a size x size box (of its pixels inside the data, if given) of an index map with
    values 0 .. levels-1: the median is >= j where at least half the box is >= j."""
    out = np.zeros(index.shape, np.float32)
    norm = None if inside is None else np.maximum(_box(inside.astype(np.float32), size), 1e-6)
    for j in range(1, levels):
        above = (index >= j) if inside is None else (index >= j) & inside
        share = _box(above.astype(np.float32), size)
        out += (share if norm is None else share / norm) >= 0.5
    return out


def _box(a: np.ndarray, size: int) -> np.ndarray:
    return cv2.blur(a, (size, size), borderType=cv2.BORDER_REPLICATE)


def _rejected_region(rejected: np.ndarray, half: int) -> np.ndarray:
    """(H, W) bool: where the finer rungs may serve inside the data, from the pixels whose Lepski test
    rejects the finest scale's window (half size `half`, pixels) against a finer one: their regions at
    least 2 e + 1 pixels wide (a morphological opening of radius e = REJECTED_OPENING x half drops the
    isolated rejections that noise makes), grown by the finest window's half size (a bump's flanks, where
    the test's step is small but the window still bends it)."""
    e = max(1, int(round(half * REJECTED_OPENING)))
    seed = cv2.erode(rejected.astype(np.uint8), np.ones((2 * e + 1, 2 * e + 1), np.uint8))
    return cv2.dilate(seed, np.ones((2 * (half + e) + 1, 2 * (half + e) + 1), np.uint8)) > 0


def _smooth_index(index: np.ndarray, levels: int, size: int, inside: np.ndarray | None = None) -> np.ndarray:
    """The chosen window index made smooth: median (drops isolated choices of a noisy risk estimate) and
    box-blurred over size x size pixels; with `inside`, each over the pixels inside the data only
    (outside them there is no index)."""
    med = _box_median(index, levels, size, inside)
    if inside is None:
        return _box(med, size)
    f = inside.astype(np.float32)
    return _box(np.where(inside, med, 0), size) / np.maximum(_box(f, size), 1e-6)


def _inside(valid: np.ndarray) -> np.ndarray | None:
    """The pixels the smoothing windows may span: the valid ones and the holes among them, the invalid
    pixels within FILL_PX of a valid one (filled with their nearest valid neighbour's remainder, which
    biases a fit by at most the remainder's change over FILL_PX); None where that is the whole image.
    Beyond it (the undecoded band past a display that does not fill the view, a large masked area) the
    windows stop at its border, one-sided as at the image's."""
    if valid.all():
        return None
    dist = cv2.distanceTransform((~valid).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    inside = dist <= FILL_PX
    return None if inside.all() else inside


class _Fitter:
    """The window fits of a ladder over an image's valid pixels: the per-axis weights, the runs of
    pixels inside the data (`_inside`) and their window tables, the per-pixel variance factors pv, pu
    (J, H, W) of the two axes, and the nearest-valid fill of the holes."""

    def __init__(self, ladder: list[Smoother], valid: np.ndarray):
        h, w = valid.shape
        nw = len(ladder)
        self.valid = valid
        self.axis_v = _axis_weights(ladder, h)
        self.axis_u = _axis_weights(ladder, w)
        self.inside = _inside(valid)
        var_v, var_u = self.axis_v[3], self.axis_u[3]
        if self.inside is None:
            self.runs_v = self.runs_u = (_NO_RUNS, _NO_RUNS)
            self.tab_v = self.tab_u = _WindowTables(ladder, np.zeros(1, np.int64), np.zeros(1, np.int64), 1)
            self.pv = np.broadcast_to(var_v[:, :, None], (nw, h, w))
            self.pu = np.broadcast_to(var_u[:, None, :], (nw, h, w))
            self.wv = self.wu = _NO_VAR                   # nothing per pixel to write
        else:
            self.runs_v, self.runs_u = _runs(self.inside, 0), _runs(self.inside, 1)
            self.tab_v, self.tab_u = _WindowTables(ladder, *self.runs_v, h), _WindowTables(ladder, *self.runs_u, w)
            self.pv = np.ascontiguousarray(np.broadcast_to(var_v[:, :, None], (nw, h, w)), np.float32)
            self.pu = np.ascontiguousarray(np.broadcast_to(var_u[:, None, :], (nw, h, w)), np.float32)
            self.wv, self.wu = self.pv, self.pu
        self.fill = None
        if not valid.all():
            self.fill = ndimage.distance_transform_edt(~valid, return_distances=False, return_indices=True)

    def filled(self, rem: np.ndarray) -> np.ndarray:
        """A field with its invalid pixels given their nearest valid neighbour's value."""
        return rem if self.fill is None else rem[self.fill[0], self.fill[1]]

    def fits(self, rem: np.ndarray) -> np.ndarray:
        """(J, H, W) float32 each window's fit of the (filled) field `rem`."""
        lo, hi, g, _, centre, scale = self.axis_v
        fits = _fit_axis0(rem, lo, hi, g, centre, scale, *self.runs_v, *self.tab_v.args(), self.wv)
        lo, hi, g, _, centre, scale = self.axis_u
        _fit_axis1(fits, lo, hi, g, centre, scale, *self.runs_u, *self.tab_u.args(), self.wu)
        return fits


def smooth_fields(fields: np.ndarray, valid: np.ndarray, smoother: Smoother | Adaptive) -> Regularised:
    """Smooth (K, H, W) fields over the valid pixels with one window (`Smoother`) or a window chosen
    per pixel (`Adaptive`). Windows stay inside the data (`_inside`): along each column and row a
    window ends where the run of pixels inside the data does, one-sided there as at the image border
    (the two passes of the separable fit each follow their own axis's runs)."""
    k, h, w = fields.shape
    if min(h, w) <= smoother.window:
        raise ValueError(f"image ({w}x{h}) is too small for a {smoother.window}-pixel smoothing window")
    ladder = smoother.ladder() if isinstance(smoother, Adaptive) else [smoother]
    ladder = [s for s in ladder if s.window < min(h, w)]
    nw = len(ladder)
    below = smoother.below if isinstance(smoother, Adaptive) else 0
    fitter = _Fitter(ladder, valid)
    inside, pv, pu = fitter.inside, fitter.pv, fitter.pu
    vf = valid.astype(np.float32)
    box = ladder[below].window
    count = _box(vf, box)
    # the largest window allowed at each pixel: one whose share of valid pixels among those inside the
    # data reaches `coverage` (holes are filled, not fitted)
    top = np.full((h, w), below, np.uint8)
    for j, s in enumerate(ladder[below + 1:], below + 1):
        share = _box(vf, s.window)
        if inside is not None:
            share = share / np.maximum(_box(inside.astype(np.float32), s.window), 1e-6)
        top[share >= smoother.coverage] = j
    windows = np.array([s.window for s in ladder], np.float32)
    edge = _edge_distance(inside, h, w) if nw > 1 else None
    out = np.empty((k, h, w))
    noise = np.empty((k, h, w), np.float32)
    gain = np.empty((k, h, w), np.float32)
    window = np.zeros((h, w), np.float32)
    for i in range(k):
        base = _base(fields[i], valid)
        rem = fitter.filled(_masked(fields[i] - base, valid))
        fits = fitter.fits(rem)
        e2 = _box(_residual2(rem, fits[below], pv[below], pu[below], valid), box)
        sigma = np.sqrt(np.maximum(e2, 0) / np.maximum(count, 1e-6))
        index = np.zeros((h, w), np.float32)
        if nw > 1:
            cap = _lepski(fits, sigma, pv, pu, top, smoother.threshold)
            index = _least_risk(fits, sigma, pv, pu, cap, ladder, edge, smoother.bias_weight)
            # the finer rungs only within a window of the border of the data, or over a region where
            # Lepski's test rejects the finest scale's window itself (`_rejected_region`)
            finer = _rejected_region(cap < below, ladder[below].half_window) | (edge < ladder[below].window)
            index = np.maximum(index, np.where(finer, 0, below).astype(np.uint8))
            size = 2 * int(round(smoother.blend * ladder[below].half_window)) + 1
            index = _smooth_index(index, nw, size, inside)
        out[i], gain[i], win = _blend(fits, index, pv, pu, base, valid, windows)
        noise[i] = np.where(valid, sigma, np.nan)
        window += win / k
    return Regularised(out, noise, gain, window)

"""2D subset DIC between a reference image and one or more deformed images.

`correlate_points` registers a list of points given initial warps (the building block, also for stereo
matching); `register_image` measures a whole grid in one deformed image from starting warps, seeds found
by ZNCC search and reliability-guided propagation; `correlate_pair` runs it for one pair of images
(`stereodic.dic.sequence` for a series of deformed images).
Displacements in pixels, u along x (columns), v along y (rows), at points of the reference image.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Iterable, Sequence

import numpy as np

from stereodic.dic.background import side_by_side
from stereodic.dic.grid import Grid
from stereodic.dic.icgn import (INCONSISTENT, LOW_TEXTURE, LOW_ZNCC, OK, SHAPE_PARAMS, UNREACHED,
                                quadratic_fit_matrix, reference_status, reference_width, shift_warp, solve_points)
from stereodic.dic.initial_guess import Features, consistent_matches, feature_guess, image_features, search_integer
from stereodic.dic.interpolation import BSplineImage
from stereodic.dic.outliers import inconsistent
from stereodic.dic.propagation import guesses_from_lattice, propagate
from stereodic.dic.texture import estimate_noise, predicted_noise, sssig


@dataclass(frozen=True)
class DicSettings:
    """subset: side in pixels (odd); shape: 'affine' or 'quadratic'; order: B-spline order (3 or 5);
    prefilter_sigma: Gaussian low-pass of both images before interpolation (pixels, 0 = none; lowers
    the interpolation bias); tol: convergence bound on the warp update (pixels at the subset edge);
    min_zncc: points below are flagged; seed_zncc: a seed needs at least this; feature_guess: every point
    starts from a local affine of feature matches (`initial_guess.feature_guess`) where nothing better
    is known, so that any motion the images allow is found, and the seeds' ZNCC search is centred on it;
    search_radius: ZNCC search range of seeds (pixels, about the feature guess, or about zero without
    one); max_seeds: seed attempts per image; max_noise_px: points whose
    predicted random error (`texture.predicted_noise`) exceeds it are flagged low_texture; max_jump_px:
    points whose displacement departs from their neighbours' median by more than this are solved again
    from their neighbours, and flagged inconsistent if they still do (`outliers`)."""

    subset: int = 21
    shape: str = "affine"
    order: int = 3
    prefilter_sigma: float = 0.7
    max_iter: int = 30
    tol: float = 1e-3
    min_zncc: float = 0.8
    seed_zncc: float = 0.9
    feature_guess: bool = True
    search_radius: int = 40
    max_seeds: int = 20
    max_noise_px: float = 0.1
    max_jump_px: float = 1.0

    @property
    def half(self) -> int:
        return self.subset // 2

    @property
    def nparams(self) -> int:
        return SHAPE_PARAMS[self.shape]


@dataclass
class PointResult:
    """Per point: warp (N, n) parameters (see icgn), zncc, iterations, status (icgn status codes)."""

    warp: np.ndarray
    zncc: np.ndarray
    iterations: np.ndarray
    status: np.ndarray

    @property
    def u(self) -> np.ndarray:
        """Displacement along x (pixels); NaN where status is not OK."""
        return np.where(self.status == OK, self.warp[:, 0], np.nan)

    @property
    def v(self) -> np.ndarray:
        """Displacement along y (pixels); NaN where status is not OK."""
        return np.where(self.status == OK, self.warp[:, self.warp.shape[1] // 2], np.nan)


@dataclass
class DicField:
    """Result on a grid for one deformed image. u, v (ny, nx): displacement of each grid point from its
    reference position (pixels, NaN where not OK; for incremental DIC, summed over the steps); `points`:
    this image's registration, flat in grid order (for incremental DIC, of the step from the previous
    image, with the subsets taken around the points' positions there); noise_px (ny, nx): the predicted
    random error of each point (pixels, `texture.predicted_noise`, NaN where the subset leaves the image);
    incremental (ny, nx) bool: the points registered from the previous image (`stereodic.dic.sequence`),
    None for a single pair."""

    grid: Grid
    points: PointResult
    u: np.ndarray
    v: np.ndarray
    noise_px: np.ndarray
    incremental: np.ndarray | None = None

    @property
    def zncc(self) -> np.ndarray:
        return self.points.zncc.reshape(self.grid.shape)

    @property
    def status(self) -> np.ndarray:
        return self.points.status.reshape(self.grid.shape)

    @property
    def ok(self) -> np.ndarray:
        return self.status == OK


def _arrays(n: int, nparams: int):
    return (np.zeros((n, nparams)), np.full(n, np.nan), np.zeros(n, np.int32),
            np.full(n, UNREACHED, np.int8))


def correlate_points(ref: BSplineImage, dfm: BSplineImage, xs: np.ndarray, ys: np.ndarray,
                     guess: np.ndarray, *, settings: DicSettings = DicSettings(),
                     subsets: np.ndarray | None = None, rows: np.ndarray | None = None) -> PointResult:
    """Register the subsets centred on given points by IC-GN (`stereodic.dic.icgn`), in parallel.

    Parameters
    ----------
    ref, dfm : BSplineImage
        The reference and deformed images' B-splines (`BSplineImage.from_image`).
    xs, ys : (N,) float
        The subset centres in the reference image, pixels (x = column, y = row; sub-pixel allowed).
    guess : (N, 2) or (N, n) float
        Starting displacements (u, v), pixels, or full warps (n parameters of `settings.shape`).
    settings : DicSettings
        Subset size, shape function, iterations, tolerance, ZNCC threshold.
    subsets : (M, k) float64, optional
        The reference side of the subsets computed beforehand (`reference_subsets`); the result is the
        same as without.
    rows : (N,) int64, optional
        The row of `subsets` of each point; None: row k for point k.

    Returns
    -------
    result : PointResult
        ``warp`` (N, n) parameters (u, v in pixels), ``zncc`` (N,), ``iterations`` (N,), ``status`` (N,)
        int8 (`stereodic.dic.icgn` codes); ``u``, ``v`` (N,) pixels, NaN where the status is not OK.
    """
    xs = np.ascontiguousarray(xs, np.float64)
    ys = np.ascontiguousarray(ys, np.float64)
    n = settings.nparams
    warp, zncc, iters, status = _arrays(xs.size, n)
    guess = np.asarray(guess, np.float64)
    if guess.shape[1] == 2:
        warp[:, 0] = guess[:, 0]
        warp[:, n // 2] = guess[:, 1]
    else:
        warp[:] = guess
    solve_points(ref.coef, ref.pixel_gradients(), dfm.coef, ref.order, ref.width, ref.height, xs, ys,
                 settings.half, warp, quadratic_fit_matrix(settings.half), settings.max_iter, settings.tol,
                 settings.min_zncc, zncc, iters, status, subsets, rows)
    return PointResult(warp, zncc, iters, status)


def subset_status(ref: BSplineImage, xs: np.ndarray, ys: np.ndarray, settings: DicSettings = DicSettings()
                  ) -> np.ndarray:
    """Whether the reference subsets at (xs, ys) can be registered at all, from the reference alone:
    (N,) int8 status OK, NO_TEXTURE or OUTSIDE."""
    st = np.empty(len(xs), np.int8)
    reference_status(ref.coef, ref.pixel_gradients(), ref.order, ref.width, ref.height,
                     np.ascontiguousarray(xs, np.float64), np.ascontiguousarray(ys, np.float64), settings.half,
                     settings.nparams, st)
    return st


def reference_subsets(ref: BSplineImage, xs: np.ndarray, ys: np.ndarray, settings: DicSettings = DicSettings()
                      ) -> np.ndarray:
    """The reference side of the subsets at (xs, ys) (their steepest-descent sums and Hessian, what IC-GN
    computes first for every registration): (N, icgn.reference_width(nparams)) float64, for
    `correlate_points(subsets=...)`; it holds each point's status (OK, NO_TEXTURE or OUTSIDE) in column 0."""
    xs, ys = np.ascontiguousarray(xs, np.float64), np.ascontiguousarray(ys, np.float64)
    data = np.empty((xs.size, reference_width(settings.nparams)))
    reference_status(ref.coef, ref.pixel_gradients(), ref.order, ref.width, ref.height, xs, ys, settings.half,
                     settings.nparams, np.empty(xs.size, np.int8), data)
    return data


JUMP_SHARE = 0.1  # a start that fails on more than this share of its points: the motion jumped, guess again
LATTICE = 4  # stride of the coarse lattice that large grids are propagated on first


class _PairSolver:
    """State of one reference/deformed pair on a grid while seeds and propagation fill it."""

    def __init__(self, ref: BSplineImage, dfm: BSplineImage, ref_img: np.ndarray, def_img: np.ndarray,
                 grid: Grid, xs: np.ndarray, ys: np.ndarray, settings: DicSettings, search: Callable | None = None,
                 subsets: np.ndarray | None = None):
        self.ref, self.dfm, self.ref_img, self.def_img = ref, dfm, ref_img, def_img
        self.subsets = subsets  # reference_subsets(ref, xs, ys), or None
        self.search = search or search_integer
        self.grid, self.xs, self.ys, self.s = grid, xs, ys, settings
        self.warp, self.zncc, self.iters, self.status = _arrays(xs.size, settings.nparams)
        self.done = (~grid.active.ravel()).astype(np.int8)
        self.fit = quadratic_fit_matrix(settings.half)
        self.seedable = np.ones(xs.size, bool)  # where automatic seeds may be tried
        self.guess = np.full((xs.size, 2), np.nan)  # the feature guess's (u, v), pixels, where there is one

    def solve(self, idx: np.ndarray) -> None:
        """Solve points `idx` from the warps already in self.warp."""
        s = self.s
        res = correlate_points(self.ref, self.dfm, self.xs[idx], self.ys[idx], self.warp[idx], settings=s,
                               subsets=self.subsets, rows=None if self.subsets is None else np.asarray(idx, np.int64))
        self.warp[idx], self.zncc[idx], self.iters[idx], self.status[idx] = (
            res.warp, res.zncc, res.iterations, res.status)
        self.done[idx] = 1

    def start_from_features(self, ref_features: Features, dfm_features: Features) -> None:
        """Solve every pending point from the feature guess (`feature_guess`) in a few parallel batches:
        on large grids the points of the lattice (every LATTICE-th row and column) first, then every other
        point from the blend of its solved lattice corners (`guesses_from_lattice`: a start within a
        small fraction of a pixel where the field is smooth, so that IC-GN needs fewer iterations than from
        the features), then the points no solved corner reaches from their own feature guess. Points that
        fail or end below the seed ZNCC stay pending (for propagation from their neighbours)."""
        idx = np.flatnonzero(self.done == 0)
        if idx.size == 0:
            return
        matches = consistent_matches(ref_features, dfm_features)
        self._lattice_first(idx, lambda i: self._solve_from(i, matches))

    def start_from_warps(self, idx: np.ndarray) -> None:
        """Solve the pending points `idx` from the warps in self.warp (a start: e.g. the previous image's
        warps) as `start_from_features` does from the feature guess: on large grids the lattice points
        from their start, then every other point from the blend of its solved lattice corners (closer
        than a start that the motion has since left), the points no solved corner reaches from their
        own start. Points that fail or end below the seed ZNCC stay pending."""
        self._lattice_first(idx, lambda i: self._solve_from(i, None))

    def _lattice_first(self, idx: np.ndarray, own: Callable[[np.ndarray], None]) -> None:
        """Solve the pending points `idx`: `own(points)` solves points from their own start; on large
        grids the lattice's first, then the others from their lattice corners (`start_from_features`)."""
        ny, nx = self.grid.shape
        if min(ny, nx) >= 4 * LATTICE:
            r, c = np.divmod(idx, nx)
            own(idx[(r % LATTICE == 0) & (c % LATTICE == 0)])
            blended = guesses_from_lattice(self.xs, self.ys, nx, LATTICE, self.warp, self.zncc, self.status,
                                           self.done)
            member = np.zeros(self.xs.size, bool)
            member[idx] = True
            self._solve_from(blended[member[blended]], None)
        own(idx[(self.done[idx] == 0) & (self.status[idx] == UNREACHED)])

    def _solve_from(self, idx: np.ndarray, matches: tuple[np.ndarray, np.ndarray] | None) -> None:
        """Solve points `idx` from their feature guess (`feature_guess` of `matches`; None: from
        self.warp); those that fail or end below the seed ZNCC return to pending."""
        if idx.size == 0:
            return
        if matches is not None:
            guess, ok = feature_guess(matches, self.xs[idx], self.ys[idx])
            idx, guess = idx[ok], guess[ok]
            nb = self.s.nparams // 2
            self.guess[idx] = guess[:, [0, 3]]
            self.warp[idx] = 0.0
            self.warp[idx, 0:3] = guess[:, 0:3]
            self.warp[idx, nb:nb + 3] = guess[:, 3:6]
        self.solve(idx)
        self.done[idx[(self.status[idx] != OK) | ~(self.zncc[idx] >= self.s.seed_zncc)]] = 0

    def propagate(self, stride: int) -> None:
        s = self.s
        propagate(self.ref.coef, self.ref.pixel_gradients(), self.dfm.coef, self.ref.order, self.ref.width,
                  self.ref.height, self.xs, self.ys, self.grid.shape[1], stride, s.half, self.warp, self.fit,
                  s.max_iter, s.tol, s.min_zncc, self.zncc, self.iters, self.status, self.done, self.subsets)

    def flag_untextured(self, idx: np.ndarray) -> np.ndarray:
        """Mark the points of `idx` whose reference subset cannot be registered (no texture, outside)
        as done; returns the others."""
        st = subset_status(self.ref, self.xs[idx], self.ys[idx], self.s)
        bad = idx[st != OK]
        self.status[bad] = st[st != OK]
        self.done[bad] = 1
        return idx[st == OK]

    def seed(self, k: int, stride: int) -> bool:
        """Integer ZNCC search then IC-GN at point k, confirmed by its neighbours (`stride` grid points
        away): a seed is kept if its ZNCC reaches seed_zncc and at least two of its neighbours (all, if
        fewer) converge from its warp; a wide search can otherwise lock on a look-alike spot. A
        rejected seed is flagged LOW_ZNCC and its neighbours return to pending."""
        s = self.s
        nb = s.nparams // 2
        good = (self.done == 1) & (self.status == OK)
        centre = (0, 0)
        if np.isfinite(self.guess[k]).all():
            centre = (int(round(self.guess[k, 0])), int(round(self.guess[k, 1])))
        elif good.any():
            centre = (int(round(np.median(self.warp[good, 0]))), int(round(np.median(self.warp[good, nb]))))
        x, y = int(round(self.xs[k])), int(round(self.ys[k]))
        du, dv, _ = self.search(self.ref_img, self.def_img, x, y, s.half, s.search_radius, centre)
        self.warp[k] = 0.0
        self.warp[k, 0] = du + (x - self.xs[k])
        self.warp[k, nb] = dv + (y - self.ys[k])
        self.solve(np.array([k]))
        if self.status[k] != OK:
            return False
        ny, nx = self.grid.shape
        r, c = divmod(k, nx)
        nbrs = np.array([rr * nx + cc for rr, cc in ((r - stride, c), (r + stride, c), (r, c - stride),
                                                     (r, c + stride))
                         if 0 <= rr < ny and 0 <= cc < nx and self.done[rr * nx + cc] == 0], dtype=np.int64)
        for q in nbrs:
            shift_warp(self.warp[k], self.xs[q] - self.xs[k], self.ys[q] - self.ys[k], self.warp[q])
        self.solve(nbrs)
        if self.zncc[k] >= s.seed_zncc and np.sum(self.status[nbrs] == OK) >= min(2, nbrs.size):
            return True
        self.status[k] = LOW_ZNCC
        self.done[nbrs] = 0
        self.status[nbrs] = UNREACHED
        return False

    def fill(self, seeds: Sequence[int]) -> None:
        """Solve every point reachable from what is solved and from seeds; flag the rest UNREACHED.

        Large grids go in two stages: propagation over a lattice of every LATTICE-th row and column,
        then one parallel sweep of all other points from a blend of their lattice corners; points
        that fail there, and those the lattice did not reach, are propagated again point by point."""
        ny, nx = self.grid.shape
        stride = LATTICE if min(ny, nx) >= 4 * LATTICE else 1
        self.grow(seeds, stride)
        if stride > 1:
            idx = guesses_from_lattice(self.xs, self.ys, nx, stride, self.warp, self.zncc, self.status,
                                       self.done)
            self.solve(idx)
            self.done[idx[self.status[idx] != OK]] = 0  # a second chance from their neighbours
            self.grow(seeds, 1)
        self.status[self.done == 0] = UNREACHED

    def grow(self, seeds: Sequence[int], stride: int) -> None:
        """Propagate (every `stride` points) from what is solved, then from `seeds`, then from
        automatic seeds among the pending seedable points on the lattice (nearest to the centre of the
        pending ones first), up to max_seeds attempts. Seeds without texture are flagged and skipped; if
        points remain after the first seed, all pending points without texture are flagged so that
        seeds avoid them."""
        ny, nx = self.grid.shape
        rows, cols = np.divmod(np.arange(self.xs.size), nx)
        on_lattice = (rows % stride == 0) & (cols % stride == 0)
        self.propagate(stride)
        attempts = 0
        on_lattice &= self.grid.active.ravel()
        lattice = np.flatnonzero(on_lattice)
        # each seed moves to its nearest lattice point
        queue = [int(lattice[np.argmin((self.xs[lattice] - self.xs[k]) ** 2
                                       + (self.ys[lattice] - self.ys[k]) ** 2)])
                 for k in seeds] if lattice.size else []
        screened = False
        while attempts < self.s.max_seeds:
            pending = np.flatnonzero((self.done == 0) & on_lattice & (self.seedable | bool(queue)))
            if pending.size == 0:
                break
            if queue:
                k = queue.pop(0)
                if self.done[k] != 0:
                    continue
            else:
                if attempts > 0 and not screened:  # once, only if the first seeds left points over
                    pending = self.flag_untextured(pending)
                    screened = True
                    if pending.size == 0:
                        break
                cx, cy = self.xs[pending].mean(), self.ys[pending].mean()
                k = pending[np.argmin((self.xs[pending] - cx) ** 2 + (self.ys[pending] - cy) ** 2)]
            attempts += 1
            if self.flag_untextured(np.array([k])).size and self.seed(k, stride):
                self.propagate(stride)

    def screen(self, noise_px: np.ndarray) -> None:
        """Flag solved points with a predicted error above max_noise_px (low_texture); solve the points
        inconsistent with their neighbours (`outliers`) again from their neighbours, and flag those that
        stay so."""
        s = self.s
        ok = self.status == OK
        self.status[ok & (noise_px > s.max_noise_px)] = LOW_TEXTURE
        nb = s.nparams // 2
        for again in (True, False):
            ok = self.status == OK
            bad = inconsistent(self.warp[:, 0].reshape(self.grid.shape), self.warp[:, nb].reshape(self.grid.shape),
                               ok.reshape(self.grid.shape), s.max_jump_px).ravel()
            if not bad.any():
                return
            if again:
                self.status[bad] = UNREACHED
                self.done[bad] = 0
                self.propagate(1)
                self.status[self.done == 0] = UNREACHED
            else:
                self.status[bad] = INCONSISTENT

    def result(self) -> PointResult:
        self.zncc[self.status == UNREACHED] = np.nan
        return PointResult(self.warp, self.zncc, self.iters, self.status)


def seed_indices(grid: Grid, seeds: Iterable[tuple[float, float]]) -> list[int]:
    """Flat indices of the active grid points nearest to each (x, y) seed position (pixels)."""
    X, Y = grid.points()
    act = np.flatnonzero(grid.active.ravel())
    return [int(act[np.argmin((X[act] - x) ** 2 + (Y[act] - y) ** 2)]) for x, y in seeds] if act.size else []


REFERENCE_CACHE_BYTES = 256 * 2 ** 20  # at most this much memory for the kept subsets of one reference image


@dataclass
class ImageRef:
    """An image as the reference of a registration: its pixels, its B-spline and (computed on first use)
    its white-noise estimate `sigma` (grey levels, `texture.estimate_noise`). With `keep_subsets` (the
    reference image of a sequence, registered against image after image on the same points) the
    reference side of its subsets is kept between registrations (`subsets`)."""

    image: np.ndarray
    bspline: BSplineImage
    keep_subsets: bool = False
    _sigma: float | None = field(default=None, repr=False, compare=False)
    _sssig: dict = field(default_factory=dict, repr=False, compare=False)
    _subsets: dict = field(default_factory=dict, repr=False, compare=False)
    _features: Features | None = field(default=None, repr=False, compare=False)

    @classmethod
    def prepare(cls, image: np.ndarray, settings: DicSettings = DicSettings(),
                bspline: BSplineImage | None = None, *, keep_subsets: bool = False) -> "ImageRef":
        """The reference data of `image` (its B-spline is computed unless given)."""
        if bspline is None:
            bspline = BSplineImage.from_image(image, order=settings.order,
                                              prefilter_sigma=settings.prefilter_sigma)
        return cls(image, bspline, keep_subsets)

    @property
    def sigma(self) -> float:
        if self._sigma is None:
            self._sigma = estimate_noise(self.image)
        return self._sigma

    def features(self) -> Features:
        """`initial_guess.image_features` of the image (computed on first use)."""
        if self._features is None:
            self._features = image_features(self.image)
        return self._features

    def matches(self, image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """`initial_guess.consistent_matches` of the image's features with those of `image`: what
        `register_image` starts from without a start, kept for a read-only `image` (`stereodic.dic.kept`),
        so that a caller can make them ahead of the registration (beside other work)."""
        return consistent_matches(self.features(), image_features(image))

    def noise(self, xs: np.ndarray, ys: np.ndarray, half: int) -> np.ndarray:
        """`texture.predicted_noise` of subsets at (xs, ys) in this image (its SSSIG maps kept per size)."""
        if half not in self._sssig:
            self._sssig[half] = sssig(self.bspline, half)
        return predicted_noise(self.bspline, xs, ys, half, self.sigma, self._sssig[half])

    def subsets(self, xs: np.ndarray, ys: np.ndarray, settings: DicSettings) -> np.ndarray | None:
        """`reference_subsets` of the points (xs, ys) if kept (`keep_subsets`): computed on first use,
        kept for one set of points per subset size and shape function; None for points off the pixel
        centres (the reference subsets of tracked, moving points) or where they would take more than
        REFERENCE_CACHE_BYTES."""
        if not self.keep_subsets:
            return None
        key = (settings.half, settings.nparams)
        kept = self._subsets.get(key)
        if kept is not None and np.array_equal(kept[0], xs) and np.array_equal(kept[1], ys):
            return kept[2]
        if (xs.size * reference_width(settings.nparams) * 8 > REFERENCE_CACHE_BYTES
                or not (np.all(xs == np.floor(xs)) and np.all(ys == np.floor(ys)))):
            return None
        data = reference_subsets(self.bspline, xs, ys, settings)
        self._subsets[key] = (np.array(xs, np.float64), np.array(ys, np.float64), data)
        return data

    def status(self, xs: np.ndarray, ys: np.ndarray, settings: DicSettings) -> np.ndarray:
        """`subset_status` of the points (xs, ys): read from the kept subsets (`subsets`) where they are
        kept, computed otherwise."""
        data = self.subsets(xs, ys, settings)
        return subset_status(self.bspline, xs, ys, settings) if data is None else data[:, 0].astype(np.int8)


def register_image(ref: ImageRef, def_img: np.ndarray, def_b: BSplineImage, grid: Grid, xs: np.ndarray,
                   ys: np.ndarray, settings: DicSettings = DicSettings(), *, seeds: Sequence[int] = (),
                   search: Callable | None = None, start: PointResult | None = None,
                   translation_only: bool = False, skip: np.ndarray | None = None,
                   skip_status: np.ndarray | None = None) -> tuple[PointResult, np.ndarray]:
    """Register the grid's points, whose subsets sit at (xs, ys) in the reference image (flat, grid
    order, pixels), in the deformed image (`def_img` and its B-spline).

    start: warps to start from (points with status OK), e.g. the previous image's result (only its
    translations with `translation_only`; on large grids the lattice's points from there, the others
    from the blend of their solved lattice corners where they have one: `_PairSolver.start_from_warps`);
    points that fail from there, or end below the seed ZNCC, start again from their neighbours. Without
    a start (or one that measured nothing), or when it fails on more than JUMP_SHARE of its points (the
    motion jumped), every pending point is first solved from its feature guess (`settings.feature_guess`:
    `initial_guess.feature_guess`), in a few large batches. The others are reached by reliability-guided
    propagation from these and from seeds (`seeds`: flat grid indices; `search`: the seeds' integer search, see
    `correlate_sequence`); with a start that measured points, automatic seeds are tried only at those
    (a point that failed in the previous image is reached from its neighbours, not searched for again at
    every image). skip: (N,) bool points left alone, reported with `skip_status` (N,) int8 (default
    UNREACHED). Returns the registration and the predicted random error (N,) of each point
    (pixels, `texture.predicted_noise` at (xs, ys) in the reference)."""
    s = settings
    nb = s.nparams // 2
    solver = _PairSolver(ref.bspline, def_b, ref.image, def_img, grid, xs, ys, s, search, ref.subsets(xs, ys, s))
    if skip is not None:
        solver.done[skip] = 1
        solver.status[skip] = UNREACHED if skip_status is None else skip_status[skip]
    if start is not None:
        if (start.status == OK).any():
            solver.seedable = start.status == OK
        carry = np.flatnonzero((start.status == OK) & (solver.done == 0))
        if translation_only:
            solver.warp[carry] = 0.0
            solver.warp[carry, 0] = start.warp[carry, 0]
            solver.warp[carry, nb] = start.warp[carry, nb]
        else:
            solver.warp[carry] = start.warp[carry]
        solver.start_from_warps(carry)
        # a second chance from their neighbours for the failed points, and for those below the seed
        # ZNCC: a stale start (a larger motion than the last image's) can end in a false optimum
        redo = carry[solver.done[carry] == 0]
    if s.feature_guess and (start is None or carry.size == 0 or redo.size > JUMP_SHARE * carry.size):
        # both images' features at once, and the reference's noise estimate (needed after the solve)
        # meanwhile: OpenCV and numpy's loops release the GIL
        ref_features, dfm_features, _ = side_by_side(ref.features, lambda: image_features(def_img),
                                                     lambda: ref.sigma)
        solver.start_from_features(ref_features, dfm_features)
    solver.fill(seeds)
    noise = ref.noise(xs, ys, s.half)
    solver.screen(noise)
    return solver.result(), noise


def correlate_pair(ref_img: np.ndarray, def_img: np.ndarray, grid: Grid, *,
                   settings: DicSettings = DicSettings(), seeds: Iterable[tuple[float, float]] = (),
                   search: Callable | None = None, start: PointResult | None = None) -> DicField:
    """2D DIC of one deformed image against the reference on a grid (`register_image`).

    Parameters
    ----------
    ref_img, def_img : (H, W) array
        The reference and deformed images, any real dtype.
    grid : Grid
        The points to measure, reference pixels (`make_grid`).
    settings : DicSettings
        Subset, shape function, interpolation, thresholds.
    seeds : iterable of (x, y)
        Start points of the propagation, reference pixels (besides the automatic seeds).
    search : callable, optional
        The seeds' integer search, `search_integer`'s signature; None: that 2-D search.
    start : PointResult, optional
        Warps (grid order) to start from, as if a previous image's result (its points with status OK).

    Returns
    -------
    field : DicField
        ``u``, ``v`` (ny, nx) displacements of the grid points, pixels (u along x, v along y), NaN where
        not OK; ``points`` (the PointResult in grid order), ``noise_px`` (ny, nx) predicted random error,
        pixels; ``zncc``, ``status``.
    """
    X, Y = grid.points()
    ref = ImageRef.prepare(ref_img, settings)
    def_b = BSplineImage.from_image(def_img, order=settings.order, prefilter_sigma=settings.prefilter_sigma)
    res, noise = register_image(ref, def_img, def_b, grid, X, Y, settings, seeds=seed_indices(grid, seeds),
                                search=search, start=start)
    return DicField(grid, res, res.u.reshape(grid.shape), res.v.reshape(grid.shape), noise.reshape(grid.shape))

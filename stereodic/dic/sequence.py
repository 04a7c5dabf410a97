"""Tracking a grid through a series of deformed images, switching point by point to incremental DIC.

Every point is registered directly against the reference image, each image starting from the previous
image's warps moved on by the point's last change of displacement (velocity-based starts, as DICe's
VELOCITY_BASED initialisation: a loading that goes on at a steady rate lands the start within a small
fraction of a pixel, and IC-GN needs about one iteration less; `register_image`): the reference subset
is compared with every image, so errors do not add up over the sequence. A point whose match against the reference decorrelates - its ZNCC falls below
`switch_zncc`, or it diverges, is left unreached, inconsistent or outside the image - switches to incremental
(updated-reference) correlation for good: from then on it is registered from the previous image to the
current one, its subset taken around its position in the previous image, and its displacement goes on
counting from its reference position (u, v are always relative to the reference image: the positions
are tracked, not the increments added). A point switches only where the incremental match is better
than the direct one. With `incremental` every point is incremental from the first image (large
deformations throughout, at the cost of adding up the per-step errors). An incremental point that is lost
stays lost.

`TrackCarry` is everything the next image needs from this one (it can be saved and restored, so a run can
stop and resume); `register_direct`, `switch_candidates`, `register_steps` and `merge_track` are the
stages of one image, which the stereo pipeline (`stereodic.dic3d.stereo`) runs with its own switching
criterion; `track_image` chains them; `correlate_sequence` runs a whole series.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Callable, Iterable, Iterator, Sequence

import cv2
import numpy as np

from stereodic.dic.background import threads
from stereodic.dic.correlate import DicField, DicSettings, ImageRef, PointResult, register_image, seed_indices
from stereodic.dic.grid import Grid
from stereodic.dic.icgn import DIVERGED, INCONSISTENT, LOW_ZNCC, OK, OUTSIDE, UNREACHED
from stereodic.dic.interpolation import BSplineImage

SWITCH_ZNCC = 0.9  # default: a point whose ZNCC against the reference falls below switches to incremental
# failures an updated reference can cure (a subset "outside" the image may be one whose warp went astray)
DECORRELATED = (LOW_ZNCC, DIVERGED, UNREACHED, INCONSISTENT, OUTSIDE)

MARGIN = 2  # pixels: a subset this far inside the image whose match went "outside" may have a stray warp
ANCHOR = 2  # grid points around a switch candidate whose direct points are also registered incrementally
CARRY_KEYS = ("incremental", "x", "y", "ok", "lost", "lost_status", "velocity")


@dataclass
class TrackCarry:
    """What the next image needs from the last one tracked (flat arrays in grid order, N points).

    direct: the last registration against the reference (warps about the grid points), None before the
    first image; step: the last incremental registration (previous image -> last image, warps about the
    points' positions in the previous image), or None; incremental (N,) bool: the points registered image
    to image; x, y (N,): the points' positions in the last image (pixels; their last known position where
    they were not measured); ok (N,) bool: measured in the last image; lost (N,) bool: incremental points
    lost for good, lost_status (N,) int8 their status then; velocity (N, 2): the last change of the
    direct translation (u, v) from one image to the next (pixels; 0 where the point was not measured
    directly in both), which the next image's start adds; images: how many images were tracked."""

    direct: PointResult | None
    step: PointResult | None
    incremental: np.ndarray
    x: np.ndarray
    y: np.ndarray
    ok: np.ndarray
    lost: np.ndarray
    lost_status: np.ndarray
    velocity: np.ndarray
    images: int = 0

    @classmethod
    def initial(cls, grid: Grid, incremental: bool = False, start: PointResult | None = None) -> "TrackCarry":
        """Before the first deformed image: every point at its reference position; all incremental with
        `incremental`; `start`: warps the first image starts from, as if a previous image's result."""
        X, Y = grid.points()
        n = X.size
        return cls(start, None, np.full(n, bool(incremental)), X, Y, grid.active.ravel().copy(),
                   np.zeros(n, bool), np.zeros(n, np.int8), np.zeros((n, 2)))

    def to_arrays(self, prefix: str) -> dict[str, np.ndarray]:
        """Arrays (for an npz file) named prefix + key; `from_arrays` reads them back exactly."""
        out = {prefix + k: getattr(self, k) for k in CARRY_KEYS}
        out[prefix + "images"] = np.array(self.images)
        for name in ("direct", "step"):
            res = getattr(self, name)
            if res is not None:
                out.update({f"{prefix}{name}_{k}": getattr(res, k) for k in ("warp", "zncc", "iterations", "status")})
        return out

    @classmethod
    def from_arrays(cls, arrays, prefix: str) -> "TrackCarry":
        def result(name):
            if f"{prefix}{name}_warp" not in arrays:
                return None
            return PointResult(*(np.array(arrays[f"{prefix}{name}_{k}"]) for k in ("warp", "zncc", "iterations", "status")))

        return cls(result("direct"), result("step"), *(np.array(arrays[prefix + k]) for k in CARRY_KEYS),
                   int(arrays[prefix + "images"]))


def register_direct(ref: ImageRef, img: np.ndarray, img_b: BSplineImage, grid: Grid, carry: TrackCarry,
                    settings: DicSettings, *, seeds: Sequence[int] = (), search: Callable | None = None
                    ) -> tuple[PointResult, np.ndarray] | tuple[None, None]:
    """The points that are not incremental, registered against the reference from the last direct warps
    moved on by the carry's velocity (`register_image`); (None, None) when every point is incremental."""
    if carry.incremental.all():
        return None, None
    X, Y = grid.points()
    start = None if carry.direct is None else shifted(carry.direct, carry.velocity[:, 0], carry.velocity[:, 1])
    return register_image(ref, img, img_b, grid, X, Y, settings, seeds=seeds, search=search, start=start,
                          skip=carry.incremental)


def shifted(res: PointResult, du: np.ndarray, dv: np.ndarray) -> PointResult:
    """`res` with the translations of its OK points moved by (du, dv) (flat, pixels; where those are NaN
    the warp stays as it was)."""
    warp = res.warp.copy()
    nb = warp.shape[1] // 2
    good = (res.status == OK) & np.isfinite(du) & np.isfinite(dv)
    warp[good, 0] += du[good]
    warp[good, nb] += dv[good]
    return PointResult(warp, res.zncc, res.iterations, res.status.astype(np.int8))


def switch_candidates(direct: PointResult | None, carry: TrackCarry, switch_zncc: float, shape: tuple[int, int],
                      half: int) -> np.ndarray:
    """(N,) bool: direct points measured in the last image whose match against the reference fell below
    `switch_zncc` or failed in a way an updated reference can cure (module docstring) - "outside" only
    where the subset, of half-width `half` at the point's last position, lay inside the image (`shape`,
    rows and columns) by MARGIN pixels; none while the last image is the reference itself, or with
    switch_zncc = 0."""
    n = carry.incremental.size
    if direct is None or carry.images == 0 or switch_zncc <= 0:
        return np.zeros(n, bool)
    h, w = shape
    inside = ((carry.x - half >= MARGIN) & (carry.x + half <= w - 1 - MARGIN) & (carry.y - half >= MARGIN)
              & (carry.y + half <= h - 1 - MARGIN))
    failed = np.isin(direct.status, DECORRELATED) & ((direct.status != OUTSIDE) | inside)
    low = (direct.status == OK) & ~(direct.zncc >= switch_zncc)
    return (low | failed) & carry.ok & ~carry.incremental


def register_steps(previous: ImageRef, img: np.ndarray, img_b: BSplineImage, grid: Grid, carry: TrackCarry,
                   direct: PointResult | None, candidates: np.ndarray, settings: DicSettings, *,
                   seeds: Sequence[int] = (), search: Callable | None = None
                   ) -> tuple[PointResult, np.ndarray] | tuple[None, None]:
    """The incremental points and the switch `candidates`, registered from the previous image (subsets
    around their positions carry.x, carry.y there) to `img`. Incremental points start from the last
    step's translation; with the candidates go the direct points measured in both images within ANCHOR
    grid points of them, as anchors they can be reached from (their start, and that of the candidates whose direct match
    converged, is the direct match's translation less the last displacement; the other candidates are
    reached from their neighbours); lost points are skipped with their status. (None, None) when there is
    nothing to register."""
    track = (carry.incremental & ~carry.lost) | candidates
    if not track.any() and not carry.incremental.all():
        return None, None
    n = track.size
    nparams = settings.nparams
    nb = nparams // 2
    if carry.step is not None:
        start = PointResult(carry.step.warp.copy(), carry.step.zncc, carry.step.iterations, carry.step.status.copy())
    else:
        start = PointResult(np.zeros((n, nparams)), np.full(n, np.nan), np.zeros(n, np.int32),
                            np.full(n, UNREACHED, np.int8))
    if candidates.any():
        X, Y = grid.points()
        near = cv2.dilate(candidates.reshape(grid.shape).astype(np.uint8), np.ones((2 * ANCHOR + 1,) * 2, np.uint8),
                          borderType=cv2.BORDER_CONSTANT, borderValue=0).astype(bool).ravel()
        anchors = near & ~carry.incremental & carry.ok & (direct.status == OK) & ~candidates
        track |= anchors
        fresh = candidates | anchors
        du = direct.warp[:, 0] - (carry.x - X)
        dv = direct.warp[:, nb] - (carry.y - Y)
        usable = fresh & np.isfinite(du) & np.isfinite(dv) & np.isin(direct.status, (OK, LOW_ZNCC))
        start.warp[fresh] = 0.0
        start.warp[usable, 0], start.warp[usable, nb] = du[usable], dv[usable]
        start.status[fresh] = np.where(usable[fresh], OK, UNREACHED)
    skip = ~track | carry.lost
    status = np.where(carry.lost, carry.lost_status, UNREACHED).astype(np.int8)
    return register_image(previous, img, img_b, grid, carry.x, carry.y, settings, seeds=seeds, search=search,
                          start=start, translation_only=True, skip=skip, skip_status=status)


def _rows(a: PointResult | None, b: PointResult | None, take_b: np.ndarray) -> PointResult:
    """Per point, the row of `b` where take_b, else of `a` (either may be None where not taken)."""
    if a is None or not (~take_b).any():
        return b
    if b is None or not take_b.any():
        return a
    pick = lambda x, y: np.where(take_b.reshape((-1,) + (1,) * (x.ndim - 1)), y, x)  # noqa: E731
    return PointResult(pick(a.warp, b.warp), pick(a.zncc, b.zncc), pick(a.iterations, b.iterations),
                       pick(a.status, b.status).astype(np.int8))


def merge_track(grid: Grid, carry: TrackCarry, direct: PointResult | None, direct_noise: np.ndarray | None,
                steps: PointResult | None, steps_noise: np.ndarray | None, switched: np.ndarray
                ) -> tuple[DicField, TrackCarry]:
    """This image's field and the next image's carry: incremental points (and the candidates that
    `switched`) from `steps`, the others from `direct`; displacements from the reference positions."""
    X, Y = grid.points()
    nb = (direct if direct is not None else steps).warp.shape[1] // 2
    incr = carry.incremental | switched
    res = _rows(direct, steps, incr)
    noise = direct_noise if steps is None else steps_noise if direct is None else np.where(incr, steps_noise,
                                                                                          direct_noise)
    ok = res.status == OK
    if steps is not None:
        step_ok = (steps.status == OK) & incr
        new_x = np.where(step_ok, carry.x + steps.warp[:, 0], np.nan)
        new_y = np.where(step_ok, carry.y + steps.warp[:, nb], np.nan)
        newly_lost = incr & ~step_ok & ~carry.lost
        lost_status = np.where(newly_lost, steps.status, carry.lost_status).astype(np.int8)
        lost = carry.lost | (incr & ~step_ok)
    else:
        new_x = new_y = np.full(X.size, np.nan)
        lost, lost_status = carry.lost, carry.lost_status
    if direct is not None:
        u = np.where(incr, new_x - X, direct.u)
        v = np.where(incr, new_y - Y, direct.v)
        x = np.where(ok, np.where(incr, new_x, X + direct.u), carry.x)
        y = np.where(ok, np.where(incr, new_y, Y + direct.v), carry.y)
    else:
        u, v = new_x - X, new_y - Y
        x, y = np.where(ok, new_x, carry.x), np.where(ok, new_y, carry.y)
    velocity = carry.velocity
    if direct is not None:
        both = ((direct.status == OK) & (carry.direct.status == OK) if carry.direct is not None
                else np.zeros(X.size, bool))[:, None]
        moved = direct.warp[:, [0, nb]] - (0.0 if carry.direct is None else carry.direct.warp[:, [0, nb]])
        velocity = np.where(both, moved, 0.0)
    nxt = TrackCarry(direct if direct is not None else carry.direct, steps if steps is not None else carry.step,
                     incr, x, y, ok, lost, lost_status, velocity, carry.images + 1)
    return DicField(grid, res, u.reshape(grid.shape), v.reshape(grid.shape), noise.reshape(grid.shape),
                    incr.reshape(grid.shape)), nxt


def track_image(ref: ImageRef, previous: ImageRef, img: np.ndarray, img_b: BSplineImage, grid: Grid,
                carry: TrackCarry, settings: DicSettings = DicSettings(), *, seeds: Sequence[int] = (),
                search: Callable | None = None, switch_zncc: float = SWITCH_ZNCC) -> tuple[DicField, TrackCarry]:
    """One deformed image of a sequence (module docstring): `ref` the reference image, `previous` the last
    image (the reference itself for the first deformed image). Returns its field and the next carry."""
    direct, dnoise = register_direct(ref, img, img_b, grid, carry, settings, seeds=seeds, search=search)
    cand = switch_candidates(direct, carry, switch_zncc, img.shape, settings.half)
    steps, snoise = register_steps(previous, img, img_b, grid, carry, direct, cand, settings, seeds=seeds,
                                   search=search)
    switched = np.zeros_like(cand)
    if cand.any():
        switched = cand & (steps.status == OK) & ((direct.status != OK) | (steps.zncc > direct.zncc))
    return merge_track(grid, carry, direct, dnoise, steps, snoise, switched)


def prefetch(items: Iterable, prepare: Callable) -> Iterator:
    """Yield (item, prepare(item)) for each item, preparing the next item in a worker thread while the
    caller works on the current one (with one thread, `background.threads`, each in turn by the caller)."""
    if threads() < 2:
        yield from ((item, prepare(item)) for item in items)
        return
    with ThreadPoolExecutor(1) as pool:
        it = iter(items)
        nxt = next(it, None)
        job = pool.submit(prepare, nxt) if nxt is not None else None
        while job is not None:
            item = nxt
            nxt = next(it, None)
            done = job.result()
            job = pool.submit(prepare, nxt) if nxt is not None else None
            yield item, done


def correlate_sequence(ref_img: np.ndarray, def_imgs: Iterable[np.ndarray], grid: Grid, *,
                       settings: DicSettings = DicSettings(), seeds: Iterable[tuple[float, float]] = (),
                       incremental: bool = False, search: Callable | None = None,
                       start: PointResult | None = None, switch_zncc: float = SWITCH_ZNCC,
                       reference: ImageRef | None = None) -> Iterable[DicField]:
    """2D DIC of a series of deformed images against one reference, tracked from image to image.

    Each image starts from the previous image's warps where those were good (points that fail from
    there, or reach less than the seed ZNCC, start again from their neighbours), then propagates into the
    rest. Points switch to incremental DIC when their ZNCC against the reference falls below
    `switch_zncc` (module docstring).

    Parameters
    ----------
    ref_img : (H, W) array
        The reference image, any real dtype.
    def_imgs : iterable of (H, W) arrays
        The deformed images, in order; read one at a time.
    grid : Grid
        The points to measure, reference pixels (`make_grid`).
    settings : DicSettings
        Subset, shape function, interpolation, thresholds.
    seeds : iterable of (x, y)
        Start points of the propagation, reference pixels.
    incremental : bool
        Register every point image to image.
    search : callable, optional
        The seeds' integer search, `search_integer`'s signature; None: that 2-D search (a rectified
        stereo pair uses `row_seed_search`).
    start : PointResult, optional
        Warps (grid order) for the first image to start from, as if a previous image's result.
    switch_zncc : float
        A point's ZNCC against the reference below which it switches to incremental DIC; 0: never.
    reference : ImageRef, optional
        `ref_img` prepared already, ``ImageRef.prepare(ref_img, settings, keep_subsets=True)`` (what it
        computed, e.g. its noise estimate, is not computed again); None: prepared here.

    Returns
    -------
    fields : iterator of DicField
        One per deformed image (a generator): ``u``, ``v`` (ny, nx) displacements from the reference
        position, pixels, summed over the steps for incremental points; ``incremental`` (ny, nx) bool.
    """
    s = settings
    seed_list = seed_indices(grid, seeds)
    images = prefetch(def_imgs, lambda img: BSplineImage.from_image(img, order=s.order,
                                                                    prefilter_sigma=s.prefilter_sigma))
    ref = ImageRef.prepare(ref_img, s, keep_subsets=True) if reference is None else reference
    previous = ref
    carry = TrackCarry.initial(grid, incremental, start)
    for img, img_b in images:
        field, carry = track_image(ref, previous, img, img_b, grid, carry, s, seeds=seed_list, search=search,
                                   switch_zncc=switch_zncc)
        previous = ImageRef(img, img_b)
        yield field

"""Stereo 3D-DIC on the rectified virtual pair: shape, 3D displacement and surface strain per state.

All image positions are in the rectified (virtual) images of the rig, pixels, x = column, y = row; the
grid of points lies in the LEFT image of the reference state 0. Per state s:
- stereo match of state 0 (left_0 -> right_0): every point from the feature guess
  (`stereodic.dic.initial_guess.feature_guess`), the rest from seeds found by a 1-D ZNCC search along
  the same row (`row_seed_search`; the rectified pair puts a scene point on one row of both images),
  or, for a rig whose rows are off its images, in a band about the offset measured in the reference
  pair (`refit.offset_seed_search`, `StereoSettings.row_offsets`), then IC-GN with the affine (or
  quadratic) subset shape - the right subset is foreshortened differently - and reliability-guided
  propagation (the 2-D engine, `stereodic.dic`);
- temporal match left_0 -> left_s (the 2-D engine's tracking, `stereodic.dic.sequence`, each point
  starting from its previous displacement plus its last change; from the feature guess at state 1 and
  wherever the motion jumped);
- cross match left_0 -> right_s, starting from the previous state's cross warps moved by the left
  camera's change of displacement (DICe's and VIC-3D's scheme) and by the last change of the disparity
  (the velocity-based start of the temporal match, carried over to the second camera): every state
  compares the SAME reference subset in both cameras, so each camera measures the same material patch
  and errors do not add up over states;
- incremental points (large deformations, where the reference subset no longer resembles the deformed
  images): a point whose ZNCC against the reference - left or cross - falls below `switch_zncc` (or whose
  match fails in a way an updated reference can cure) switches for good, if that matches it better: its
  left track goes image to image (left_{s-1} -> left_s, its displacement still counted from its reference
  position) and its stereo match is redone at every state, left_s -> right_s, with the subset around
  its tracked left position, starting from its previous stereo warp (at the switch: the previous cross
  warp composed with the inverse of the previous temporal warp). With `incremental` every point is
  incremental from state 1;
- triangulation of (left position, right position) with the EVM-corrected rays (`triangulate`,
  corrected=True; the right match may sit a fraction of a pixel off the row after IC-GN: passed as
  row_right), the rays' distance reported as gap_mm; a match more than `max_gap_px` rows off the row
  where the left ray is seen (`epipolar.epipolar_error`), less the reference pair's measured offset
  there (none for a rig that fits), is a wrong match and is flagged ray_gap;
- 3D points and displacements X_s - X_0 in the rig's reporting frame (`Rig.to_world`: the rig's WCS
  unless it carries a world_from_rig transform), strain on the local tangent plane (`strain_3d`).
A point is `converged` in a state only if both cameras' matches are OK there, the rays meet, and its
state-0 point is measured; positions, displacements and strains are NaN exactly where it is not.

The unit of work is one state: `solve_state(run, k, pair, carry, previous)` -> (its result, the carry
for state k + 1), where `run` is the per-run data (`StereoRun`: rig, grid, settings, the reference
image's B-spline, the reference points), `pair` the state's rectified images (`PreparedPair`) and
`carry` (`StereoCarry`) what the previous state leaves the next: the warps every state starts from.
`StereoDic.run` chains the states in memory; `stereodic.dic3d.run` chains them through files on disk.
"""

from __future__ import annotations

from dataclasses import KW_ONLY, dataclass, field, replace
from typing import Iterable, Iterator, Sequence

import cv2
import numpy as np

from stereodic.dic import BSplineImage, DicSettings, ImageRef, PointResult, correlate_points, row_seed_search
from stereodic.dic.correlate import register_image, seed_indices
from stereodic.dic.grid import Grid
from stereodic.dic.icgn import OK, OUTSIDE, STATUS_NAMES, UNREACHED
from stereodic.dic.sequence import (DECORRELATED, SWITCH_ZNCC, TrackCarry, merge_track, prefetch, register_direct,
                                    register_steps, shifted, switch_candidates)
from stereodic.dic3d.diagnose import NO_REFERENCE, RAY_GAP
from stereodic.dic3d.epipolar import epipolar_error
from stereodic.dic3d.refit import offset_at, offset_seed_search
from stereodic.stereo.rig import Rig
from stereodic.strain.fit import Strain, StrainFit, strain_3d
from stereodic.strain.measures import StrainMeasure, measure_strain
from stereodic.stereo.triangulate import triangulate

CROSS_DECORRELATED = tuple(c for c in DECORRELATED if c != OUTSIDE)


@dataclass(frozen=True)
class StereoSettings:
    """dic: the 2-D engine's settings (subset, shape, ...); disparity: (dmin, dmax) pixels of the row
    search of the seeds (x_right - x_left), None = half the image width either way; strain_window: grid
    points per side of the strain fit (odd), None = no strain; incremental: every point incremental from
    state 1 (module docstring); switch_zncc: a point whose ZNCC against the reference falls below
    switches to incremental (0 = never); max_gap_px: largest epipolar error (rows, virtual pixels) of a
    trusted match beyond the measured row offset; strain_measure: one of `strain_measures.MEASURES`;
    vertical_search: rows above and below the (offset) row that the seed search also covers; row_offsets:
    the quadratic surface of the reference pair's row offsets (`refit.RowOffsets.coef`, pixels), () =
    none: the rig's rows."""

    dic: DicSettings = DicSettings()
    disparity: tuple[int, int] | None = None
    strain_window: int | None = 5
    incremental: bool = False
    max_gap_px: float = 1.0
    switch_zncc: float = SWITCH_ZNCC
    strain_measure: str = "green-lagrange"
    vertical_search: int = 0
    row_offsets: tuple[float, ...] = ()


@dataclass
class CameraMatch:
    """One camera's match of the grid in one state, (ny, nx) arrays: u, v (pixels: the point is at
    (x + u, y + v) in this camera's rectified image of the state; NaN where status is not OK), zncc,
    status (the 2-D engine's codes), noise_px (the match's predicted random error, pixels,
    `texture.predicted_noise`), real (ny, nx, 2): where the point is in the camera's original
    (unrectified) image of the state, (column, row) pixels - the real position its rectified position
    samples (the rig's IMM) - NaN where not OK."""

    u: np.ndarray
    v: np.ndarray
    zncc: np.ndarray
    status: np.ndarray
    noise_px: np.ndarray
    real: np.ndarray | None = None

    @property
    def ok(self) -> np.ndarray:
        return self.status == OK


@dataclass
class StereoState:
    """The result of one state: left and right matches; points (ny, nx, 3) and displacement from state 0
    (ny, nx, 3) in the rig's reporting frame, mm; gap_mm (ny, nx) the rays' distance; converged (ny, nx);
    status (ny, nx) str (STATUS_NAMES, prefixed 'left:' or 'right:', or ray_gap, no_reference); strain (the
    fit, Green-Lagrange) and measure (the settings' strain measure, principal strains, von Mises), or None
    without a strain window; incremental (ny, nx) bool: the points tracked state to state in this state;
    deformation (ny, nx, 3) mm: the displacement with the state's rigid motion taken out, where it is
    (`stereodic.dic3d.frame.ReportingFrame`), else None."""

    state: int
    left: CameraMatch
    right: CameraMatch
    points: np.ndarray
    displacement: np.ndarray
    gap_mm: np.ndarray
    converged: np.ndarray
    status: np.ndarray
    strain: Strain | None
    incremental: np.ndarray
    measure: StrainMeasure | None = None
    deformation: np.ndarray | None = None


@dataclass
class PreparedPair:
    """One state's rectified images and their B-splines (the 2-D engine's interpolants)."""

    left: np.ndarray
    right: np.ndarray
    left_b: BSplineImage
    right_b: BSplineImage
    _left_ref: ImageRef | None = field(default=None, repr=False, compare=False)

    @classmethod
    def prepare(cls, left: np.ndarray, right: np.ndarray, settings: DicSettings) -> "PreparedPair":
        return cls(left, right, *(BSplineImage.from_image(img, order=settings.order,
                                                          prefilter_sigma=settings.prefilter_sigma)
                                  for img in (left, right)))

    def left_ref(self, *, keep_subsets: bool = False) -> ImageRef:
        """The left image as a registration's reference (`ImageRef`; keep_subsets: that of a run, made
        anew). Without keep_subsets the same one each time: the noise maps that a state's tracked points
        take of it (`_stereo_at`) serve the next state's incremental steps from it (`register_steps`)."""
        if keep_subsets:
            return ImageRef(self.left, self.left_b, True)
        if self._left_ref is None:
            self._left_ref = ImageRef(self.left, self.left_b)
        return self._left_ref


@dataclass
class StereoRun:
    """Per-run data: the rig, the grid, the settings, seed positions (left rectified reference pixels)
    and their grid indices, the left reference image prepared (`ImageRef`, which keeps the reference
    side of the grid's subsets once computed: every state's temporal and cross matches register the
    same reference subsets), per camera where a subset sees only image (`view_map`), and once state 0 is
    solved its points (ny, nx, 3) reporting frame mm and the strain fit on them (`with_reference`)."""

    rig: Rig
    grid: Grid
    settings: StereoSettings
    seeds: list
    seed_idx: list
    ref: ImageRef
    views: dict
    ref_points: np.ndarray | None = None
    ref_strain: StrainFit | None = None

    @classmethod
    def prepare(cls, rig: Rig, grid: Grid, settings: StereoSettings, seeds: Sequence[tuple[float, float]],
                reference: PreparedPair) -> "StereoRun":
        half = settings.dic.subset // 2
        views = {side: view_map(rig.camera(side).imm.valid, half=half) for side in ("left", "right")}
        return cls(rig, grid, settings, list(seeds), seed_indices(grid, seeds), reference.left_ref(keep_subsets=True),
                   views)

    def with_reference(self, state0: StereoState) -> "StereoRun":
        window = self.settings.strain_window
        return replace(self, ref_points=state0.points,
                       ref_strain=StrainFit(state0.points, window=window) if window else None)

    @property
    def disparity(self) -> tuple[int, int]:
        w = self.rig.sensor.width
        return self.settings.disparity or (-(w // 2), w // 2)

    def seed_search(self):
        """The stereo seeds' integer search: along the rows, or about their measured offsets."""
        st = self.settings
        if st.row_offsets:
            return offset_seed_search(*self.disparity, st.row_offsets, st.vertical_search)
        return row_seed_search(*self.disparity, rows=st.vertical_search)

    def row_excess(self, xl: np.ndarray, yl: np.ndarray, xr: np.ndarray, yr: np.ndarray) -> np.ndarray:
        """(N,) |epipolar error - measured row offset| of matches (xl, yl) <-> (xr, yr), rows."""
        e = epipolar_error(self.rig, xl, yl, xr, yr)
        if self.settings.row_offsets:
            e = e - offset_at(self.settings.row_offsets, xl, yl)
        return np.abs(e)


CROSS_KEYS = ("warp", "zncc", "iterations", "status")
# pixels beyond a subset that must see image too: the cubic B-spline's prefilter spreads the blank band's
# edge over a few pixels (its pole 0.268 per pixel: 2 % after 3); on the simulated rig 3 takes out every
# biased point at the band (1 keeps some, 5 takes out more but no worse ones)
VIEW_MARGIN_PX = 3


@dataclass
class StereoCarry:
    """What state k + 1 needs from state k (flat, grid order): left: the left track (`TrackCarry`);
    cross: the last direct cross registration left_0 -> right (warps about the grid points); stereo: the
    last stereo match left_s -> right_s of the incremental points (warps about their left positions);
    prev_u, prev_v: the left displacements the cross warps were last moved by; disparity_rate (N, 2): the
    last change, from one state to the next, of the cross translation less the left one (pixels; 0 where
    not measured in both), by which the next cross start is moved on beyond the left's change."""

    left: TrackCarry
    cross: PointResult
    stereo: PointResult
    prev_u: np.ndarray
    prev_v: np.ndarray
    disparity_rate: np.ndarray
    state: int = 0

    def to_arrays(self) -> dict[str, np.ndarray]:
        """Arrays for an npz file; `from_arrays` reads them back exactly."""
        out = self.left.to_arrays("left_")
        for name in ("cross", "stereo"):
            out.update({f"{name}_{k}": getattr(getattr(self, name), k) for k in CROSS_KEYS})
        out.update(prev_u=self.prev_u, prev_v=self.prev_v, disparity_rate=self.disparity_rate,
                   state=np.array(self.state))
        return out

    @classmethod
    def from_arrays(cls, a) -> "StereoCarry":
        res = lambda name: PointResult(*(np.array(a[f"{name}_{k}"]) for k in CROSS_KEYS))  # noqa: E731
        return cls(TrackCarry.from_arrays(a, "left_"), res("cross"), res("stereo"), np.array(a["prev_u"]),
                   np.array(a["prev_v"]), np.array(a["disparity_rate"]), int(a["state"]))


def _match(grid: Grid, res: PointResult, xs: np.ndarray, ys: np.ndarray, noise: np.ndarray) -> CameraMatch:
    """A CameraMatch from a registration of points at (xs, ys) (flat, grid order)."""
    X, Y = grid.points()
    ok = res.status == OK
    nb = res.warp.shape[1] // 2
    u = np.where(ok, xs + res.warp[:, 0] - X, np.nan)
    v = np.where(ok, ys + res.warp[:, nb] - Y, np.nan)
    return CameraMatch(u.reshape(grid.shape), v.reshape(grid.shape),
                       np.where(ok, res.zncc, np.nan).reshape(grid.shape), res.status.reshape(grid.shape),
                       noise.reshape(grid.shape))


def _composed(cross: PointResult, temporal: PointResult | None, du: np.ndarray, dv: np.ndarray, nparams: int
              ) -> np.ndarray:
    """(N, nparams) stereo warps left -> right about the points' left positions, from a cross warp
    (reference -> right) and the temporal warp (reference -> left; None = identity) about the grid
    points, (du, dv) the temporal translation: translation = cross - temporal, gradient = the affine part
    of M_c M_t^-1 - I = (G_c - G_t) (I + G_t)^-1 (higher-order terms zero)."""
    nb = nparams // 2
    n = cross.warp.shape[0]
    out = np.zeros((n, nparams))
    out[:, 0] = cross.warp[:, 0] - du
    out[:, nb] = cross.warp[:, nb] - dv
    g = lambda w: np.stack([w[:, [1, 2]], w[:, [nb + 1, nb + 2]]], axis=1)  # noqa: E731  (N, 2, 2)
    gc = g(cross.warp)
    gt = np.zeros_like(gc) if temporal is None else g(temporal.warp)
    gs = (gc - gt) @ np.linalg.inv(np.eye(2) + gt)
    out[:, [1, 2]], out[:, [nb + 1, nb + 2]] = gs[:, 0], gs[:, 1]
    return out


def view_map(valid: np.ndarray, *, half: int) -> np.ndarray:
    """(H, W) bool over a rectified image whose pixels are `valid` (the IMM's: they sample the real
    image): True where a subset of half size `half` centred within half a pixel of that pixel, and
    VIEW_MARGIN_PX beyond it (the B-spline's reach), sees only valid pixels, their bilinear neighbours
    included. A subset that takes in the blank band where the virtual image lies beyond the real one
    registers that band's edge, not the specimen."""
    r = half + VIEW_MARGIN_PX + 1
    return cv2.erode(valid.astype(np.uint8), np.ones((2 * r + 1, 2 * r + 1), np.uint8),
                     borderType=cv2.BORDER_CONSTANT, borderValue=0).astype(bool)


def in_view(view: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Whether subsets centred at rectified positions (x, y) (any shape; NaN: not matched) see only
    image, by `view_map`'s `view`."""
    h, w = view.shape
    ok = np.isfinite(x) & np.isfinite(y)
    i = np.clip(np.rint(np.where(ok, x, 0)), 0, w - 1).astype(np.intp)
    j = np.clip(np.rint(np.where(ok, y, 0)), 0, h - 1).astype(np.intp)
    return ok & view[j, i]


def _combine(left: CameraMatch, right: CameraMatch, gap_ok: np.ndarray, ref_ok: np.ndarray,
             view_ok: dict[str, np.ndarray]):
    """(converged, status strings) of a state: the first failure of left, right, rays, reference;
    view_ok: per side, whether its subset sees only image (`in_view`)."""
    names = np.array(STATUS_NAMES, dtype=object)
    status = np.full(left.status.shape, "ok", dtype=object)
    status[~ref_ok] = NO_REFERENCE
    status[~gap_ok] = RAY_GAP
    for side in ("right", "left"):
        status[~view_ok[side]] = f"{side}:{STATUS_NAMES[OUTSIDE]}"
    status[~right.ok] = "right:" + names[right.status[~right.ok]]
    status[~left.ok] = "left:" + names[left.status[~left.ok]]
    return status == "ok", status


def stereo_match(run: StereoRun, pair: PreparedPair) -> tuple[PointResult, np.ndarray]:
    """left -> right on the grid of one pair: row-search seeds, IC-GN, propagation (the state-0 match);
    returns it and its predicted random error (N,) pixels."""
    X, Y = run.grid.points()
    return register_image(run.ref if pair.left is run.ref.image else pair.left_ref(), pair.right, pair.right_b,
                          run.grid, X, Y, run.settings.dic, seeds=run.seed_idx, search=run.seed_search())


def _reference_state(run: StereoRun, pair: PreparedPair) -> tuple[StereoState, StereoCarry]:
    g, s = run.grid, run.settings.dic
    X, Y = g.points()
    stereo, noise = stereo_match(run, pair)
    ref_st = run.ref.status(X, Y, s)
    ref_st[~g.active.ravel()] = UNREACHED
    zero = np.where(ref_st == OK, 0.0, np.nan).reshape(g.shape)
    left_noise = run.ref.noise(X, Y, s.half).reshape(g.shape)
    left = CameraMatch(zero, zero.copy(), np.where(ref_st == OK, 1.0, np.nan).reshape(g.shape),
                       ref_st.reshape(g.shape), left_noise)
    right = _match(g, stereo, X, Y, noise)
    carry = StereoCarry(TrackCarry.initial(g, run.settings.incremental), stereo, stereo, np.zeros(X.size),
                        np.zeros(X.size), np.zeros((X.size, 2)), 0)
    return _state(run, 0, left, right, np.zeros(g.shape, bool)), carry


def solve_state(run: StereoRun, k: int, pair: PreparedPair, carry: StereoCarry | None = None,
                previous: PreparedPair | None = None) -> tuple[StereoState, StereoCarry]:
    """State k (module docstring): the reference (k = 0, no carry) or a deformed state from the carry of
    state k - 1, whose images `previous` are needed when points are tracked incrementally. Returns the
    state's result and the carry for state k + 1. A pure function of its arguments: the same inputs give
    bit-identical results."""
    if k == 0:
        return _reference_state(run, pair)
    if run.ref_points is None:
        raise ValueError("solve_state: the run has no reference points (StereoRun.with_reference)")
    g, st = run.grid, run.settings
    s = st.dic
    X, Y = g.points()
    lc = carry.left
    ldir, ldn = register_direct(run.ref, pair.left, pair.left_b, g, lc, s, seeds=run.seed_idx)
    cdir = cdn = None
    prev_u, prev_v, rate = carry.prev_u, carry.prev_v, carry.disparity_rate
    if ldir is not None:
        lu, lv = ldir.u, ldir.v
        start = shifted(carry.cross, lu - prev_u + rate[:, 0], lv - prev_v + rate[:, 1])
        cdir, cdn = register_image(run.ref, pair.right, pair.right_b, g, X, Y, s, seeds=run.seed_idx, start=start,
                                   skip=lc.incremental)
        rate = _disparity_rate(carry, cdir, lu, lv, s.nparams // 2)
        prev_u, prev_v = np.where(np.isfinite(lu), lu, prev_u), np.where(np.isfinite(lv), lv, prev_v)
    cand = switch_candidates(ldir, lc, st.switch_zncc, pair.left.shape, s.half)
    if cdir is not None and st.switch_zncc > 0:   # a right subset outside the right image stays outside
        low = ((cdir.status == OK) & ~(cdir.zncc >= st.switch_zncc)) | np.isin(cdir.status, CROSS_DECORRELATED)
        cand |= low & lc.ok & ~lc.incremental
    cand &= carry.cross.status == OK              # the stereo match of a switching point starts from it
    prev_ref = run.ref if previous is None or previous.left is run.ref.image else previous.left_ref()
    lsteps, lsn = register_steps(prev_ref, pair.left, pair.left_b, g, lc, ldir, cand, s, seeds=run.seed_idx)
    stereo, snoise = carry.stereo, None
    if lsteps is not None:
        nb = s.nparams // 2
        incr = lc.incremental | cand
        start = PointResult(carry.stereo.warp.copy(), carry.stereo.zncc, carry.stereo.iterations,
                            carry.stereo.status.copy())
        if cand.any():
            comp = _composed(carry.cross, lc.direct, lc.x - X, lc.y - Y, s.nparams)
            start.warp[cand] = comp[cand]
            start.status[cand] = OK
        step_ok = lsteps.status == OK
        xs = np.where(incr & step_ok, X + (lc.x + lsteps.warp[:, 0] - X), np.nan)
        ys = np.where(incr & step_ok, Y + (lc.y + lsteps.warp[:, nb] - Y), np.nan)
        stereo, snoise = _stereo_at(pair, s, xs, ys, start)
    switched = np.zeros_like(cand)
    if cand.any():
        old = np.fmin(ldir.zncc, cdir.zncc)
        new = np.fmin(lsteps.zncc, stereo.zncc)
        switched = cand & (lsteps.status == OK) & (stereo.status == OK) & (
            (ldir.status != OK) | (cdir.status != OK) | (new > old))
    field_, left_carry = merge_track(g, lc, ldir, ldn, lsteps, lsn, switched)
    incr = left_carry.incremental
    left = CameraMatch(field_.u, field_.v, np.where(field_.ok, field_.zncc, np.nan), field_.status, field_.noise_px)
    if lsteps is not None:
        lu, lv = field_.u.ravel(), field_.v.ravel()
        xs_t, ys_t = X + lu, Y + lv
        tracked = _match(g, stereo, np.where(np.isfinite(xs_t), xs_t, 0.0), np.where(np.isfinite(ys_t), ys_t, 0.0),
                         snoise)
    if cdir is None:
        right = tracked
    else:
        direct = _match(g, cdir, X, Y, cdn)
        right = direct if lsteps is None or not incr.any() else _pick(direct, tracked, incr.reshape(g.shape))
    nxt = StereoCarry(left_carry, cdir if cdir is not None else carry.cross, stereo, prev_u, prev_v, rate, k)
    return _state(run, k, left, right, incr.reshape(g.shape)), nxt


def _disparity_rate(carry: StereoCarry, cross: PointResult, lu: np.ndarray, lv: np.ndarray, nb: int) -> np.ndarray:
    """(N, 2) the change of (cross translation - left displacement) from the carry's state to this one
    (`cross`, left displacements (lu, lv)); 0 where either state did not measure it."""
    now = cross.warp[:, [0, nb]] - np.stack([lu, lv], 1)
    before = carry.cross.warp[:, [0, nb]] - np.stack([carry.prev_u, carry.prev_v], 1)
    left_before = carry.left.direct  # None: the carry's state is the reference, where the left moved by 0
    both = ((cross.status == OK) & (carry.cross.status == OK) & np.isfinite(now).all(1)
            & (True if left_before is None else left_before.status == OK))
    return np.where(both[:, None], now - before, 0.0)


def _pick(a: CameraMatch, b: CameraMatch, take_b: np.ndarray) -> CameraMatch:
    """Per point, b's match where take_b, else a's."""
    return CameraMatch(*(np.where(take_b, getattr(b, f), getattr(a, f)) for f in ("u", "v", "zncc", "status",
                                                                                   "noise_px")))


def _stereo_at(pair: PreparedPair, s: DicSettings, xs: np.ndarray, ys: np.ndarray, prev: PointResult
               ) -> tuple[PointResult, np.ndarray]:
    """left_s -> right_s with subsets around the tracked left positions (xs, ys) (NaN: not tracked), each
    from its warp in `prev` (points not OK there are not tracked and keep their status); returns the
    match and its predicted random error (N,)."""
    track = np.isfinite(xs) & np.isfinite(ys) & (prev.status == OK)
    res = PointResult(prev.warp.copy(), np.full(xs.size, np.nan), np.zeros(xs.size, np.int32),
                      np.where(track, UNREACHED, prev.status).astype(np.int8))
    noise = np.full(xs.size, np.nan)
    if track.any():
        r = correlate_points(pair.left_b, pair.right_b, xs[track], ys[track], res.warp[track], settings=s)
        res.warp[track], res.zncc[track], res.iterations[track], res.status[track] = (
            r.warp, r.zncc, r.iterations, r.status)
        noise[track] = pair.left_ref().noise(xs[track], ys[track], s.half)
    return res, noise


def _state(run: StereoRun, k: int, left: CameraMatch, right: CameraMatch, incremental: np.ndarray) -> StereoState:
    g, rig = run.grid, run.rig
    X, Y = g.points()
    for side, m in (("left", left), ("right", right)):
        m.real = rig.camera(side).imm.real_position(X.reshape(g.shape) + m.u, Y.reshape(g.shape) + m.v)
    both = (left.ok & right.ok).ravel()
    pts = np.full((X.size, 3), np.nan)
    gap = np.full(X.size, np.nan)
    excess = np.zeros(X.size)
    if both.any():
        xl, yl = X[both] + left.u.ravel()[both], Y[both] + left.v.ravel()[both]
        xr, yr = X[both] + right.u.ravel()[both], Y[both] + right.v.ravel()[both]
        t = triangulate(rig, xl, xr, yl, row_right=yr, corrected=True)
        pts[both], gap[both] = rig.to_world(t.points), t.gap_mm
        excess[both] = run.row_excess(xl, yl, xr, yr)
    gap_ok = ~(excess > run.settings.max_gap_px).reshape(g.shape)
    ref_points = run.ref_points if k > 0 else None
    ref_ok = np.ones(g.shape, bool) if ref_points is None else np.isfinite(ref_points).all(-1)
    view_ok = {side: in_view(run.views[side], X.reshape(g.shape) + m.u, Y.reshape(g.shape) + m.v) | ~m.ok
               for side, m in (("left", left), ("right", right))}
    converged, status = _combine(left, right, gap_ok, ref_ok, view_ok)
    pts = np.where(converged[..., None], pts.reshape(g.shape + (3,)), np.nan)
    disp = pts - (pts if ref_points is None else ref_points)
    strain = measure = None
    if run.settings.strain_window:
        if ref_points is None:
            strain = strain_3d(pts, disp, window=run.settings.strain_window)
        else:
            strain = run.ref_strain(disp)
        measure = measure_strain(strain, measure=run.settings.strain_measure)
    return StereoState(k, left, right, pts, disp, np.where(converged, gap.reshape(g.shape), np.nan),
                       converged, status, strain, incremental, measure)


@dataclass
class StereoDic:
    """The stereo 3D-DIC pipeline over the states of one experiment, in memory (module docstring).

    Parameters
    ----------
    rig : Rig
        The rectified pair: its rays triangulate the matches.
    grid : Grid
        The points, in the left rectified image of state 0, virtual pixels (`make_grid`).
    settings : StereoSettings
        The 2-D engine's settings, disparity range, strain window and measure, ray-gap limit.
    seeds : sequence of (x, y)
        Start points of the propagation, left rectified pixels (besides the automatic seeds).
    """

    rig: Rig
    grid: Grid
    _: KW_ONLY
    settings: StereoSettings = StereoSettings()
    seeds: Sequence[tuple[float, float]] = field(default_factory=tuple)

    def stereo_match(self, left: np.ndarray, right: np.ndarray) -> PointResult:
        """left -> right on the grid: row-search seeds, IC-GN, propagation (state 0)."""
        pair = PreparedPair.prepare(left, right, self.settings.dic)
        return stereo_match(StereoRun.prepare(self.rig, self.grid, self.settings, self.seeds, pair), pair)[0]

    def run(self, pairs: Iterable[tuple[np.ndarray, np.ndarray]]) -> Iterator[StereoState]:
        """Solve the states one after the other.

        Parameters
        ----------
        pairs : iterable of ((Hv, Wv) array, (Hv, Wv) array)
            The rectified (left, right) images of each state (`rectify_pair`, of the rig's virtual size),
            state 0 (the reference) first; read one at a time (the next one is prepared while the current
            one is solved).

        Returns
        -------
        states : iterator of StereoState
            One per pair: ``points`` and ``displacement`` (ny, nx, 3) in the rig's reporting frame, mm
            (`Rig.to_world`), ``gap_mm``, ``converged``, ``status``, the strain and its measure.
        """
        s = self.settings.dic
        run = carry = previous = None
        for k, (_, pair) in enumerate(prefetch(pairs, lambda p: PreparedPair.prepare(p[0], p[1], s))):
            if run is None:
                run = StereoRun.prepare(self.rig, self.grid, self.settings, self.seeds, pair)
            state, carry = solve_state(run, k, pair, carry, previous)
            if k == 0:
                run = run.with_reference(state)
            previous = pair
            yield state

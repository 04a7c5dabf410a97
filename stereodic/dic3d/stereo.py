"""Stereo 3D-DIC on the rectified virtual pair: shape, 3D displacement and surface strain per state.

All image positions are in the rectified (virtual) images of the rig, pixels, x = column, y = row; the
grid of points lies in the LEFT image of the reference state 0. Per state s:
- stereo match of state 0 (left_0 -> right_0): seeds by a 1-D ZNCC search along the same row
  (`row_seed_search`; the rectified pair puts a scene point on one row of both images), then IC-GN with
  the affine (or quadratic) subset shape - the right subset is foreshortened differently - and
  reliability-guided propagation (the 2-D engine, `stereodic.dic`);
- temporal match left_0 -> left_s (the 2-D engine's sequence, optionally incremental);
- cross match left_0 -> right_s, starting from the previous state's cross warps moved by the left
  camera's change of displacement (DICe's and VIC-3D's scheme): every state compares the SAME reference
  subset in both cameras, so each camera measures the same material patch and errors do not add up
  over states. With `incremental` (large deformations, where the reference subset no longer resembles
  the deformed images) the left track is incremental and the stereo match is redone at every state,
  left_s -> right_s, with subsets around the tracked left positions, from the previous state's warps;
- triangulation of (left position, right position) with the EVM-corrected rays (`triangulate`,
  corrected=True; the right match may sit a fraction of a pixel off the row after IC-GN: passed as
  row_right); a ray gap above `max_gap_px` virtual pixels means a wrong match and is flagged;
- 3D displacement X_s - X_0 (WCS mm), Green-Lagrange strain on the local tangent plane (`strain_3d`).
A point is `converged` in a state only if both cameras' matches are OK there, the rays meet, and its
state-0 point is measured; positions, displacements and strains are NaN exactly where it is not.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator, Sequence

import numpy as np

from stereodic.dic import BSplineImage, DicSettings, PointResult, correlate_pair, correlate_points, \
    correlate_sequence, row_seed_search
from stereodic.dic.correlate import subset_status
from stereodic.dic.grid import Grid
from stereodic.dic.icgn import OK, STATUS_NAMES, UNREACHED
from stereodic.rig import Rig
from stereodic.strain import Strain, strain_3d
from stereodic.triangulate import triangulate

RAY_GAP = "ray_gap"        # combined statuses beyond the 2-D engine's
NO_REFERENCE = "no_reference"


@dataclass(frozen=True)
class StereoSettings:
    """dic: the 2-D engine's settings (subset, shape, ...); disparity: (dmin, dmax) pixels of the row
    search of the seeds (x_right - x_left), None = half the image width either way; strain_window: grid
    points per side of the strain fit (odd), None = no strain; incremental: see the module docstring;
    max_gap_px: largest distance between the two rays, in virtual pixel pitches, of a trusted point;
    vertical_search: rows above and below the row that the seed search also covers (0: the row only; more
    for a rig whose calibration no longer fits its images, whose matches sit off the row)."""

    dic: DicSettings = DicSettings()
    disparity: tuple[int, int] | None = None
    strain_window: int | None = 5
    incremental: bool = False
    max_gap_px: float = 1.0
    vertical_search: int = 0


@dataclass
class CameraMatch:
    """One camera's match of the grid in one state, (ny, nx) arrays: u, v (pixels: the point is at
    (x + u, y + v) in this camera's rectified image of the state; NaN where status is not OK), zncc,
    status (the 2-D engine's codes)."""

    u: np.ndarray
    v: np.ndarray
    zncc: np.ndarray
    status: np.ndarray

    @property
    def ok(self) -> np.ndarray:
        return self.status == OK


@dataclass
class StereoState:
    """The result of one state: left and right matches; points (ny, nx, 3) WCS mm and displacement from
    state 0 (ny, nx, 3) mm; gap_mm (ny, nx) the rays' distance; converged (ny, nx); status (ny, nx)
    str (STATUS_NAMES, prefixed 'left:' or 'right:', or ray_gap, no_reference); strain or None."""

    state: int
    left: CameraMatch
    right: CameraMatch
    points: np.ndarray
    displacement: np.ndarray
    gap_mm: np.ndarray
    converged: np.ndarray
    status: np.ndarray
    strain: Strain | None


def _match(grid: Grid, res: PointResult, xs: np.ndarray, ys: np.ndarray) -> CameraMatch:
    """A CameraMatch from a registration of points at (xs, ys) (flat, grid order)."""
    X, Y = grid.points()
    ok = res.status == OK
    nb = res.warp.shape[1] // 2
    u = np.where(ok, xs + res.warp[:, 0] - X, np.nan)
    v = np.where(ok, ys + res.warp[:, nb] - Y, np.nan)
    return CameraMatch(u.reshape(grid.shape), v.reshape(grid.shape),
                       np.where(ok, res.zncc, np.nan).reshape(grid.shape), res.status.reshape(grid.shape))


def _shifted(res: PointResult, du: np.ndarray, dv: np.ndarray) -> PointResult:
    """`res` with its translations moved by (du, dv) (flat); points where those are NaN are dropped."""
    warp = res.warp.copy()
    nb = warp.shape[1] // 2
    good = (res.status == OK) & np.isfinite(du) & np.isfinite(dv)
    warp[good, 0] += du[good]
    warp[good, nb] += dv[good]
    return PointResult(warp, res.zncc, res.iterations, np.where(good, OK, res.status).astype(np.int8))


def _combine(left: CameraMatch, right: CameraMatch, gap_ok: np.ndarray, ref_ok: np.ndarray):
    """(converged, status strings) of a state: the first failure of left, right, rays, reference."""
    names = np.array(STATUS_NAMES, dtype=object)
    status = np.full(left.status.shape, "ok", dtype=object)
    status[~ref_ok] = NO_REFERENCE
    status[~gap_ok] = RAY_GAP
    status[~right.ok] = "right:" + names[right.status[~right.ok]]
    status[~left.ok] = "left:" + names[left.status[~left.ok]]
    return status == "ok", status


class StereoDic:
    """The pipeline over the states of one experiment (module docstring). `rig` gives the rays; images
    are the rectified ones (`rectify_pair`), all of the rig's virtual size."""

    def __init__(self, rig: Rig, grid: Grid, settings: StereoSettings = StereoSettings(),
                 seeds: Sequence[tuple[float, float]] = ()):
        self.rig, self.grid, self.s, self.seeds = rig, grid, settings, list(seeds)
        w = rig.sensor.width
        self.disparity = settings.disparity or (-(w // 2), w // 2)
        self.max_gap_mm = settings.max_gap_px * float(np.max(rig.sensor.pitch_mm))

    def stereo_match(self, left: np.ndarray, right: np.ndarray) -> PointResult:
        """left -> right on the grid: row-search seeds, IC-GN, propagation (state 0)."""
        f = correlate_pair(left, right, self.grid, self.s.dic, self.seeds, search=row_seed_search(*self.disparity, rows=self.s.vertical_search))
        return f.points

    def run(self, pairs: Sequence[tuple[np.ndarray, np.ndarray]]) -> Iterator[StereoState]:
        """Yield one StereoState per rectified (left, right) pair, state 0 (the reference) first."""
        g, s = self.grid, self.s
        X, Y = g.points()
        left0, right0 = pairs[0]
        ref_b = BSplineImage.from_image(left0, s.dic.order, s.dic.prefilter_sigma)
        stereo = self.stereo_match(left0, right0)
        ref_st = subset_status(ref_b, X, Y, s.dic)
        ref_st[~g.active.ravel()] = UNREACHED
        zero = np.where(ref_st == OK, 0.0, np.nan).reshape(g.shape)
        left = CameraMatch(zero, zero.copy(), np.where(ref_st == OK, 1.0, np.nan).reshape(g.shape),
                           ref_st.reshape(g.shape))
        right = _match(g, stereo, X, Y)
        first = self._state(0, left, right, None)
        yield first
        if len(pairs) == 1:
            return
        temporal = correlate_sequence(left0, (p[0] for p in pairs[1:]), g, s.dic, self.seeds, s.incremental)
        cross, prev_u, prev_v = stereo, np.zeros(X.size), np.zeros(X.size)
        for k, field in enumerate(temporal, start=1):
            left = CameraMatch(field.u, field.v, np.where(field.ok, field.zncc, np.nan), field.status)
            lu, lv = field.u.ravel(), field.v.ravel()
            if s.incremental:
                right, cross = self._stereo_at(pairs[k], X + lu, Y + lv, cross)
            else:
                start = _shifted(cross, lu - prev_u, lv - prev_v)
                cross = correlate_pair(left0, pairs[k][1], g, s.dic, self.seeds, start=start).points
                right = _match(g, cross, X, Y)
                prev_u, prev_v = np.where(np.isfinite(lu), lu, prev_u), np.where(np.isfinite(lv), lv, prev_v)
            yield self._state(k, left, right, first.points)

    def _stereo_at(self, pair, xs, ys, prev: PointResult) -> tuple[CameraMatch, PointResult]:
        """Incremental mode: left_s -> right_s with subsets around the tracked left positions (xs, ys),
        each from its previous stereo warp; the right match as a CameraMatch about the grid points."""
        s = self.s.dic
        lb = BSplineImage.from_image(pair[0], s.order, s.prefilter_sigma)
        rb = BSplineImage.from_image(pair[1], s.order, s.prefilter_sigma)
        track = np.isfinite(xs) & np.isfinite(ys) & (prev.status == OK)
        warp = prev.warp.copy()
        res = PointResult(warp, np.full(xs.size, np.nan), np.zeros(xs.size, np.int32),
                          np.where(track, UNREACHED, prev.status).astype(np.int8))
        if track.any():
            r = correlate_points(lb, rb, xs[track], ys[track], warp[track], s)
            res.warp[track], res.zncc[track], res.iterations[track], res.status[track] = (
                r.warp, r.zncc, r.iterations, r.status)
        return _match(self.grid, res, np.where(track, xs, 0.0), np.where(track, ys, 0.0)), res

    def _state(self, k: int, left: CameraMatch, right: CameraMatch, ref_points: np.ndarray | None) -> StereoState:
        g = self.grid
        X, Y = g.points()
        both = (left.ok & right.ok).ravel()
        pts = np.full((X.size, 3), np.nan)
        gap = np.full(X.size, np.nan)
        if both.any():
            t = triangulate(self.rig, X[both] + left.u.ravel()[both], X[both] + right.u.ravel()[both],
                            Y[both] + left.v.ravel()[both], Y[both] + right.v.ravel()[both], corrected=True)
            pts[both], gap[both] = t.points, t.gap_mm
        gap_ok = ~(gap > self.max_gap_mm).reshape(g.shape)
        ref_ok = np.ones(g.shape, bool) if ref_points is None else np.isfinite(ref_points).all(-1)
        converged, status = _combine(left, right, gap_ok, ref_ok)
        pts = np.where(converged[..., None], pts.reshape(g.shape + (3,)), np.nan)
        disp = pts - (pts if ref_points is None else ref_points)
        strain = None
        if self.s.strain_window:
            base = pts if ref_points is None else ref_points
            strain = strain_3d(base, disp, self.s.strain_window)
        return StereoState(k, left, right, pts, disp, np.where(converged, gap.reshape(g.shape), np.nan),
                           converged, status, strain)

"""A rig whose calibration no longer fits its images: the rows' offsets measured in the reference pair,
the stereo search that follows them, and the rig's relative orientation fitted again from the matched
speckle.

Positions are in the rectified (virtual) images of the rig, pixels, x = column, y = row; rays and
centres in the rig's frame (the WCS of its rays), mm.

Row offsets. In a rectified pair a scene point is seen on one row of both images; a camera that moved
after its calibration moves the right image's rows by dy(x, y) = y_right - y_left, a smooth field (a
turn of the camera: a shift, a tilt, a slight bend). `measure_row_offsets` matches the two images'
features, at most max_dy rows apart, refined by IC-GN (`rectify.row_alignment`) and fits dy with a quadratic
surface in (x, y) (least squares, the matches beyond 5 robust standard deviations left out); the seeds
of the stereo match then search a band about the fitted offset (`offset_seed_search`) instead of the
row itself.

Relative orientation. Matches cannot fix the scale, so the baseline stays the calibration's (both
centres kept) and the left camera stays as it is: the right camera is turned about its optical centre by
a rotation R. Of a turn's three axes the rows tell two: a turn about the baseline shifts the right rows
up or down, a turn about the viewing direction (the sensor's normal) tilts them; a turn about the third
axis (perpendicular to both) moves the right image along its rows, which only changes the depth, like
the baseline's length, and bends the rows by a second-order amount that a flat specimen cannot tell
from a wrong focal length: it is kept. For a match, the left ray (C_L, d_l) and the turned right ray
(C_R, R d_r) must meet: their signed distance (b . n / |n|, n = d_l x R d_r), in virtual pixel pitches,
is the residual; the two angles are fitted by least squares with a soft-L1 loss (a few false matches
weigh little). `refit_rig` then rebuilds the rectified pair on the same sensor (the plane is parallel
to the unchanged baseline): the right camera's IMM and model-less directions resampled from the old
ones along the turned rays from its centre (exact for central lenses). Where a new virtual pixel samples
beyond the old virtual image it is blank (a band as wide as the turn moves the image). A right camera of a
parametric model (an imported calibration) is turned in its model instead and computed from it exactly,
so it has no such band: only where its real image ends.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np

from stereodic.dic import ImageRef
from stereodic.dic3d.epipolar import EpipolarReport, check
from stereodic.virtual.imm import BLANK, IMM
from stereodic.stereo.rectify import RowAlignment, row_alignment
from stereodic.stereo.rig import Rig, RigCamera
from stereodic.virtual.sampling import bilinear
from stereodic.stereo.triangulate import rays_at

MATCH_HALF = 10       # half-width of the features' subsets (row_alignment's)
BUMP_DEG = 1.0        # a larger correction is warned about: more than a knock turns a camera on its mount
FEATURES = 300        # matched features refined, at most (row_alignment's count)


@dataclass
class RowOffsets:
    """The rows' offsets of a rectified pair: the matched features (`rectify.RowAlignment`), the
    quadratic surface dy = c0 + c1 x + c2 y + c3 x^2 + c4 x y + c5 y^2 fitted to them (coef, pixels) and
    the robust standard deviation of the fit's residuals (spread_px); inliers: the matches it kept."""

    matches: RowAlignment
    coef: tuple[float, ...]
    spread_px: float
    inliers: np.ndarray

    def predict(self, x, y) -> np.ndarray:
        """The fitted row offset (pixels) at left positions (x, y)."""
        return offset_at(self.coef, x, y)

    @property
    def band(self) -> int:
        """Rows above and below the fitted offset that a seed search covers: the fit's largest residual
        and 2 rows of margin."""
        m = self.matches
        resid = np.abs(m.dy[self.inliers] - self.predict(m.x[self.inliers], m.y[self.inliers]))
        return int(np.ceil(max(float(resid.max()), 3 * self.spread_px))) + 2

    def line(self) -> str:
        dy = self.matches.dy[self.inliers]
        return (f"rows of the reference pair: the right image's rows are {np.min(dy):+.1f} to {np.max(dy):+.1f} px "
                f"(median {np.median(dy):+.2f}) off the left's over {dy.size} matched features")


def _terms(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return np.stack([np.ones_like(x), x, y, x * x, x * y, y * y], axis=-1)


def offset_at(coef: tuple[float, ...], x, y) -> np.ndarray:
    """The row offset (pixels) of the quadratic surface `coef` (`RowOffsets.coef`) at left positions (x, y)
    (arrays of one shape, pixels)."""
    return _terms(np.asarray(x, np.float64), np.asarray(y, np.float64)) @ np.asarray(coef, np.float64)


def measure_row_offsets(left: np.ndarray, right: np.ndarray, *, max_dy: int | None = None) -> RowOffsets | None:
    """The rows' offsets of a rectified pair (module docstring).

    Parameters
    ----------
    left, right : (H, W) array
        The rectified pair, pixels (blank pixels 0).
    max_dy : int, optional
        Rows above and below its own that a feature's match is accepted in; None: `rectify.row_band`.

    Returns
    -------
    offsets : RowOffsets or None
        The matches and the fitted surface, pixels; None when fewer than 12 features match.
    """
    m = row_alignment(left, right, max_dy=max_dy, half=MATCH_HALF, count=FEATURES)
    if m.dy.size < 12:
        return None
    scale = float(max(left.shape))            # the surface's terms in units of the image size: well conditioned
    A = _terms(m.x / scale, m.y / scale)
    keep = np.ones(m.dy.size, bool)
    for _ in range(3):
        c = np.linalg.lstsq(A[keep], m.dy[keep], rcond=None)[0]
        r = m.dy - A @ c
        spread = 1.4826 * float(np.median(np.abs(r[keep] - np.median(r[keep]))))
        keep = np.abs(r) <= max(5 * spread, 0.05)
    c = np.linalg.lstsq(A[keep], m.dy[keep], rcond=None)[0]
    coef = c / np.array([1, scale, scale, scale ** 2, scale ** 2, scale ** 2])
    return RowOffsets(m, tuple(float(v) for v in coef), spread, keep)


def offset_seed_search(dmin: int, dmax: int, coef: tuple[float, ...], rows: int):
    """A seed search with `stereodic.dic.search_integer`'s signature (its radius and centre ignored) for
    a rectified pair whose rows are off by the surface `coef` (`RowOffsets.coef`): shifts dmin..dmax
    along the row and `rows` rows either side of the fitted offset (cv2.matchTemplate, ZNCC)."""
    def search(ref, dfm, x, y, half, radius, centre):
        h, w = ref.shape
        if not (half <= x < w - half and half <= y < h - half):
            return 0, 0, -1.0
        dv0 = int(round(float(offset_at(coef, x, y))))
        lo, hi = max(x + dmin, half), min(x + dmax, w - 1 - half)
        top, bottom = max(y + dv0 - rows, half), min(y + dv0 + rows, h - 1 - half)
        if hi < lo or bottom < top:
            return 0, 0, -1.0
        tpl = np.ascontiguousarray(ref[y - half:y + half + 1, x - half:x + half + 1], np.float32)
        band = np.ascontiguousarray(dfm[top - half:bottom + half + 1, lo - half:hi + half + 1], np.float32)
        score = np.nan_to_num(cv2.matchTemplate(band, tpl, cv2.TM_CCOEFF_NORMED), nan=-1.0)
        r, c = np.unravel_index(int(np.argmax(score)), score.shape)
        return int(lo + c - x), int(top + r - y), float(score[r, c])
    return search


def pair_report(rig: Rig, left: np.ndarray, offsets: RowOffsets) -> EpipolarReport | None:
    """`epipolar.check` of the offsets' matched features (their inliers), with their predicted noise in
    the left image."""
    m, k = offsets.matches, offsets.inliers
    noise = ImageRef.prepare(np.asarray(left, np.float32)).noise(m.x[k], m.y[k], MATCH_HALF)   # `left`'s B-spline
    return check(rig, m.x[k], m.y[k], m.x_right[k], m.y[k] + m.dy[k], noise)


@dataclass
class RigCorrection:
    """The right camera's correction: about_baseline, about_view: its turns (degrees) about the baseline
    (rows shift) and about the viewing direction (rows tilt), right-handed in the rig frame; R (3, 3) the
    turn; before, after: the epipolar error of the reference pair's matched features with the calibration
    and with the corrected rig (None: no feature matched)."""

    about_baseline: float
    about_view: float
    R: np.ndarray
    before: EpipolarReport
    after: EpipolarReport | None

    @property
    def angle_deg(self) -> float:
        return float(np.degrees(np.linalg.norm(cv2.Rodrigues(np.asarray(self.R, np.float64))[0])))

    def line(self) -> str:
        after = (f"median {self.after.median:+.3f} px, p95 {self.after.p95:.3f} px" if self.after is not None
                 else "not measured (no feature matched)")
        return (f"the rig's calibration does not fit these images: its right camera turned by {self.angle_deg:.4f} "
                f"deg ({self.about_baseline:+.4f} about the baseline, {self.about_view:+.4f} about the viewing "
                f"direction) from the reference pair's speckle, centres kept (0 mm: matches cannot fix the scale); "
                f"epipolar error median {self.before.median:+.3f} px, p95 {self.before.p95:.3f} px before, {after} "
                f"after (--keep-rig: keep the calibration as it is)")


def _axes(rig: Rig) -> tuple[np.ndarray, np.ndarray]:
    """(baseline unit vector, viewing direction: the sensor's normal less its baseline component)."""
    e1 = rig.baseline / np.linalg.norm(rig.baseline)
    n = rig.sensor.normal - (rig.sensor.normal @ e1) * e1
    return e1, n / np.linalg.norm(n)


def fit_orientation(rig: Rig, xl, yl, xr, yr) -> tuple[float, float]:
    """The right camera's turns about the baseline and about the viewing direction that make the
    matches' rays meet (module docstring).

    Parameters
    ----------
    rig : Rig
        The calibrated rectified pair.
    xl, yl, xr, yr : (N,) float
        Matches (xl, yl) <-> (xr, yr) in the rectified pair, pixels (N >= 2).

    Returns
    -------
    about_baseline, about_view : float
        The turns, degrees, right-handed about the baseline (left to right centre) and the viewing
        direction (`turn` makes the rotation).
    """
    _, dl = rays_at(rig, "left", np.asarray(xl, np.float64), np.asarray(yl, np.float64))
    _, dr = rays_at(rig, "right", np.asarray(xr, np.float64), np.asarray(yr, np.float64))
    ok = np.isfinite(dl).all(1) & np.isfinite(dr).all(1)
    dl, dr = dl[ok], dr[ok]
    b, pitch = rig.baseline, float(rig.sensor.pitch_mm[1])

    def residuals(p):
        n = np.cross(dl, dr @ turn(rig, *p).T)
        return (n @ b) / np.linalg.norm(n, axis=1) / pitch

    from scipy.optimize import least_squares  # here: a refit only (0.2 s of import)
    fit = least_squares(residuals, np.zeros(2), loss="soft_l1", f_scale=0.5, x_scale=0.1)
    return float(fit.x[0]), float(fit.x[1])


def turn(rig: Rig, about_baseline: float, about_view: float) -> np.ndarray:
    """(3, 3) the rotation by `about_baseline` degrees about the rig's baseline and `about_view` degrees
    about its viewing direction (one rotation vector)."""
    e1, n = _axes(rig)
    return cv2.Rodrigues(np.radians(about_baseline) * e1 + np.radians(about_view) * n)[0]


def refit_rig(rig: Rig, R: np.ndarray) -> Rig:
    """The rectified pair rebuilt with the right camera turned by R about its centre (module docstring).

    Parameters
    ----------
    rig : Rig
        The calibrated rectified pair.
    R : (3, 3) float
        The right camera's turn, rig frame (`turn`): its real rays are R times the rig's.

    Returns
    -------
    rig : Rig
        The same sensor, left camera, centres, model and reporting frame. A right camera of a parametric
        model (`stereodic import`) gets its model turned, its IMM and directions computed from it exactly
        (`exact_camera`: no blank band beyond what its real image covers); any other has its IMM and
        model-less directions resampled (blank where its new rays sample beyond the old virtual image).
    """
    cam, s = rig.right, rig.sensor
    if cam.model is not None:
        return replace(rig, right=RigCamera(cam.name, cam.centre, None, None, cam.im, dict(cam.info),
                                            turned_model(cam.model, R, cam.frame), cam.frame, cam.sensor))
    d = (s.grid() - cam.centre) @ np.asarray(R, np.float64)   # rows: R^T (p - C), the calibrated ray
    uv = s.intersect(cam.centre, d)
    real = cam.imm.real_position(uv[..., 0], uv[..., 1])
    valid = np.isfinite(real).all(axis=-1)
    maps = [np.where(valid, real[..., i], BLANK).astype(np.float32) for i in range(2)]
    direction = bilinear(cam.direction, uv[..., 0], uv[..., 1]) @ np.asarray(R, np.float64).T
    direction /= np.linalg.norm(direction, axis=-1, keepdims=True)
    direction[~valid] = np.nan
    right = RigCamera(cam.name, cam.centre, IMM(*maps, valid, cam.imm.real_size), direction, cam.im,
                      dict(cam.info, blank_pixels=int((~valid).sum())))
    return replace(rig, right=right)


def turned_model(model, R: np.ndarray, frame: np.ndarray):
    """A parametric camera (`calib.camera_models.CameraModel`, in the world frame of `frame` =
    world_from_rig (4, 4)) turned about its optical centre by R (3, 3, rig frame; `turn`): it sees a point
    p where the model saw C + R^T (p - C), C its centre. Returns the model with its pose R, t changed (the
    centre, the intrinsics and the lens kept)."""
    F = np.asarray(frame, np.float64)[:3, :3]
    W = F @ np.asarray(R, np.float64).T @ F.T               # R^T in the world frame
    centre = model.centre
    rot = model.R @ W
    return replace(model, R=rot, t=-rot @ centre)


def correct_rig(rig: Rig, left: np.ndarray, right: np.ndarray, offsets: RowOffsets, before: EpipolarReport,
                rectify) -> tuple[Rig, RigCorrection, RowOffsets | None]:
    """The rig re-oriented from a reference pair whose rows are off (`fit_orientation`, `refit_rig`).

    Parameters
    ----------
    rig : Rig
        The calibrated rectified pair.
    left, right : (H, W) array
        The reference pair rectified with it.
    offsets : RowOffsets
        Their rows' offsets (`measure_row_offsets`).
    before : EpipolarReport
        Their epipolar error with the calibration (`pair_report`).
    rectify : callable
        rectify(rig) -> the reference pair rectified with another rig.

    Returns
    -------
    rig : Rig
        The corrected rig.
    correction : RigCorrection
        The turn and the epipolar error before and after.
    offsets : RowOffsets or None
        The corrected pair's rows' offsets (None: no feature matched).
    """
    m, k = offsets.matches, offsets.inliers
    a, c = fit_orientation(rig, m.x[k], m.y[k], m.x_right[k], m.y[k] + m.dy[k])
    R = turn(rig, a, c)
    fixed = refit_rig(rig, R)
    left2, right2 = rectify(fixed)
    after = measure_row_offsets(left2, right2)
    report = pair_report(fixed, left2, after) if after is not None else None
    return fixed, RigCorrection(a, c, R, before, report), after


@dataclass
class ReferenceGeometry:
    """What the reference pair says about the rig: rig (the one to use: the calibration's, or
    corrected), offsets (its rows' offsets in the reference pair, None: no feature matched), before (the
    epipolar error of the calibration, None: not measured), correction (None: the calibration kept),
    notes (lines for the user)."""

    rig: Rig
    offsets: RowOffsets | None
    before: EpipolarReport | None
    correction: RigCorrection | None
    notes: list[str]

    def settings(self, settings, *, band: int | None = None):
        """The stereo settings (`stereo.StereoSettings`) with the seeds' search about the measured rows'
        offsets when the rig does not fit (`band` rows either side; None: the fit's own band) and the
        rig's rows otherwise (`band` rows either side; None: 0)."""
        follow = self.offsets is not None and (self.correction is not None or (self.before and self.before.bumped))
        if not follow:
            return replace(settings, row_offsets=(), vertical_search=band or 0)
        return replace(settings, row_offsets=self.offsets.coef,
                       vertical_search=self.offsets.band if band is None else band)


def reference_geometry(rig: Rig, rectify, *, keep_rig: bool = False, max_gap_px: float = 1.0,
                       rig_name: str = "the rig") -> ReferenceGeometry:
    """Measure the reference pair's rows' offsets and, when the rig does not fit them, re-orient its
    right camera (module docstring).

    Parameters
    ----------
    rig : Rig
        The calibrated rectified pair.
    rectify : callable
        rectify(rig) -> the reference pair (left, right) rectified with a rig.
    keep_rig : bool
        Keep the calibration as it is: InputError naming --keep-rig when its rows are off by more than
        `max_gap_px` (95th percentile), a warning note otherwise.
    max_gap_px : float
        Rows off by which a match is trusted, pixels.
    rig_name : str
        The rig's file, in messages.

    Returns
    -------
    geometry : ReferenceGeometry
        The rig to use, the offsets, the correction and the notes.
    """
    from calib.errors import InputError
    left, right = rectify(rig)
    offsets = measure_row_offsets(left, right)
    if offsets is None:
        return ReferenceGeometry(rig, None, None, None, [
            "rows of the reference pair: fewer than 12 features of the left image matched in the right one (no "
            "speckle in common?): the stereo seeds search along the rig's rows"])
    before = pair_report(rig, left, offsets)
    notes = [offsets.line()]
    if before is None or not before.bumped:
        return ReferenceGeometry(rig, offsets, before, None, notes)
    if keep_rig:
        if before.p95 > max_gap_px:
            dy = offsets.matches.dy[offsets.inliers]
            raise InputError("--keep-rig", f"{rig_name} does not fit these images: the reference pair's rows are "
                                           f"{dy.min():+.1f} to {dy.max():+.1f} px off (epipolar error p95 "
                                           f"{before.p95:.2f} px, it allows {before.expected_p95:.3f}, matches are "
                                           f"trusted to --max-gap {max_gap_px:g}); leave out --keep-rig to re-orient "
                                           f"its right camera from the speckle")
        notes.append(f"warning: {before.line()}: has a camera moved since the calibration? (--keep-rig: kept; the "
                     f"stereo search follows the measured rows)")
        return ReferenceGeometry(rig, offsets, before, None, notes)
    fixed, correction, after = correct_rig(rig, left, right, offsets, before, rectify)
    notes.append(correction.line())
    if correction.angle_deg > BUMP_DEG:
        notes.append(f"warning: a turn of {correction.angle_deg:.2f} deg is more than a bumped camera's: are the "
                     f"cameras swapped (--left-suffix/--right-suffix, --left/--right), or is {rig_name} the rig of "
                     f"another setup?")
    return ReferenceGeometry(fixed, after, before, correction, notes)

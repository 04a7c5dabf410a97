"""Where the display stands relative to a camera, from what the camera's pixels see of it: the readings of
the alignment aid (the seed's reduced-dimensional PRVM wants the camera square to the display; tip 2.1
wants the stage axis along the display's normal).

Frames. A camera's rays (`PrvmRays`, `PinholeRays`) live in a frame of their own (mm): a PRVM's WCS,
or a pinhole camera's frame (x right, y down, z forward). The display frame is DESIGN.md's: x along the
display's columns, y along its rows (down), z along its normal away from the camera; display pixel
(c, r) lies at (c * pitch_x, r * pitch_y, 0). `fit_display_pose` finds the display's pose in the rays'
frame, X_rays = R @ X_display + t, by least squares on the decoded points: every pixel's ray must meet
the posed display plane at the display point the pixel decoded (residuals in display mm). That is exact
for any lens, central or not, whose rays are known; no pinhole model enters. The start comes from the
homography between display points and the rays' slopes seen from the projection centre.

Readings (`read_alignment`), all in the display's frame and defined by the rays alone:
- line of sight: the ray of the image centre ((W-1)/2, (H-1)/2), direction a = (a_x, a_y, a_z).
  tilt_x = atan2(-a_y, a_z): rotation about the camera's x axis, positive when the camera looks up the
  screen; tilt_y = atan2(a_x, a_z): about its y axis, positive when it looks to the right (as seen
  from the camera). The camera is square to the display when both are 0.
- roll: the direction on the display of the image's central row, from the point seen by pixel
  ((W-1)/4, (H-1)/2) to the one seen by (3(W-1)/4, (H-1)/2): atan2(dy, dx); positive when the row runs
  down to the right on the screen (the camera turned clockwise as seen from behind it).
- distance: from the projection centre to the display plane, along the normal (mm).
- the captured crosshair's centre: where the line of sight meets the display; the expected one: the
  foot of the perpendicular from the projection centre, where the line of sight meets the display once
  the camera is turned square about its centre. They lie distance * tan(tilt) apart.

Without intrinsics, `PatternIntrinsics` estimates a pinhole from the homography alone (principal point at
the image centre, square pixels, no distortion, the focal length from Zhang's two constraints on the
most oblique view so far); its accuracy is in docs/real-bench.md. `stage_axis` turns two poses at two
stage positions into the direction the display travels: the drift of the display across its own plane
per mm of travel.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from calib.camera_models import CameraModel, unproject
from calib.prvm_file import PRVM

# a view whose display normal is within this angle of the camera's axis does not fix the focal length
MIN_OBLIQUITY_DEG = 3.0


class PrvmRays:
    """The rays of a PRVM (its WCS, mm), bilinear between pixel centres (exact at integer pixels).

    centre: (3,) the projection centre (the point nearest to all rays, e.g.
    `stereodic.virtual.camera.fit_optical_centre`), for the distance and the expected crosshair.
    """

    kind = "prvm"

    def __init__(self, prvm: PRVM, centre):
        self.prvm = prvm
        self.width, self.height = prvm.width, prvm.height
        self.valid = prvm.valid
        self.centre = np.asarray(centre, np.float64).reshape(3)

    def rays(self, u, v) -> tuple[np.ndarray, np.ndarray]:
        """(origin, direction) (..., 3) of pixel coordinates (u, v) (arrays of one shape); NaN outside the
        sensor or next to an invalid pixel."""
        u, v = np.broadcast_arrays(np.asarray(u, np.float64), np.asarray(v, np.float64))
        w, h = self.width, self.height
        inside = (u >= 0) & (u <= w - 1) & (v >= 0) & (v <= h - 1)
        u0 = np.clip(np.floor(np.where(inside, u, 0)), 0, w - 2).astype(int)
        v0 = np.clip(np.floor(np.where(inside, v, 0)), 0, h - 2).astype(int)
        fu, fv = np.where(inside, u, 0) - u0, np.where(inside, v, 0) - v0
        o = np.zeros(u.shape + (3,))
        d = np.zeros(u.shape + (3,))
        ok = inside.copy()
        for du, dv, wt in ((0, 0, (1 - fu) * (1 - fv)), (1, 0, fu * (1 - fv)), (0, 1, (1 - fu) * fv),
                           (1, 1, fu * fv)):
            uu, vv = u0 + du, v0 + dv
            ok &= self.valid[vv, uu] | (wt == 0)
            o += wt[..., None] * self.prvm.origin[vv, uu]
            d += wt[..., None] * self.prvm.direction[vv, uu]
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        o[~ok] = np.nan
        d[~ok] = np.nan
        return o, d


class PinholeRays:
    """The rays of an OpenCV pinhole camera in its own frame: K (3, 3) pixels, dist (n,) OpenCV
    distortion coefficients; every ray leaves the origin. kind: "pinhole" (a calibration file) or
    "pattern" (estimated from the pattern alone)."""

    def __init__(self, K, dist, width: int, height: int, *, kind: str = "pinhole"):
        self.K = np.asarray(K, np.float64).reshape(3, 3)
        self.dist = np.zeros(5) if dist is None else np.asarray(dist, np.float64).ravel()
        self.width, self.height, self.kind = int(width), int(height), kind
        self.valid = np.ones((self.height, self.width), bool)
        self.centre = np.zeros(3)

    def rays(self, u, v) -> tuple[np.ndarray, np.ndarray]:
        u, v = np.broadcast_arrays(np.asarray(u, np.float64), np.asarray(v, np.float64))
        k = self.K
        model = CameraModel(k[0, 0], k[1, 1], k[0, 2], k[1, 2], k[0, 1], "opencv", self.dist)
        d, _ = unproject(model, np.stack([u.ravel(), v.ravel()], axis=-1))
        return np.zeros(u.shape + (3,)), d.reshape(u.shape + (3,))


@dataclass
class PoseFit:
    """The display's pose in the rays' frame: X_rays = rotation @ X_display + translation (mm);
    rms_px: RMS distance (display pixels) between where the rays meet the posed display and the points
    decoded there; points: how many pixels were used."""

    rotation: np.ndarray
    translation: np.ndarray
    rms_px: float
    points: int

    @property
    def normal(self) -> np.ndarray:
        """(3,) the display's normal in the rays' frame (away from the camera)."""
        return self.rotation[:, 2]

    def to_display(self, points: np.ndarray) -> np.ndarray:
        """Display-frame coordinates (..., 3) of rays-frame points (..., 3)."""
        return (np.asarray(points) - self.translation) @ self.rotation

    def hit(self, origin: np.ndarray, direction: np.ndarray, pitch_mm) -> np.ndarray:
        """(..., 2) display pixels (c, r) where rays (rays' frame) meet the display plane."""
        n = self.normal
        lam = ((self.translation - origin) @ n) / (direction @ n)
        q = self.to_display(origin + lam[..., None] * direction)
        return q[..., :2] / np.asarray(pitch_mm, float)


def _initial_pose(direction: np.ndarray, display_mm: np.ndarray, centre: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closed-form pose from the homography display (x, y) -> ray slopes seen from `centre` (exact for a
    central camera, a start for others)."""
    pick = slice(None, None, max(1, len(direction) // 2000))     # a start needs few points
    slopes = direction[pick, :2] / direction[pick, 2:3]
    g, _ = cv2.findHomography(display_mm[pick], slopes, 0)
    if g is None:
        raise ValueError("the decoded display points do not determine a pose")
    lam = 2.0 / (np.linalg.norm(g[:, 0]) + np.linalg.norm(g[:, 1]))
    mid = np.append(display_mm.mean(axis=0), 1.0)
    if (g @ mid) @ direction.mean(axis=0) < 0:               # the display lies in front of the camera
        lam = -lam
    r1, r2 = lam * g[:, 0], lam * g[:, 1]
    u, _, vt = np.linalg.svd(np.stack([r1, r2, np.cross(r1, r2)], axis=1))
    rot = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
    return rot, centre + lam * g[:, 2]


def _cross_matrix(v: np.ndarray) -> np.ndarray:
    """(N, 3, 3) matrices [v]x with [v]x w = v x w."""
    m = np.zeros(v.shape[:-1] + (3, 3))
    m[..., 0, 1], m[..., 0, 2], m[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    return m - np.swapaxes(m, -1, -2)


def _refine(rot, t, o, d, x, iterations: int = 30):
    """Gauss-Newton on the pose: each ray (o, d) in the rays' frame must meet the display plane at the
    display point x (mm). The update turns the display by a small rotation and shifts it, both in its own
    frame. Returns the pose and the (N, 2) residuals (mm)."""
    for _ in range(iterations):
        op, dp = (o - t) @ rot, d @ rot                     # rays in the display frame
        s = op[:, 2] / dp[:, 2]
        r = op[:, :2] - s[:, None] * dp[:, :2] - x
        slope = dp[:, :2] / dp[:, 2:3]
        a = np.zeros((len(o), 2, 3))                        # d(hit) / d(origin)
        a[:, 0, 0] = a[:, 1, 1] = 1.0
        a[:, :, 2] = -slope
        b = -s[:, None, None] * a                           # d(hit) / d(direction)
        jac = np.concatenate([a @ _cross_matrix(op) + b @ _cross_matrix(dp), -a], axis=2).reshape(-1, 6)
        step = np.linalg.solve(jac.T @ jac, -jac.T @ r.ravel())
        t = t + rot @ step[3:]
        rot = rot @ Rotation.from_rotvec(step[:3]).as_matrix()
        if np.abs(step).max() < 1e-12:
            break
    op, dp = (o - t) @ rot, d @ rot
    return rot, t, op[:, :2] - (op[:, 2] / dp[:, 2])[:, None] * dp[:, :2] - x


def fit_display_pose(model, coord: np.ndarray, valid: np.ndarray, pitch_mm, *, max_points: int = 20_000) -> PoseFit:
    """The display's pose in the frame of `model`'s rays from the decoded display coordinates.

    model: `PrvmRays` or `PinholeRays`; coord: (2, H, W) display pixels seen by each camera pixel;
    valid: (H, W) bool; pitch_mm: (pitch_x, pitch_y) of the display. Uses an even sub-grid of at most
    ~max_points pixels; after the first fit, points more than 5 RMS (and 1 display pixel) off are left
    out and the pose refitted. Raises ValueError with fewer than 100 usable pixels.
    """
    pitch = np.asarray(pitch_mm, np.float64)
    use = valid & model.valid
    if use.sum() < 100:
        raise ValueError(f"only {int(use.sum())} camera pixels decoded the display")
    step = max(1, int(np.sqrt(use.sum() / max_points)))
    v, u = np.nonzero(use[::step, ::step])
    v, u = v * step, u * step
    o, d = model.rays(u.astype(np.float64), v.astype(np.float64))
    x = np.stack([coord[0][v, u], coord[1][v, u]], axis=1) * pitch
    ok = np.isfinite(o).all(axis=1) & np.isfinite(d).all(axis=1)
    o, d, x = o[ok], d[ok], x[ok]
    rot, t = _initial_pose(d, x, model.centre)
    rot, t, r = _refine(rot, t, o, d, x)
    dist = np.linalg.norm(r / pitch, axis=1)
    keep = dist <= max(5 * np.sqrt(np.mean(dist ** 2)), 1.0)
    if not keep.all():
        rot, t, r = _refine(rot, t, o[keep], d[keep], x[keep])
        dist = np.linalg.norm(r / pitch, axis=1)
    return PoseFit(rot, t, float(np.sqrt(np.mean(dist ** 2))), int(len(dist)))


@dataclass
class Reading:
    """The camera against the display (see the module docstring): tilt_x_deg, tilt_y_deg, roll_deg
    (degrees), distance_mm; line_of_sight_px and foot_px: (2,) display pixels of the captured and the
    expected crosshair's centre; rms_px: the pose fit's residual (display pixels)."""

    tilt_x_deg: float
    tilt_y_deg: float
    roll_deg: float
    distance_mm: float
    line_of_sight_px: np.ndarray
    foot_px: np.ndarray
    rms_px: float

    def square_within(self, tolerance_deg: float) -> bool:
        """Whether both tilts are within `tolerance_deg` (degrees)."""
        return abs(self.tilt_x_deg) <= tolerance_deg and abs(self.tilt_y_deg) <= tolerance_deg

    def to_json(self) -> dict:
        return {"tilt_x_deg": self.tilt_x_deg, "tilt_y_deg": self.tilt_y_deg, "roll_deg": self.roll_deg,
                "distance_mm": self.distance_mm, "line_of_sight_px": [float(x) for x in self.line_of_sight_px],
                "foot_px": [float(x) for x in self.foot_px], "rms_px": self.rms_px}


def _centre_pixels(model) -> tuple[np.ndarray, np.ndarray]:
    """u, v of the line of sight's pixel and of the row's two chord ends (image centre, 1/4 and 3/4 width)."""
    w, h = model.width - 1, model.height - 1
    return np.array([w / 2, w / 4, 3 * w / 4]), np.full(3, h / 2)


def read_alignment(model, fit: PoseFit, pitch_mm) -> Reading:
    """The readings of a camera (`model`) whose display pose is `fit`; ValueError if the image centre's
    pixels have no ray."""
    o, d = model.rays(*_centre_pixels(model))
    if not np.isfinite(d).all():
        raise ValueError("the pixels at the image centre have no ray in the camera model")
    a = d[0] @ fit.rotation                                     # line of sight in the display frame
    hits = fit.hit(o, d, pitch_mm)
    chord = hits[2] - hits[1]
    centre = fit.to_display(model.centre)
    return Reading(float(np.degrees(np.arctan2(-a[1], a[2]))), float(np.degrees(np.arctan2(a[0], a[2]))),
                   float(np.degrees(np.arctan2(chord[1], chord[0]))), float(-centre[2]), hits[0],
                   centre[:2] / np.asarray(pitch_mm, float), fit.rms_px)


def display_points(model, fit: PoseFit, u, v, pitch_mm) -> np.ndarray:
    """(..., 2) display pixels seen by camera pixels (u, v) (NaN where there is no ray)."""
    return fit.hit(*model.rays(u, v), pitch_mm)


def square_points(model, fit: PoseFit, u, v, pitch_mm) -> np.ndarray:
    """(..., 2) display pixels that camera pixels (u, v) would see with the camera turned about its
    projection centre until square (line of sight along the normal, central row along the display's x)."""
    o, d = model.rays(*_centre_pixels(model))
    hits = fit.hit(o, d, pitch_mm) * np.asarray(pitch_mm, float)
    z = d[0] @ fit.rotation
    x = np.append(hits[2] - hits[1], 0.0)
    x -= (x @ z) * z
    x /= np.linalg.norm(x)
    turn = np.stack([x, np.cross(z, x), z])                    # display frame -> the square camera's
    c = fit.to_display(model.centre)
    o, d = model.rays(u, v)
    o2 = c + (fit.to_display(o) - c) @ turn.T
    d2 = (d @ fit.rotation) @ turn.T
    p = o2 - (o2[..., 2] / d2[..., 2])[..., None] * d2
    return p[..., :2] / np.asarray(pitch_mm, float)


@dataclass
class StageAxis:
    """The stage's direction of travel in the display's frame, from the display poses at two stage
    positions.

    axis: (3,) unit vector (z > 0, away from the camera): DESIGN.md's `stage.axis`. angle_x_deg,
    angle_y_deg: its angle from the display's normal towards the display's +x (right, as seen from the
    camera) and +y (down): atan(a_x / a_z), atan(a_y / a_z). drift: (2,) the display's sideways drift per mm
    of travel (a_x / a_z, a_y / a_z). travel_mm: the travel measured between the poses; commanded_mm:
    the travel the stage was told; rotation_deg: how far the display turned between the positions
    (carriage pitch and yaw).
    """

    axis: np.ndarray
    angle_x_deg: float
    angle_y_deg: float
    drift: np.ndarray
    travel_mm: float
    commanded_mm: float
    rotation_deg: float

    def to_json(self) -> dict:
        return {"axis": [float(a) for a in self.axis], "angle_x_deg": self.angle_x_deg,
                "angle_y_deg": self.angle_y_deg, "drift_um_per_mm": [float(1000 * s) for s in self.drift],
                "travel_mm": self.travel_mm, "commanded_mm": self.commanded_mm, "rotation_deg": self.rotation_deg}


def stage_axis(first: PoseFit, second: PoseFit, commanded_mm: float) -> StageAxis:
    """The stage axis from the display poses at two stage positions `commanded_mm` apart (mm), both in
    the frame of the same (unmoved) camera's rays. The display may be the moving part or the camera:
    the relative motion is the same line."""
    move = (second.translation - first.translation) @ first.rotation
    travel = float(np.linalg.norm(move))
    a = move / travel if travel > 0 else np.array([0.0, 0.0, 1.0])
    a = a if a[2] >= 0 else -a
    turn = Rotation.from_matrix(first.rotation.T @ second.rotation).magnitude()
    return StageAxis(a, float(np.degrees(np.arctan2(a[0], a[2]))), float(np.degrees(np.arctan2(a[1], a[2]))),
                     a[:2] / a[2], travel, float(abs(commanded_mm)), float(np.degrees(turn)))


class PatternIntrinsics:
    """A pinhole camera estimated from the pattern alone, over a session: principal point at the image
    centre, square pixels, no distortion; the focal length from Zhang's two constraints on the homography
    of the most oblique view seen so far (a view within MIN_OBLIQUITY_DEG of square does not fix it).
    Before such a view the focal length is the image diagonal (a 53-degree diagonal field) and
    `focal_measured` is False. A known stage travel fixes it better (`scale_focal`): single views no
    longer change it then. focal_px: a known focal length (pixels) instead."""

    def __init__(self, width: int, height: int, *, focal_px: float | None = None):
        self.width, self.height = int(width), int(height)
        self.fixed = focal_px is not None
        self.focal_px = float(focal_px) if focal_px is not None else float(np.hypot(width, height))
        self.focal_measured = self.fixed
        self.obliquity_deg = 0.0
        self.from_travel = False

    def _k(self, f: float) -> np.ndarray:
        return np.array([[f, 0.0, (self.width - 1) / 2], [0.0, f, (self.height - 1) / 2], [0.0, 0.0, 1.0]])

    def update(self, homography: np.ndarray, pitch_mm) -> PinholeRays:
        """The camera model after one more view: `homography` (3, 3) display pixels -> image pixels."""
        if not self.fixed:
            h = np.linalg.inv(self._k(1.0)) @ homography @ np.diag([1 / pitch_mm[0], 1 / pitch_mm[1], 1.0])
            h1, h2 = h[:, 0], h[:, 1]
            a = np.array([h1[0] * h2[0] + h1[1] * h2[1], h1[0] ** 2 + h1[1] ** 2 - h2[0] ** 2 - h2[1] ** 2])
            b = np.array([h1[2] * h2[2], h1[2] ** 2 - h2[2] ** 2])
            w = -(a @ b) / (a @ a)
            if w > 0:
                f = 1 / np.sqrt(w)
                k = np.linalg.inv(self._k(f)) @ h
                r1, r2 = k[:, 0] / np.linalg.norm(k[:, 0]), k[:, 1] / np.linalg.norm(k[:, 1])
                n = np.cross(r1, r2)
                oblique = float(np.degrees(np.arccos(min(1.0, abs(n[2]) / np.linalg.norm(n)))))
                if oblique >= MIN_OBLIQUITY_DEG and oblique > self.obliquity_deg:
                    self.focal_px, self.obliquity_deg, self.focal_measured = float(f), oblique, True
        return self.model()

    def model(self) -> PinholeRays:
        """The camera model with the current focal length."""
        return PinholeRays(self._k(self.focal_px), None, self.width, self.height, kind="pattern")

    def scale_focal(self, ratio: float) -> PinholeRays:
        """Scale the focal length by `ratio` (a known stage travel over the travel measured with the
        current focal length: the distances a pinhole fit finds scale with it) and keep it."""
        self.focal_px *= float(ratio)
        self.focal_measured = self.from_travel = True
        self.obliquity_deg = np.inf
        return self.model()


__all__ = ["MIN_OBLIQUITY_DEG", "PrvmRays", "PinholeRays", "PoseFit", "fit_display_pose", "Reading",
           "read_alignment", "display_points", "square_points", "StageAxis", "stage_axis", "PatternIntrinsics"]

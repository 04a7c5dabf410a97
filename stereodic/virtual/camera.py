"""The virtual camera's geometry: fitted ray models and the virtual sensor plane (seed, "Virtual camera").

Everything here is in the WCS, millimetres. A virtual sensor is a plane with an even, rectangular pixel
grid: virtual pixel (U, V) (column, row; integers at pixel centres) lies at
`origin + U * pitch_u * axis_u + V * pitch_v * axis_v`. Its normal `axis_u x axis_v` points away from the
camera (the direction the rays travel), so a sensor facing the camera head-on has axis_u = +x,
axis_v = +y, normal = +z.

A virtual camera is a sensor plus a model for the rays of its pixels:
- "modelless": each virtual pixel keeps the real ray that crosses the plane there (error free);
- "pinhole": every ray passes through the optical centre fitted to all real rays;
- "telecentric": every ray is parallel to the fitted telecentric direction.
The image on the sensor is the same for all three (the Inverse Mapping Matrix depends on the plane
only); the model decides the rays of the Virtual PRVM and hence the Error Vector Matrix.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from calib.errors import InputError
from calib.prvm_file import PRVM
from stereodic.virtual.sampling import bilinear

MODELS = ("modelless", "pinhole", "telecentric")


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


@dataclass
class VirtualSensor:
    """An even pixel grid on a plane of the WCS.

    origin: (3,) mm, centre of virtual pixel (0, 0). axis_u, axis_v: (3,) orthonormal unit vectors along
    increasing column and row. pitch_mm: (pitch along u, pitch along v) in mm (a single number means
    square pixels). width, height: pixel count.
    """

    origin: np.ndarray
    axis_u: np.ndarray
    axis_v: np.ndarray
    pitch_mm: tuple[float, float]
    width: int
    height: int

    def __post_init__(self):
        self.origin = np.asarray(self.origin, dtype=np.float64).reshape(3)
        self.axis_u = _unit(self.axis_u).reshape(3)
        self.axis_v = _unit(self.axis_v).reshape(3)
        if abs(self.axis_u @ self.axis_v) > 1e-9:
            raise ValueError("virtual sensor axes are not orthogonal")
        pitch = np.broadcast_to(np.asarray(self.pitch_mm, dtype=np.float64), (2,))
        if not np.all(pitch > 0):
            raise ValueError(f"virtual pixel pitch must be positive, got {pitch}")
        self.pitch_mm = (float(pitch[0]), float(pitch[1]))
        self.width, self.height = int(self.width), int(self.height)

    @property
    def normal(self) -> np.ndarray:
        """(3,) unit normal of the plane, axis_u x axis_v (away from the camera)."""
        return np.cross(self.axis_u, self.axis_v)

    @property
    def centre(self) -> np.ndarray:
        """(3,) WCS mm of the middle of the pixel grid."""
        return self.points(np.array((self.width - 1) / 2), np.array((self.height - 1) / 2))

    def points(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """(..., 3) WCS mm of virtual pixel coordinates (u, v) (arrays of one shape)."""
        return (self.origin + (np.asarray(u, np.float64)[..., None] * self.pitch_mm[0]) * self.axis_u
                + (np.asarray(v, np.float64)[..., None] * self.pitch_mm[1]) * self.axis_v)

    def grid(self) -> np.ndarray:
        """(height, width, 3) WCS mm of every virtual pixel centre."""
        v, u = np.mgrid[0:self.height, 0:self.width].astype(np.float64)
        return self.points(u, v)

    def intersect(self, origin: np.ndarray, direction: np.ndarray) -> np.ndarray:
        """(..., 2) virtual pixel coordinates (u, v) where lines (origin, direction) cross the plane.

        NaN where a line is parallel to the plane or not finite.
        """
        n = self.normal
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((self.origin - origin) @ n) / (direction @ n)
            p = origin + t[..., None] * direction - self.origin
        return np.stack([p @ self.axis_u / self.pitch_mm[0], p @ self.axis_v / self.pitch_mm[1]], axis=-1)

    def with_field(self, centre_uv_mm: tuple[float, float], pitch_mm, width: int, height: int) -> VirtualSensor:
        """The same plane and axes with a new grid: `centre_uv_mm` is the grid's middle, in mm along
        axis_u and axis_v from this sensor's origin."""
        pu, pv = np.broadcast_to(np.asarray(pitch_mm, np.float64), (2,))
        middle = self.origin + centre_uv_mm[0] * self.axis_u + centre_uv_mm[1] * self.axis_v
        origin = middle - (width - 1) / 2 * pu * self.axis_u - (height - 1) / 2 * pv * self.axis_v
        return VirtualSensor(origin, self.axis_u, self.axis_v, (pu, pv), width, height)

    @classmethod
    def from_pinhole(cls, K: np.ndarray, R: np.ndarray, centre: np.ndarray, width: int, height: int,
                     distance_mm: float) -> VirtualSensor:
        """The sensor of the pinhole camera (K, R) with optical centre `centre` (WCS mm), placed at
        `distance_mm` in front of the centre: its pixels see exactly what camera K, R sees.

        K: 3x3 intrinsics without skew (pixels); R: 3x3 world-to-camera rotation (OpenCV: x_cam =
        R x_world + t).
        """
        K, R = np.asarray(K, np.float64), np.asarray(R, np.float64)
        if abs(K[0, 1]) > 1e-12 * abs(K[0, 0]):
            raise ValueError("a camera matrix with skew has no virtual sensor with rectangular pixels")
        pu, pv = distance_mm / K[0, 0], distance_mm / K[1, 1]
        foot = np.asarray(centre, np.float64) + distance_mm * R[2]
        origin = foot - K[0, 2] * pu * R[0] - K[1, 2] * pv * R[1]
        return cls(origin, R[0], R[1], (pu, pv), width, height)

    def to_dict(self) -> dict:
        return {"origin": self.origin.tolist(), "axis_u": self.axis_u.tolist(), "axis_v": self.axis_v.tolist(),
                "pitch_mm": list(self.pitch_mm), "width": self.width, "height": self.height}

    @classmethod
    def from_dict(cls, d: dict) -> VirtualSensor:
        return cls(d["origin"], d["axis_u"], d["axis_v"], tuple(d["pitch_mm"]), d["width"], d["height"])


@dataclass
class VirtualCamera:
    """A virtual sensor and the model of its rays.

    model: one of MODELS. centre: (3,) WCS mm, the optical centre (pinhole model). direction: (3,) unit,
    z > 0, the common ray direction (telecentric model).
    """

    sensor: VirtualSensor
    model: str = "modelless"
    centre: np.ndarray | None = None
    direction: np.ndarray | None = None

    def __post_init__(self):
        if self.model not in MODELS:
            raise ValueError(f"model must be one of {MODELS}, got {self.model!r}")
        if self.model == "pinhole" and self.centre is None:
            raise ValueError("a pinhole virtual camera needs its optical centre")
        if self.model == "telecentric" and self.direction is None:
            raise ValueError("a telecentric virtual camera needs its ray direction")
        if self.centre is not None:
            self.centre = np.asarray(self.centre, np.float64).reshape(3)
        if self.direction is not None:
            self.direction = _unit(self.direction).reshape(3)

    def to_dict(self) -> dict:
        d = {"model": self.model, "sensor": self.sensor.to_dict()}
        if self.centre is not None:
            d["centre"] = self.centre.tolist()
        if self.direction is not None:
            d["direction"] = self.direction.tolist()
        return d

    @classmethod
    def from_dict(cls, d: dict) -> VirtualCamera:
        return cls(VirtualSensor.from_dict(d["sensor"]), d["model"], d.get("centre"), d.get("direction"))


# ---------------------------------------------------------------------------------------------- fitting

def _sample_rays(prvm: PRVM, max_rays: int) -> tuple[np.ndarray, np.ndarray]:
    """(N, 3) origins and directions of valid rays on an even sub-grid of at most ~max_rays pixels."""
    step = max(1, int(np.ceil(np.sqrt(prvm.valid.sum() / max_rays))))
    valid = prvm.valid[::step, ::step]
    return prvm.origin[::step, ::step][valid], prvm.direction[::step, ::step][valid]


def _cauchy_weights(r: np.ndarray, floor: float) -> np.ndarray:
    """Robust weights for residuals r >= 0: Cauchy with scale 3 x median (bad pixels count little)."""
    c = max(3.0 * float(np.median(r)), floor)
    return 1.0 / (1.0 + (r / c) ** 2)


def fit_optical_centre(prvm: PRVM, *, iterations: int = 12, max_rays: int = 250_000
                       ) -> tuple[np.ndarray, np.ndarray]:
    """The point nearest to all rays, and how far each ray misses it.

    Minimises sum w_i * dist(C, ray_i)^2 (a 3x3 linear system) with iteratively re-weighted Cauchy
    weights, so that a few bad pixels do not pull the centre.

    Parameters
    ----------
    prvm : PRVM
        The camera's (H, W) rays, WCS mm.
    iterations : int
        Re-weighting iterations.
    max_rays : int
        The fit uses an even sub-grid of at most this many valid rays.

    Returns
    -------
    centre : (3,) float64
        The optical centre, WCS mm.
    miss_mm : (H, W) float64
        Distance from the centre to each pixel's ray, mm; NaN where the pixel is not valid.
    """
    if not prvm.valid.any():
        raise InputError(None, "the PRVM has no valid pixel")
    o, d = _sample_rays(prvm, max_rays)
    w = np.ones(len(o))
    eye = np.eye(3)
    for _ in range(iterations):
        A = w.sum() * eye - np.einsum("n,ni,nj->ij", w, d, d)
        b = w @ o - np.einsum("n,ni,n->i", w, d, np.einsum("ni,ni->n", d, o))
        centre = np.linalg.solve(A, b)
        w = _cauchy_weights(_miss(o, d, centre), floor=1e-9)
    return centre, miss_distance(prvm, centre)


def _miss(o: np.ndarray, d: np.ndarray, point: np.ndarray) -> np.ndarray:
    """Distance from `point` to each line (o, d); d unit."""
    p = point - o
    return np.linalg.norm(p - np.einsum("...i,...i->...", p, d)[..., None] * d, axis=-1)


def miss_distance(prvm: PRVM, centre: np.ndarray) -> np.ndarray:
    """How far each pixel's ray misses a point (the non-centrality about an optical centre).

    Parameters
    ----------
    prvm : PRVM
        The camera's (H, W) rays, WCS mm.
    centre : (3,) float
        The point, WCS mm.

    Returns
    -------
    miss_mm : (H, W) float64
        Distance from `centre` to each pixel's ray, mm; NaN where not valid.
    """
    return np.where(prvm.valid, _miss(prvm.origin, prvm.direction, np.asarray(centre, np.float64)), np.nan)


def miss_in_pixels(prvm: PRVM, centre: np.ndarray, miss_mm: np.ndarray, z_mm: float) -> np.ndarray:
    """The image error a pinhole at `centre` makes for a point on the plane z = z_mm.

    For the point P where a ray crosses z = z_mm, the pinhole ray C->P differs from the real ray by the
    angle asin(miss / |P - C|); divided by the pixel's angular pitch (the mean angle between its ray and
    its neighbours' rays) it is the displacement in pixels.

    Parameters
    ----------
    prvm : PRVM
        The camera's (H, W) rays, WCS mm.
    centre : (3,) float
        The pinhole's centre, WCS mm (`fit_optical_centre`).
    miss_mm : (H, W) float
        Each ray's distance from `centre`, mm (`miss_distance`).
    z_mm : float
        The plane, WCS z, mm.

    Returns
    -------
    error_px : (H, W) float64
        Camera pixels; NaN where not valid.
    """
    p = prvm.at_z(z_mm)
    with np.errstate(invalid="ignore"):
        angle = np.arcsin(np.clip(miss_mm / np.linalg.norm(p - centre, axis=-1), 0, 1))
    return angle / angular_pitch(prvm)


def angular_pitch(prvm: PRVM) -> np.ndarray:
    """(H, W) radians: the angle between a pixel's ray and its neighbours' (geometric mean of the
    column and row steps)."""
    d = np.where(prvm.valid[..., None], prvm.direction, np.nan)
    du = np.linalg.norm(np.gradient(d, axis=1), axis=-1)
    dv = np.linalg.norm(np.gradient(d, axis=0), axis=-1)
    return np.sqrt(du * dv)


def fit_telecentric_direction(prvm: PRVM, iterations: int = 12, max_rays: int = 250_000
                              ) -> tuple[np.ndarray, np.ndarray]:
    """The common direction of a telecentric lens's rays, and how far each ray deviates from it.

    Robust (Cauchy re-weighted) mean of the unit directions. Returns (direction (3,) unit with z > 0,
    deviation_rad (H, W): the angle between each ray and the direction, NaN where not valid).
    """
    if not prvm.valid.any():
        raise InputError(None, "the PRVM has no valid pixel")
    _, d = _sample_rays(prvm, max_rays)
    w = np.ones(len(d))
    for _ in range(iterations):
        direction = _unit(w @ d)
        w = _cauchy_weights(np.linalg.norm(d - direction, axis=-1), floor=1e-12)
    dev = 2 * np.arcsin(np.clip(np.linalg.norm(prvm.direction - direction, axis=-1) / 2, 0, 1))
    return direction, np.where(prvm.valid, dev, np.nan)


# ----------------------------------------------------------------------------------- the default sensor

def project_to_plane(prvm: PRVM, sensor: VirtualSensor) -> np.ndarray:
    """The Projected Real Pixels: (H, W, 2) float64 virtual pixel coordinates (u, v) where each real
    pixel's ray crosses the sensor plane; NaN where the real pixel is not valid."""
    q = sensor.intersect(prvm.origin, prvm.direction)
    q[~prvm.valid] = np.nan
    return q


def facing_sensor(prvm: PRVM, look: np.ndarray, through: np.ndarray) -> VirtualSensor:
    """A unit-pitch, 1x1 sensor on the plane through `through` (WCS mm) with normal `look`, its axis_u
    along the real image's columns (so the virtual image is not rotated against the real one)."""
    n = _unit(look)
    helper = np.array([1.0, 0, 0]) if abs(n[0]) < 0.9 else np.array([0, 1.0, 0])
    a = _unit(np.cross(helper, n))
    probe = VirtualSensor(through, a, np.cross(n, a), 1.0, 1, 1)
    q = project_to_plane(prvm, probe)
    step = np.nanmean(np.diff(q, axis=1).reshape(-1, 2), axis=0)  # mean real column step on the plane
    axis_u = _unit(step[0] * probe.axis_u + step[1] * probe.axis_v)
    return VirtualSensor(through, axis_u, np.cross(n, axis_u), 1.0, 1, 1)


def largest_field(prvm: PRVM, plane: VirtualSensor, width: int, height: int, pitch_mm=None,
                  raster: int = 2048) -> VirtualSensor:
    """The biggest width x height grid on `plane` (its origin and axes; pitch ignored) whose every pixel
    centre lies inside the real camera's field (the quadrilaterals of 4 valid real pixels), so that no
    virtual pixel is blank. With `pitch_mm` given, the grid keeps that pitch and is placed where it fits
    best; InputError if it does not fit.

    Method: the boundary of the valid real field (through the centres of its outermost real cells, half a
    real pixel inside) is projected onto the plane and rasterised on ~`raster` cells, scaled so that the
    grid becomes a square; the largest inscribed square is the maximum of the chessboard distance
    transform. Accurate to about 2 raster cells.
    """
    unit = VirtualSensor(plane.origin, plane.axis_u, plane.axis_v, 1.0, 1, 1)
    q = project_to_plane(prvm, unit)  # mm along the plane's axes
    good = np.isfinite(q).all(axis=-1)
    cells = (good[:-1, :-1] & good[1:, :-1] & good[:-1, 1:] & good[1:, 1:]).astype(np.uint8)
    contours, hierarchy = cv2.findContours(cells, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE)
    if not contours:
        raise InputError(None, "the PRVM has no 2x2 block of valid pixels")
    outer = max((i for i in range(len(contours)) if hierarchy[0, i, 3] < 0),
                key=lambda i: cv2.contourArea(contours[i]))
    polys = [contours[outer]] + [c for i, c in enumerate(contours) if hierarchy[0, i, 3] == outer]
    polys = [bilinear(q, c[:, 0, 0] + 0.5, c[:, 0, 1] + 0.5) for c in polys]
    aspect = (width - 1) / max(height - 1, 1)
    pts = np.concatenate(polys)
    lo = np.array([pts[:, 0].min(), pts[:, 1].min() * aspect])
    cell = max(pts[:, 0].max() - lo[0], pts[:, 1].max() * aspect - lo[1]) / raster
    lo -= 4 * cell  # a margin of zeros: cv2.distanceTransform takes outside the image as non-zero
    to_raster = lambda p: np.round((np.c_[p[:, 0], p[:, 1] * aspect] - lo) / cell * 16).astype(np.int32)
    mask = np.zeros((raster + 9, raster + 9), np.uint8)
    cv2.fillPoly(mask, [to_raster(polys[0])], 1, shift=4)
    for hole in polys[1:]:
        cv2.fillPoly(mask, [to_raster(hole)], 0, shift=4)
    dist = cv2.distanceTransform(mask, cv2.DIST_C, 3)
    if pitch_mm is None:
        half = float(dist.max()) - 2.0
        if half <= 0:
            raise InputError(None, "the real field is too small to hold a virtual camera")
        pitch = half * 2 * cell / (width - 1)
        centre_rc = np.unravel_index(np.argmax(dist), dist.shape)
        pitch_mm = (pitch, pitch)
    else:
        pu, pv = np.broadcast_to(np.asarray(pitch_mm, np.float64), (2,))
        need = max((width - 1) * pu, (height - 1) * pv * aspect) / 2 / cell + 2.0
        centre_rc = np.unravel_index(np.argmax(dist), dist.shape)
        if dist[centre_rc] < need:
            biggest = (float(dist.max()) - 2) * 2 * cell / (width - 1)
            raise InputError(None, f"a {width}x{height} virtual camera at pitch {pu:g} x {pv:g} mm is larger "
                                   f"than the real field (largest pitch that fits: {biggest:.6g} mm)")
        pitch_mm = (pu, pv)
    centre = lo + np.array([centre_rc[1], centre_rc[0]], np.float64) * cell
    return plane.with_field((centre[0], centre[1] / aspect), pitch_mm, width, height)


def default_camera(prvm: PRVM, *, model: str = "pinhole", width: int | None = None, height: int | None = None,
                   pitch_mm=None, plane_z_mm: float | None = None) -> VirtualCamera:
    """The default virtual camera of a real one: the largest field inside the real one (no blank pixel)
    on a plane through the point where the real image's central ray crosses z = plane_z_mm.

    The plane faces the camera's mean viewing direction (pinhole, modelless) or the telecentric
    direction (telecentric), with its columns along the real image's columns.

    Parameters
    ----------
    prvm : PRVM
        The real camera's (H, W) rays, WCS mm.
    model : {"pinhole", "modelless", "telecentric"}
        The model of the virtual rays (module docstring).
    width, height : int, optional
        The virtual pixel count; None: the real one's.
    pitch_mm : float or (float, float), optional
        The virtual pixel pitch (u, v), mm; None: the largest that fits. InputError if the grid does not
        fit inside the real field at the pitch given.
    plane_z_mm : float, optional
        WCS z, mm, where the central ray meets the plane; None: the PRVM's reference_z_mm.

    Returns
    -------
    camera : VirtualCamera
        The sensor (origin, axes, pitch in the WCS, mm) and the model, with the fitted optical centre
        (pinhole) or ray direction (telecentric).
    """
    width = prvm.width if width is None else int(width)
    height = prvm.height if height is None else int(height)
    z = prvm.reference_z_mm if plane_z_mm is None else float(plane_z_mm)
    centre = direction = None
    if model == "telecentric":
        direction, _ = fit_telecentric_direction(prvm)
        look = direction
    else:
        centre, _ = fit_optical_centre(prvm)
        look = prvm.direction[prvm.valid].mean(axis=0)
    ys, xs = np.nonzero(prvm.valid)
    k = np.argmin((xs - (prvm.width - 1) / 2) ** 2 + (ys - (prvm.height - 1) / 2) ** 2)
    through = prvm.at_z(z)[ys[k], xs[k]]
    sensor = largest_field(prvm, facing_sensor(prvm, look, through), width, height, pitch_mm)
    return VirtualCamera(sensor, model, centre if model == "pinhole" else None, direction)

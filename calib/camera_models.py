"""Parametric camera models of other calibration software, exactly: projection, its exact inverse, and the
per-pixel rays (PRVM) they imply.

A `CameraModel` is one camera of another program's calibration file, in that file's own world frame:
  x_cam = R x_world + t                        (world -> camera, mm; camera x right, y down, z forward)
  (x, y) = (X_cam / Z_cam, Y_cam / Z_cam)      normalised coordinates
  (x_d, y_d) = distort(x, y)                   the lens model, below
  u = fx x_d + skew y_d + cx,  v = fy y_d + cy pixels; integers at pixel centres (OpenCV's convention)
The skew term is K[0, 1] in pixels, as VIC-3D and DICe write it (OpenCV's cv2.projectPoints and
cv2.undistortPoints ignore K[0, 1]; here it is part of the model, so a skewed camera's rays are right).

Lens models (`lens`, with `coefficients`):
- "opencv": OpenCV's full model, coefficients (k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4, tau_x, tau_y)
  (any of OpenCV's lengths 0, 4, 5, 8, 12, 14; missing ones are zero): rational radial, tangential, thin
  prism, then the tilted sensor (tau_x, tau_y in radians; OpenCV's computeTiltProjectionMatrix). It is
  also VIC-3D's kappa model x_d = x (1 + kappa1 r^2 + kappa2 r^4 + kappa3 r^6) (k1, k2, 0, 0, k3), mrcal's
  LENSMODEL_OPENCV4/5/8/12 and Kalibr's radtan (k1, k2, p1, p2).
- "radial": DICe's radial polynomials r_d = r (1 + k1 r^a + k2 r^b + k3 r^c) with the powers (a, b, c) of
  `powers`: DICe's K1R1_K2R2_K3R3 is powers (0, 1, 2), K1R2_K2R4_K3R6 (1, 3, 5), K1R3_K2R5_K3R7 (2, 4, 6)
  (DICe_Camera.cpp, sensor_to_image).
- "equidistant": the fisheye model of Kalibr (pinhole-equi) and OpenCV's cv2.fisheye: theta = the angle
  from the optical axis, theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8),
  (x_d, y_d) = theta_d (cos phi, sin phi); valid beyond 90 degrees from the axis.

The inverse (`unproject`) is Newton's method on the model itself, to 1e-10 pixel, kept inside the model's
valid region: where the mapping is one-to-one and keeps orientation, traced outward from the principal
point along each direction up to the first fold (`fold_radius`: the first zero or pole of the Jacobian
determinant, whatever the sign of the radial factor; for the equidistant lens the first maximum of
theta_d). A pixel whose inverse would lie beyond it is reported invalid rather than given a mirrored ray.
`image_of` is the forward model with that region, for maps computed at any sub-pixel position.

Rays and frames (`prvms_of`, `rig_frame`): DESIGN.md's ray convention needs every ray to travel towards +z. Files whose
cameras look along -z (VIC-3D's usual world frame) are therefore turned into an internal frame, the file's
frame rotated 180 degrees about x (or, where neither fits, rotated so that the cameras' mean optical axis
is +z); `world_from_internal` (4, 4) is the rigid transform from the internal frame back to the file's
world frame, recorded in the PRVM meta (and the rig) as "world_from_rig".
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from calib.errors import InputError
from calib.prvm_file import PRVM

LENSES = ("opencv", "radial", "equidistant")
OPENCV_LENGTHS = (0, 4, 5, 8, 12, 14)
FLIP_X = np.diag([1.0, -1.0, -1.0, 1.0])   # the rotation of 180 degrees about x, as a 4x4 transform
TOL_PX = 1e-10                              # Newton's target on the re-projection of an inverted pixel
SINGLE_PLANE_MM = 1000.0                    # a lone camera's reference plane, in front of its centre (prvms_of)
VALID_PX = 1e-7                             # an inverse that does not re-project this well is not one


@dataclass
class CameraModel:
    """One camera of a calibration file (module docstring): intrinsics fx, fy, cx, cy, skew (pixels),
    lens model and its coefficients (and `powers` for the "radial" lens), the world-to-camera pose R (3, 3)
    and t (3,) mm in the file's world frame, image width and height (pixels; None where the file does not
    say), and the camera's name in the file."""

    fx: float
    fy: float
    cx: float
    cy: float
    skew: float = 0.0
    lens: str = "opencv"
    coefficients: np.ndarray = field(default_factory=lambda: np.zeros(0))
    R: np.ndarray = field(default_factory=lambda: np.eye(3))
    t: np.ndarray = field(default_factory=lambda: np.zeros(3))
    width: int | None = None
    height: int | None = None
    name: str = "cam0"
    powers: tuple[float, float, float] = (2, 4, 6)

    def __post_init__(self):
        if self.lens not in LENSES:
            raise ValueError(f"unknown lens model {self.lens!r} (known: {', '.join(LENSES)})")
        self.fx, self.fy, self.cx, self.cy, self.skew = (float(v) for v in (self.fx, self.fy, self.cx, self.cy,
                                                                             self.skew))
        c = np.asarray(self.coefficients, np.float64).ravel()
        if self.lens == "opencv":
            if c.size not in OPENCV_LENGTHS:
                raise ValueError(f"OpenCV distortion has {', '.join(map(str, OPENCV_LENGTHS))} coefficients, "
                                 f"got {c.size}")
            c = np.concatenate([c, np.zeros(14 - c.size)])
        elif c.size > (3 if self.lens == "radial" else 4):
            raise ValueError(f"the {self.lens} lens has at most {3 if self.lens == 'radial' else 4} coefficients")
        else:
            c = np.concatenate([c, np.zeros((3 if self.lens == "radial" else 4) - c.size)])
        self.coefficients = c
        self.R = np.asarray(self.R, np.float64).reshape(3, 3)
        self.t = np.asarray(self.t, np.float64).reshape(3)
        if self.width is not None:
            self.width, self.height = int(self.width), int(self.height)

    @property
    def K(self) -> np.ndarray:
        """(3, 3) camera matrix [[fx, skew, cx], [0, fy, cy], [0, 0, 1]]."""
        return np.array([[self.fx, self.skew, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def centre(self) -> np.ndarray:
        """(3,) the optical centre in the file's world frame, mm: -R^-1 t (R as the file writes it, which
        may be orthonormal only to its printed digits: the program projects with that R, so its inverse is
        the inverse of that matrix, not its transpose)."""
        return -np.linalg.solve(self.R, self.t)

    def to_world(self, directions: np.ndarray) -> np.ndarray:
        """(..., 3) camera-frame directions turned into the file's world frame: R^-1 d (as `centre`),
        normalised to unit length."""
        d = affine(np.linalg.inv(self.R), np.zeros(3), directions)
        return d / np.sqrt(np.sum(d * d, axis=-1, keepdims=True))

    def to_dict(self) -> dict:
        """The model as JSON data (recorded in the PRVM meta of an imported camera)."""
        d = {"name": self.name, "lens": self.lens, "fx": self.fx, "fy": self.fy, "cx": self.cx, "cy": self.cy,
             "skew": self.skew, "coefficients": self.coefficients.tolist(), "R": self.R.tolist(),
             "t": self.t.tolist(), "width": self.width, "height": self.height}
        if self.lens == "radial":
            d["powers"] = list(self.powers)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "CameraModel":
        """The model of `to_dict`'s JSON data (exact: JSON keeps every float's digits)."""
        return cls(d["fx"], d["fy"], d["cx"], d["cy"], d["skew"], d["lens"], d["coefficients"], d["R"], d["t"],
                   d["width"], d["height"], d["name"], tuple(d.get("powers", (2, 4, 6))))


# ------------------------------------------------------------------------------------------- lenses

def _tilt(tau_x: float, tau_y: float) -> np.ndarray:
    """OpenCV's tilt projection matrix (computeTiltProjectionMatrix): the sensor tilted by tau_x about x,
    then tau_y about y, projected back along the optical axis."""
    cx, sx, cy, sy = np.cos(tau_x), np.sin(tau_x), np.cos(tau_y), np.sin(tau_y)
    rot_x = np.array([[1, 0, 0], [0, cx, sx], [0, -sx, cx]])
    rot_y = np.array([[cy, 0, -sy], [0, 1, 0], [sy, 0, cy]])
    rxy = rot_y @ rot_x
    proj_z = np.array([[rxy[2, 2], 0, -rxy[0, 2]], [0, rxy[2, 2], -rxy[1, 2]], [0, 0, 1]])
    return proj_z @ rxy


def distort(cam: CameraModel, xy: np.ndarray) -> np.ndarray:
    """(N, 2) distorted normalised coordinates (x_d, y_d) of normalised coordinates `xy` (N, 2); for the
    equidistant lens `xy` may also be (N, 3) camera-frame directions (to reach beyond 90 degrees)."""
    c = cam.coefficients
    if cam.lens == "equidistant":
        if xy.shape[1] == 3:
            rho, z = np.hypot(xy[:, 0], xy[:, 1]), xy[:, 2]
            theta, a, b = np.arctan2(rho, z), xy[:, 0], xy[:, 1]
        else:
            rho = np.hypot(xy[:, 0], xy[:, 1])
            theta, a, b = np.arctan(rho), xy[:, 0], xy[:, 1]
        t2 = theta * theta
        theta_d = theta * (1 + t2 * (c[0] + t2 * (c[1] + t2 * (c[2] + t2 * c[3]))))
        with np.errstate(invalid="ignore", divide="ignore"):
            s = np.where(rho > 0, theta_d / np.where(rho > 0, rho, 1.0), 1.0)
        return np.stack([a * s, b * s], axis=-1)
    x, y = xy[:, 0], xy[:, 1]
    r2 = x * x + y * y
    if cam.lens == "radial":
        r = np.sqrt(r2)
        s = 1 + sum(k * r ** p for k, p in zip(c, cam.powers) if k != 0)
        return np.stack([x * s, y * s], axis=-1)
    k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4, tx, ty = c
    radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    if k4 != 0 or k5 != 0 or k6 != 0:      # (terms that are zero are skipped: the same values, faster)
        radial = radial / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
    xd, yd = x * radial, y * radial
    if p1 != 0 or p2 != 0:
        xy2 = 2 * x * y
        xd = xd + p1 * xy2 + p2 * (r2 + 2 * x * x)
        yd = yd + p1 * (r2 + 2 * y * y) + p2 * xy2
    if s1 != 0 or s2 != 0 or s3 != 0 or s4 != 0:
        xd = xd + s1 * r2 + s2 * r2 * r2
        yd = yd + s3 * r2 + s4 * r2 * r2
    if tx != 0 or ty != 0:
        m = _tilt(tx, ty)
        w = m[2, 0] * xd + m[2, 1] * yd + m[2, 2]
        xd, yd = (m[0, 0] * xd + m[0, 1] * yd + m[0, 2]) / w, (m[1, 0] * xd + m[1, 1] * yd + m[1, 2]) / w
    return np.stack([xd, yd], axis=-1)


def to_pixels(cam: CameraModel, xy_d: np.ndarray) -> np.ndarray:
    """(N, 2) pixels of distorted normalised coordinates (N, 2): u = fx x_d + skew y_d + cx, v = fy y_d + cy."""
    return np.stack([cam.fx * xy_d[:, 0] + cam.skew * xy_d[:, 1] + cam.cx, cam.fy * xy_d[:, 1] + cam.cy], -1)


def from_pixels(cam: CameraModel, uv: np.ndarray) -> np.ndarray:
    """(N, 2) distorted normalised coordinates of pixels `uv` (N, 2): the exact inverse of `to_pixels`."""
    yd = (uv[:, 1] - cam.cy) / cam.fy
    return np.stack([(uv[:, 0] - cam.cx - cam.skew * yd) / cam.fx, yd], axis=-1)


def project(cam: CameraModel, points: np.ndarray) -> np.ndarray:
    """(N, 2) pixels of world points (N, 3) (the file's world frame, mm); NaN behind the camera (or, for the
    equidistant lens, at the camera's centre)."""
    p = affine(cam.R, cam.t, np.asarray(points, np.float64).reshape(-1, 3))
    if cam.lens == "equidistant":
        return to_pixels(cam, distort(cam, p))
    with np.errstate(invalid="ignore", divide="ignore"):
        xy = p[:, :2] / np.where(p[:, 2:] > 0, p[:, 2:], np.nan)
    return to_pixels(cam, distort(cam, xy))


def image_of(cam: CameraModel, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N, 2) pixels of world points (N, 3) (the file's world frame, mm) through the model, and (N,)
    whether each lies in the model's valid region (in front of the camera and inside the first fold,
    `fold_radius`; below the first fold of an equidistant lens): the exact forward model, for maps that
    need real positions at sub-pixel virtual positions without inverting anything."""
    p = affine(cam.R, cam.t, np.asarray(points, np.float64).reshape(-1, 3))
    if cam.lens == "equidistant":
        ok = np.arctan2(np.hypot(p[:, 0], p[:, 1]), p[:, 2]) < _equidistant_top(cam)
        uv = to_pixels(cam, distort(cam, p))
    else:
        with np.errstate(invalid="ignore", divide="ignore"):
            xy = p[:, :2] / np.where(p[:, 2:] > 0, p[:, 2:], np.nan)
        ok = np.isfinite(xy).all(axis=1)
        ok[ok] = _inside(_region(cam), xy[ok])
        uv = to_pixels(cam, distort(cam, np.where(ok[:, None], xy, 0.0)))
    return uv, ok & np.isfinite(uv).all(axis=1)


def _jacobian(cam: CameraModel, xy: np.ndarray, at: np.ndarray, h: float = 1e-7) -> np.ndarray:
    """(N, 2, 2) d distort / d xy by forward differences from `at` = distort(cam, xy) (Newton's steps
    need only its direction: the residual, not the Jacobian, decides when an inverse is exact)."""
    jx = (distort(cam, xy + [h, 0]) - at) / h
    jy = (distort(cam, xy + [0, h]) - at) / h
    return np.stack([jx, jy], axis=-1)


def _image_radius(cam: CameraModel) -> float:
    """The largest distorted normalised radius of the image's corners (the part of the model that matters)."""
    w, h = (cam.width or 2 * cam.cx + 1), (cam.height or 2 * cam.cy + 1)
    corners = np.array([[-0.5, -0.5], [w - 0.5, -0.5], [-0.5, h - 0.5], [w - 0.5, h - 0.5]])
    return float(np.linalg.norm(from_pixels(cam, corners), axis=1).max())


def fold_radius(cam: CameraModel, *, directions: int = 720) -> tuple[np.ndarray, np.ndarray]:
    """The valid region of a polynomial lens (module docstring): for `directions` angles phi of the
    undistorted normalised plane, the radius where the model first stops being one-to-one and keeping
    orientation, tracing outward from the principal point: the first zero (or pole) of the Jacobian
    determinant of `distort`, whatever the sign of the radial factor; or where the distorted point leaves
    twice the image's radius (no pixel lies beyond). Returns (phi (M,), r (M,)), phi in [-pi, pi)."""
    phi = np.linspace(-np.pi, np.pi, directions, endpoint=False)
    r = np.geomspace(1e-4, 1e4, 1500)
    reach = 2 * _image_radius(cam)
    out = np.full(directions, r[-1])
    u = np.stack([np.cos(phi), np.sin(phi)], -1)
    lo = np.zeros(directions)
    hi = np.full(directions, np.nan)
    for k0 in range(0, len(r), 100):      # in blocks, so that far radii are evaluated only where needed
        todo = np.isnan(hi)
        if not todo.any():
            break
        rk = r[k0:k0 + 100]
        xy = (u[todo, None, :] * rk[None, :, None]).reshape(-1, 2)
        det = _det(cam, xy).reshape(todo.sum(), len(rk))
        far = (np.linalg.norm(distort(cam, xy), axis=1) > reach).reshape(det.shape)
        stop = ~np.isfinite(det) | (det <= 0) | far
        first = np.where(stop.any(1), stop.argmax(1), -1)
        idx = np.nonzero(todo)[0]
        hit = first >= 0
        hi[idx[hit]] = rk[first[hit]]
        lo[idx[hit]] = np.where(first[hit] > 0, rk[np.maximum(first[hit] - 1, 0)], r[k0 - 1] if k0 else 0.0)
    found = np.isfinite(hi)
    for _ in range(40):     # bisection between the last good and the first stopping radius
        mid = (lo + np.where(found, hi, lo)) / 2
        xy = u * mid[:, None]
        det = _det(cam, xy)
        far = np.linalg.norm(distort(cam, xy), axis=1) > reach
        stop = ~np.isfinite(det) | (det <= 0) | far
        hi = np.where(found & stop, mid, hi)
        lo = np.where(found & ~stop, mid, lo)
    out[found] = lo[found]
    return phi, out


def _det(cam: CameraModel, xy: np.ndarray) -> np.ndarray:
    """(N,) the Jacobian determinant of `distort` at xy (N, 2), by central differences scaled to |xy|."""
    h = 1e-7 * np.maximum(1.0, np.linalg.norm(xy, axis=1))[:, None]
    jx = (distort(cam, xy + h * [1, 0]) - distort(cam, xy - h * [1, 0])) / (2 * h)
    jy = (distort(cam, xy + h * [0, 1]) - distort(cam, xy - h * [0, 1])) / (2 * h)
    with np.errstate(invalid="ignore", over="ignore"):
        return jx[:, 0] * jy[:, 1] - jy[:, 0] * jx[:, 1]


def _inside(fold: tuple[np.ndarray, np.ndarray], xy: np.ndarray) -> np.ndarray:
    """(N,) whether normalised points xy (N, 2) lie inside the traced valid region `fold` (fold_radius)."""
    phi, r = fold
    a = np.arctan2(xy[:, 1], xy[:, 0])
    limit = np.interp(a, np.append(phi, np.pi), np.append(r, r[0]))
    return np.hypot(xy[:, 0], xy[:, 1]) < limit


_REGIONS: dict = {}


def _region(cam: CameraModel) -> tuple[np.ndarray, np.ndarray]:
    """`fold_radius` of the camera, computed once per lens, intrinsics and image size."""
    key = (cam.lens, cam.fx, cam.fy, cam.cx, cam.cy, cam.skew, cam.width, cam.height, tuple(cam.powers),
           cam.coefficients.tobytes())
    if key not in _REGIONS:
        if len(_REGIONS) > 64:
            _REGIONS.clear()
        _REGIONS[key] = fold_radius(cam)
    return _REGIONS[key]


def _solve_polynomial(cam: CameraModel, target: np.ndarray, iterations: int) -> tuple[np.ndarray, np.ndarray]:
    """Normalised (x, y) with distort(x, y) = target (N, 2), by damped Newton steps kept inside the valid
    region (`fold_radius`); and whether each converged (to TOL_PX in pixels) inside it."""
    scale = max(abs(cam.fx), abs(cam.fy))
    fold = _region(cam)
    xy = target.copy()
    start_out = ~_inside(fold, xy)
    if start_out.any():       # start inside the region, on the same direction
        phi, r = fold
        lim = np.interp(np.arctan2(xy[start_out, 1], xy[start_out, 0]), np.append(phi, np.pi), np.append(r, r[0]))
        xy[start_out] *= (0.5 * lim / np.maximum(np.hypot(xy[start_out, 0], xy[start_out, 1]), 1e-300))[:, None]
    err = np.linalg.norm(distort(cam, xy) - target, axis=1) * scale
    active = np.isfinite(err) & (err > TOL_PX)
    for _ in range(iterations):
        if not active.any():
            break
        a = np.nonzero(active)[0]
        at = distort(cam, xy[a])
        j = _jacobian(cam, xy[a], at)
        r = at - target[a]
        det = j[:, 0, 0] * j[:, 1, 1] - j[:, 0, 1] * j[:, 1, 0]
        with np.errstate(invalid="ignore", divide="ignore"):
            step = np.stack([j[:, 1, 1] * r[:, 0] - j[:, 0, 1] * r[:, 1],
                             j[:, 0, 0] * r[:, 1] - j[:, 1, 0] * r[:, 0]], axis=-1) / det[:, None]
        trial, e = xy[a] - step, np.full(len(a), np.inf)
        good = np.zeros(len(a), bool)
        pending, lam = np.arange(len(a)), 1.0
        for _halving in range(30):     # damping: accept a step only where it lowers the residual in the region
            t = xy[a[pending]] - lam * step[pending]
            ep = np.linalg.norm(distort(cam, t) - target[a[pending]], axis=1) * scale
            ok = np.isfinite(ep) & (ep < err[a[pending]]) & _inside(fold, t)
            trial[pending[ok]], e[pending[ok]], good[pending[ok]] = t[ok], ep[ok], True
            pending, lam = pending[~ok], lam / 2
            if not len(pending):
                break
        xy[a[good]] = trial[good]
        err[a[good]] = e[good]
        active[a[~good]] = False   # no progress: converged to rounding, or no inverse here
        active[a[good]] = e[good] > TOL_PX
    return xy, (err < VALID_PX) & _inside(fold, xy)


def _equidistant_top(cam: CameraModel) -> float:
    """The angle (radians) of the equidistant lens's first fold, where theta_d(theta) stops rising (or 180
    degrees): its valid region is theta below it."""
    k = cam.coefficients
    t = np.linspace(0.0, np.pi, 20001)
    t2 = t * t
    der = 1 + t2 * (3 * k[0] + t2 * (5 * k[1] + t2 * (7 * k[2] + t2 * 9 * k[3])))
    falling = np.nonzero(der <= 0)[0]
    return float(t[falling[0]]) if len(falling) else float(np.pi)


def _solve_equidistant(cam: CameraModel, target: np.ndarray, iterations: int) -> tuple[np.ndarray, np.ndarray]:
    """Camera-frame unit directions whose equidistant image is `target` (N, 2), and whether each lies on
    the first rising branch of theta_d(theta) (below its first fold, and below 180 degrees): Newton's
    method on theta kept inside the bracket where theta_d is monotonic (bisection where a step leaves it)."""
    k = cam.coefficients
    theta_d = np.hypot(target[:, 0], target[:, 1])
    phi = np.arctan2(target[:, 1], target[:, 0])

    def f(t):
        t2 = t * t
        return t * (1 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3])))), \
            1 + t2 * (3 * k[0] + t2 * (5 * k[1] + t2 * (7 * k[2] + t2 * 9 * k[3])))

    top = _equidistant_top(cam)
    lo, hi = np.zeros_like(theta_d), np.full_like(theta_d, top)
    reach = theta_d < f(np.array([top]))[0][0]
    theta = np.clip(theta_d, 0.0, top / 2)
    for _ in range(iterations):
        val, der = f(theta)
        below = val < theta_d
        lo, hi = np.where(below, theta, lo), np.where(below, hi, theta)
        with np.errstate(invalid="ignore", divide="ignore"):
            step = theta - (val - theta_d) / der
        theta = np.where((step > lo) & (step < hi), step, (lo + hi) / 2)
    val, der = f(theta)
    scale = max(abs(cam.fx), abs(cam.fy))
    ok = reach & (np.abs(val - theta_d) * scale < VALID_PX) & (der > 0) & (theta < top)
    d = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], axis=-1)
    return d, ok


def unproject(cam: CameraModel, uv: np.ndarray, iterations: int = 60) -> tuple[np.ndarray, np.ndarray]:
    """Camera-frame unit directions (N, 3) of pixels `uv` (N, 2), the exact inverse of the model (module
    docstring), and valid (N,) bool: False where the model has no inverse (beyond a fold)."""
    target = from_pixels(cam, np.asarray(uv, np.float64).reshape(-1, 2))
    if cam.lens == "equidistant":
        return _solve_equidistant(cam, target, iterations)
    xy, ok = _solve_polynomial(cam, target, iterations)
    d = np.concatenate([xy, np.ones((len(xy), 1))], axis=1)
    return d / np.linalg.norm(d, axis=1, keepdims=True), ok


# ------------------------------------------------------------------------------------- rays, frames

def pixel_grid(width: int, height: int) -> np.ndarray:
    """(H * W, 2) every pixel centre (u, v), row by row."""
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    return np.stack([u.ravel(), v.ravel()], axis=-1)


def affine(a: np.ndarray, b: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(..., 3) a @ p + b for every point p of `points` (..., 3), a (3, 3), b (3,): column by column
    (a matrix product of a long (N, 3) array by a 3x3 one is slow, and threads badly on a busy machine)."""
    p = np.asarray(points, np.float64)
    return p[..., 0:1] * a[:, 0] + p[..., 1:2] * a[:, 1] + p[..., 2:3] * a[:, 2] + b


def transform(m: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(..., 3) points moved by the 4x4 rigid transform m."""
    return affine(m[:3, :3], m[:3, 3], points)


def invert(m: np.ndarray) -> np.ndarray:
    """The inverse of a 4x4 rigid transform."""
    out = np.eye(4)
    out[:3, :3] = m[:3, :3].T
    out[:3, 3] = -m[:3, :3].T @ m[:3, 3]
    return out


def world_rays(cam: CameraModel, *, step: int = 1) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit directions (H', W', 3) in the file's world frame of the pixels of every `step`-th row and
    column, their validity (H', W') and the camera centre (3,)."""
    v, u = np.mgrid[0:cam.height:step, 0:cam.width:step].astype(np.float64)
    d, ok = unproject(cam, np.stack([u.ravel(), v.ravel()], axis=-1))
    return cam.to_world(d).reshape(v.shape + (3,)), ok.reshape(v.shape), cam.centre


def internal_frame(cams: list[CameraModel]) -> np.ndarray:
    """world_from_internal (4, 4) for a set of cameras of one file: identity if every ray already travels
    towards +z, else the 180-degree rotation about x if that makes them all do so, else the rotation that
    takes the cameras' mean optical axis to +z (module docstring)."""
    dirs = np.concatenate([d[ok] for d, ok, _ in (world_rays(c, step=max(1, min(c.width, c.height) // 16))
                                                  for c in cams)])
    if len(dirs) == 0:
        return np.eye(4)
    if (dirs[:, 2] > 0).all():
        return np.eye(4)
    if (dirs[:, 2] < 0).all():
        return FLIP_X.copy()
    axis = sum(c.R[2] for c in cams)
    axis /= np.linalg.norm(axis)
    # the rotation taking `axis` to +z about axis x +z (Rodrigues), world <- internal is its inverse
    v = np.cross(axis, [0.0, 0.0, 1.0])
    s, co = np.linalg.norm(v), axis[2]
    if s < 1e-12:
        rot = np.eye(3) if co > 0 else FLIP_X[:3, :3]
    else:
        k = v / s
        kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
        rot = np.eye(3) + s * kx + (1 - co) * kx @ kx
    out = np.eye(4)
    out[:3, :3] = rot.T
    return out


def central_ray(cam: CameraModel) -> tuple[np.ndarray, np.ndarray]:
    """The ray of the image's centre pixel ((W - 1) / 2, (H - 1) / 2): (centre (3,), unit direction (3,)) in
    the file's world frame (the optical axis where the principal point is the image's centre)."""
    d, ok = unproject(cam, np.array([[(cam.width - 1) / 2, (cam.height - 1) / 2]]))
    if not ok[0]:
        return cam.centre, cam.to_world(np.array([0.0, 0.0, 1.0]))
    return cam.centre, cam.to_world(d[0])


def convergence_z(cams: list[CameraModel], world_from_internal: np.ndarray) -> float:
    """z (internal frame, mm) of the point where the first two cameras' central rays (`central_ray`) pass
    closest: the working point of a stereo rig, also of an exported rectified pair, whose off-centre
    principal points make the central rays meet on the pair's common plane although the optical axes are
    parallel. If they do not meet in front of both cameras: ten baselines in front of them."""
    inner = invert(world_from_internal)
    rays = [central_ray(cam) for cam in cams[:2]]
    c = [transform(inner, r[0]) for r in rays]
    a = [inner[:3, :3] @ r[1] for r in rays]
    w = c[0] - c[1]
    b = a[0] @ a[1]
    den = 1 - b * b
    if den > 1e-12:
        s = (b * (a[1] @ w) - a[0] @ w) / den
        t = ((a[1] @ w) - b * (a[0] @ w)) / den
        if s > 0 and t > 0:
            return float(((c[0] + s * a[0]) + (c[1] + t * a[1]))[2] / 2)
    ahead = 10 * np.linalg.norm(w) * (a[0] + a[1]) / 2
    return float(((c[0] + c[1]) / 2 + ahead)[2])


def prvm_of(cam: CameraModel, *, world_from_internal: np.ndarray | None = None, reference_z_mm: float = 0.0,
            where=None, dataset: str = "", step: int = 1) -> PRVM:
    """The PRVM of `cam` (every pixel's ray through its optical centre) in the internal frame given by
    `world_from_internal` (identity: the file's world frame), origins on z = reference_z_mm. Pixels where
    the model has no inverse are not valid. `step` > 1 samples every step-th row and column only (a
    coarse PRVM, for the geometry of a rig whose maps come from the model itself). InputError naming
    `where` if no pixel is valid or a ray does not travel towards +z (it would not meet the display side)."""
    if cam.width is None or cam.height is None:
        raise InputError(where, f"camera {cam.name!r} has no image size")
    wfi = np.eye(4) if world_from_internal is None else np.asarray(world_from_internal, np.float64)
    inner = invert(wfi)
    v, u = np.mgrid[0:cam.height:step, 0:cam.width:step].astype(np.float64)
    d, ok = unproject(cam, np.stack([u.ravel(), v.ravel()], axis=-1))
    d = cam.to_world(d) @ inner[:3, :3].T        # camera -> world -> internal
    c = transform(inner, cam.centre)
    if not ok.any():
        raise InputError(where, f"camera {cam.name!r}: its lens model has no ray for any pixel")
    if (d[ok, 2] <= 1e-9).any():
        bad = int((d[ok, 2] <= 1e-9).sum())
        raise InputError(where, f"camera {cam.name!r}: {bad} pixels' rays do not meet the display side (they do "
                                f"not travel towards +z in any frame that keeps the others doing so)")
    d = np.where(ok[:, None], d, np.nan)
    with np.errstate(invalid="ignore", divide="ignore"):
        origin = c + ((reference_z_mm - c[2]) / d[:, 2])[:, None] * d
    shape = v.shape
    meta = {"camera": cam.name, "reference_z_mm": float(reference_z_mm), "dataset": dataset,
            "model": cam.to_dict(), "world_from_rig": wfi.tolist()}
    if step > 1:
        meta["step"] = int(step)
    return PRVM(origin.reshape(shape + (3,)), d.reshape(shape + (3,)), ok.reshape(shape), None, meta)


def rig_frame(cams: list[CameraModel], *, where=None) -> tuple[np.ndarray, float]:
    """(world_from_internal (4, 4), reference z mm) of the cameras of one file: the internal frame
    (`internal_frame`) and the plane of their rays' origins: through their working point
    (`convergence_z`). A single camera's plane is z = 0 of the internal frame if that lies in front of its
    optical centre (a board's or a world's plane seen by the camera), else the plane SINGLE_PLANE_MM in
    front of the centre (a camera at its file's origin: a plane through the centre would hold no field)."""
    for cam in cams:
        if cam.width is None or cam.height is None:
            raise InputError(where, f"camera {cam.name!r} has no image size")
    wfi = internal_frame(cams)
    if len(cams) > 1:
        return wfi, convergence_z(cams, wfi)
    cz = transform(invert(wfi), cams[0].centre)[2]
    return wfi, (0.0 if cz < -SINGLE_PLANE_MM / 100 else cz + SINGLE_PLANE_MM)


def prvms_of(cams: list[CameraModel], *, where=None, dataset: str = "", step: int = 1) -> list[PRVM]:
    """The PRVMs (`prvm_of`, every `step`-th pixel) of the cameras of one file in their common internal
    frame, origins on their reference plane (`rig_frame`)."""
    wfi, z = rig_frame(cams, where=where)
    return [prvm_of(c, world_from_internal=wfi, reference_z_mm=z, where=where, dataset=dataset, step=step)
            for c in cams]

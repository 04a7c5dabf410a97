"""The five lens families of the simulated rig, each giving the TRUE ray of any sensor point.

Frames: the camera frame has x right (along sensor columns), y down (along rows), z forward (the
optical axis, towards the scene); `Lens.rotation` maps camera-frame vectors to the WCS and
`Lens.centre_mm` is the camera frame's origin in the WCS (the projection centre of a central lens).
The WCS is DESIGN.md's: mm, display plane at stage position z, x along display columns, y along rows,
z along the stage axis away from the camera, so the camera sits at negative z looking towards +z.

Pixel coordinates (u, v) are continuous, (column, row), pixel centres at integers. `Lens.rays(u, v)`
returns (origin, direction) in the WCS, float64, origin on the plane z = 0 (the truth's reference
plane), direction a unit vector with z > 0.

Families (`make_lens`):
  brown        pinhole + Brown-Conrady radial/tangential distortion (machine-vision 12 mm lens)
  freeform     "smartphone": pinhole + smooth global distortion + local Gaussian bumps
  noncentral   pinhole camera behind a thick tilted glass window, traced with Snell's law
  telecentric  object-side telecentric: parallel rays, small distortion of the object-plane points
  scheimpflug  pinhole lens with mild distortion viewing the display obliquely, its sensor tilted so
               that the display plane is in focus (the Scheimpflug condition, `scheimpflug_tilt_deg`)
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from calib.errors import InputError
from calib.prvm_file import PRVM
from scanners.sim import LENS_FAMILIES
from scanners.sim.distortion import Distortion
from scanners.sim.optics import rotation, through_slab

PIXEL_MM = 0.0053                                  # 1.3 MP machine-vision sensor, 5.3 um pixels
DEFAULT_TARGET_MM = (959.5 * 0.2745, 539.5 * 0.2745, 0.0)   # centre of the default 24" 1080p display


@dataclass(frozen=True)
class Window:
    """A plane-parallel glass window in front of a camera (camera frame): its entry face crosses the
    optical axis at `distance_mm`, its normal is the axis tilted by `tilt_deg` about the camera y axis."""

    distance_mm: float = 15.0
    thickness_mm: float = 10.0
    index: float = 1.5
    tilt_deg: float = 25.0

    @property
    def normal(self) -> np.ndarray:
        return rotation("y", np.radians(self.tilt_deg)) @ np.array([0.0, 0.0, 1.0])


@dataclass
class Lens:
    """A camera's geometry: sensor size, pose and the optics that turn sensor points into rays.

    width, height: pixels; pixel_mm: pixel pitch (mm); rotation: 3x3 camera-to-WCS; centre_mm: (3,)
    camera frame origin in the WCS; focus_mm: distance along the axis (from the camera frame origin) of
    the plane in focus; params: the family's parameters (for the truth's metadata); colour: lateral
    chromatic aberration of a colour sensor's photosites (`scanners.sim.bayer.LateralColour`), None for
    a monochrome one.
    """

    family: str
    width: int
    height: int
    pixel_mm: float
    rotation: np.ndarray
    centre_mm: np.ndarray
    focus_mm: float
    vignetting: float                  # mechanical falloff: relative illumination *= 1 + vignetting*rn^2
    params: dict = field(default_factory=dict)
    colour: object = None

    # -- to be provided by each family (camera frame) --
    def _camera_rays(self, u, v) -> tuple[np.ndarray, np.ndarray]:
        raise NotImplementedError

    def relative_illumination(self, u, v) -> np.ndarray:
        """Irradiance on the sensor relative to the centre for a uniform scene (vignetting), float64."""
        raise NotImplementedError

    def blur_diameter_px(self, u, v, points_mm: np.ndarray) -> np.ndarray:
        """Diameter (pixels) of the defocus blur circle at sensor point (u, v) for scene points
        `points_mm` (..., 3) (WCS) seen there; thin-lens geometry."""
        raise NotImplementedError

    def diffraction_sigma_px(self, wavelength_mm: float = 550e-6) -> float:
        """Standard deviation (pixels) of the Gaussian approximating the diffraction (Airy) spot."""
        raise NotImplementedError

    # -- common --
    def rays(self, u, v) -> tuple[np.ndarray, np.ndarray]:
        """True rays of sensor points (u, v) (any broadcastable shapes): (origin, direction), each
        (..., 3) float64 in the WCS; origin on the plane z = 0, direction unit with z > 0."""
        u, v = np.broadcast_arrays(np.asarray(u, np.float64), np.asarray(v, np.float64))
        if self.colour is not None:
            u, v = self.colour.sensor_point(u, v)
        o, d = self._camera_rays(u, v)
        d = d @ self.rotation.T
        o = o @ self.rotation.T + self.centre_mm
        if np.any(d[..., 2] <= 0):
            raise InputError("lens", "some pixel rays do not point towards +z (the display side)")
        return o - (o[..., 2] / d[..., 2])[..., None] * d, d

    def axis_depth(self, points_mm: np.ndarray) -> np.ndarray:
        """Distance (mm) of WCS points in front of the camera frame origin, along the optical axis."""
        return (np.asarray(points_mm) - self.centre_mm) @ self.rotation[:, 2]

    def pixel_grid(self) -> tuple[np.ndarray, np.ndarray]:
        """(u, v) of every pixel centre, each (height, width) float64."""
        return np.meshgrid(np.arange(self.width, dtype=np.float64), np.arange(self.height, dtype=np.float64))

    def true_prvm(self, **meta) -> PRVM:
        """The true PRVM: the ray through each pixel centre, reference plane z = 0."""
        o, d = self.rays(*self.pixel_grid())
        return PRVM(o, d, np.ones((self.height, self.width), bool),
                    np.zeros((self.height, self.width), np.float32),
                    {"reference_z_mm": 0.0, "lens": self.describe(), **meta})

    def _radius_norm2(self, u, v) -> np.ndarray:
        cu, cv = (self.width - 1) / 2, (self.height - 1) / 2
        return ((u - cu) ** 2 + (v - cv) ** 2) / (cu * cu + cv * cv)

    def describe(self) -> dict:
        """The lens as plain JSON data."""
        return {"family": self.family, "width": self.width, "height": self.height, "pixel_mm": self.pixel_mm,
                "rotation": self.rotation.tolist(), "centre_mm": self.centre_mm.tolist(),
                "focus_mm": self.focus_mm, "vignetting": self.vignetting, **self.params}


@dataclass
class CentralLens(Lens):
    """A thin lens with projection centre at the camera frame origin and a (possibly tilted) sensor.

    fx, fy, cx, cy: pinhole intrinsics (pixels) of the untilted sensor, fx * pixel_mm being the sensor
    distance behind the lens; distortion: forward, on normalised coordinates; sensor_tilt_deg: the
    sensor plane's rotation about the camera y axis (Scheimpflug); window: optional glass in front
    (which makes the camera non-central); focal_mm, f_number: the thin lens (defocus blur).
    """

    fx: float = 0.0
    fy: float = 0.0
    cx: float = 0.0
    cy: float = 0.0
    distortion: Distortion = field(default_factory=Distortion)
    sensor_tilt_deg: float = 0.0
    window: Window | None = None
    focal_mm: float = 12.0
    f_number: float = 5.6

    def sensor_points(self, u, v) -> np.ndarray:
        """Camera-frame positions (mm, (..., 3)) of sensor points, the sensor drawn in front of the lens
        (the usual unflipped picture), its centre on the axis at the sensor distance."""
        dist = self.fx * self.pixel_mm
        local = np.stack([(u - self.cx) * dist / self.fx, (v - self.cy) * dist / self.fy,
                          np.zeros(np.shape(u))], axis=-1)
        return local @ rotation("y", np.radians(self.sensor_tilt_deg)).T + np.array([0.0, 0.0, dist])

    def chief_directions(self, u, v) -> np.ndarray:
        """Camera-frame unit directions (..., 3) of the chief rays leaving the lens (before any window)."""
        p = self.sensor_points(u, v)
        x, y = self.distortion.invert(p[..., 0] / p[..., 2], p[..., 1] / p[..., 2])
        d = np.stack([x, y, np.ones_like(x)], axis=-1)
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    def _camera_rays(self, u, v):
        d = self.chief_directions(u, v)
        o = np.zeros_like(d)
        if self.window is not None:
            w = self.window
            o, d = through_slab(o, d, np.array([0.0, 0.0, w.distance_mm]), w.normal, w.thickness_mm, w.index)
        return o, d

    def relative_illumination(self, u, v):
        u, v = np.broadcast_arrays(np.asarray(u, np.float64), np.asarray(v, np.float64))
        cos_field = self.chief_directions(u, v)[..., 2]
        return cos_field ** 4 * (1.0 + self.vignetting * self._radius_norm2(u, v))

    def blur_diameter_px(self, u, v, points_mm):
        s = self.axis_depth(points_mm)
        image_dist = self.focal_mm * s / (s - self.focal_mm)     # where the scene point is sharp
        sensor_dist = self.sensor_points(u, v)[..., 2]
        aperture = self.focal_mm / self.f_number
        return aperture * np.abs(sensor_dist - image_dist) / image_dist / self.pixel_mm

    def diffraction_sigma_px(self, wavelength_mm=550e-6):
        working_f_number = self.f_number * self.fx * self.pixel_mm / self.focal_mm
        return 0.42 * wavelength_mm * working_f_number / self.pixel_mm


@dataclass
class TelecentricLens(Lens):
    """Object-side telecentric lens: every ray is parallel to the optical axis.

    magnification: sensor size / object size; cx, cy: the axis on the sensor (pixels); distortion acts
    on object-plane coordinates divided by `norm_mm` (half the object field's diagonal);
    numerical_aperture: object-side NA (defocus blur 2 NA |depth - focus|).
    """

    magnification: float = 0.2
    cx: float = 0.0
    cy: float = 0.0
    distortion: Distortion = field(default_factory=Distortion)
    numerical_aperture: float = 0.005

    @property
    def norm_mm(self) -> float:
        return 0.5 * np.hypot(self.width, self.height) * self.pixel_mm / self.magnification

    def _camera_rays(self, u, v):
        scale = self.pixel_mm / self.magnification / self.norm_mm
        x, y = self.distortion.invert((u - self.cx) * scale, (v - self.cy) * scale)
        o = np.stack([x * self.norm_mm, y * self.norm_mm, np.zeros_like(x)], axis=-1)
        d = np.zeros_like(o)
        d[..., 2] = 1.0
        return o, d

    def relative_illumination(self, u, v):
        u, v = np.broadcast_arrays(np.asarray(u, np.float64), np.asarray(v, np.float64))
        return 1.0 + self.vignetting * self._radius_norm2(u, v)

    def blur_diameter_px(self, u, v, points_mm):
        blur_obj = 2.0 * self.numerical_aperture * np.abs(self.axis_depth(points_mm) - self.focus_mm)
        return blur_obj * self.magnification / self.pixel_mm * np.ones(np.shape(u))

    def diffraction_sigma_px(self, wavelength_mm=550e-6):
        image_f_number = self.magnification / (2 * self.numerical_aperture)
        return 0.42 * wavelength_mm * image_f_number / self.pixel_mm


def look_at(centre_mm, target_mm, roll_deg: float = 0.0) -> np.ndarray:
    """Camera-to-WCS rotation of a camera at `centre_mm` whose axis points at `target_mm`, its rows
    along the WCS y axis as far as possible, then rolled by `roll_deg` about the axis."""
    z = np.asarray(target_mm, float) - np.asarray(centre_mm, float)
    z /= np.linalg.norm(z)
    y = np.array([0.0, 1.0, 0.0]) - z[1] * z
    y /= np.linalg.norm(y)
    r = np.stack([np.cross(y, z), y, z], axis=1)
    return r @ rotation("z", np.radians(roll_deg))


_COMMON = ("pixel_mm", "distance_mm", "focus_mm", "target_mm", "offset_mm", "roll_deg", "vignetting",
           "principal_offset_px")
_FAMILY_KEYS = {
    "brown": ("focal_mm", "f_number", "k", "p", "ripple"),
    "freeform": ("focal_mm", "f_number", "k", "p", "bumps", "bump_sigma_px", "bump_amplitude_px", "ripple"),
    "noncentral": ("focal_mm", "f_number", "k", "p", "window", "ripple"),
    "telecentric": ("magnification", "numerical_aperture", "k"),
    "scheimpflug": ("focal_mm", "f_number", "k", "p", "sensor_tilt_deg", "view_deg", "ripple"),
}
# the default lenses are focused on the display at the middle of the default stage travel (0, 50 mm)
FOCUS_BEYOND_TARGET_MM = 25.0
# a large-field telecentric lens (like the commercial 0.06x ones covering ~100 mm): a 5.3 um pixel sees
# 88 um = 0.32 display pixels, so the display's pixels are not resolved; working F/8 (NA = m / (2 F))
TELECENTRIC_MAGNIFICATION = 0.06
TELECENTRIC_WORKING_F_NUMBER = 8.0


def scheimpflug_tilt_deg(camera_to_wcs: np.ndarray, focus_mm: float, focal_mm: float) -> float:
    """Sensor tilt (degrees, about the camera y axis, `CentralLens.sensor_tilt_deg`) that puts the plane
    of sharp focus on the display plane (WCS normal z) through the axis point at `focus_mm`.

    A thin lens images the plane n.P = d (camera frame, P in mm) onto the plane (f n - d e_z).Q = -d f
    (sensor drawn in front of the lens, Q = P f / (P_z - f)): the sensor must lie in that plane. Its
    normal, (-f n_x, -f n_y, (F - f) n_z) for d = F n_z, gives tan(tilt) = f / (F - f) * tan(object
    tilt) = m tan(object tilt); the small component n_y (a camera off the display's row through the
    target, or rolled) is left uncorrected, as a one-axis Scheimpflug mount does.
    """
    n = camera_to_wcs.T @ np.array([0.0, 0.0, 1.0])            # display normal in the camera frame
    return float(np.degrees(np.arctan2(-focal_mm * n[0], (focus_mm - focal_mm) * n[2])))


def make_lens(family: str, *, width: int = 1280, height: int = 1024, seed: int = 0, **overrides) -> Lens:
    """A lens of one family with realistic parameters drawn from a seed, posed ~400 mm in front of the
    default display's centre, looking at it.

    Parameters
    ----------
    family : str
        One of LENS_FAMILIES (InputError otherwise).
    width, height : int
        The sensor's pixel count.
    seed : int
        Draws the lens's parameters and pose.
    **overrides
        All optional: pixel_mm; distance_mm (camera to target along -z); focus_mm (in-focus distance along the
        axis, default: to the display plane 25 mm beyond the target, distance + 25 for a camera facing it);
        target_mm (WCS point on the axis); offset_mm (x, y of the camera relative to the target; scheimpflug:
        default -distance * tan(view_deg) in x, an oblique view); roll_deg; vignetting (mechanical r^2
        coefficient); principal_offset_px (cx, cy offset from the sensor centre); and per family: focal_mm,
        f_number, k (k1, k2, k3), p (p1, p2), bumps ((n, 5) array of (u, v, sigma, du, dv) in pixels, or a
        count), bump_sigma_px (lo, hi), bump_amplitude_px (lo, hi), ripple ((amplitude_px, wavelength_px): a
        radial ripple about the principal point, finer than any of our families' distortion, e.g. (0.3, 15);
        not for telecentric), window (a Window), magnification, numerical_aperture, sensor_tilt_deg (default
        for scheimpflug: the Scheimpflug condition for the display plane in focus, `scheimpflug_tilt_deg`),
        view_deg (angle between the scheimpflug camera's axis and the display normal, from which its default
        offset follows).

    Returns
    -------
    lens : Lens
        Its true rays (`Lens.true_prvm`, WCS mm) and projection.
    """
    if family not in LENS_FAMILIES:
        raise InputError("--lens", f"unknown lens family {family!r} (known: {', '.join(LENS_FAMILIES)})")
    if int(width) != width or int(height) != height or width < 2 or height < 2:
        raise InputError("--width/--height", f"sensor size must be whole numbers >= 2, got {width}x{height}")
    allowed = _COMMON + _FAMILY_KEYS[family]
    bad = sorted(set(overrides) - set(allowed))
    if bad:
        raise InputError("lens", f"{family} lens has no parameter(s) {', '.join(bad)} "
                                 f"(known: {', '.join(allowed)})")
    rng = np.random.default_rng([seed, LENS_FAMILIES.index(family)])
    dev = lambda scale: float(rng.normal(0.0, scale))  # noqa: E731 - seeded deviation
    q = dict(pixel_mm=PIXEL_MM, distance_mm=400.0, focus_mm=None, target_mm=DEFAULT_TARGET_MM,
             offset_mm=(dev(15.0), dev(10.0)), roll_deg=dev(0.7), vignetting=-0.05,
             principal_offset_px=(dev(8.0), dev(8.0)), focal_mm=12.0, f_number=5.6)
    q.update({
        "brown": dict(k=(-0.07 * (1 + dev(0.15)), 0.10 * (1 + dev(0.15)), 0.0), p=(dev(3e-4), dev(3e-4))),
        "freeform": dict(k=(0.04 * (1 + dev(0.15)), -0.02, 0.0), p=(dev(2e-4), dev(2e-4)),
                         bumps=max(3, round(25 * width * height / (1280 * 1024))),
                         bump_sigma_px=(20.0, 60.0), bump_amplitude_px=(1.0, 3.0)),
        "noncentral": dict(k=(-0.03 * (1 + dev(0.15)), 0.02, 0.0), p=(dev(2e-4), dev(2e-4)),
                           window=Window(tilt_deg=25.0 + dev(2.0))),
        "telecentric": dict(magnification=TELECENTRIC_MAGNIFICATION,
                            numerical_aperture=TELECENTRIC_MAGNIFICATION / (2 * TELECENTRIC_WORKING_F_NUMBER),
                            k=(1e-3 * (1 + dev(0.2)), 0.0, 0.0), vignetting=-0.06),
        # a 25 mm lens at f/8 viewing the display ~30 degrees off its normal (m ~ 0.056: a ~1.7 degree tilt)
        "scheimpflug": dict(k=(-0.02 * (1 + dev(0.15)), 0.005, 0.0), p=(dev(2e-4), dev(2e-4)),
                            focal_mm=25.0, f_number=8.0, view_deg=30.0 + dev(2.0), sensor_tilt_deg=None),
    }[family])
    q.update(overrides)
    if family == "scheimpflug" and "offset_mm" not in overrides:
        q["offset_mm"] = (-q["distance_mm"] * np.tan(np.radians(q["view_deg"])), dev(5.0))
    for key in ("pixel_mm", "distance_mm", "focal_mm", "f_number", "magnification", "numerical_aperture"):
        if key in q and not (np.isfinite(q[key]) and q[key] > 0):
            raise InputError("lens", f"{key} must be positive, got {q[key]!r}")
    target = np.asarray(q["target_mm"], float)
    centre = target + np.array([q["offset_mm"][0], q["offset_mm"][1], -q["distance_mm"]])
    rot = look_at(centre, target, q["roll_deg"])
    focus = q["distance_mm"] + FOCUS_BEYOND_TARGET_MM if q["focus_mm"] is None else float(q["focus_mm"])
    if family == "scheimpflug" and q["focus_mm"] is None:      # oblique: the axis meets the plane farther
        focus /= rot[2, 2]
    cx = (width - 1) / 2 + q["principal_offset_px"][0]
    cy = (height - 1) / 2 + q["principal_offset_px"][1]
    common = dict(family=family, width=int(width), height=int(height), pixel_mm=q["pixel_mm"], rotation=rot,
                  centre_mm=centre, focus_mm=focus, vignetting=q["vignetting"])
    k = tuple(float(c) for c in q["k"])
    if family == "telecentric":
        dist = Distortion(k=k)
        return TelecentricLens(**common, params={"magnification": q["magnification"], "cx": cx, "cy": cy,
                                                 "numerical_aperture": q["numerical_aperture"],
                                                 "distortion": dist.to_json()},
                               magnification=q["magnification"], cx=cx, cy=cy, distortion=dist,
                               numerical_aperture=q["numerical_aperture"])
    if not q["focal_mm"] < focus:
        raise InputError("lens", f"focus distance {focus} mm must exceed the focal length {q['focal_mm']} mm")
    sensor_dist = q["focal_mm"] * focus / (focus - q["focal_mm"])     # thin lens, focused at focus_mm
    f_px = sensor_dist / q["pixel_mm"]
    bumps = np.zeros((0, 5))
    if family == "freeform":
        bumps = _bumps(rng, q["bumps"], width, height, q["bump_sigma_px"], q["bump_amplitude_px"])
    bumps_norm = np.column_stack([(bumps[:, 0] - cx) / f_px, (bumps[:, 1] - cy) / f_px, bumps[:, 2:] / f_px])
    ripple = tuple(float(v) for v in q.get("ripple", (0.0, 1.0)))
    if len(ripple) != 2 or not (ripple[1] > 0 and 2 * np.pi * abs(ripple[0]) < ripple[1]):
        raise InputError("lens", f"ripple must be (amplitude_px, wavelength_px) with 2 pi amplitude < wavelength, "
                                 f"got {ripple}")
    dist = Distortion(k=k, p=tuple(float(c) for c in q["p"]), bumps=bumps_norm,
                      ripple=(ripple[0] / f_px, ripple[1] / f_px))
    params = {"fx": f_px, "fy": f_px, "cx": cx, "cy": cy, "focal_mm": q["focal_mm"], "f_number": q["f_number"],
              "distortion": {"k": list(k), "p": list(dist.p), "bumps_px": bumps.tolist(),
                             **({"ripple_px": list(ripple)} if ripple[0] else {})}}
    tilt = q.get("sensor_tilt_deg", 0.0)
    tilt = scheimpflug_tilt_deg(rot, focus, q["focal_mm"]) if tilt is None else float(tilt)
    window = q.get("window")
    if tilt:
        params["sensor_tilt_deg"] = tilt
    if window is not None:
        if not (window.thickness_mm >= 0 and window.index >= 1 and window.distance_mm > 0):
            raise InputError("lens", f"window needs thickness >= 0, index >= 1, distance > 0, got {window}")
        params["window"] = {"distance_mm": window.distance_mm, "thickness_mm": window.thickness_mm,
                            "index": window.index, "tilt_deg": window.tilt_deg}
    return CentralLens(**common, params=params, fx=f_px, fy=f_px, cx=cx, cy=cy, distortion=dist,
                       sensor_tilt_deg=tilt, window=window, focal_mm=q["focal_mm"], f_number=q["f_number"])


def _bumps(rng, count, width, height, sigma_px, amplitude_px) -> np.ndarray:
    """(n, 5) Gaussian displacement bumps (u, v, sigma, du, dv) in pixels, over the sensor."""
    if not np.isscalar(count):
        return np.asarray(count, float).reshape(-1, 5)
    n = int(count)
    sigma = rng.uniform(*sigma_px, n)
    amp = rng.uniform(*amplitude_px, n)
    ang = rng.uniform(0, 2 * np.pi, n)
    return np.column_stack([rng.uniform(0, width - 1, n), rng.uniform(0, height - 1, n), sigma,
                            amp * np.cos(ang), amp * np.sin(ang)])

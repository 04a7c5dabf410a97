"""The simulated stereo DIC experiment: a speckled plate with known deformation, seen by the two cameras of
a simulated stereo rig (`scanners.sim.stereo` poses), in a series of load states.

The specimen: a flat rectangular plate (`Specimen`), centred near the rig's target, tilted about the WCS
y axis (so that the two cameras foreshorten it differently), with a speckle pattern (the Boolean model
of blurred dots of `scanners.sim.speckle`) painted in its MATERIAL coordinates (X1, X2), mm from the
plate's centre along its edges e1 = (cos tilt, 0, sin tilt) and e2 = (0, 1, 0); n = e1 x e2 points away
from the cameras.

A state (`DicState`) maps every material point to the WCS:
    p(X) = C + t + R A (l1 X'1, l2 X'2, w(X')),   w(X) = -h (1 - r^2/Rb^2)^2 for r = |X| < Rb, else 0,
    X' = Q(theta(r)) X,   theta(r) = theta0 exp(-r^2 / (2 s^2))   (a twist: Q the 2-D rotation),
A = [e1 e2 n] (the plate frame), R a rotation about the plate's centre C, t a translation (mm), l1, l2
in-plane stretches, h the height of a bulge of radius Rb towards the cameras, theta0 the angle of a
twist of radius s about the plate's centre (a rotation that fades with the distance from the centre: a
deformation no affine subset follows when theta0 is large). Its deformation gradient (material frame)
is F = R A J T with J = [[l1, 0], [0, l2], [dw/dX'1, dw/dX'2]] (at X') and T = dX'/dX = Q(theta) +
Q(theta + pi/2) X grad(theta)^T, grad(theta) = -theta X / s^2, so the Green-Lagrange strain in the
plate's frame is E = (T^T J^T J T - I) / 2 exactly. The twist keeps |X'| = |X|, so a ray meets the
deformed plate where it would without it, at X' (then X = Q(-theta(|X'|)) X').

Rendering one camera image of one state: each pixel is sampled at S x S points; the TRUE ray of each
sample (`Lens.rays`) meets the deformed plate where w(X(s)) equals the ray's height above the plate
frame, a scalar equation in the ray parameter s (Newton); the material point X gives the speckle's
reflectance analytically (`SpeckleSampler`); uniform diffuse light; then the camera's defocus and
diffraction blur, pixel integration, vignetting, PRNU, shot and read noise and 8-bit quantisation
(`SimCamera`'s pieces). Outside the plate a dark untextured background.

`simulate_dic` writes a `stereodic.capture/1` dataset of kind "dic" (cameras cam0 = left, cam1 = right,
one image per camera and state: s{state:03d}/cam{k}.png), the TRUE camera models as PRVMs
(truth_cam0.npz, truth_cam1.npz; the `simulate dic` command adds rig.npz, their rectified pair built by
`stereodic.stereo.rig`) and truth.npz (`DicTruth`). `truth_at_pixels` gives the truth at the points the left
camera sees at given real pixels, through the simulator's own lens rays and the plate's geometry.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from numba import njit, prange

from calib.atomic import write_npz
from calib.capture import MANIFEST, Capture, Frame, Pattern, load_capture
from calib.errors import InputError
from calib.imageio import write_gray
from calib.progress import progress
from scanners.sim.camera import SimCamera
from scanners.sim.defocus import blur_and_integrate
from scanners.sim.lenses import DEFAULT_TARGET_MM, Lens
from scanners.sim.optics import rotation
from scanners.sim.sensor import Sensor
from scanners.sim.speckle import SpeckleSampler, make_speckle
from scanners.sim.stereo import CAMERAS, stereo_lenses

TARGET = np.asarray(DEFAULT_TARGET_MM, np.float64)
BACKGROUND = 0.05          # reflectance off the plate
ROWS_PER_CHUNK = 32


@dataclass(frozen=True)
class Specimen:
    """The plate in its reference state: centre (WCS mm), tilt about the WCS y axis (degrees), size
    (mm along e1, e2); the speckle's dot radius and grid unit (mm), coverage and seed."""

    centre_mm: tuple = tuple(TARGET)
    tilt_deg: float = 10.0
    size_mm: tuple = (320.0, 260.0)
    unit_mm: float = 0.35
    dot_radius: float = 1.3          # in speckle units
    coverage: float = 0.5
    seed: int = 0

    @property
    def frame(self) -> np.ndarray:
        """A = [e1 e2 n] (3x3, columns), WCS."""
        return rotation("y", -math.radians(self.tilt_deg))

    def speckle(self):
        w, h = (int(math.ceil(s / self.unit_mm)) for s in self.size_mm)
        return make_speckle(w, h, self.dot_radius, self.coverage, self.seed)


@dataclass(frozen=True)
class DicState:
    """One load state (module docstring): name, in-plane stretches (l1, l2), bulge height h (mm, towards
    the cameras) and radius Rb (mm), rigid rotation (rotation vector, degrees, about the plate's centre)
    and translation (WCS mm), twist angle theta0 (degrees, about the plate's normal) and radius s (mm)."""

    name: str
    stretch: tuple = (1.0, 1.0)
    bulge_mm: float = 0.0
    bulge_radius_mm: float = 60.0
    rotation_deg: tuple = (0.0, 0.0, 0.0)
    translation_mm: tuple = (0.0, 0.0, 0.0)
    twist_deg: float = 0.0
    twist_radius_mm: float = 40.0

    def twist(self, X1, X2, inverse: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(X'1, X'2, theta): material points twisted (X' = Q(theta(|X|)) X; with `inverse`, X from X'),
        theta (radians) at each."""
        X1, X2 = np.asarray(X1, np.float64), np.asarray(X2, np.float64)
        theta = math.radians(self.twist_deg) * np.exp(-(X1 * X1 + X2 * X2) / (2.0 * self.twist_radius_mm ** 2))
        a = -theta if inverse else theta
        c, s = np.cos(a), np.sin(a)
        return c * X1 - s * X2, s * X1 + c * X2, theta

    @property
    def rotation(self) -> np.ndarray:
        """3x3 rotation matrix of the rotation vector (Rodrigues)."""
        v = np.radians(np.asarray(self.rotation_deg, np.float64))
        a = float(np.linalg.norm(v))
        if a == 0:
            return np.eye(3)
        k = v / a
        K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
        return np.eye(3) + math.sin(a) * K + (1 - math.cos(a)) * K @ K


def standard_states(strain: float = 0.01, poisson: float = 0.3, bulge_mm: float = 2.0) -> list[DicState]:
    """The default series: reference; rigid translation; rigid rotation; uniaxial tension (`strain`
    engineering strain along e1, Poisson contraction along e2); an out-of-plane bulge."""
    return [DicState("reference"),
            DicState("translation", translation_mm=(0.8, -0.5, 1.5)),
            DicState("rotation", rotation_deg=(0.4, -0.6, 1.5)),
            DicState("tension", stretch=(1.0 + strain, 1.0 - poisson * strain)),
            DicState("bulge", bulge_mm=bulge_mm)]


@njit(cache=True, inline="always")
def _bulge(x1, x2, h, rb):
    """w and its derivatives at material point (x1, x2)."""
    rho = (x1 * x1 + x2 * x2) / (rb * rb)
    if h == 0.0 or rho >= 1.0:
        return 0.0, 0.0, 0.0
    q = 1.0 - rho
    return -h * q * q, 4.0 * h * q * x1 / (rb * rb), 4.0 * h * q * x2 / (rb * rb)


@njit(cache=True)
def _bulge_many(x1, x2, h, rb, out):
    """`_bulge` at every point: out (N, 3) = w, dw/dX1, dw/dX2."""
    for i in range(x1.size):
        out[i, 0], out[i, 1], out[i, 2] = _bulge(x1[i], x2[i], h, rb)


def bulge(state: DicState, X1, X2) -> np.ndarray:
    """(..., 3): the bulge w (mm) and its derivatives at material points (X1, X2) (mm)."""
    X1, X2 = np.broadcast_arrays(np.asarray(X1, np.float64), np.asarray(X2, np.float64))
    out = np.empty((X1.size, 3))
    _bulge_many(np.ascontiguousarray(X1).ravel(), np.ascontiguousarray(X2).ravel(), float(state.bulge_mm),
                float(state.bulge_radius_mm), out)
    return out.reshape(X1.shape + (3,))


@njit(cache=True, parallel=True)
def _trace(o, d, C, A, l1, l2, h, rb, X, hit_t):
    """Material points X (N, 2) where rays (o, d) (N, 3) meet the deformed plate p(X) = C + A (l1 X1,
    l2 X2, w(X)) (A here includes the rigid rotation; C the translated centre); hit_t (N,) the ray
    parameter (NaN: no convergence)."""
    for i in prange(o.shape[0]):
        oo = np.empty(3)
        dd = np.empty(3)
        for k in range(3):
            oo[k] = (o[i, 0] - C[0]) * A[0, k] + (o[i, 1] - C[1]) * A[1, k] + (o[i, 2] - C[2]) * A[2, k]
            dd[k] = d[i, 0] * A[0, k] + d[i, 1] * A[1, k] + d[i, 2] * A[2, k]
        s = -oo[2] / dd[2]
        ok = False
        for _ in range(30):
            x1 = (oo[0] + s * dd[0]) / l1
            x2 = (oo[1] + s * dd[1]) / l2
            w, w1, w2 = _bulge(x1, x2, h, rb)
            g = w - oo[2] - s * dd[2]
            dg = w1 * dd[0] / l1 + w2 * dd[1] / l2 - dd[2]
            step = g / dg
            s -= step
            if abs(step) < 1e-10:
                ok = True
                break
        X[i, 0] = (oo[0] + s * dd[0]) / l1
        X[i, 1] = (oo[1] + s * dd[1]) / l2
        hit_t[i] = s if ok else np.nan


@dataclass
class DicTruth:
    """The exact answer of a simulated DIC dataset: the specimen and its states."""

    specimen: Specimen
    states: list[DicState]
    meta: dict = field(default_factory=dict)

    def _placed(self, state: int) -> tuple[np.ndarray, np.ndarray, DicState]:
        st = self.states[state]
        return (np.asarray(self.specimen.centre_mm) + np.asarray(st.translation_mm),
                st.rotation @ self.specimen.frame, st)

    def position(self, state: int, X1, X2) -> np.ndarray:
        """(..., 3) WCS mm of material points (X1, X2) (mm) in `state`."""
        C, A, st = self._placed(state)
        X1, X2 = np.broadcast_arrays(np.asarray(X1, np.float64), np.asarray(X2, np.float64))
        if st.twist_deg:
            X1, X2, _ = st.twist(X1, X2)
        q = np.stack([st.stretch[0] * X1, st.stretch[1] * X2, bulge(st, X1, X2)[..., 0]], -1)
        return C + q @ A.T

    def strain(self, state: int, X1, X2) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Green-Lagrange (E11, E22, E12) in the plate's frame (e1, e2) at material points (X1, X2)."""
        st = self.states[state]
        X1, X2 = np.broadcast_arrays(np.asarray(X1, np.float64), np.asarray(X2, np.float64))
        l1, l2 = st.stretch
        if not st.twist_deg:
            g = bulge(st, X1, X2)[..., 1:]
            e11 = 0.5 * (l1 * l1 + g[..., 0] ** 2 - 1.0)
            e22 = 0.5 * (l2 * l2 + g[..., 1] ** 2 - 1.0)
            e12 = 0.5 * g[..., 0] * g[..., 1]
            return e11, e22, e12
        Y1, Y2, theta = st.twist(X1, X2)
        g = bulge(st, Y1, Y2)[..., 1:]
        J = np.zeros(X1.shape + (3, 2))
        J[..., 0, 0], J[..., 1, 1], J[..., 2, 0], J[..., 2, 1] = l1, l2, g[..., 0], g[..., 1]
        c, s = np.cos(theta), np.sin(theta)
        k = -theta / st.twist_radius_mm ** 2          # grad(theta) = k X
        qx = np.stack([c * X1 - s * X2, s * X1 + c * X2], -1)   # Q X
        perp = np.stack([-qx[..., 1], qx[..., 0]], -1)           # Q(theta + pi/2) X
        T = np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)
        T = T + perp[..., :, None] * (k[..., None] * np.stack([X1, X2], -1))[..., None, :]
        F = J @ T
        Cg = np.swapaxes(F, -1, -2) @ F
        return 0.5 * (Cg[..., 0, 0] - 1.0), 0.5 * (Cg[..., 1, 1] - 1.0), 0.5 * Cg[..., 0, 1]

    def material_at(self, origin: np.ndarray, direction: np.ndarray, state: int = 0) -> np.ndarray:
        """(N, 2) material points (mm) hit by rays (N, 3) in `state`; NaN where missed or off the
        plate."""
        C, A, st = self._placed(state)
        o = np.ascontiguousarray(np.asarray(origin, np.float64).reshape(-1, 3))
        d = np.ascontiguousarray(np.asarray(direction, np.float64).reshape(-1, 3))
        X = np.empty((len(o), 2))
        t = np.empty(len(o))
        _trace(o, d, C, np.ascontiguousarray(A), float(st.stretch[0]), float(st.stretch[1]),
               float(st.bulge_mm), float(st.bulge_radius_mm), X, t)
        if st.twist_deg:
            X[:, 0], X[:, 1], _ = st.twist(X[:, 0], X[:, 1], inverse=True)
        half = np.asarray(self.specimen.size_mm) / 2
        X[~np.isfinite(t) | np.any(np.abs(X) > half, axis=1)] = np.nan
        return X

    def lenses(self) -> tuple[Lens, Lens]:
        """The true (left, right) lenses of the dataset (`dic_lenses` of the family, size and seed it was
        simulated with)."""
        ln = self.meta["lenses"]
        return dic_lenses(ln["width"], ln["height"], ln["seed"], ln["family"])

    def to_json(self) -> dict:
        return {"format": "stereodic.dic-truth/1", "units": "WCS mm; strains Green-Lagrange in the plate "
                "frame e1 = (cos tilt, 0, sin tilt), e2 = (0, 1, 0)", "specimen": asdict(self.specimen),
                "states": [asdict(s) for s in self.states], **self.meta}

    @classmethod
    def from_json(cls, d: dict) -> "DicTruth":
        sp = Specimen(**{k: tuple(v) if isinstance(v, list) else v for k, v in d["specimen"].items()})
        states = [DicState(**{k: tuple(v) if isinstance(v, list) else v for k, v in s.items()})
                  for s in d["states"]]
        return cls(sp, states, {k: v for k, v in d.items()
                                if k not in ("format", "units", "specimen", "states")})


def truth_arrays(truth: DicTruth, step_units: float = 10.0) -> dict:
    """The truth on a grid of material points every `step_units` speckle units: X1 (n1,), X2 (n2,) mm;
    position, displacement (S, n2, n1, 3) WCS mm (displacement from the reference state 0); exx, eyy,
    exy (S, n2, n1) Green-Lagrange in the plate frame."""
    sp = truth.specimen
    step = step_units * sp.unit_mm
    x1 = np.arange(-sp.size_mm[0] / 2, sp.size_mm[0] / 2 + 1e-9, step)
    x2 = np.arange(-sp.size_mm[1] / 2, sp.size_mm[1] / 2 + 1e-9, step)
    G1, G2 = np.meshgrid(x1, x2)
    pos = np.stack([truth.position(k, G1, G2) for k in range(len(truth.states))])
    strains = [truth.strain(k, G1, G2) for k in range(len(truth.states))]
    return dict(X1=x1, X2=x2, position=pos, displacement=pos - pos[0],
                **{c: np.stack([e[k] for e in strains]) for k, c in enumerate(("exx", "eyy", "exy"))})


def load_dic_truth(dataset: str | os.PathLike) -> DicTruth:
    """The truth of a simulated DIC dataset.

    Parameters
    ----------
    dataset : path
        The dataset's folder (``stereodic simulate dic``).

    Returns
    -------
    truth : DicTruth
        From its truth.npz: the specimen and its states; positions (WCS mm) and strains of any material
        point (`DicTruth.position`, ...). InputError if the file is missing.
    """
    path = Path(dataset) / "truth.npz"
    if not path.is_file():
        raise InputError(path, "truth file is missing (not a simulated DIC dataset?)")
    with np.load(path, allow_pickle=False) as z:
        return DicTruth.from_json(json.loads(str(z["meta"])))


def render_states(cam: SimCamera, truth: DicTruth, sampler: SpeckleSampler, noise: bool = True
                  ) -> list[np.ndarray]:
    """The camera images (uint8, or uint16 above 8 bits) of the plate in every state of `truth` (module
    docstring); each sub-sample's ray is computed once for all states."""
    lens, s = cam.lens, cam.supersample
    h, w = cam.shape
    n = len(truth.states)
    sub = (np.arange(s) + 0.5) / s - 0.5
    us = (np.arange(w)[:, None] + sub[None, :]).ravel()
    refl = np.empty((n, h * s, w * s), np.float32)
    centre = np.empty((n, h, w, 3))
    sp = truth.specimen
    half = np.asarray(sp.size_mm) / 2
    for v0 in range(0, h, ROWS_PER_CHUNK):
        vs = (np.arange(v0, min(h, v0 + ROWS_PER_CHUNK))[:, None] + sub[None, :]).ravel()
        o, d = lens.rays(*np.meshgrid(us, vs))
        rows = len(vs) // s
        for k in range(n):
            X = truth.material_at(o, d, k)
            on = np.isfinite(X).all(1)
            value = np.full(len(X), BACKGROUND)
            value[on] = sampler((X[on, 0] + half[0]) / sp.unit_mm, (X[on, 1] + half[1]) / sp.unit_mm) / 255.0
            refl[k, v0 * s:v0 * s + len(vs)] = value.reshape(len(vs), -1)
            # the points seen at the pixel centres, for the defocus blur (the plate's centre if off it)
            Xc = np.nan_to_num(X.reshape(len(vs), -1, 2)[s // 2::s, s // 2::s])
            centre[k, v0:v0 + rows] = truth.position(k, Xc[..., 0], Xc[..., 1])
    images = []
    for k in range(n):
        blur = lens.blur_diameter_px(*lens.pixel_grid(), centre[k]).astype(np.float32)
        e = blur_and_integrate(refl[k], s, blur, cam.sigma_px)
        e *= cam.vignetting * cam.gain * np.float32(cam.exposure_e)
        images.append(cam.sensor.digitise(e, cam.rng if noise else None))
    return images


def mm_per_pixel(lens: Lens) -> float:
    """Size (mm) on the WCS plane z = 0 of one pixel at the sensor's centre."""
    cu, cv = (lens.width - 1) / 2, (lens.height - 1) / 2
    o, _ = lens.rays(np.array([cu, cu + 1.0]), np.array([cv, cv]))
    return float(np.linalg.norm(o[1] - o[0]))


def dic_lenses(width: int = 640, height: int = 512, seed: int = 0, lens: str = "brown",
               baseline_mm: float = 200.0, distance_mm: float = 400.0) -> tuple[Lens, Lens]:
    """The default DIC cameras: the scanner's pose (`stereo_lenses`), a ~225 mm field whatever the
    sensor size (pixel pitch scaled), focused on the target."""
    return stereo_lenses(lens, lens, width, height, seed, baseline_mm, distance_mm,
                         pixel_mm=0.0053 * 1280 / width, focus_mm=distance_mm + 10.0)


def simulate_dic(out_dir: str | os.PathLike, states: list[DicState] | None = None, width: int = 640,
                 height: int = 512, seed: int = 0, lens: str = "brown", supersample: int = 2, noise: bool = True,
                 tilt_deg: float = 10.0, dot_px: float = 1.3, bit_depth: int = 8,
                 plate: tuple[float, float] = (1.45, 1.45)) -> Capture:
    """Render a DIC dataset (module docstring) to `out_dir` and return it loaded. states: default
    `standard_states()`; dot_px: the speckle dots' Gaussian radius in pixels (a dot looks ~4x as wide);
    plate: the plate's size over the field of view along x and y (above 1: it fills the images; below:
    a part on a dark background, as a tension bar is seen)."""
    states = standard_states() if states is None else states
    if not states:
        raise InputError("states", "need at least one state")
    if width < 32 or height < 32:
        raise InputError("--width/--height", f"sensor must be at least 32x32, got {width}x{height}")
    if not min(plate) > 0:
        raise InputError("plate", f"the plate's size over the field of view must be positive, got {plate}")
    left, right = dic_lenses(width, height, seed, lens)
    unit = mm_per_pixel(left)
    fov = unit * width
    specimen = Specimen(tilt_deg=tilt_deg, size_mm=(plate[0] * fov, plate[1] * fov * height / width), unit_mm=unit,
                        dot_radius=dot_px, seed=seed)
    truth = DicTruth(specimen, states, {"field_of_view_mm": fov, "cameras": list(CAMERAS),
                                        "lenses": {"family": lens, "width": width, "height": height, "seed": seed}})
    sampler = SpeckleSampler(specimen.speckle())
    sensor = Sensor(bit_depth=bit_depth)
    cams = []
    for k, ln in enumerate((left, right)):
        cam = SimCamera(ln, sensor=sensor, supersample=supersample, seed=seed + 7919 * (k + 1))
        cam.exposure_e = 0.9 * (1 - sensor.dark_offset) * sensor.full_well_e
        cams.append(cam)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / MANIFEST).unlink(missing_ok=True)
    frames = []
    for name, cam in progress(list(zip(CAMERAS, cams)), "simulating dic", total=2):
        for k, img in enumerate(render_states(cam, truth, sampler, noise)):
            f = Frame(name, f"s{k:03d}/{name}.png", Pattern("none"), state=k)
            write_gray(out / f.file, img)
            frames.append(f)
    frames.sort(key=lambda f: (f.state, f.camera))
    for name, ln in zip(CAMERAS, (left, right)):
        ln.true_prvm(camera=name, dataset=f"simulated dic rig, seed {seed}",
                     wcs=f"simulated dic rig, seed {seed}").save(out / f"truth_{name}.npz")
    write_npz(out / "truth.npz", meta=np.array(json.dumps(truth.to_json())), **truth_arrays(truth))
    extra = {"simulated": {"lens": lens, "seed": seed, "noise": noise, "supersample": supersample,
                           "truth": "truth.npz", "true_prvms": [f"truth_{n}.npz" for n in CAMERAS],
                           "states": [s.name for s in states]}}
    cap = Capture(out, "dic", {n: (ln.width, ln.height) for n, ln in zip(CAMERAS, (left, right))}, frames,
                  None, (0.0, 0.0, 1.0), extra, {n: bit_depth for n in CAMERAS})
    cap.save()
    return load_capture(out)


def truth_at_pixels(truth: DicTruth, uv: np.ndarray) -> dict:
    """The truth at the material points the LEFT camera sees at its real image positions uv (..., 2)
    (column, row pixels) in the reference state 0: each position's true ray (the simulator's own
    `Lens.rays` of `DicTruth.lenses`) meets the plate there. Returns material (N, 2) mm, position and
    displacement (S, N, 3) WCS mm, exx, eyy, exy (S, N) Green-Lagrange in the plate frame, N the number of
    positions; NaN where the ray misses the plate."""
    uv = np.asarray(uv, np.float64).reshape(-1, 2)
    o, d = truth.lenses()[0].rays(uv[:, 0], uv[:, 1])
    X = truth.material_at(o, d, 0)
    pos = np.stack([truth.position(k, X[:, 0], X[:, 1]) for k in range(len(truth.states))])
    strains = [truth.strain(k, X[:, 0], X[:, 1]) for k in range(len(truth.states))]
    return dict(material=X, position=pos, displacement=pos - pos[0],
                **{c: np.stack([e[k] for e in strains]) for k, c in enumerate(("exx", "eyy", "exy"))})

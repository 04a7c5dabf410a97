"""The simulated structured-light scanner: two cameras (`scanners.sim.stereo` poses) and a fringe
projector (`scanners.sim.projector`) between them, scanning analytic scenes (`scanners.sim.scan_scene`).

Rendering one camera frame:
 1. each pixel is sampled at S x S sub-pixel points; the TRUE ray of each sub-sample hits the scene's
    nearest surface (occlusion), computed once per scene (`lit_view`);
 2. the hit point is lit if the segment to the projector's centre is clear (shadows) and the projector
    sees it; its panel column comes from the projector's lens, its irradiance factor from the incidence
    angle, throw and the projector's field falloff;
 3. radiance = albedo * (ambient + irradiance factor * projector emission of the pattern at that column,
    through the projector's gamma);
 4. the camera's defocus and diffraction blur, pixel integration, vignetting, PRNU, exposure, shot and
    read noise and 8-bit quantisation (`scanners.sim.camera.SimCamera`'s sensor model).

`simulate_scan` writes a `stereodic.capture/1` dataset of kind "scan" (cameras cam0 = left, cam1 =
right; one state per scene; the projector's fringes along its columns, for each period its number of
steps, per state and camera), with a top-level `projector` block (panel size, gamma, axis, periods, steps), the true
PRVMs truth_cam0.npz / truth_cam1.npz (the `simulate scan` command adds rig.npz, their rectified pair
built by `stereodic.stereo.rig`), and truth.npz whose `meta` lists every state's exact surfaces.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from calib.atomic import write_npz
from calib.capture import MANIFEST, Capture, Frame, Pattern, load_capture
from calib.errors import InputError
from calib.imageio import write_gray
from calib.patterns import gray_sequence, pattern_filename
from calib.progress import progress
from scanners.sim.camera import SimCamera
from scanners.sim.defocus import blur_and_integrate
from scanners.sim.lenses import DEFAULT_TARGET_MM, Lens
from scanners.sim.projector import Projector, make_projector
from scanners.sim.scan_scene import Blob, HeightField, Plane, Scene, Sphere, ball_bar
from scanners.sim.screens import fringe_shifts
from scanners.sim.sensor import Sensor
from scanners.sim.stereo import CAMERAS, stereo_lenses

TARGET = np.asarray(DEFAULT_TARGET_MM, np.float64)
DEFAULT_PERIODS = (1280, 160, 32, 8)   # panel px: ratios 8, 5, 4 unwrap safely; 8 px sets the depth noise
BASE_EXPOSURE_MS = 10.0                # the simulated cameras' exposure time (recorded with several exposures)
FINE_STEPS, COARSE_STEPS = 16, 3       # default steps: the finest period measures, the coarser ones unwrap
# the measuring volume (WCS mm, about the target): x, y, z extent; L0 is its diagonal
VOLUME_MM = (200.0, 160.0, 100.0)
L0_MM = float(np.linalg.norm(VOLUME_MM))
ROWS_PER_CHUNK = 32


@dataclass
class ScanRig:
    """The simulated scanner: left and right lenses, projector, camera sensor, S x S supersampling,
    ambient light (relative to the projector's full irradiance at its nominal distance)."""

    left: Lens
    right: Lens
    projector: Projector
    sensor: Sensor
    supersample: int = 2
    ambient: float = 0.05

    def cameras(self, seed: int) -> list[SimCamera]:
        """The two SimCameras, exposed so that a white surface facing the projector at its nominal
        distance, fully lit, reaches 95 % of full scale."""
        cams = []
        for k, lens in enumerate((self.left, self.right)):
            cam = SimCamera(lens, sensor=self.sensor, supersample=self.supersample, seed=seed + 7919 * k)
            cam.exposure_e = 0.95 * (1 - self.sensor.dark_offset) * self.sensor.full_well_e / (1 + self.ambient)
            cams.append(cam)
        return cams


def default_scan_rig(*, width: int = 1280, height: int = 1024, seed: int = 0, lens: str = "brown",
                     baseline_mm: float = 200.0, distance_mm: float = 400.0, supersample: int = 2,
                     bit_depth: int = 8, ambient: float = 0.05) -> ScanRig:
    """The default scanner: ~200 mm field of view, two cameras and a 1280 x 800 projector 420 mm from
    the target, 60 mm above the baseline, gamma 2.2.

    Parameters
    ----------
    width, height : int
        The cameras' image size, pixels: the sensor spans the 1280-pixel field of 5.3 um pixels with a
        12 mm lens at `distance_mm`, whatever the pixel count.
    seed : int
        Seeds the lenses.
    lens : str
        The cameras' lens family (`scanners.sim.lenses`).
    baseline_mm : float
        The cameras' distance, mm.
    distance_mm : float
        Their distance from the target, mm.
    supersample : int
        Sub-samples per pixel side.
    bit_depth : int
        The sensors' bits per pixel.
    ambient : float
        Ambient light relative to the projector's full irradiance at its nominal distance.

    Returns
    -------
    rig : ScanRig
        The two lenses (WCS mm), the projector, the sensor, the supersampling and the ambient light.
    """
    left, right = stereo_lenses(lens, lens, width, height, seed, baseline_mm, distance_mm,
                                pixel_mm=0.0053 * 1280 / width)
    return ScanRig(left, right, make_projector(TARGET), Sensor(bit_depth=bit_depth), supersample, ambient)


@dataclass
class LitView:
    """What one camera's sub-samples see of one scene: c (H*S, W*S) float32 projector panel column (NaN:
    not lit - shadow, miss, outside the projector's field); factor: float32 irradiance factor; albedo:
    float32 (0 on a miss); blur_px (H, W) defocus diameters; points (H, W, 3) the points the pixel
    centres see (NaN on a miss); gloss: float32 the specular lobe's reflectance towards the camera (0 for a
    matte surface), added to the albedo for the projector's light."""

    c: np.ndarray
    factor: np.ndarray
    albedo: np.ndarray
    blur_px: np.ndarray
    points: np.ndarray
    gloss: np.ndarray


def _unit(v: np.ndarray) -> np.ndarray:
    """Rows of `v` (N, 3) scaled to unit length."""
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def lit_view(cam: SimCamera, scene: Scene, projector: Projector) -> LitView:
    """Trace every sub-sample of `cam` into `scene` and towards `projector` (module docstring)."""
    lens, s = cam.lens, cam.supersample
    h, w = cam.shape
    sub = (np.arange(s) + 0.5) / s - 0.5
    us = (np.arange(w)[:, None] + sub[None, :]).ravel()
    c = np.empty((h * s, w * s), np.float32)
    factor = np.empty_like(c)
    albedo = np.empty_like(c)
    gloss = np.zeros_like(c)
    pts = np.empty((h * s, w * s, 3))
    for v0 in range(0, h, ROWS_PER_CHUNK):
        vs = (np.arange(v0, min(h, v0 + ROWS_PER_CHUNK))[:, None] + sub[None, :]).ravel()
        o, d = lens.rays(*np.meshgrid(us, vs))
        o = o + ((lens.centre_mm[2] - o[..., 2]) / d[..., 2])[..., None] * d   # start at the camera
        hit = scene.intersect(o.reshape(-1, 3), d.reshape(-1, 3))
        seen = np.isfinite(hit.t)
        cc, _, cos_field = projector.project(hit.point)
        lit = seen & np.isfinite(cc)
        lit[lit] &= ~scene.blocked(hit.point[lit] + 1e-4 * hit.normal[lit], projector.centre_mm)
        f = np.where(lit, projector.irradiance_factor(hit.point, hit.normal, cos_field), 0.0)
        rows = slice(v0 * s, v0 * s + len(vs))
        c[rows] = np.where(lit, cc, np.nan).reshape(len(vs), -1)
        factor[rows] = f.reshape(len(vs), -1)
        albedo[rows] = np.where(seen, hit.albedo, 0.0).reshape(len(vs), -1)
        if hit.specular.any():      # Blinn-Phong: the half vector of the directions to projector and camera
            half = _unit(_unit(projector.centre_mm - hit.point) - d.reshape(-1, 3))
            lobe = hit.specular * np.clip(np.einsum("ij,ij->i", half, hit.normal), 0, 1) ** hit.shininess
            gloss[rows] = np.where(lit, lobe, 0.0).reshape(len(vs), -1)
        pts[rows] = np.where(seen[:, None], hit.point, np.nan).reshape(len(vs), -1, 3)
    centre = pts[s // 2::s, s // 2::s]
    focus = lens.centre_mm + lens.focus_mm * lens.rotation[:, 2]
    blur = lens.blur_diameter_px(*lens.pixel_grid(), np.where(np.isfinite(centre), centre, focus))
    return LitView(c, factor, albedo, blur.astype(np.float32), centre, gloss)


def render_frame(cam: SimCamera, view: LitView, projector: Projector, pattern: Pattern, ambient: float,
                 noise: bool = True, exposure: float = 1.0) -> np.ndarray:
    """The camera image (uint8, or uint16 above 8 bits) of the scene of `view` under `pattern`, exposed
    `exposure` times the camera's exposure."""
    radiance = view.albedo * np.float32(ambient) + (view.albedo + view.gloss) * view.factor * \
        projector.emission(pattern, view.c)
    e = blur_and_integrate(radiance, cam.supersample, view.blur_px, cam.sigma_px)
    e *= cam.vignetting * cam.gain * np.float32(cam.exposure_e * exposure)
    return cam.sensor.digitise(e, cam.rng if noise else None)


# ----------------------------------------------------------------------------------------- scenes

def _background() -> Plane:
    """A matte grey plate 60 mm behind the target, catching the objects' shadows."""
    return Plane(centre=TARGET + [0, 0, 60.0], normal=(0, 0, -1), size_mm=(340.0, 280.0), albedo=0.35,
                 texture=0.3, seed=9)


def _rot_x(deg: float) -> np.ndarray:
    a = np.radians(deg)
    return np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])


BAR_DIRECTIONS = ((1, 0, 0), (1, 0.55, 0), (1, -0.55, 0), (1, 0.5, 0.45), (1, -0.5, 0.45), (1, 0.5, -0.45),
                  (1, -0.5, -0.45))
PLANE_POSES = (((0, 0, 0), (0, 0, -1)), ((0, 0, -30), (0.3, 0, -1)), ((0, 0, 30), (-0.3, 0, -1)),
               ((0, 0, 0), (0, 0.3, -1)))


TURNTABLE_VIEWS = 8                     # a whole turn in steps of 45 degrees
# the turntable's part, in its own frame (x right, y down, z away from the scanner at 0 degrees): a blob
# of radius 35 mm with lobes (direction, angular width rad, relative height) and a 25 mm ball on its top
TURNTABLE_LOBES = ((0.2, 0.1, -1, 0.28, 0.3), (1, 0.3, -0.2, 0.3, -0.15), (0.6, -0.1, 0.8, 0.25, 0.3),
                   (-0.7, 0.4, 0.6, 0.3, 0.25), (-1, -0.2, -0.5, 0.25, 0.3), (0.1, 0.6, 1, 0.3, -0.15),
                   (-0.3, -0.5, -0.8, 0.25, 0.25), (0.8, 0.5, -0.9, 0.22, 0.25), (0.9, -0.4, 0.3, 0.25, 0.3),
                   (-0.9, 0.1, 0.1, 0.3, -0.12), (-0.2, 0.3, 0.9, 0.25, 0.3), (0.5, 0.7, 0.2, 0.3, 0.25))
TURNTABLE_BALL = (np.array([0.0, -41.0, 0.0]), 12.5)     # centre about the blob's, radius, mm


def turntable_transform(deg: float) -> np.ndarray:
    """(4, 4) the turntable turned by `deg` degrees: a rotation about the vertical (y) axis through the
    target, WCS mm (applied to the part's points at 0 degrees, it gives them at `deg`)."""
    a = np.radians(deg)
    t = np.eye(4)
    t[:3, :3] = [[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]]
    t[:3, 3] = TARGET - t[:3, :3] @ TARGET
    return t


def turntable_scenes(*, views: int = TURNTABLE_VIEWS) -> list[Scene]:
    """A free-form part on a turntable scanned all the way round: `views` scenes, the part turned by
    360 / views degrees from one to the next (`turntable_transform`), no background.

    Parameters
    ----------
    views : int
        The number of views of the whole turn.

    Returns
    -------
    scenes : list of Scene
        Scene k: the blob (TURNTABLE_LOBES, centred on the target) and its ball, turned by 360 k / views
        degrees, WCS mm.
    """
    scenes = []
    for k in range(views):
        t = turntable_transform(360.0 * k / views)
        lobes = np.array(TURNTABLE_LOBES, np.float64)
        lobes[:, :3] = lobes[:, :3] @ t[:3, :3].T
        ball, radius = TURNTABLE_BALL
        scenes.append(Scene([Blob(centre=TARGET, radius_mm=35.0, lobes=lobes, seed=4),
                             Sphere(centre=t[:3, :3] @ (TARGET + ball) + t[:3, 3], radius_mm=radius, seed=5)],
                            f"turntable {360.0 * k / views:g} deg"))
    return scenes


def standard_scenes(*, objects=("sphere", "ballbar", "plane", "freeform"), background: bool = True) -> list[Scene]:
    """The acceptance scenes (VDI/VDE 2634-2 style), in the measuring volume VOLUME_MM about the target.

    Parameters
    ----------
    objects : sequence of str
        Which: "sphere" (a 50 mm sphere at the centre and 30 mm nearer: 2 scenes), "ballbar" (a bar of
        two 25 mm spheres 150 mm apart in 7 orientations), "plane" (a 180 x 40 mm plate in 4 poses),
        "freeform" (a smooth part 90 mm wide), "turntable" (`turntable_scenes`: a closed free-form part
        all the way round, TURNTABLE_VIEWS scenes; not among the default acceptance scenes).
    background : bool
        The sphere and free-form scenes stand in front of a plate that takes their shadows.

    Returns
    -------
    scenes : list of Scene
        Their exact surfaces, WCS mm, in the order of `objects`' kinds above.
    """
    back = [_background()] if background else []
    scenes = []
    if "sphere" in objects:
        for k, z in enumerate((0.0, -30.0)):
            scenes.append(Scene([Sphere(centre=TARGET + [10.0, 5.0, z], radius_mm=25.0)] + back, f"sphere {k + 1}"))
    if "ballbar" in objects:
        for k, direction in enumerate(BAR_DIRECTIONS):
            scenes.append(Scene(ball_bar(TARGET, direction), f"ball bar {k + 1}"))
    if "plane" in objects:
        for k, (offset, normal) in enumerate(PLANE_POSES):
            scenes.append(Scene([Plane(centre=TARGET + offset, normal=normal, size_mm=(180.0, 40.0))],
                                f"plane {k + 1}"))
    if "freeform" in objects:
        scenes.append(Scene([HeightField(centre=TARGET + [0, 0, 10.0], rotation=np.diag([1.0, -1, -1]) @ _rot_x(10),
                                         half_mm=45.0)] + back, "free-form"))
    if "turntable" in objects:
        scenes += turntable_scenes()
    return scenes


# ---------------------------------------------------------------------------------------- dataset

def steps_per_period(periods, steps) -> list[int]:
    """`steps` (one int for all periods, one per period, or None: FINE_STEPS for the shortest period and
    COARSE_STEPS for the others) as a list aligned with `periods`; InputError unless each is a whole
    number >= 3."""
    if steps is None:
        steps = [FINE_STEPS if p == min(periods) else COARSE_STEPS for p in periods]
    per = [steps] * len(periods) if np.ndim(steps) == 0 else list(steps)
    if len(per) != len(periods) or any(int(n) != n or n < 3 for n in per):
        raise InputError("--steps", f"need one whole number >= 3 of phase steps, or one per period "
                                    f"({len(periods)}), got {steps}")
    return [int(n) for n in per]


def scan_frames(state: int, periods, steps, low: int, high: int, gray_width: int = 0) -> list[Frame]:
    """The frame records of one state: for each camera, each period, each shift (x-axis fringes);
    steps: one int, or one per period; gray_width: first the Gray code of that many panel columns
    (`calib.patterns.gray_sequence`: with one period down to stripes of half of it, with none down to
    single columns) and its flats; 0: none."""
    frames = []
    for cam in CAMERAS:
        if gray_width:
            seq = gray_sequence(gray_width, 1, period_px=periods[0] if periods else None)
            frames += [Frame(cam, f"s{state:03d}/{cam}_{pattern_filename(pat, k)}", pat, state=state)
                       for k, (pat, _) in enumerate(seq) if pat.type != "fringe"]
        for p, n in zip(periods, steps_per_period(periods, steps)):
            for k, shift in enumerate(fringe_shifts(n)):
                frames.append(Frame(cam, f"s{state:03d}/{cam}_P{p:g}_s{k}.png",
                                    Pattern("fringe", {"axis": "x", "period_px": p, "shift_rad": shift,
                                                       "low": low, "high": high}), state=state))
    return frames


def _exposed(frames: list[Frame], exposures) -> list[Frame]:
    """Each frame at each relative exposure (module docstring of `simulate_scan`); one exposure: as is."""
    if len(exposures) == 1 and exposures[0] == 1.0:
        return frames
    return [replace(f, file=f"{f.file[:-4]}_e{x:g}.png", exposure_ms=BASE_EXPOSURE_MS * x)
            for f in frames for x in exposures]


def simulate_scan(out_dir: str | os.PathLike, *, scenes: list[Scene] | None = None, rig: ScanRig | None = None,
                  periods=DEFAULT_PERIODS, steps=None, seed: int = 0, noise: bool = True, low: int = 10,
                  high: int = 250, gray: bool = False, exposures=(1.0,)) -> Capture:
    """Render a scan dataset (module docstring) with the true PRVMs of its cameras.

    Parameters
    ----------
    out_dir : path
        The dataset's folder (created).
    scenes : list of Scene, optional
        One state per scene; None: `standard_scenes()`.
    rig : ScanRig, optional
        The scanner; None: `default_scan_rig(seed=seed)`.
    periods : sequence of float
        Fringe periods, projector pixels; the longest must cover the projector's columns.
    steps : int or sequence of int, optional
        Phase steps, one for all periods or one per period; None: FINE_STEPS for the shortest period,
        COARSE_STEPS for the others.
    seed : int
        Seeds the sensors' noise (and the default rig).
    noise : bool
        Sensor noise (False: the expected images, rounded).
    low, high : int
        The fringes' code values, 0 <= low < high <= 255.
    gray : bool
        Project the column Gray code first (`scan_frames`): `periods` is then empty (Gray code alone) or
        one period (Gray code plus phase shifting).
    exposures : sequence of float
        Each pattern is taken at each of these exposures (relative to the default, which brings a white
        surface facing the projector to 95 % of full scale); with several, the frames record
        `exposure_ms` (BASE_EXPOSURE_MS times the factor) and their files end in _e<factor>.

    Returns
    -------
    capture : Capture
        The loaded dataset (kind "scan", cameras cam0 = left, cam1 = right); beside it truth_cam0.npz and
        truth_cam1.npz (true rays, WCS mm; `stereodic.stereo.rig.build_rig` makes their rectified pair) and
        truth.npz (`load_truth`).
    """
    rig = rig or default_scan_rig(seed=seed)
    scenes = standard_scenes() if scenes is None else scenes
    periods = [int(p) if float(p) == int(p) else float(p) for p in periods]
    per = steps_per_period(periods, steps) if periods else []
    if gray and len(periods) > 1:
        raise InputError("--periods", f"Gray code orders one fringe period, got {len(periods)}")
    if not gray and max(periods) < rig.projector.width_px:
        raise InputError("--periods", f"the longest period ({max(periods):g} px) must cover the projector's "
                                      f"{rig.projector.width_px} columns (absolute phase)")
    if not 0 <= low < high <= 255:
        raise InputError("--low/--high", f"need 0 <= low < high <= 255, got {low}, {high}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / MANIFEST).unlink(missing_ok=True)
    cams = rig.cameras(seed)
    frames = []
    for state, scene in enumerate(progress(scenes, "simulating scan", total=len(scenes))):
        state_frames = _exposed(scan_frames(state, periods, steps, low, high, rig.projector.width_px if gray else 0),
                                exposures)
        for name, cam in zip(CAMERAS, cams):
            view = lit_view(cam, scene, rig.projector)
            for f in state_frames:
                if f.camera == name:
                    write_gray(out / f.file, render_frame(cam, view, rig.projector, f.pattern, rig.ambient, noise,
                                                          (f.exposure_ms or BASE_EXPOSURE_MS) / BASE_EXPOSURE_MS))
        frames += state_frames
    for name, lens in zip(CAMERAS, (rig.left, rig.right)):
        lens.true_prvm(camera=name, dataset=f"simulated scanner, seed {seed}",
                       wcs=f"simulated scanner, seed {seed}").save(out / f"truth_{name}.npz")
    p = rig.projector
    geometry = {"centre_mm": p.centre_mm.tolist(), "rotation": p.rotation.tolist(), "fx": p.fx, "fy": p.fy,
                "cx": p.cx, "cy": p.cy, "k1": p.k1, "k2": p.k2, "distance_mm": p.distance_mm}
    meta = {"format": "stereodic.scan.pipeline-truth/1", "units": "WCS mm", "volume_mm": list(VOLUME_MM),
            "L0_mm": L0_MM, "projector": {**p.record(), **geometry}, "ambient": rig.ambient,
            "states": [{"state": k, **sc.describe()} for k, sc in enumerate(scenes)]}
    write_npz(out / "truth.npz", meta=np.array(json.dumps(meta)))
    extra = {"projector": {**p.record(), "axis": "x", "periods_px": periods,
                           **({"steps": per[0] if len(set(per)) == 1 else per} if per else {})},
             "simulated": {"lens": rig.left.family, "seed": seed, "noise": noise, "supersample": rig.supersample,
                           "truth": "truth.npz", "true_prvms": [f"truth_{n}.npz" for n in CAMERAS],
                           "scenes": [sc.name for sc in scenes]}}
    cap = Capture(out, "scan", {n: (ln.width, ln.height) for n, ln in zip(CAMERAS, (rig.left, rig.right))},
                  frames, None, (0.0, 0.0, 1.0), extra, {n: rig.sensor.bit_depth for n in CAMERAS})
    cap.save()
    return load_capture(out)


def load_truth(dataset: str | os.PathLike) -> dict:
    """The truth of a simulated scan dataset.

    Parameters
    ----------
    dataset : path
        The dataset's folder (`simulate_scan`).

    Returns
    -------
    truth : dict
        truth.npz's meta (JSON data, WCS mm): the measuring volume, the projector, and every state's
        exact surfaces (``states[k]["surfaces"]``; objects via `scan_scene.surface_from_dict`).
        InputError if the file is missing.
    """
    path = Path(dataset) / "truth.npz"
    if not path.is_file():
        raise InputError(path, "truth file is missing (not a simulated scan dataset?)")
    with np.load(path, allow_pickle=False) as z:
        return json.loads(str(z["meta"]))

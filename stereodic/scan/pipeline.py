"""The structured-light scan: fringe images of two cameras -> absolute projector phase per camera ->
rectified virtual phase maps -> 1-D matching along rows -> triangulation -> point cloud.

Steps for one state (one scan) of a `kind: "scan"` dataset:
 1. decode (`decode_camera`, `calib.phase.decode_frames`, the calibration's decoding in one pass over
    the frames in memory): per fringe period the wrapped phase, modulation and quality flags, corrected
    for the projector's gamma when the manifest's `projector` block states it
    (`calib.phase.WaveformCorrection`), then temporal unwrapping (`calib.phase.unwrap_temporal`) into the
    absolute projector column; flagged pixels become NaN;
 2. rectify (`virtual_phase`): the absolute phase (never the wrapped one) and the modulation are
    interpolated through each camera's IMM into the common virtual image; a virtual pixel any of whose 4
    real neighbours is flagged or blank is NaN (the quality mask is carried along);
 2b. filter (`stereodic.scan.phase_filter.smooth_phase`): a local quadratic fit of each virtual phase map
    (Gaussian weights, sigma SMOOTH_PX) where the whole window is valid and continuous, else NaN: the
    white phase noise drops 6.4-fold, edges, holes and silhouettes (mixed pixels) lose an 8-pixel band;
 3. match (`stereodic.scan.matching.match_rows`): equal phase along each row, sub-pixel, with monotonicity,
    slope and left-right checks;
 4. triangulate (`stereodic.stereo.triangulate`) with the EVM-corrected (model-less) rays, or the pinhole rays
    for comparison; points whose rays pass further apart than `max_gap_px` virtual pixels are dropped;
 5. cloud (`stereodic.scan.cloud`): statistical outlier removal, normals, per-point quality = the smaller of
    the two cameras' fringe modulations as a fraction of full scale (0..1), and the ray gap (mm).

The manifest's top-level `projector` block: `width_px` (panel columns, the extent of the absolute phase,
required), `periods_px` and `steps` (what the frames must contain; `steps` one number for all periods or
a list, one per `periods_px` entry), `gamma` and `black_level` (the emission curve
L(v) = black + (1 - black) (v / 255)^gamma; omitted: linear, no correction).
"""

from __future__ import annotations

import os
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from calib.capture import Capture, load_capture
from calib.decode import DARK_FRACTION, MAX_MISMATCH_SIGMA, MODULATION_FRACTION
from calib.errors import InputError
from calib.phase import LOW_MODULATION, UNWRAP, WaveformCorrection, decode_frames, unwrap_temporal
from stereodic.scan.matching import match_rows
from stereodic.scan.phase_filter import smooth_phase
from stereodic.stereo.rig import Rig, check_camera_sizes
from stereodic.stereo.triangulate import triangulate

MIN_MODULATION_FRACTION = 0.02   # of full scale: fringes weaker than this are not measured
SMOOTH_PX = 3.0                  # phase filter sigma (virtual pixels): white noise / 6.4, edges eroded by 8 px


@dataclass
class PhaseMap:
    """One camera's decoded scan. coord: (H, W) float32 absolute projector column (panel pixels), NaN
    where not measured; modulation: (H, W) float32 fringe amplitude of the shortest period as a fraction
    of full scale, offset: its mean level (same unit); quality: (H, W) uint8 `calib.phase` flags
    (0 = good); steps: frames of the shortest period."""

    coord: np.ndarray
    modulation: np.ndarray
    offset: np.ndarray
    quality: np.ndarray
    steps: int


@dataclass
class ScanResult:
    """Matched and triangulated virtual pixels of one scan (N of them). points: (N, 3) float64 WCS mm;
    gap_mm: (N,) distance between the two rays; quality: (N,) float32 (module docstring); row, x_left,
    x_right: (N,) virtual image positions of the match (pixels)."""

    points: np.ndarray
    gap_mm: np.ndarray
    quality: np.ndarray
    row: np.ndarray
    x_left: np.ndarray
    x_right: np.ndarray


# ------------------------------------------------------------------------------------------- input

def projector_block(capture: Capture) -> dict:
    """The manifest's `projector` block, checked: width_px, and optional periods_px, steps, gamma."""
    p = capture.extra.get("projector")
    where = capture.manifest_path
    if not isinstance(p, dict) or not isinstance(p.get("width_px"), int) or p["width_px"] <= 0:
        raise InputError(where, "a scan dataset needs a top-level 'projector' block with 'width_px' (the "
                                "panel columns the fringe phase spans)")
    for key in ("gamma", "black_level"):
        if key in p and not (isinstance(p[key], (int, float)) and p[key] >= 0):
            raise InputError(where, f"projector.{key} must be a non-negative number, got {p[key]!r}")
    steps = p.get("steps")
    if steps is not None and not isinstance(steps, int):
        if not (isinstance(steps, list) and all(isinstance(n, int) for n in steps)
                and len(steps) == len(p.get("periods_px", []))):
            raise InputError(where, f"projector.steps must be a whole number or a list of one per periods_px "
                                    f"entry, got {steps!r}")
    return p


def check_scan_dataset(capture: Capture, cameras: tuple[str, str], state: int) -> dict[str, dict[float, list]]:
    """Frames of `state` per camera and period, checked against each other and the projector block;
    InputError naming the manifest for a dataset of another kind, a missing camera or state, x-axis
    fringes missing or with fewer than 3 distinct shifts, periods that differ between the cameras or
    from the projector block's `periods_px`, or a different number of steps than its `steps`."""
    where = capture.manifest_path
    if capture.kind != "scan":
        raise InputError(where, f"kind is {capture.kind!r}: `stereodic scan` needs a dataset of kind 'scan'")
    proj = projector_block(capture)
    out = {}
    for cam in cameras:
        if cam not in capture.cameras:
            raise InputError(where, f"has no camera {cam!r} (cameras: {', '.join(capture.cameras)}); name the "
                                    f"rig's cameras with --camera LEFT,RIGHT")
        sets: dict[float, list] = defaultdict(list)
        for f in capture.select(cam, state=state, type="fringe"):
            if f.pattern.axis != "x":
                raise InputError(where, f"{f.file}: scan fringes run along the projector columns (axis 'x'), "
                                        f"got axis {f.pattern.axis!r}")
            sets[float(f.pattern.period_px)].append(f)
        if not sets:
            raise InputError(where, f"camera {cam!r} has no fringe frames in state {state}")
        for period, frames in sets.items():
            if len({round(f.pattern.shift_rad, 9) for f in frames}) < 3:
                raise InputError(where, f"camera {cam!r}, state {state}: the fringe of period {period:g} px has "
                                        f"{len(frames)} frame(s) with fewer than 3 distinct shifts (missing "
                                        f"patterns)")
            want_steps = _steps(proj, period)
            if want_steps is not None and len(frames) != want_steps:
                raise InputError(where, f"camera {cam!r}, state {state}: period {period:g} px has {len(frames)} "
                                        f"frames, the projector block says steps = {proj['steps']}")
        if "periods_px" in proj:
            want = sorted(float(p) for p in proj["periods_px"])
            if sorted(sets) != want:
                raise InputError(where, f"camera {cam!r}, state {state}: the frames' projector periods "
                                        f"{_fmt(sorted(sets))} differ from the projector block's periods_px "
                                        f"{_fmt(want)}")
        out[cam] = sets
    if sorted(out[cameras[0]]) != sorted(out[cameras[1]]):
        raise InputError(where, f"state {state}: cameras {cameras[0]!r} and {cameras[1]!r} have different "
                                f"projector periods ({_fmt(sorted(out[cameras[0]]))} vs "
                                f"{_fmt(sorted(out[cameras[1]]))})")
    return out


def _steps(proj: dict, period: float) -> int | None:
    """The number of steps the projector block states for `period` (None: not stated)."""
    steps = proj.get("steps")
    if steps is None or isinstance(steps, int):
        return steps
    periods = [float(p) for p in proj.get("periods_px", [])]
    return int(steps[periods.index(period)]) if period in periods else None


def _fmt(periods) -> str:
    return "[" + ", ".join(f"{p:g}" for p in periods) + "]"


# ------------------------------------------------------------------------------------------ decode

def _correction(proj: dict, frames) -> WaveformCorrection | None:
    """The phase correction for the projector's gamma (None: linear emission or pre-compensated)."""
    pat = frames[0].pattern
    if "gamma" not in proj or pat.params.get("precompensated"):
        return None
    black = float(proj.get("black_level", 0.0))
    phi = 2 * np.pi * np.arange(1024) / 1024
    code = pat.low + (pat.high - pat.low) / 2 * (1 + np.cos(phi))
    wave = black + (1 - black) * (code / 255.0) ** float(proj["gamma"])
    return WaveformCorrection(wave, [f.pattern.shift_rad for f in frames])


def decode_camera(capture: Capture, camera: str, sets: dict[float, list], images=None) -> PhaseMap:
    """Absolute projector column of every pixel of `camera` from its fringe sets (period -> frames, see
    `check_scan_dataset`). images: optional {file: array} already in memory (else read from disk)."""
    proj = projector_block(capture)
    w, h = capture.cameras[camera]
    periods = sorted(sets, reverse=True)
    quality = np.zeros((h, w), np.uint8)
    phases, last = [], None
    for period in periods:
        raws = [images[f.file] if images is not None else capture.read(f) for f in sets[period]]
        full = capture.max_value(camera, raws[0])
        try:
            res = decode_frames(raws, [f.pattern.shift_rad for f in sets[period]], full, DARK_FRACTION * full,
                                MIN_MODULATION_FRACTION * full, _correction(proj, sets[period]))
        except ValueError as exc:
            raise InputError(capture.manifest_path, f"camera {camera!r}, period {period:g} px: {exc}") from None
        stride = max(1, res.modulation.size // 500_000)          # the 90th percentile from a sample
        sample = res.modulation.ravel()[::stride][res.quality.ravel()[::stride] == 0]
        if sample.size:
            res.quality[res.modulation < MODULATION_FRACTION * np.percentile(sample, 90)] |= LOW_MODULATION
        quality |= res.quality
        phases.append(res.phase)
        last = res
    try:
        un = unwrap_temporal(periods, phases, int(proj["width_px"]), valid=quality == 0)
    except ValueError as exc:
        raise InputError(capture.manifest_path, f"camera {camera!r}: {exc}") from None
    for (p_long, p_short), s in zip(zip(periods, periods[1:]), un.mismatch_sigma):
        if s > MAX_MISMATCH_SIGMA:
            raise InputError(capture.manifest_path, f"camera {camera!r}: the period ratio {p_long:g}/{p_short:g} "
                                                    f"is too large for the phase noise (the periods disagree by "
                                                    f"{s:.3f} period RMS, safe <= {MAX_MISMATCH_SIGMA})")
    quality[~un.consistent] |= UNWRAP
    coord = np.where(quality == 0, un.coord.astype(np.float32), np.float32(np.nan))
    scale = np.float32(1.0 / full)
    return PhaseMap(coord, last.modulation * scale, last.offset * scale, quality, last.frames)


def virtual_phase(rig: Rig, side: str, real: np.ndarray) -> np.ndarray:
    """(Hv, Wv) float32: a real per-pixel map (absolute phase, modulation; NaN = not measured) in `side`'s
    virtual image: bilinear through the IMM, NaN where the virtual pixel is blank or any of its 4 real
    neighbours is NaN."""
    imm = rig.camera(side).imm
    if real.shape != (imm.real_size[1], imm.real_size[0]):
        raise InputError(None, f"the {side} camera's images are {real.shape[1]}x{real.shape[0]}, the rig's "
                               f"{side} camera is {imm.real_size[0]}x{imm.real_size[1]}")
    out = cv2.remap(np.ascontiguousarray(real, np.float32), imm.map_x, imm.map_y, cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_CONSTANT, borderValue=float("nan"))
    out[~imm.valid] = np.nan
    return out


# ---------------------------------------------------------------------------------- match + 3D

def match_and_triangulate(rig: Rig, phase_left: np.ndarray, phase_right: np.ndarray, quality_left: np.ndarray,
                          quality_right: np.ndarray, corrected: bool = True, max_gap_px: float = 2.0,
                          matches: np.ndarray | None = None) -> ScanResult:
    """Match the two virtual phase maps along rows and triangulate (module docstring, steps 3-4).
    quality_*: virtual per-pixel quality maps (the point takes the smaller); matches: x_right per left
    pixel from an earlier call (to triangulate the same matches with other rays)."""
    xr = match_rows(phase_left, phase_right) if matches is None else matches
    row, xl = np.nonzero(np.isfinite(xr))
    xrs = xr[row, xl].astype(np.float64)
    tri = triangulate(rig, xl.astype(np.float64), xrs, row.astype(np.float64), corrected=corrected)
    k = np.clip(np.rint(xrs).astype(np.intp), 0, xr.shape[1] - 1)
    q = np.minimum(quality_left[row, xl], quality_right[row, k])
    good = np.isfinite(tri.points).all(axis=1) & (tri.gap_mm <= max_gap_px * min(rig.sensor.pitch_mm)) \
        & np.isfinite(q)
    return ScanResult(tri.points[good], tri.gap_mm[good], q[good].astype(np.float32), row[good],
                      xl[good].astype(np.float64), xrs[good])


def scan_state(rig: Rig, capture: Capture, state: int, *, cameras: tuple[str, str] | None = None,
               corrected: bool = True, images=None, smooth_px: float = SMOOTH_PX) -> tuple[ScanResult, dict]:
    """One scan: decode both cameras, rectify, filter the phase, match, triangulate (module docstring).

    Parameters
    ----------
    rig : Rig
        The rectified pair of the dataset's two cameras.
    capture : Capture
        A dataset of kind ``scan`` (`calib.capture.load_capture`).
    state : int
        The state (scan) to process.
    cameras : (str, str), optional
        The dataset's left and right cameras; None: the rig's camera names.
    corrected : bool
        Triangulate with the EVM-corrected (real) rays; False: the pinhole rays.
    images : dict of str to ndarray, optional
        Frames already in memory, by file name; None: read from disk.
    smooth_px : float
        The phase filter's Gaussian sigma, virtual pixels (`stereodic.scan.phase_filter`); 0: none.

    Returns
    -------
    result : ScanResult
        The N matched points: ``points`` (N, 3) float64 WCS mm, ``gap_mm``, ``quality``, and their
        virtual positions ``row``, ``x_left``, ``x_right`` (pixels).
    maps : dict
        "phase" (left, right) filtered and "modulation" (left, right) (Hv, Wv) float32 virtual maps,
        "matches" (Hv, Wv) x_right, "real" (left, right) PhaseMaps of the real images. InputError if
        nothing matched (the object is outside the common field of view, or unlit).
    """
    cameras = cameras or (rig.left.name, rig.right.name)
    sets = check_scan_dataset(capture, cameras, state)
    phases, mods, real = [], [], []
    for side, cam in zip(("left", "right"), cameras):
        pm = decode_camera(capture, cam, sets[cam], images)
        real.append(pm)
        try:
            phases.append(virtual_phase(rig, side, pm.coord))
        except InputError as exc:
            raise InputError(capture.manifest_path, f"camera {cam!r}: {exc.problem}") from None
        mods.append(virtual_phase(rig, side, pm.modulation))
    phases = [smooth_phase(p, sigma_px=smooth_px) for p in phases]
    xr = match_rows(phases[0], phases[1])
    result = match_and_triangulate(rig, phases[0], phases[1], mods[0], mods[1], corrected, matches=xr)
    if len(result.points) == 0:
        raise InputError(capture.root, f"state {state}: no point was matched: nothing lit by the projector is "
                                       f"seen by both cameras (is the object inside the common field of view?)")
    return result, {"phase": tuple(phases), "modulation": tuple(mods), "matches": xr,
                    "real": tuple(real)}


@dataclass(frozen=True)
class ScanJob:
    """One scan of a batch: state `state` of the dataset `dataset` into the PLY file `cloud` (and a
    Poisson mesh into `mesh`, unless None)."""

    dataset: str
    state: int
    cloud: Path
    mesh: Path | None = None


def plan_scans(rig: Rig, dataset: str | os.PathLike, out: str | os.PathLike, states=None,
               cameras: tuple[str, str] | None = None, mesh: str | os.PathLike | None = None) -> list[ScanJob]:
    """The scans of every state of `dataset` (or those listed), checked: `out` for a single state, else
    `<out stem>_s<state>.ply` per state, and the meshes named the same way from `mesh`. InputError
    naming the manifest for a dataset without the rig's cameras' states, or without a state listed."""
    capture = load_capture(dataset)
    cameras = cameras or (rig.left.name, rig.right.name)
    all_states = capture.states(cameras[0]) if cameras[0] in capture.cameras else []
    states = all_states if states is None else list(states)
    if not states:
        raise InputError(capture.manifest_path, "has no scan states for the rig's cameras")
    for s in states:
        if s not in all_states:
            raise InputError(capture.manifest_path, f"has no state {s} (states: {all_states})")
    check_camera_sizes(rig, capture.cameras, cameras, capture.manifest_path)
    for s in states:  # every state's frames checked before the first is scanned
        check_scan_dataset(capture, cameras, s)

    def name(path, s):
        path = Path(path)
        return path if len(states) == 1 else path.with_name(f"{path.stem}_s{s:03d}{path.suffix or '.ply'}")

    return [ScanJob(os.fspath(dataset), s, name(out, s), None if mesh is None else name(mesh, s)) for s in states]


def scan_job(rig: Rig, job: ScanJob, cameras: tuple[str, str] | None = None, corrected: bool = True,
             neighbours: int = 20, std_ratio: float = 3.0, smooth_px: float = SMOOTH_PX,
             capture: Capture | None = None) -> list[tuple[Path, int, str]]:
    """One scan (`scan_state`) into its cloud (statistical outliers removed, normals towards the rig) and
    mesh files; `capture`: the job's dataset already loaded. Returns [(file, count, what is counted:
    "points" or, for a mesh, "vertices")]."""
    from stereodic.scan.cloud import make_cloud, poisson_mesh, write_cloud, write_mesh
    capture = capture or load_capture(job.dataset)
    viewpoint = (rig.left.centre + rig.right.centre) / 2
    result, _ = scan_state(rig, capture, job.state, cameras=cameras, corrected=corrected, smooth_px=smooth_px)
    cloud, _ = make_cloud(result.points, {"quality": result.quality, "gap_mm": result.gap_mm}, viewpoint,
                          neighbours=neighbours, std_ratio=std_ratio)
    write_cloud(job.cloud, cloud)
    written = [(job.cloud, len(cloud.point.positions), "points")]
    if job.mesh is not None:
        surface = poisson_mesh(cloud)
        write_mesh(job.mesh, surface)
        written.append((job.mesh, len(surface.vertices), "vertices"))
    return written


def scan_to_files(rig: Rig, dataset: str | os.PathLike, out: str | os.PathLike, states=None,
                  cameras: tuple[str, str] | None = None, mesh: str | os.PathLike | None = None,
                  corrected: bool = True, neighbours: int = 20, std_ratio: float = 3.0,
                  smooth_px: float = SMOOTH_PX) -> list[tuple[Path, int, str]]:
    """Scan every state of `dataset` (or those listed) into PLY clouds (`plan_scans`, `scan_job`).
    Returns [(file, count, what is counted: "points" or, for a mesh, "vertices")]."""
    from calib.progress import progress
    jobs = plan_scans(rig, dataset, out, states, cameras, mesh)
    capture = load_capture(dataset)
    written = []
    for job in progress(jobs, "scanning", total=len(jobs)):
        written += scan_job(rig, job, cameras, corrected, neighbours, std_ratio, smooth_px, capture)
    return written

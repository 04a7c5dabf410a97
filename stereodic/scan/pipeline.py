"""The structured-light scan: fringe images of two cameras -> absolute projector phase per camera ->
rectified virtual phase maps -> 1-D matching along rows -> triangulation -> point cloud.

Steps for one state (one scan) of a `kind: "scan"` dataset:
 1. decode (`decode_camera`, `calib.phase.decode_frames`, the calibration's decoding in one pass over
    the frames in memory): per fringe period the wrapped phase, modulation and quality flags, corrected
    for the projector's gamma when the manifest's `projector` block states it
    (`calib.phase.WaveformCorrection`), then temporal unwrapping (`calib.phase.unwrap_temporal`) into the
    absolute projector column; flagged pixels become NaN. A pixel with a clipped sample in any set is
    flagged SATURATED, not solved from its unclipped samples as the calibration does: on a scanned object
    a clipped sample marks a highlight, whose neighbours in time (the samples nearly as bright) and in
    space (the camera's blur spreads it) are not the linear cosine the fit assumes; solved, such pixels
    bent a bright sphere's front by +60 um (docs/scanner.md, "Clipped pixels"). Gray code: see
    `calib.graycode`;
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

from calib.capture import Capture, Frame, load_capture
from calib.decode import DARK_FRACTION, MAX_MISMATCH_SIGMA, MODULATION_FRACTION
from calib.errors import InputError
from calib.graycode import decode_gray, unwrap_with_gray
from calib.phase import (LOW_MODULATION, QUALITY_NAMES, SATURATED, UNWRAP, WaveformCorrection, decode_frames,
                         unwrap_temporal)
from stereodic.scan.matching import match_rows
from stereodic.scan.phase_filter import row_slope, smooth_phase
from stereodic.stereo.rig import Rig, check_camera_sizes
from stereodic.stereo.triangulate import triangulate

MIN_MODULATION_FRACTION = 0.02   # of full scale: fringes weaker than this are not measured
VISIBILITY_FRACTION = 0.3        # of the well-lit pixels' fringe visibility: less, with little light, is shadow
GRAY_NOISE_FRACTION = 0.01      # of full scale: a Gray-code bit whose frame and inverse differ less is undecided
SMOOTH_PX = 3.0                  # phase filter sigma (virtual pixels): white noise / 6.4, edges eroded by 8 px
MERGE_VOXEL_MM = 0.25            # merged views are averaged in voxels of this size, mm
MERGE_GAP_MM = 1.0               # the merged mesh is trimmed farther than this from every point, mm


@dataclass
class PhaseMap:
    """One camera's decoded scan. coord: (H, W) float32 absolute projector column (panel pixels), NaN
    where not measured; modulation: (H, W) float32 fringe amplitude of the shortest period as a fraction
    of full scale, offset: its mean level (same unit); quality: (H, W) uint8 `calib.phase` flags
    (0 = good); steps: frames of the shortest period; stripe_px: for a Gray-code coordinate without
    fringes, its stripe width (the coordinate is a staircase), else 0."""

    coord: np.ndarray
    modulation: np.ndarray
    offset: np.ndarray
    quality: np.ndarray
    steps: int
    stripe_px: int = 0


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


@dataclass
class ScanSets:
    """One camera's frames of one state: fringes (period -> frames, x axis), gray ((bit, inverse) -> frame,
    x axis; the row code, axis y, is not needed: matching runs along the rows) and flats (level -> frame)."""

    fringes: dict[float, list]
    gray: dict[tuple[int, bool], Frame]
    flats: dict[float, Frame]

    def gray_bits(self) -> list[int]:
        """The Gray-code bits present, least significant first."""
        return sorted({b for b, _ in self.gray})


def load_scan(dataset: str | os.PathLike, *, projector: tuple[int, int] | None = None,
              cameras: tuple[str, str] = ("left", "right")) -> Capture:
    """The scan dataset `dataset`: its capture.json, or, given `projector` (width, height) and no
    capture.json, a folder in OpenCV's GrayCodePattern order (`calib.graycode.opencv_folder`, its two
    image series named `cameras`)."""
    path = Path(dataset)
    if projector is not None and path.is_dir() and not (path / "capture.json").is_file():
        from calib.graycode import opencv_folder
        return opencv_folder(path, projector, cameras)
    return load_capture(dataset)


def check_scan_dataset(capture: Capture, cameras: tuple[str, str], state: int) -> dict[str, ScanSets]:
    """Frames of `state` per camera (`ScanSets`), checked against each other and the projector block;
    InputError naming the manifest for a dataset of another kind, a missing camera or state, neither
    x-axis fringes nor Gray code, fringes with fewer than 3 distinct shifts, periods that differ between the
    cameras or from the projector block's `periods_px`, a different number of steps than its `steps`, a
    Gray code lacking a bit or an inverse (or, without inverses, the white and black frames), or Gray code
    beside more than one fringe period or with stripes wider than half the period."""
    where = capture.manifest_path
    if capture.kind != "scan":
        raise InputError(where, f"kind is {capture.kind!r}: `stereodic scan` needs a dataset of kind 'scan'")
    proj = projector_block(capture)
    out = {}
    for cam in cameras:
        if cam not in capture.cameras:
            raise InputError(where, f"has no camera {cam!r} (cameras: {', '.join(capture.cameras)}); name the "
                                    f"rig's cameras with --camera LEFT,RIGHT")
        sets = ScanSets(defaultdict(list), {}, {})
        for f in capture.select(cam, state=state):
            if f.pattern.type == "fringe":
                if f.pattern.axis != "x":
                    raise InputError(where, f"{f.file}: scan fringes run along the projector columns (axis 'x'), "
                                            f"got axis {f.pattern.axis!r}")
                sets.fringes[float(f.pattern.period_px)].append(f)
            elif f.pattern.type == "gray" and f.pattern.axis == "x":
                sets.gray[(f.pattern.bit, bool(f.pattern.params.get("inverse", False)))] = f
            elif f.pattern.type == "flat":
                sets.flats[float(f.pattern.level)] = f
        if not sets.fringes and not sets.gray:
            raise InputError(where, f"camera {cam!r} has no fringe or Gray-code (axis x) frames in state {state}")
        for period, frames in sets.fringes.items():
            exposures = by_exposure(frames)
            shifts = {e: sorted(round(f.pattern.shift_rad, 9) for f in fs) for e, fs in exposures.items()}
            if len({tuple(v) for v in shifts.values()}) > 1:
                counts = ", ".join(f"{len(v)} at {_ms(e)}" for e, v in shifts.items())
                raise InputError(where, f"camera {cam!r}, state {state}: the exposures of period {period:g} px do "
                                        f"not match (not the same shifts at every exposure: frames {counts})")
            frames = next(iter(exposures.values()))
            if len({round(f.pattern.shift_rad, 9) for f in frames}) < 3:
                raise InputError(where, f"camera {cam!r}, state {state}: the fringe of period {period:g} px has "
                                        f"{len(frames)} frame(s) with fewer than 3 distinct shifts (missing "
                                        f"patterns)")
            want_steps = _steps(proj, period)
            if want_steps is not None and len(frames) != want_steps:
                raise InputError(where, f"camera {cam!r}, state {state}: period {period:g} px has {len(frames)} "
                                        f"frames, the projector block says steps = {proj['steps']}")
        if len({f.exposure_ms for f in sets.gray.values()}) > 1:
            raise InputError(where, f"camera {cam!r}, state {state}: Gray-code frames at several exposures are not "
                                    f"merged (take the Gray code at one exposure)")
        if "periods_px" in proj and (sets.fringes or proj["periods_px"]):
            want = sorted(float(p) for p in proj["periods_px"])
            if sorted(sets.fringes) != want:
                raise InputError(where, f"camera {cam!r}, state {state}: the frames' projector periods "
                                        f"{_fmt(sorted(sets.fringes))} differ from the projector block's periods_px "
                                        f"{_fmt(want)}")
        if sets.gray:
            _check_gray(sets, int(proj["width_px"]), f"camera {cam!r}, state {state}", where)
        out[cam] = sets
    a, b = (out[c] for c in cameras)
    if sorted(a.fringes) != sorted(b.fringes) or sorted(a.gray) != sorted(b.gray):
        raise InputError(where, f"state {state}: cameras {cameras[0]!r} and {cameras[1]!r} have different "
                                f"patterns (projector periods {_fmt(sorted(a.fringes))} vs {_fmt(sorted(b.fringes))}, "
                                f"Gray-code bits {a.gray_bits()} vs {b.gray_bits()})")
    return out


def _check_gray(sets: ScanSets, width_px: int, ctx: str, where) -> None:
    """InputError naming `where` unless the Gray code is whole (see `check_scan_dataset`)."""
    from calib.graycode import gray_bits
    bits = sets.gray_bits()
    top = gray_bits(width_px)
    missing = [b for b in range(bits[0], top) if (b, False) not in sets.gray]
    if missing or bits[-1] >= top:
        raise InputError(where, f"{ctx}: the Gray code of the {width_px} projector columns needs bits "
                                f"{bits[0]}..{top - 1}; " + (f"bit(s) {', '.join(map(str, missing))} missing"
                                                             if missing else f"bit {bits[-1]} is beyond them"))
    inverted = [b for b in bits if (b, True) in sets.gray]
    if inverted and len(inverted) != len(bits):
        lacking = [b for b in bits if (b, True) not in sets.gray]
        raise InputError(where, f"{ctx}: Gray-code bit(s) {', '.join(map(str, lacking))} lack their inverse frame "
                                f"(the other bits have one)")
    if not inverted and len(sets.flats) < 2:
        raise InputError(where, f"{ctx}: Gray code without inverse frames needs a white and a black flat frame "
                                f"for its thresholds")
    if sets.fringes:
        if len(sets.fringes) > 1:
            raise InputError(where, f"{ctx}: Gray code orders one fringe period, got {_fmt(sorted(sets.fringes))}")
        period = next(iter(sets.fringes))
        if 2 ** bits[0] > period / 2:
            raise InputError(where, f"{ctx}: Gray-code stripes of {2 ** bits[0]} px cannot order fringes of "
                                    f"{period:g} px (at most half the period: add the bits down to "
                                    f"{int(np.log2(period / 2))})")


def by_exposure(frames: list) -> dict:
    """The frames grouped by `exposure_ms` (None: not recorded), longest exposure first."""
    groups = defaultdict(list)
    for f in frames:
        groups[f.exposure_ms].append(f)
    return dict(sorted(groups.items(), key=lambda kv: -(kv[0] or 0.0)))


def _ms(exposure: float | None) -> str:
    return "no exposure_ms" if exposure is None else f"{exposure:g} ms"


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


def decode_camera(capture: Capture, camera: str, sets: ScanSets, images=None) -> PhaseMap:
    """Absolute projector column of every pixel of `camera` from its fringe and Gray-code frames (see
    `check_scan_dataset`): fringes alone are unwrapped temporally, Gray code alone gives its stripes,
    Gray code and one fringe period the phase ordered by the code (`calib.graycode`). images: optional
    {file: array} already in memory (else read from disk)."""
    proj = projector_block(capture)
    read = lambda f: images[f.file] if images is not None else capture.read(f)  # noqa: E731
    w, h = capture.cameras[camera]
    periods = sorted(sets.fringes, reverse=True)
    quality = np.zeros((h, w), np.uint8)
    phases, last, full = [], None, None
    for period in periods:
        res, full = _decode_period(capture, camera, period, sets.fringes[period], read)
        quality |= res.quality
        phases.append(res.phase)
        last = res
    if sets.gray:
        gray, full = _decode_gray(capture, camera, sets, read)
        quality |= gray.quality
        if not periods:
            coord = np.where(quality == 0, gray.coord, np.float32(np.nan))
            scale = np.float32(0.5 / full)
            return PhaseMap(coord, gray.contrast * scale, gray.offset * np.float32(1 / full), quality, 1,
                            gray.stripe_px)
        coord, consistent = unwrap_with_gray(gray.coord, phases[0], periods[0], gray.stripe_px)
    else:
        try:
            un = unwrap_temporal(periods, phases, int(proj["width_px"]), valid=quality == 0)
        except ValueError as exc:
            raise InputError(capture.manifest_path, f"camera {camera!r}: {exc}") from None
        for (p_long, p_short), s in zip(zip(periods, periods[1:]), un.mismatch_sigma):
            if s > MAX_MISMATCH_SIGMA:
                raise InputError(capture.manifest_path, f"camera {camera!r}: the period ratio {p_long:g}/{p_short:g} "
                                                        f"is too large for the phase noise (the periods disagree by "
                                                        f"{s:.3f} period RMS, safe <= {MAX_MISMATCH_SIGMA})")
        coord, consistent = un.coord, un.consistent
    quality[~consistent] |= UNWRAP
    coord = np.where(quality == 0, coord.astype(np.float32), np.float32(np.nan))
    scale = np.float32(1.0 / full)
    return PhaseMap(coord, last.modulation * scale, last.offset * scale, quality, last.frames)


def _decode_period(capture: Capture, camera: str, period: float, frames: list, read):
    """(`calib.phase.WrappedPhase`, full scale) of one period's frames; with several exposures merged per
    pixel: the longest exposure that is unclipped, lit and modulated (HDR). LOW_MODULATION where the
    modulation per unit of exposure is below MODULATION_FRACTION of its 90th percentile and the fringes'
    visibility (modulation / offset) below VISIBILITY_FRACTION of its 90th percentile (shadows, stray light:
    little of the projector's light, and what there is mostly unmodulated; a dark surface that the projector
    lights has weak fringes but sharp ones, and is kept). A pixel with a clipped sample is SATURATED (module docstring, step 1)."""
    proj = projector_block(capture)
    merged, exposure_of = None, None
    for exposure, group in by_exposure(frames).items():
        raws = [read(f) for f in group]
        full = capture.max_value(camera, raws[0])
        try:
            res = decode_frames(raws, [f.pattern.shift_rad for f in group], full, DARK_FRACTION * full,
                                MIN_MODULATION_FRACTION * full, _correction(proj, group))
        except ValueError as exc:
            where = f"camera {camera!r}, period {period:g} px" + ("" if exposure is None else f", {exposure:g} ms")
            raise InputError(capture.manifest_path, f"{where}: {exc}") from None
        res.quality[(res.clipped != 0).any(axis=0)] |= SATURATED
        if merged is None:
            merged, exposure_of = res, np.full(res.phase.shape, exposure or 1.0, np.float32)
            continue
        take = (merged.quality != 0) & (res.quality == 0)
        for name in ("phase", "offset", "modulation", "noise", "quality"):
            getattr(merged, name)[take] = getattr(res, name)[take]
        exposure_of[take] = exposure
    # shadows: little of the projector's light per unit of exposure, whatever the exposure, and little of it modulated
    light = merged.modulation / exposure_of
    stride = max(1, light.size // 500_000)                      # the 90th percentile from a sample
    sample = light.ravel()[::stride][merged.quality.ravel()[::stride] == 0]
    if sample.size:
        visibility = merged.modulation / np.maximum(merged.offset, np.float32(1e-6))
        lit = visibility.ravel()[::stride][merged.quality.ravel()[::stride] == 0]
        merged.quality[(light < MODULATION_FRACTION * np.percentile(sample, 90))
                       & (visibility < VISIBILITY_FRACTION * np.percentile(lit, 90))] |= LOW_MODULATION
    return merged, full


def _decode_gray(capture: Capture, camera: str, sets: ScanSets, read):
    """`calib.graycode.decode_gray` of the camera's Gray-code frames and flats, and the full scale."""
    bits = sets.gray_bits()
    patterns = [read(sets.gray[(b, False)]) for b in bits]
    full = capture.max_value(camera, patterns[0])
    inverses = [read(sets.gray[(b, True)]) for b in bits] if (bits[0], True) in sets.gray else None
    levels = sorted(sets.flats)
    white, black = (read(sets.flats[levels[-1]]), read(sets.flats[levels[0]])) if len(levels) >= 2 else (None, None)
    dec = decode_gray(patterns, inverses, white, black, low_bit=bits[0],
                      extent_px=int(projector_block(capture)["width_px"]),
                      min_contrast=2 * MIN_MODULATION_FRACTION * full, min_difference=GRAY_NOISE_FRACTION * full)
    return dec, full


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

def _smooth(phase: np.ndarray, smooth_px: float, stripe_px: int) -> np.ndarray:
    """The phase filter; a Gray-code staircase (stripe_px > 0) with its stairs taken as continuous and
    steps up to a stripe and a half more than 4 x its slope."""
    if not stripe_px:
        return smooth_phase(phase, sigma_px=smooth_px)
    return smooth_phase(phase, sigma_px=smooth_px, plateaus=True,
                        max_step=4 * abs(row_slope(phase, 16)) + 1.5 * stripe_px)


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
    phases = [_smooth(p, smooth_px, pm.stripe_px) for p, pm in zip(phases, real)]
    xr = match_rows(phases[0], phases[1])
    result = match_and_triangulate(rig, phases[0], phases[1], mods[0], mods[1], corrected, matches=xr)
    if len(result.points) == 0:
        counts = {name: sum(int(((pm.quality & bit) != 0).sum()) for pm in real)
                  for bit, name in QUALITY_NAMES.items()}
        most = f"; most pixels flagged: {max(counts, key=counts.get)}" if max(counts.values()) else ""
        raise InputError(capture.root, f"state {state}: no point was matched: nothing lit by the projector is "
                                       f"seen by both cameras (is the object inside the common field of view?)"
                                       f"{most}")
    return result, {"phase": tuple(phases), "modulation": tuple(mods), "matches": xr,
                    "real": tuple(real)}


@dataclass(frozen=True)
class ScanJob:
    """One scan of a batch: state `state` of the dataset `dataset` into the PLY file `cloud` (and a
    Poisson mesh into `mesh`, unless None); projector: (width, height) of a folder in OpenCV's Gray-code
    order (`load_scan`), else None."""

    dataset: str
    state: int
    cloud: Path
    mesh: Path | None = None
    projector: tuple[int, int] | None = None


def plan_scans(rig: Rig, dataset: str | os.PathLike, out: str | os.PathLike, states=None,
               cameras: tuple[str, str] | None = None, mesh: str | os.PathLike | None = None,
               projector: tuple[int, int] | None = None) -> list[ScanJob]:
    """The scans of every state of `dataset` (or those listed), checked: `out` for a single state, else
    `<out stem>_s<state>.ply` per state, and the meshes named the same way from `mesh`; projector: as
    `load_scan`'s. InputError naming the manifest for a dataset without the rig's cameras' states, or
    without a state listed."""
    cameras = cameras or (rig.left.name, rig.right.name)
    capture = load_scan(dataset, projector=projector, cameras=cameras)
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

    return [ScanJob(os.fspath(dataset), s, name(out, s), None if mesh is None else name(mesh, s), projector)
            for s in states]


def scan_job(rig: Rig, job: ScanJob, cameras: tuple[str, str] | None = None, corrected: bool = True,
             neighbours: int = 20, std_ratio: float = 3.0, smooth_px: float = SMOOTH_PX,
             capture: Capture | None = None) -> list[tuple[Path, int, str]]:
    """One scan (`scan_state`) into its cloud (statistical outliers removed, normals towards the rig) and
    mesh files; `capture`: the job's dataset already loaded. Returns [(file, count, what is counted:
    "points" or, for a mesh, "vertices")]."""
    from stereodic.scan.cloud import make_cloud, poisson_mesh, write_cloud, write_mesh
    capture = capture or load_scan(job.dataset, projector=job.projector,
                                   cameras=cameras or (rig.left.name, rig.right.name))
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
                  smooth_px: float = SMOOTH_PX, projector: tuple[int, int] | None = None) -> list[tuple[Path, int, str]]:
    """Scan every state of `dataset` (or those listed) into PLY clouds (`plan_scans`, `scan_job`);
    projector: as `load_scan`'s. Returns [(file, count, what is counted: "points" or, for a mesh,
    "vertices")]."""
    from calib.progress import progress
    jobs = plan_scans(rig, dataset, out, states, cameras, mesh, projector)
    capture = load_scan(dataset, projector=projector, cameras=cameras or (rig.left.name, rig.right.name))
    written = []
    for job in progress(jobs, "scanning", total=len(jobs)):
        written += scan_job(rig, job, cameras, corrected, neighbours, std_ratio, smooth_px, capture)
    return written


def merge_to_files(rig: Rig, dataset: str | os.PathLike, out: str | os.PathLike, *, states=None,
                   cameras: tuple[str, str] | None = None, mesh: str | os.PathLike | None = None,
                   projector: tuple[int, int] | None = None, corrected: bool = True, neighbours: int = 20,
                   std_ratio: float = 3.0, smooth_px: float = SMOOTH_PX, voxel_mm: float = MERGE_VOXEL_MM,
                   turntable: tuple | None = None):
    """The states of `dataset` as views of one object taken round it in order (a turntable's turn, or
    the object moved): each scanned as `scan_job` does (outliers removed, normals towards the rig),
    registered view to view with the loop closed (`stereodic.scan.views.register_turn`, started from a
    global search) or, with `turntable` = (point (3,), direction (3,)), WCS mm, a turntable's axis, as turns
    about one fitted axis (`views.register_turntable`, started from the nominal whole turn in equal steps
    about that axis: `views.turntable_transforms`), merged into one
    cloud (`views.merged_cloud`, voxels of `voxel_mm` mm) written to `out` and, with `mesh`, its Poisson
    surface trimmed MERGE_GAP_MM from the data (`cloud.poisson_mesh`) written there.

    Returns
    -------
    written : list of (path, int, str)
        (file, count, "points" or "vertices") of the merged cloud and mesh.
    states : list of int
        The views' states, in order.
    registration : stereodic.scan.views.Registration
        Each view's transform into the first view's frame (WCS mm), its residual and fitness; with
        `turntable`, a `views.TurntableRegistration` (also the fitted axis and angles).
    """
    from calib.progress import progress
    from stereodic.scan.cloud import make_cloud, poisson_mesh, write_cloud, write_mesh
    from stereodic.scan.views import merged_cloud, register_turn, register_turntable, turntable_transforms
    jobs = plan_scans(rig, dataset, out, states, cameras, None, projector)
    if len(jobs) < 2:
        raise InputError(dataset, f"has {len(jobs)} scan state to merge: merging needs two views or more")
    capture = load_scan(dataset, projector=projector, cameras=cameras or (rig.left.name, rig.right.name))
    viewpoint = (rig.left.centre + rig.right.centre) / 2
    points, normals = [], []
    for job in progress(jobs, "scanning views", total=len(jobs)):
        result, _ = scan_state(rig, capture, job.state, cameras=cameras, corrected=corrected, smooth_px=smooth_px)
        cloud, _ = make_cloud(result.points, {}, viewpoint, neighbours=neighbours, std_ratio=std_ratio)
        points.append(cloud.point.positions.numpy().astype(np.float64))
        normals.append(cloud.point.normals.numpy().astype(np.float64))
    registration = (register_turn(points) if turntable is None else
                    register_turntable(points, initial=turntable_transforms(len(points), *turntable)))
    merged = merged_cloud(points, registration, normals=normals, voxel_mm=voxel_mm)
    write_cloud(out, merged)
    written = [(Path(out), len(merged.point.positions), "points")]
    if mesh is not None:
        surface = poisson_mesh(merged, max_gap_mm=MERGE_GAP_MM)
        write_mesh(mesh, surface)
        written.append((Path(mesh), len(surface.vertices), "vertices"))
    return written, [j.state for j in jobs], registration

"""Decode a calibration capture: for one camera and one stage position, the display point each camera
pixel sees (display pixels, column c and row r), with its quality.

Frames are streamed: each is read (the next ones already being read on threads: PNG decoding releases
the GIL) and added to the sums of its fringe set (`calib.phase.FringeSums`) in one pass, so memory stays
at a few arrays per set whatever the number of frames; the intensity matrix's per-pixel linearisation
(if flats were captured) is applied to the solution of each set, which equals applying it to every
frame. Repeated frames (`repeat`) are averaged by the same sums.
"""

from __future__ import annotations

from collections import defaultdict
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Iterator

import cv2
import numpy as np

from calib.capture import Capture, Frame
from calib.errors import InputError
from calib.intensity import IntensityMatrix, fit_intensity
from calib.phase import (DARK, EDGE, LOW_MODULATION, NO_DATA, SATURATED, UNWRAP, FringeSums,
                         WaveformCorrection, correct_phase, unwrap_temporal)

AXES = ("x", "y")
# a pixel is dark when its brightest fringe frame stays below this fraction of full scale
DARK_FRACTION = 0.02
# a pixel has low modulation when B is below this fraction of the well-lit pixels' modulation
MODULATION_FRACTION = 0.2
# the largest robust spread (in periods) of the disagreement between successive periods that still
# makes a wrong fringe order (a disagreement beyond 0.75 period) a 7-sigma event
MAX_MISMATCH_SIGMA = 0.1
# the display's edge (`display_edge`): the modulation's profile is measured out to this distance (camera
# pixels) from the bezel; a shortfall from its plateau beyond EDGE_FALL (or the profile's ripple) marks
# the edge
EDGE_PROFILE_PX = 16
EDGE_FALL = 0.05


@dataclass
class DecodedPosition:
    """Display coordinates seen by each camera pixel at one stage position (or display pose: z_mm NaN,
    `pose` its number).

    coord: (2, H, W) float64 display pixels (column c, row r); modulation, mean: (2, H, W) float32 fringe
    amplitude B and mean A of the shortest period (decoding units: relative luminance with an intensity
    matrix, camera values without); quality: (H, W) uint8 flag bits of `calib.phase` (0 = good);
    steps: frames per set of the shortest period, per axis; period_px: the shortest period, per axis;
    mismatch_sigma: per axis, the measured spread of the period-to-period disagreement; clipped: (pixels
    with clipped samples in some fringe set, each solved from its unclipped samples; pixels flagged
    SATURATED, too few left in some set).
    """

    z_mm: float
    coord: np.ndarray
    modulation: np.ndarray
    mean: np.ndarray
    quality: np.ndarray
    steps: tuple[int, int]
    period_px: tuple[float, float]
    mismatch_sigma: dict = field(default_factory=dict)
    clipped: tuple[int, int] = (0, 0)
    pose: int | None = None

    @property
    def valid(self) -> np.ndarray:
        return self.quality == 0


def _frames_by_set(capture: Capture, camera: str, z_mm) -> dict[str, dict[float, list[Frame]]]:
    sets: dict[str, dict[float, list[Frame]]] = {a: defaultdict(list) for a in AXES}
    for f in capture.select(camera, **capture.at(z_mm), type="fringe"):
        sets[f.pattern.axis][float(f.pattern.period_px)].append(f)
    return sets


def read_ahead(capture: Capture, frames: list[Frame], depth: int = 2) -> Iterator[tuple[Frame, np.ndarray]]:
    """(frame, image) for each of `frames` in order, the next `depth` images being read on threads
    meanwhile (at most depth + 1 images in memory)."""
    with ThreadPoolExecutor(depth) as pool:
        pending = [pool.submit(capture.read, f) for f in frames[:depth]]
        for i, f in enumerate(frames):
            image = pending.pop(0).result()
            if i + depth < len(frames):
                pending.append(pool.submit(capture.read, frames[i + depth]))
            yield f, image


def intensity_matrix(capture: Capture, camera: str, z_mm) -> IntensityMatrix | None:
    """The IM from the flat frames at stage position z_mm, or at the nearest position that has flats
    (a stage-free capture: at pose z_mm, else the first pose with flats); None if the dataset has no
    flats for this camera. Repeated flats are averaged."""
    flats = capture.select(camera, type="flat")
    if not flats:
        return None
    where = (lambda f: f.pose) if capture.posed else (lambda f: f.z_mm)
    zs = sorted({where(f) for f in flats}, key=lambda z: (z != z_mm, abs(z - z_mm), z))
    by_level: dict[float, list[Frame]] = defaultdict(list)
    for f in flats:
        if where(f) == zs[0]:
            by_level[float(f.pattern.level)].append(f)
    levels = sorted(by_level)
    w, h = capture.cameras[camera]
    images = np.zeros((len(levels), h, w), np.float32)
    full = None
    ordered = [(j, f) for j, level in enumerate(levels) for f in by_level[level]]
    for (j, _), (f, img) in zip(ordered, read_ahead(capture, [f for _, f in ordered])):
        full = capture.max_value(camera, img)
        cv2.accumulate(img, images[j])
    for j, level in enumerate(levels):
        if len(by_level[level]) > 1:
            images[j] /= len(by_level[level])
    try:
        return fit_intensity(levels, images, full, min_range=DARK_FRACTION * full)
    except ValueError as exc:
        raise InputError(capture.path(by_level[levels[0]][0]).parent, f"flat frames of camera {camera!r} at "
                                                                      f"{capture.label(zs[0])}: {exc}") from None


def _waveform_correction(capture: Capture, frames: list[Frame], im: IntensityMatrix) -> WaveformCorrection:
    """The phase correction of one fringe set for the display response measured by `im`."""
    pat = frames[0].pattern
    shifts = [f.pattern.shift_rad for f in frames]
    if pat.params.get("precompensated"):
        return WaveformCorrection(np.cos(2 * np.pi * np.arange(1024) / 1024), shifts)
    if any((f.pattern.low, f.pattern.high) != (pat.low, pat.high) for f in frames):
        raise InputError(capture.manifest_path, f"frames of one fringe set ({frames[0].file}, ...) have "
                                                "different low/high levels")
    try:
        return WaveformCorrection(im.fringe_waveform(pat.low, pat.high), shifts)
    except ValueError as exc:
        raise InputError(capture.manifest_path, f"{frames[0].file}: {exc}") from None


def decode_position(capture: Capture, camera: str, z_mm: float, im: IntensityMatrix | None,
                    progress=None) -> DecodedPosition:
    """Decode both axes at one stage position.

    im: the intensity matrix to linearise frames with (None: raw values). progress: an optional callable
    called once per frame read. Raises InputError (naming the manifest or the images) when the frames
    do not form complete fringe sets, the longest period cannot give an absolute phase, every pixel is
    dark or saturated, or the period ratios are too large for the measured phase noise.
    """
    w, h = capture.cameras[camera]
    sets = _frames_by_set(capture, camera, z_mm)
    display = capture.display
    extent = {"x": display.width_px, "y": display.height_px}
    coords, mods, means, steps, shortest, mismatch = [], [], [], [], [], {}
    clip_any = np.zeros((h, w), bool)
    raw_mods = []
    quality = np.zeros((h, w), np.uint8)
    if im is not None:
        quality[~np.isfinite(im.gain)] |= DARK
    first_file = None
    for axis in AXES:
        if not sets[axis]:
            raise InputError(capture.manifest_path, f"camera {camera!r} has no {axis}-axis fringes at "
                                                    f"{capture.label(z_mm)} (both axes are needed)")
    for axis in AXES:
        for period, frames in sets[axis].items():
            if len({round(f.pattern.shift_rad, 9) for f in frames}) < 3:
                raise InputError(capture.manifest_path,
                                 f"camera {camera!r}, {capture.label(z_mm)}: the {axis} fringe of period {period:g} px "
                                 f"has {len(frames)} frame(s) with fewer than 3 distinct shifts")
    order = {axis: sorted(sets[axis], reverse=True) for axis in AXES}
    stream = read_ahead(capture, [f for axis in AXES for period in order[axis] for f in sets[axis][period]])
    for axis in AXES:
        periods = order[axis]
        phases, last = [], None
        for period in periods:
            frames = sets[axis][period]
            sums = None
            for _ in frames:
                f, raw = next(stream)
                first_file = first_file or capture.path(f)
                if sums is None:
                    full = capture.max_value(camera, raw)
                    sums = FringeSums((h, w), squares=len(frames) > 3, full_scale=full)
                sums.add(raw, f.pattern.shift_rad)
                if progress is not None:
                    progress()
            lit = (sums.raw_max >= DARK_FRACTION * full) & (sums.raw_max < full)
            res = sums.solve(full, DARK_FRACTION * full, 0.0, None if im is None else (im.offset, im.gain),
                             raw_modulation=period == periods[-1])
            if im is not None:
                correct_phase(res, _waveform_correction(capture, frames, im))
            res.quality[~(res.modulation >= _modulation_floor(res.modulation, lit))] |= LOW_MODULATION
            if res.clipped is not None:
                clip_any |= (res.clipped != 0).any(axis=0)
            quality |= res.quality
            phases.append(res.phase)
            last = res                    # periods run longest first: the last is the shortest
            del sums
        if not (quality == 0).any():
            _raise_unusable(capture, camera, z_mm, quality, first_file)
        try:
            un = unwrap_temporal(periods, phases, extent[axis], valid=quality == 0)
        except ValueError as exc:
            raise InputError(capture.manifest_path, f"camera {camera!r}, {axis} fringes: {exc}") from None
        for (p_long, p_short), s in zip(zip(periods, periods[1:]), un.mismatch_sigma):
            if s > MAX_MISMATCH_SIGMA:
                raise InputError(capture.manifest_path,
                                 f"camera {camera!r}, {capture.label(z_mm)}, {axis} fringes: the period ratio "
                                 f"{p_long:g}/{p_short:g} = {p_long / p_short:.3g} is too large for the "
                                 f"measured phase noise (the periods disagree by {s:.3f} period RMS, safe "
                                 f"<= {MAX_MISMATCH_SIGMA}); add a period near {np.sqrt(p_long * p_short):.0f} px"
                                 + ("" if im is not None else " or capture flat frames (an uncompensated "
                                                              "display gamma distorts the phase)"))
        mismatch[axis] = un.mismatch_sigma
        quality[~un.consistent] |= UNWRAP
        coords.append(un.coord)
        mods.append(last.modulation)
        raw_mods.append(last.raw_modulation)
        means.append(last.offset)
        steps.append(last.frames)
        shortest.append(periods[-1])
    coord = np.stack(coords)
    quality[~np.isfinite(coord).all(axis=0)] |= NO_DATA
    # the edge shows in the camera's own modulation: the IM's per-pixel gain, measured on flats seen
    # through the same mix of display and bezel, would cancel it
    quality[display_edge(coord, np.stack(raw_mods), quality, (display.width_px, display.height_px))] |= EDGE
    del raw_mods
    if not (quality == 0).any():
        _raise_unusable(capture, camera, z_mm, quality, first_file)
    lost = (quality & SATURATED) != 0
    clipped = (int(np.count_nonzero(clip_any & ~lost)), int(np.count_nonzero(clip_any & lost)))
    return DecodedPosition(np.nan if capture.posed else float(z_mm), coord, np.stack(mods), np.stack(means),
                           quality, tuple(steps), tuple(shortest), mismatch, clipped,
                           z_mm if capture.posed else None)


def display_edge(coord: np.ndarray, modulation: np.ndarray, quality: np.ndarray,
                 extent: tuple[int, int]) -> np.ndarray:
    """(H, W) bool: the decoded pixels at the display's edge, whose view (its blur and area) takes in
    part of the bezel, which biases the decoded point towards the display's inside.

    coord: (2, H, W) decoded display (c, r); modulation: (2, H, W) B of each axis in camera values (not
    normalised per pixel; NaN taken as 0); quality: the flags so far; extent: the display's
    (width_px, height_px). The bezel is where pixels see no usable fringe (DARK, LOW_MODULATION, NO_DATA,
    UNWRAP; not SATURATED, which sees the display). The good pixels next to it straddle the edge (a sampled image
    cannot place an edge finer than a pixel) and are the edge; how much farther the bezel's influence
    reaches is measured: the median modulation of the good pixels at each whole distance d (camera
    pixels) from the bezel against its plateau, the median over d = EDGE_PROFILE_PX / 2 ..
    EDGE_PROFILE_PX, whose lowest bin (the display grid's aliasing ripples the profile) sets the
    tolerance; the edge extends over the run of distances from the bezel where the modulation falls
    short of the plateau by more than that or EDGE_FALL and still rises. Only pixels whose decoded point lies
    within EDGE_PROFILE_PX + 2 camera pixels (in display pixels) of the display's border are
    considered, so that bezel-like spots inside the display (dust, hot pixels) leave their neighbours
    alone."""
    good = quality == 0
    bezel = ((quality & (DARK | LOW_MODULATION | NO_DATA | UNWRAP)) != 0) & ((quality & SATURATED) == 0)
    edge = np.zeros(quality.shape, bool)
    if not bezel.any() or not good.any():
        return edge
    din = cv2.distanceTransform((~bezel).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    cand = np.nonzero(good & (din <= EDGE_PROFILE_PX))
    if not cand[0].size:
        return edge
    c, r = coord[0][cand], coord[1][cand]
    border = np.minimum(np.minimum(c + 0.5, extent[0] - 0.5 - c), np.minimum(r + 0.5, extent[1] - 0.5 - r))
    sample = good[::4, ::4]
    scale = np.concatenate([np.hypot(*np.gradient(a[::4, ::4]))[sample] for a in coord]) / 4
    scale = float(np.percentile(scale[np.isfinite(scale)], 95)) if np.isfinite(scale).any() else 1.0
    near = border < (EDGE_PROFILE_PX + 2) * scale
    rows, cols = cand[0][near], cand[1][near]
    d = np.rint(din[rows, cols]).astype(int)
    b = np.nan_to_num((modulation[0][rows, cols] + modulation[1][rows, cols]) / 2)
    medians = np.array([np.median(b[d == k]) if np.count_nonzero(d == k) >= 30 else np.nan
                        for k in range(EDGE_PROFILE_PX + 1)])
    half = EDGE_PROFILE_PX // 2
    ref = medians[half:][np.isfinite(medians[half:])]
    reach = 1
    if ref.size >= 3:
        plateau = float(np.median(ref))
        low = plateau - max(EDGE_FALL * plateau, plateau - float(ref.min()))
        # the run of short bins from the bezel, while the modulation still rises (the edge's shortfall
        # shrinks with the distance; the ripple's comes and goes)
        while reach + 1 < half and medians[reach + 1] < low and medians[reach + 1] > medians[reach]:
            reach += 1
    hit = d <= reach
    edge[rows[hit], cols[hit]] = True
    return edge


def _modulation_floor(modulation: np.ndarray, lit: np.ndarray) -> float:
    """The least modulation of a usable pixel: MODULATION_FRACTION of the well-lit pixels' (the 90th
    percentile of those lit, unsaturated and with a finite modulation, taken again among those above a
    fifth of the first estimate, so that pixels seeing the bezel or room light do not lower it however
    many they are). A sample of the pixels suffices."""
    ref = modulation[lit & np.isfinite(modulation)][::97]
    if not ref.size:
        return np.inf
    top = float(np.percentile(ref, 90))
    ref = ref[ref > 0.2 * top]
    return MODULATION_FRACTION * float(np.percentile(ref, 90))


def _raise_unusable(capture: Capture, camera: str, z_mm: float, quality: np.ndarray, where) -> None:
    dark = np.mean(quality & DARK > 0)
    sat = np.mean(quality & SATURATED > 0)
    if dark > 0.5:
        why = f"all pixels are too dark ({dark:.0%} dark)"
    elif sat > 0.5:
        why = f"the images are saturated ({sat:.0%} of pixels reach full scale)"
    else:
        why = "no pixel has a usable fringe (low modulation everywhere)"
    raise InputError(where if where is not None else capture.manifest_path,
                     f"camera {camera!r}, {capture.label(z_mm)}: {why}")

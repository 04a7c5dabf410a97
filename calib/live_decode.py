"""Decoding a fringe set held in memory, for live use (the alignment aid, `scanners.align`).

`decode_display` turns the frames of both axes (each period's N phase steps, as the camera delivered
them) into the display coordinate (c, r) that each camera pixel sees, with the checks of
`calib.decode`: pixels too dark, saturated, of low modulation, or whose periods disagree are masked.
`track_display` decodes the shortest period of each axis alone, its fringe order taken from a previous
map: half the frames, for a camera that moved little since (less than a quarter period at every pixel).
`flat_correction` measures the display's response from a few flat frames (the intensity calibration,
tip 3.6) and returns the `calib.phase.WaveformCorrection` that removes the periodic phase error a
nonlinear response (gamma) gives a plain fringe; without it a 3-step fringe of a gamma-2.2 display errs
by up to 0.25 rad, too much for a period ratio of 16 to unwrap.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.decode import DARK_FRACTION, MAX_MISMATCH_SIGMA, MODULATION_FRACTION
from calib.intensity import fit_intensity
from calib.phase import LOW_MODULATION, NO_DATA, UNWRAP, WaveformCorrection, decode_frames, unwrap_temporal

AXES = ("x", "y")


@dataclass
class DisplayMap:
    """What each camera pixel sees of the display.

    coord: (2, H, W) float64 display pixels (column c, row r); valid: (H, W) bool; quality: (H, W) uint8
    flag bits of `calib.phase` (0 = good); mean: (H, W) float32 the fringe offset A of the shortest x
    period (a flat picture of the screen, in camera values); mismatch_sigma: per axis, the spread of the
    period-to-period disagreement (periods of the shorter fringe).
    """

    coord: np.ndarray
    valid: np.ndarray
    quality: np.ndarray
    mean: np.ndarray
    mismatch_sigma: dict

    @property
    def valid_fraction(self) -> float:
        return float(self.valid.mean())


def flat_correction(levels, images, full_scale: float, low: float, high: float, shifts) -> WaveformCorrection:
    """The phase correction of plain fringes of code values [low, high] at `shifts` (radians) for the
    display response that flat frames measure.

    levels: (J,) code values of the flats (J >= 3 distinct); images: the camera frame of each; full_scale:
    the camera's saturation value. Raises ValueError when the flats show no usable response (the camera
    sees no screen, or every pixel is saturated).
    """
    im = fit_intensity(levels, images, full_scale, min_range=DARK_FRACTION * full_scale)
    return WaveformCorrection(im.fringe_waveform(low, high), shifts)


def _decode_set(frames: list[np.ndarray], shifts, full_scale: float, correction: WaveformCorrection | None):
    """One fringe set's wrapped phase, low modulation flagged as in `calib.decode`."""
    res = decode_frames(frames, shifts, full_scale, DARK_FRACTION * full_scale, 0.0, correction)
    good = res.modulation[(res.quality == 0) & np.isfinite(res.modulation)][::97]
    min_mod = MODULATION_FRACTION * float(np.percentile(good, 90)) if good.size else np.inf
    res.quality[~(res.modulation >= min_mod)] |= LOW_MODULATION
    return res


def decode_display(frames: dict, shifts, display_size: tuple[int, int], full_scale: float, *,
                   correction: WaveformCorrection | None = None) -> DisplayMap:
    """Decode both axes of a fringe set.

    frames: {(axis, period_px): [N frames (H, W), one per shift]} for axis "x" and "y" and two or more
    periods each, the longest covering the display along its axis; shifts: the N shifts (radians) of
    every set; display_size: (width, height) display pixels; full_scale: the camera's saturation value;
    correction: the display response's phase correction (`flat_correction`) or None. Raises ValueError
    if an axis is missing or the periods disagree more than the decoder accepts (the ratio of successive
    periods too large for the phase noise: `calib.decode.MAX_MISMATCH_SIGMA`).
    """
    coords, mismatch = [], {}
    quality = None
    mean = None
    for axis, extent in zip(AXES, display_size):
        periods = sorted((p for a, p in frames if a == axis), reverse=True)
        if not periods:
            raise ValueError(f"no {axis}-axis fringes")
        phases = []
        for period in periods:
            res = _decode_set(frames[axis, period], shifts, full_scale, correction)
            quality = res.quality if quality is None else quality | res.quality
            phases.append(res.phase)
            if axis == "x":
                mean = res.offset                       # the last set is the shortest period's
        un = unwrap_temporal(periods, phases, extent, valid=quality == 0)
        worst = max((s for s in un.mismatch_sigma if np.isfinite(s)), default=0.0)
        if worst > MAX_MISMATCH_SIGMA:
            raise ValueError(f"the {axis} fringe periods {'/'.join(f'{p:g}' for p in periods)} disagree by "
                             f"{worst:.3f} period RMS, safe <= {MAX_MISMATCH_SIGMA}; with a noisy camera, add a "
                             "period between them")
        quality[~un.consistent] |= UNWRAP
        mismatch[axis] = un.mismatch_sigma
        coords.append(un.coord)
    coord = np.stack(coords)
    quality[~np.isfinite(coord).all(axis=0)] |= NO_DATA
    return DisplayMap(coord, quality == 0, quality, mean, mismatch)


def track_display(frames: dict, shifts, previous: DisplayMap, full_scale: float, *,
                  correction: WaveformCorrection | None = None, tolerance: float = 0.25) -> DisplayMap:
    """Decode one period per axis, unwrapped against a previous map of the same camera.

    frames: {(axis, period_px): [N frames]} with one period for "x" and one for "y"; previous: the map
    the fringe order is taken from (each pixel's coordinate rounded to the nearest whole period of the
    new phase). A pixel whose new phase disagrees with the previous coordinate by more than `tolerance`
    periods is marked inconsistent (UNWRAP); mismatch_sigma holds, per axis, the median disagreement.
    A pixel that moved by a whole period is not seen: if all did, the coordinates slip by one period,
    which moves the display in its own plane and leaves its orientation (the tilts) unchanged.
    """
    coords, mismatch = [], {}
    quality = np.where(previous.valid, 0, UNWRAP).astype(np.uint8)
    for i, axis in enumerate(AXES):
        periods = [p for a, p in frames if a == axis]
        if len(periods) != 1:
            raise ValueError(f"tracking needs one {axis}-axis period, got {len(periods)}")
        res = _decode_set(frames[axis, periods[0]], shifts, full_scale, correction)
        quality |= res.quality
        turns = res.phase.astype(np.float64) / (2 * np.pi)
        cycles = previous.coord[i] / periods[0] - turns
        order = np.rint(cycles)
        frac = np.abs(cycles - order)
        with np.errstate(invalid="ignore"):
            quality[~(frac <= tolerance)] |= UNWRAP
        coords.append((turns + order) * periods[0])
        good = frac[quality == 0]
        mismatch[axis] = [float(np.median(good)) if good.size else float("nan")]
        if axis == "x":
            mean = res.offset
    coord = np.stack(coords)
    quality[~np.isfinite(coord).all(axis=0)] |= NO_DATA
    return DisplayMap(coord, quality == 0, quality, mean, mismatch)


__all__ = ["DisplayMap", "flat_correction", "decode_display", "track_display"]

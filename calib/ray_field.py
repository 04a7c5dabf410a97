"""The ray field of one camera, the steps every calibration path shares: least-squares lines through the
decoded points (with the cover glass), the regularisation of the lines on two planes, and the PRVM with
the meta every calibration writes; `Calibration`, what a calibration returns.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np

from calib.capture import Capture
from calib.decode import DecodedPosition
from calib.intensity import IntensityMatrix
from calib.phase import QUALITY_NAMES
from calib.positions import point_weights
from calib.prvm import GLASS_ITERATIONS, Lines, fit_lines, fit_posed_lines, glass_offset
from calib.prvm_file import PRVM
from calib.regularise import Adaptive, Smoother, deepest_half, finest_scale, smooth_fields

AUTO = Adaptive(half_window=-1)          # marker: choose the windows from the data (`auto_smoother`)
# warn when more than this fraction of the pixels could not be calibrated
MASKED_WARNING = 0.001


@dataclass
class Calibration:
    """Result of `calibrate_camera`.

    prvm: the rays to save (regularised unless regularisation was turned off); raw: the unregularised
    lines; lines: the final lines; positions: the decoded stage positions (or poses); quality: (H, W)
    uint8, the OR of the flags of every position at which the pixel's point was dropped; intensity: the
    IM of the first position (None without flats; a Bayer camera's: `calib.bayer.BayerIntensity`);
    notes: warnings for the user (masked areas, missing flats, poses left out); poses: the estimated
    display poses (`calib.handheld.PoseReport`, or the stage's, `calib.stage_poses.StageFit`; None when
    the nominal stage positions were used without refinement).
    """

    prvm: PRVM
    raw: Lines
    lines: Lines
    positions: list[DecodedPosition]
    quality: np.ndarray
    intensity: IntensityMatrix | None
    notes: list[str] = field(default_factory=list)
    poses: object | None = None


def _points(capture: Capture, positions: list[DecodedPosition]) -> tuple[np.ndarray, np.ndarray]:
    """(M, H, W, 2) WCS x, y of the decoded points and (M, H, W) weights (`point_weights`)."""
    h, w = positions[0].valid.shape
    pts = np.empty((len(positions), h, w, 2))
    wts = np.empty((len(positions), h, w), np.float32)
    for i, p in enumerate(positions):
        pts[i] = capture.display_to_wcs(p.coord[0], p.coord[1], p.z_mm)[..., :2]
        wts[i] = point_weights(p)
    return pts, wts


def fit_rays(capture: Capture, positions: list[DecodedPosition], z_ref: float = 0.0, poses=None) -> Lines:
    """Least-squares lines through the decoded points, corrected for the cover glass if declared.

    poses: the displays' estimated poses in the WCS (rotation (M, 3, 3), translation (M, 3)), for
    points off the nominal stage positions (`calib.stage_poses`); None: the nominal positions."""
    if poses is not None:
        return fit_posed_lines([p.coord for p in positions], [point_weights(p) for p in positions], poses[0],
                               poses[1], capture.display.pitch_mm, glass=capture.display.cover_glass,
                               z_ref=z_ref).lines
    z = np.array([p.z_mm for p in positions])
    points, weights = _points(capture, positions)
    lines = fit_lines(z, points, weights, z_ref)
    glass = capture.display.cover_glass
    if glass is not None and glass.thickness_mm > 0:
        for _ in range(GLASS_ITERATIONS):
            shift = glass_offset(np.nan_to_num(lines.slope), glass)
            lines = fit_lines(z, points + shift[None], weights, z_ref)
    return lines


def coverage_notes(camera: str, quality: np.ndarray, valid: np.ndarray) -> list[str]:
    masked = ~valid
    if masked.mean() <= MASKED_WARNING:
        return []
    rows, cols = np.nonzero(masked)
    reasons = ", ".join(f"{name} {np.mean(quality & flag > 0):.1%}" for flag, name in QUALITY_NAMES.items()
                        if (quality & flag).any())
    edge = max(masked[0].mean(), masked[-1].mean(), masked[:, 0].mean(), masked[:, -1].mean()) > 0.1
    hint = (" - does the display cover the camera's whole field of view at every stage position?"
            if edge else "")
    return [f"camera {camera!r}: {masked.mean():.1%} of the pixels are not calibrated (columns "
            f"{cols.min()}-{cols.max()}, rows {rows.min()}-{rows.max()}; {reasons}){hint}; "
            f"see the mask with --report or `stereodic show`"]


def auto_smoother(positions: list[DecodedPosition]) -> Adaptive:
    """The default regularisation: windows chosen per pixel (`Adaptive`) on a ladder doubling from the
    smallest window the data need (`calib.regularise.finest_scale`, from the decoded points of the
    first and last stage positions) while narrower than the image; from one position alone, which
    cannot tell lens structure from noise, from `calib.regularise.deepest_half`, and the window
    Lepski's alone at 3 sigma (the risk's bias estimate would follow the display's own errors: on the
    reduced test's capture 0.028 display px of homography residual against 0.021)."""
    first, last = positions[0], positions[-1]
    h, w = first.valid.shape
    if len(positions) > 1:
        half = finest_scale(first.coord, last.coord, first.valid & last.valid)
    else:
        half = deepest_half(h, w)
    levels = 1
    while 2 * half * 2 ** levels + 1 < min(h, w):
        levels += 1
    if len(positions) > 1:
        return Adaptive(half_window=half, levels=levels)
    return Adaptive(half_window=half, levels=levels, bias_weight=0.0, threshold=3.0)


def regularisation_meta(smoother: Smoother | Adaptive | None, mean_window_px: float) -> dict | None:
    """What `meta.regularisation` records: the method, its windows (pixels) and the mean window used."""
    if smoother is None:
        return None
    if isinstance(smoother, Smoother):
        return {"method": "local polynomial", "window_px": smoother.window, "order": smoother.order}
    return {"method": "local polynomial, window per pixel (least estimated risk, capped by Lepski's test)",
            "windows_px": [s.window for s in smoother.ladder()], "order": smoother.order,
            "bias_weight": smoother.bias_weight, "threshold_sigma": smoother.threshold,
            "mean_window_px": mean_window_px}


def smooth_plane(raw: Lines, z_mm: float, smoother: Smoother | Adaptive,
                 regularised: bool) -> tuple[np.ndarray | None, np.ndarray, float]:
    """Smooth the points x, y (WCS mm) where the raw lines cross the plane z = z_mm.

    regularised: whether the smoothed points are the result (else the raw points stay, and only their
    noise is estimated). Returns (the smoothed (H, W, 2) points, None unless regularised; the (H, W)
    float32 1-sigma uncertainty (mm, RMS over x and y) of the resulting points (the noise after
    smoothing, `calib.regularise.Regularised`); the mean window
    (pixels)). Each field is smoothed on its own, so smoothing the two planes one after the other gives
    the same result as together with half the working arrays (at 5 MP they set the peak memory).
    """
    reg = smooth_fields(raw.at(z_mm).transpose(2, 0, 1), raw.valid, smoother)
    noise = reg.noise * reg.gain if regularised else reg.noise
    sigma = np.sqrt((noise[0] ** 2 + noise[1] ** 2) / 2)
    return reg.fields.transpose(1, 2, 0) if regularised else None, sigma, float(np.nanmean(reg.window))


def ray_meta(capture: Capture, camera: str, positions: list[DecodedPosition], im, regularisation: dict | None,
             z_a: float, z_b: float, z_ref: float, notes: list[str]) -> dict:
    """The PRVM meta every calibration writes (stage-specific or pose-specific keys are added to it)."""
    return {"camera": camera, "dataset": os.fspath(capture.root), "reference_z_mm": z_ref,
            "periods_px": {a: sorted({float(f.pattern.period_px) for f in capture.select(camera, type="fringe",
                                                                                          axis=a)}) for a in "xy"},
            "steps": [list(p.steps) for p in positions][0],
            "regularisation": regularisation,
            "cover_glass": None if capture.display.cover_glass is None else vars(capture.display.cover_glass),
            "intensity_matrix": im is not None,
            "clipped_pixels": [list(p.clipped) for p in positions],
            **({"bayer": capture.bayer[camera]} if camera in capture.bayer else {}),
            "uncertainty_z_mm": [z_a, z_b],
            "notes": notes}


def ray_prvm(raw: Lines, lines: Lines, sigma: np.ndarray, quality: np.ndarray, im, meta: dict) -> PRVM:
    """The PRVM of final `lines` (`raw`: the unregularised fit, for its residual and counts)."""
    extra = {"quality": quality, "uncertainty_mm": sigma.astype(np.float32, copy=False),
             "used_positions": raw.used.astype(np.uint8)}
    if im is not None:
        extra.update(im.to_arrays())
    prvm = PRVM(lines.origin(), lines.direction(), raw.valid.copy(), raw.residual_mm, meta, extra)
    prvm.origin[~prvm.valid] = np.nan
    prvm.direction[~prvm.valid] = np.nan
    return prvm


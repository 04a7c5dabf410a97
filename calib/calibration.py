"""The calibration pipeline of one camera: capture -> decoded display points -> per-pixel rays (PRVM).

1. Intensity matrix from the flat frames (at the first stage position, or the nearest one with flats).
2. Each stage position decoded to display pixels (`calib.decode`; a Bayer camera channel by channel,
   `calib.bayer`), then to WCS points (`Capture.display_to_wcs`: pitch, stage position and stage axis).
3. With 3 or more positions, the display's pose at each is refined from the data (`calib.stage_poses`:
   tilt, and the z and lateral errors off the nominal travel) and used where it lowers the residual
   significantly.
4. A weighted least-squares line per pixel through its points (2 or more positions); with a cover glass
   the points are corrected for refraction using the fitted direction, and the lines refitted.
5. The ray field regularised (`calib.regularise`; a Bayer camera's each colour's photosites as their
   own field), and the per-pixel uncertainty estimated.

A stage-free capture (frames with `pose`) takes `calib.handheld` instead: the poses and rays together.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import cv2
import numpy as np

from calib.capture import Capture
from calib.decode import DecodedPosition, decode_position, intensity_matrix
from calib.errors import InputError
from calib.intensity import IntensityMatrix
from calib.phase import QUALITY_NAMES
from calib.progress import progress
from calib.prvm import GLASS_ITERATIONS, Lines, fit_lines, fit_posed_lines, glass_offset
from calib.prvm_file import PRVM
from calib.regularise import Adaptive, Smoother, deepest_half, finest_scale, smooth_fields
AUTO = Adaptive(half_window=-1)          # marker: choose the windows from the data (`auto_smoother`)
# warn when more than this fraction of the pixels could not be calibrated
MASKED_WARNING = 0.001
# when the first position's intensity matrix lacks more than this fraction of the pixels, another
# position's flats fill them in (below it, the few pixels are not worth reading the flats again)
IM_REFILL = 0.001
# a point's variance is the mean of the modulation's prediction over this window of decoded pixels
# (`point_weights`)
WEIGHT_WINDOW_PX = 31


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


def default_camera(capture: Capture, camera: str | None) -> str:
    """The camera to calibrate: the one named, or the dataset's only camera."""
    if camera is None:
        if len(capture.cameras) != 1:
            raise InputError(capture.manifest_path, f"the dataset has cameras {', '.join(capture.cameras)}; "
                                                    "choose one with --camera")
        return next(iter(capture.cameras))
    if camera not in capture.cameras:
        raise InputError(capture.manifest_path, f"no camera {camera!r} (have {', '.join(capture.cameras)})")
    return camera


def decode_all(capture: Capture, camera: str) -> tuple[list[DecodedPosition], IntensityMatrix | None, list[str]]:
    """Decode every stage position (or pose) of `camera`; returns (positions, IM of the first position,
    notes)."""
    if camera in capture.bayer:
        from calib.bayer import decode_bayer
        return decode_bayer(capture, camera)
    zs = capture.positions(camera)
    notes = []
    n_frames = len(capture.select(camera, type="fringe"))
    bar = progress(range(n_frames), desc=f"decoding {camera}", total=n_frames)
    it = iter(bar)
    # the display response and each pixel's linearisation are the camera's and display's, not the
    # position's (and the phase does not depend on a pixel's offset and gain): one IM serves all
    # positions, but for the pixels it lacks (they saw no display at its position: a display that does
    # not fill the view), those of another position's flats where there are enough of them
    im = intensity_matrix(capture, camera, zs[0])
    if im is None:
        notes.append("no flat frames: the display's response is not compensated (a display gamma "
                     "then leaves a periodic phase error); capture flats at several levels")
    flat_zs = {f.pose if capture.posed else f.z_mm for f in capture.select(camera, type="flat")}
    positions = []
    for z in zs:
        im_z = im
        if im is not None and z != zs[0] and z in flat_zs and np.mean(~np.isfinite(im.gain)) > IM_REFILL:
            im_z = im.filled(intensity_matrix(capture, camera, z))
        positions.append(decode_position(capture, camera, z, im_z, progress=lambda: next(it, None)))
    return positions, im, notes


def point_weights(position: DecodedPosition) -> np.ndarray:
    """(H, W) float32 weight of each pixel's decoded point: its inverse variance in display pixels^2
    (0 where not decoded).

    The sigma of a coordinate is ~ period / (B sqrt(N)) (B the fringe modulation, N the steps), on the
    same scale at every position of a pixel. That prediction is averaged over a `WEIGHT_WINDOW_PX`
    square of decoded pixels: the noise level varies slowly (defocus, vignetting, distance and viewing
    angle), while a pixel's own B also follows the display's pixel grid where the camera resolves it (an
    in-focus display, a telecentric lens), and so does its decoding error: weighting by each pixel's
    own B makes the weighted mean of the errors nonzero (a telecentric lens's rays then move by 1.6 um
    as a whole, 0.019 camera pixels on the bench), and B of one pixel is a noisy estimate besides.
    """
    p = position
    var = sum((per / (np.maximum(m, 1e-6) * np.sqrt(n))) ** 2 for per, m, n in zip(p.period_px, p.modulation, p.steps))
    valid = p.valid
    size = (WEIGHT_WINDOW_PX, WEIGHT_WINDOW_PX)
    total = cv2.boxFilter(np.where(valid, var, 0.0).astype(np.float64), -1, size, normalize=False,
                          borderType=cv2.BORDER_CONSTANT)
    count = cv2.boxFilter(valid.astype(np.float64), -1, size, normalize=False, borderType=cv2.BORDER_CONSTANT)
    return np.where(valid, count / np.maximum(total, 1e-300), 0.0).astype(np.float32)


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


def _coverage_notes(camera: str, quality: np.ndarray, valid: np.ndarray) -> list[str]:
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


def _clipping_notes(camera: str, positions: list[DecodedPosition]) -> list[str]:
    solved = sum(p.clipped[0] for p in positions)
    lost = sum(p.clipped[1] for p in positions)
    if not solved and not lost:
        return []
    return [f"camera {camera!r}: clipped samples (at full scale or 0): {solved} pixel-positions decoded from "
            f"their unclipped samples, {lost} left out (fewer than 3 samples left in a fringe set); lower the "
            f"exposure or the fringe's high level if that is many"]


def auto_smoother(positions: list[DecodedPosition]) -> Adaptive:
    """The default regularisation: windows chosen per pixel (`Adaptive`) on a ladder doubling from the
    smallest window the data need (`calib.regularise.finest_scale`, from the decoded points of the
    first and last stage positions) while narrower than the image; from one position alone, which
    cannot tell lens structure from noise, from `calib.regularise.deepest_half`."""
    first, last = positions[0], positions[-1]
    h, w = first.valid.shape
    if len(positions) > 1:
        half = finest_scale(first.coord, last.coord, first.valid & last.valid)
    else:
        half = deepest_half(h, w)
    levels = 1
    while 2 * half * 2 ** levels + 1 < min(h, w):
        levels += 1
    return Adaptive(half_window=half, levels=levels)


def _regularisation_meta(smoother: Smoother | Adaptive | None, mean_window_px: float) -> dict | None:
    """What `meta.regularisation` records: the method, its windows (pixels) and the mean window used."""
    if smoother is None:
        return None
    if isinstance(smoother, Smoother):
        return {"method": "local polynomial", "window_px": smoother.window, "order": smoother.order}
    return {"method": "local polynomial, window per pixel (Lepski)",
            "windows_px": [s.window for s in smoother.ladder()], "order": smoother.order,
            "threshold_sigma": smoother.threshold, "mean_window_px": mean_window_px}


def smooth_plane(raw: Lines, z_mm: float, smoother: Smoother | Adaptive,
                 regularised: bool) -> tuple[np.ndarray | None, np.ndarray, float]:
    """Smooth the points x, y (WCS mm) where the raw lines cross the plane z = z_mm.

    regularised: whether the smoothed points are the result (else the raw points stay, and only their
    noise is estimated). Returns (the smoothed (H, W, 2) points, None unless regularised; the (H, W)
    float32 1-sigma uncertainty (mm, RMS over x and y) of the resulting points; the mean window
    (pixels)). Each field is smoothed on its own, so smoothing the two planes one after the other gives
    the same result as together with half the working arrays (at 5 MP they set the peak memory).
    """
    reg = smooth_fields(raw.at(z_mm).transpose(2, 0, 1), raw.valid, smoother)
    noise = reg.noise * reg.gain if regularised else reg.noise
    sigma = np.sqrt((noise[0] ** 2 + noise[1] ** 2) / 2)
    return reg.fields.transpose(1, 2, 0) if regularised else None, sigma, float(np.nanmean(reg.window))


def regularise_lines(capture: Capture, camera: str, raw: Lines, positions: list[DecodedPosition],
                     smoother: Smoother | Adaptive | None, z_a: float, z_b: float,
                     z_ref: float) -> tuple[Lines, np.ndarray, dict | None]:
    """The regularised lines (the points where `raw` crosses the planes z = z_a and z = z_b smoothed;
    a Bayer camera's colours each on their own, `calib.bayer.smooth_planes`), their (H, W, 2) float32
    1-sigma uncertainty on those planes, and `meta.regularisation`. smoother: as `calibrate_camera`'s
    (None: raw lines, the noise still estimated)."""
    used = auto_smoother(positions) if smoother is None or smoother == AUTO else smoother
    regularised = smoother is not None
    if camera in capture.bayer:
        from calib.bayer import smooth_planes
        smooth = smooth_planes(capture.bayer[camera], positions, smoother)
    else:
        def smooth(lines, z):
            return smooth_plane(lines, z, used, regularised)
    try:
        xy_a, sigma_a, window_a = smooth(raw, z_a)
        xy_b, sigma_b, window_b = smooth(raw, z_b)
    except ValueError as exc:
        raise InputError(capture.manifest_path, f"camera {camera!r}: {exc}") from None
    sigma = np.stack([sigma_a, sigma_b], axis=2)
    lines = Lines.through(z_a, xy_a, z_b, xy_b, raw.valid, raw.residual_mm, raw.used, z_ref) if regularised else raw
    return lines, sigma, _regularisation_meta(None if not regularised else used, (window_a + window_b) / 2)


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


def dropped_quality(positions: list[DecodedPosition]) -> np.ndarray:
    """(H, W) uint8: the OR of the flags of every position at which the pixel's point was dropped."""
    quality = np.zeros(positions[0].valid.shape, np.uint8)
    for p in positions:
        quality |= np.where(p.valid, 0, p.quality).astype(np.uint8)
    return quality


def calibrate_camera(capture: Capture, *, camera: str | None = None, smoother: Smoother | Adaptive | None = AUTO,
                     z_ref: float = 0.0, refine: bool = True) -> Calibration:
    """Calibrate one camera of a calibration dataset: its per-pixel rays (PRVM).

    A stage-free capture (display poses) is calibrated by `calib.handheld`.

    Parameters
    ----------
    capture : Capture
        A stereodic.capture/1 dataset of kind ``calibration`` (`calib.capture.load_capture`).
    camera : str, optional
        The camera to calibrate; None: the dataset's only camera.
    smoother : Smoother or Adaptive or None
        The regularisation. AUTO: windows chosen from the data (`auto_smoother`); a `Smoother`: one fixed
        window; None: rays left unregularised (the noise is still estimated with the automatic smoother,
        for the uncertainty).
    z_ref : float
        The plane of the rays' origins, WCS z, mm.
    refine : bool
        With 3 or more stage positions, estimate the display's pose at each (`calib.stage_poses`) and use
        it where it lowers the residual significantly.

    Returns
    -------
    calibration : Calibration
        ``prvm``: the (H, W) rays in the WCS (origins on z = z_ref, mm), with their validity, uncertainty
        and quality flags; and the raw and final lines, decoded positions, intensity matrix, notes and
        estimated poses behind them.
    """
    if capture.kind != "calibration":
        raise InputError(capture.manifest_path, f"dataset kind is {capture.kind!r}, expected 'calibration'")
    camera = default_camera(capture, camera)
    if capture.posed:
        from calib.handheld import calibrate_handheld
        return calibrate_handheld(capture, camera, smoother, z_ref)
    zs = capture.z_positions(camera)
    if len(zs) < 2:
        raise InputError(capture.manifest_path, f"camera {camera!r} has frames at {len(zs)} stage position(s); "
                                                "a ray needs at least 2 (or use --reduced)")
    positions, im, notes = decode_all(capture, camera)
    stage = None
    if refine and len(zs) >= 3:
        from calib.stage_poses import estimate_stage
        stage = estimate_stage(capture, positions)
    raw = fit_rays(capture, positions, z_ref, None if stage is None or not stage.used else stage.poses)
    quality = dropped_quality(positions)
    if not raw.valid.any():
        raise InputError(capture.manifest_path, f"camera {camera!r}: no pixel was decoded at 2 or more "
                                                "stage positions")
    notes += _coverage_notes(camera, quality, raw.valid) + _clipping_notes(camera, positions)

    z_a, z_b = zs[0], zs[-1]
    lines, sigma, regularisation = regularise_lines(capture, camera, raw, positions, smoother, z_a, z_b, z_ref)
    meta = ray_meta(capture, camera, positions, im, regularisation, z_a, z_b, z_ref, notes)
    meta.update({"z_positions_mm": zs, "stage_axis": list(capture.stage_axis)})
    if stage is not None:
        meta["stage_poses"] = stage.to_json()
    prvm = ray_prvm(raw, lines, sigma, quality, im, meta)
    return Calibration(prvm, raw, lines, positions, quality, im, notes, stage)

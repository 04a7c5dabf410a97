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

from calib.capture import Capture
from calib.errors import InputError
from calib.handheld import calibrate_handheld
from calib.positions import clipping_notes, dropped_quality
from calib.ray_field import AUTO, Calibration, coverage_notes, fit_rays, ray_meta, ray_prvm
from calib.regularise import Adaptive, Smoother
from calib.sensor import decode_all, regularise_lines
from calib.stage_poses import estimate_stage


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
        return calibrate_handheld(capture, camera, smoother, z_ref)
    zs = capture.z_positions(camera)
    if len(zs) < 2:
        raise InputError(capture.manifest_path, f"camera {camera!r} has frames at {len(zs)} stage position(s); "
                                                "a ray needs at least 2 (or use --reduced)")
    positions, im, notes = decode_all(capture, camera)
    stage = None
    if refine and len(zs) >= 3:
        stage = estimate_stage(capture, positions)
    raw = fit_rays(capture, positions, z_ref, None if stage is None or not stage.used else stage.poses)
    quality = dropped_quality(positions)
    if not raw.valid.any():
        raise InputError(capture.manifest_path, f"camera {camera!r}: no pixel was decoded at 2 or more "
                                                "stage positions")
    notes += coverage_notes(camera, quality, raw.valid) + clipping_notes(camera, positions)

    z_a, z_b = zs[0], zs[-1]
    lines, sigma, regularisation = regularise_lines(capture, camera, raw, positions, smoother, z_a, z_b, z_ref)
    meta = ray_meta(capture, camera, positions, im, regularisation, z_a, z_b, z_ref, notes)
    meta.update({"z_positions_mm": zs, "stage_axis": list(capture.stage_axis)})
    if stage is not None:
        meta["stage_poses"] = stage.to_json()
    prvm = ray_prvm(raw, lines, sigma, quality, im, meta)
    return Calibration(prvm, raw, lines, positions, quality, im, notes, stage)


"""What differs with the camera's sensor, monochrome or a raw Bayer mosaic (`calib.bayer`): decoding every
position (`decode_all`) and regularising the lines (`regularise_lines`, a Bayer camera's colours each as
a field of its own).
"""

from __future__ import annotations

import numpy as np

from calib.bayer import decode_bayer, smooth_planes
from calib.capture import Capture
from calib.decode import DecodedPosition
from calib.errors import InputError
from calib.intensity import IntensityMatrix
from calib.positions import decode_positions
from calib.prvm import Lines
from calib.ray_field import AUTO, auto_smoother, regularisation_meta, smooth_plane
from calib.regularise import Adaptive, Smoother


def decode_all(capture: Capture, camera: str) -> tuple[list[DecodedPosition], IntensityMatrix | None, list[str]]:
    """Decode every stage position (or pose) of `camera`, monochrome or Bayer; returns (positions, IM of
    the first position, notes)."""
    if camera in capture.bayer:
        return decode_bayer(capture, camera)
    return decode_positions(capture, camera)


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
    return lines, sigma, regularisation_meta(None if not regularised else used, (window_a + window_b) / 2)


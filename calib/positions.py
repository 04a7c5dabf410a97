"""A camera's decoded positions: every stage position (or display pose) of a monochrome camera decoded
to display coordinates, each decoded point's weight, and the flags of the points dropped.

A Bayer camera decodes each colour's photosites as a camera of its own with `decode_positions`
(`calib.bayer`); `calib.sensor.decode_all` picks the way for any camera.
"""

from __future__ import annotations

import cv2
import numpy as np

from calib.capture import Capture
from calib.decode import DecodedPosition, decode_position, intensity_matrix
from calib.intensity import IntensityMatrix
from calib.progress import progress

# when the first position's intensity matrix lacks more than this fraction of the pixels, another
# position's flats fill them in (below it, the few pixels are not worth reading the flats again)
IM_REFILL = 0.001
# a point's variance is the mean of the modulation's prediction over this window of decoded pixels
# (`point_weights`)
WEIGHT_WINDOW_PX = 31


def decode_positions(capture: Capture, camera: str) -> tuple[list[DecodedPosition], IntensityMatrix | None,
                                                             list[str]]:
    """Decode every stage position (or pose) of a monochrome `camera` (for any camera:
    `calib.sensor.decode_all`); returns (positions, IM of the first position, notes)."""
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


def dropped_quality(positions: list[DecodedPosition]) -> np.ndarray:
    """(H, W) uint8: the OR of the flags of every position at which the pixel's point was dropped."""
    quality = np.zeros(positions[0].valid.shape, np.uint8)
    for p in positions:
        quality |= np.where(p.valid, 0, p.quality).astype(np.uint8)
    return quality


def clipping_notes(camera: str, positions: list[DecodedPosition]) -> list[str]:
    solved = sum(p.clipped[0] for p in positions)
    lost = sum(p.clipped[1] for p in positions)
    if not solved and not lost:
        return []
    return [f"camera {camera!r}: clipped samples (at full scale or 0): {solved} pixel-positions decoded from "
            f"their unclipped samples, {lost} left out (fewer than 3 samples left in a fringe set); lower the "
            f"exposure or the fringe's high level if that is many"]


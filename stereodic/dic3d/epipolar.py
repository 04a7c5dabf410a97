"""The rig's epipolar error in a matched reference pair: do the rectified rows still match?

A scene point seen at (xl, yl) in the left rectified image is seen in the right one on the row y* where
the right camera's ray at column xr meets the left ray: y* = yl for central lenses (the rows of the
rectified pair match), and the EVM moves it for non-central ones. The epipolar error of a match (xl, yl)
<-> (xr, yr) is yr - y*, pixels; y* is found on the signed distance between the left ray and the right
ray at (xr, y), which is linear in y over a pixel (evaluated at yr and yr + 1, `triangulate.ray_distances`,
EVM-corrected rays).

A camera that moved after the calibration (a bumped rig) shifts or turns its rows: the errors' median
leaves zero (a shift) or their spread grows (a turn about the optical axis). What the calibration
allows: each match's own random error (its predicted noise, `texture.predicted_noise`) and the rig's
row error, ROW_ERROR_PX (a RIG file does not record one: 0.02 px, where a PRVM calibration gives
0.001-0.005 px and OpenCV's on Brown-Conrady lenses 0.008 px - the README's `bench rectify` figures).
`check` warns when the median's size exceeds 3 x ROW_ERROR_PX, or the 95th percentile of |error|
exceeds 3 x its expected value 1.96 sqrt(ROW_ERROR_PX^2 + (median predicted noise)^2).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stereodic.stereo.rig import Rig
from stereodic.stereo.triangulate import ray_distances

ROW_ERROR_PX = 0.02


def epipolar_error(rig: Rig, xl: np.ndarray, yl: np.ndarray, xr: np.ndarray, yr: np.ndarray) -> np.ndarray:
    """(N,) epipolar errors yr - y* of matches (xl, yl) <-> (xr, yr) in the rectified pair, pixels
    (module docstring); NaN where a ray is blank."""
    xl, yl, xr, yr = (np.ravel(np.asarray(a, np.float64)) for a in (xl, yl, xr, yr))
    d0 = ray_distances(rig, xl, yl, xr, yr)
    d1 = ray_distances(rig, xl, yl, xr, yr + 1.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return d0 / (d1 - d0)


@dataclass
class EpipolarReport:
    """median (signed) and p95 (of |error|) of the epipolar errors, pixels; points: how many; expected_p95:
    what the calibration allows (module docstring); bumped: the rig looks moved since its calibration."""

    median: float
    p95: float
    points: int
    expected_p95: float
    bumped: bool

    def line(self) -> str:
        return (f"epipolar error of the reference pair (right row - where the left ray is seen): median "
                f"{self.median:+.3f} px, p95 {self.p95:.3f} px over {self.points} points (the calibration allows "
                f"a p95 of {self.expected_p95:.3f} px)")


def check(rig: Rig, xl, yl, xr, yr, noise_px) -> EpipolarReport | None:
    """The report of the matched points (NaN entries skipped; None when none is left); noise_px: the
    matches' predicted random errors, pixels."""
    e = epipolar_error(rig, xl, yl, xr, yr)
    noise = np.ravel(noise_px)
    good = np.isfinite(e) & np.isfinite(noise)
    if not good.any():
        return None
    e, noise = e[good], noise[good]
    median, p95 = float(np.median(e)), float(np.percentile(np.abs(e), 95))
    expected = 1.96 * float(np.hypot(ROW_ERROR_PX, np.median(noise)))
    return EpipolarReport(median, p95, int(e.size), expected, abs(median) > 3 * ROW_ERROR_PX or p95 > 3 * expected)

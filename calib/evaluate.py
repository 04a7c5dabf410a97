"""Rays against the truth: the error of each pixel's ray on the working plane and over the working volume.

The plane error of a pixel is the distance (mm) between its estimated and true ray on the plane z = z_mm,
divided by the pixel footprint there (the mean distance between neighbouring true rays on that plane), so
it reads in camera pixels. A ray is a line, and one can be right on one plane and wrong in direction: the
volume error is the RMS of the same distance over planes spanning the calibrated stage range and half that
range again beyond each end, each divided by the footprint on the working plane (so a wrong direction shows
as an error growing away from the working plane, in the working plane's pixels).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.prvm_file import PRVM


def footprint_mm(truth: PRVM, z_mm: float) -> float:
    """Mean distance (mm) between neighbouring true rays on the plane z = z_mm."""
    p = truth.at_z(z_mm)
    du = np.linalg.norm(np.diff(p, axis=1), axis=-1)
    dv = np.linalg.norm(np.diff(p, axis=0), axis=-1)
    return float(0.5 * (np.nanmean(du) + np.nanmean(dv)))


def working_plane(truth: PRVM) -> float:
    """The plane (WCS z, mm) on which rays are compared: the first true stage position recorded in a
    simulated truth, else the reference plane."""
    z = truth.extra.get("stage_true_z_mm")
    return float(z[0]) if z is not None and len(z) else truth.reference_z_mm


MAX_MEDIAN_ERROR_PX = 20.0  # a calibration this far from a truth everywhere is not of the truth's camera


def check_truth(estimate: PRVM, truth: PRVM, estimate_name: str, truth_name: str) -> None:
    """InputError (naming `truth_name`) unless `truth` can be the truth of the camera `estimate`
    calibrated: the same size, the same camera name where both files record one, and rays that meet
    the truth's on the working plane (median error below MAX_MEDIAN_ERROR_PX camera pixels: a
    calibration that far off everywhere is another camera's, dataset's or WCS's)."""
    from calib.errors import InputError
    if (estimate.width, estimate.height) != (truth.width, truth.height):
        raise InputError(truth_name, f"is the truth of a {truth.width}x{truth.height} camera, but {estimate_name} "
                                     f"is {estimate.width}x{estimate.height}")
    a, b = estimate.meta.get("camera"), truth.meta.get("camera")
    if a and b and a != b:
        raise InputError(truth_name, f"is the truth of camera {b!r}, but {estimate_name} calibrated {a!r}")
    err = ray_error_px(estimate, truth)
    median = float(np.nanmedian(err)) if np.isfinite(err).any() else float("nan")
    if not median <= MAX_MEDIAN_ERROR_PX:
        raise InputError(truth_name, f"is not the truth of {estimate_name}: their rays are a median {median:.0f} "
                                     f"camera pixels apart (another camera, dataset or world frame?)")


def ray_error_px(estimate: PRVM | np.ndarray, truth: PRVM, *, z_mm: float | None = None,
                 footprint: float | None = None) -> np.ndarray:
    """Each pixel's ray error against the truth on one plane, in camera pixels (module docstring).

    Parameters
    ----------
    estimate : PRVM or (H, W, 3) float64
        The calibrated rays, or their points on the plane z = z_mm (WCS, mm; NaN where not valid).
    truth : PRVM
        The true rays of the same (H, W) camera, in the same WCS.
    z_mm : float, optional
        The plane, WCS z, mm; None: `working_plane` of the truth.
    footprint : float, optional
        The pixel footprint on that plane, mm; None: `footprint_mm` of the truth there.

    Returns
    -------
    error : (H, W) float64
        Distance between the estimated and true ray on the plane over the footprint, camera pixels; NaN
        where the estimate is not valid.
    """
    z = working_plane(truth) if z_mm is None else z_mm
    fp = footprint_mm(truth, z) if footprint is None else footprint
    if isinstance(estimate, PRVM):
        points, valid = estimate.at_z(z), estimate.valid
    else:
        points = np.asarray(estimate)
        valid = np.isfinite(points).all(axis=-1)
    err = np.linalg.norm(points - truth.at_z(z), axis=-1) / fp
    return np.where(valid, err, np.nan)


def volume_planes(truth: PRVM, count: int = 11, beyond: float = 0.5) -> np.ndarray:
    """(count,) planes (WCS z, mm) evenly from `beyond` x the stage range before the first true stage
    position to as far after the last; just the working plane without a recorded stage range."""
    z = truth.extra.get("stage_true_z_mm")
    if z is None or len(z) < 2:
        return np.array([working_plane(truth)])
    near, far = float(np.min(z)), float(np.max(z))
    span = far - near
    return np.linspace(near - beyond * span, far + beyond * span, count)


def volume_error_px(estimate: PRVM, truth: PRVM, planes: np.ndarray | None = None) -> np.ndarray:
    """(H, W) float64 RMS over `planes` (default `volume_planes`) of the distance between the estimated
    and true ray on each plane, in camera pixels of the working plane's footprint; NaN where the estimate
    is not valid."""
    planes = volume_planes(truth) if planes is None else np.asarray(planes, float)
    fp = footprint_mm(truth, working_plane(truth))
    sq = sum(ray_error_px(estimate, truth, z_mm=z, footprint=fp) ** 2 for z in planes)
    return np.sqrt(sq / len(planes))


def positions_seen(truth: PRVM, width_px: int, height_px: int) -> np.ndarray:
    """(H, W) int: at how many stage positions of a simulated truth each pixel centre's true ray met the
    pixel area of a display of width_px x height_px pixels (its `display_cr` within -0.5 .. size - 0.5)."""
    cr = truth.extra["display_cr"]
    inside = (cr[..., 0] >= -0.5) & (cr[..., 0] <= width_px - 0.5) & (cr[..., 1] >= -0.5) & (cr[..., 1] <= height_px - 0.5)
    return inside.sum(axis=0)


@dataclass
class ErrorStats:
    """RMS, 99th percentile and maximum (pixels) over the valid pixels, and the valid fraction."""

    rms: float
    p99: float
    max: float
    valid: float

    @classmethod
    def of(cls, err: np.ndarray, *, margin: int = 0) -> "ErrorStats":
        """Statistics of an error map.

        Parameters
        ----------
        err : (H, W) float64
            An error map, pixels (`ray_error_px`); NaN where not valid.
        margin : int
            Pixels left out at each image border.

        Returns
        -------
        stats : ErrorStats
            RMS, 99th percentile and maximum (pixels) over the finite pixels, and their fraction
            (NaN statistics and 0.0 when none is finite).
        """
        e = err[margin:err.shape[0] - margin, margin:err.shape[1] - margin] if margin else err
        ok = np.isfinite(e)
        if not ok.any():
            return cls(float("nan"), float("nan"), float("nan"), 0.0)
        v = e[ok]
        return cls(float(np.sqrt(np.mean(v * v))), float(np.percentile(v, 99)), float(v.max()), float(ok.mean()))

"""Triangulation of matched virtual pixels of a rectified rig: 3D points (WCS, mm) and the ray gap.

A match is (x_left, row) in the left virtual image and (x_right, row) in the right one (sub-pixel
positions; integers at virtual pixel centres). Each position gives a ray through its point on the
common plane (`VirtualSensor.points`):
- corrected=True (default): the camera's model-less ray there, i.e. the pinhole ray corrected by the
  EVM - the real ray that the rectified image shows at that position (directions interpolated
  bilinearly in the virtual grid). This is right for every lens, also for surfaces far from the plane;
- corrected=False: the pinhole ray from the camera's optical centre (what the Q matrix computes).
The point is the midpoint of the closest points of the two rays; `gap_mm` is their distance (zero for a
perfect match of a perfect rig; a quality figure). Rays that are blank or parallel give NaN.
`rays_at` and `closest_points` are the numpy statement of this; `triangulate` runs it as one fused compiled
kernel (ray lookup + closest points per match, matches in parallel, no temporaries: C with OpenMP in
`stereodic.stereo._kernels`, stereodic/stereo/src), ~10 M matches/s.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stereodic.stereo._kernels import distances_all, triangulate_all
from stereodic.stereo.rig import Rig
from stereodic.virtual.sampling import bilinear


@dataclass
class Triangulation:
    """points: (..., 3) WCS mm, midpoints of the two rays; gap_mm: (...,) distance between the rays."""

    points: np.ndarray
    gap_mm: np.ndarray


def rays_at(rig: Rig, side: str, x: np.ndarray, row: np.ndarray, *, corrected: bool = True
            ) -> tuple[np.ndarray, np.ndarray]:
    """The rays of virtual positions of one camera of the rig (module docstring).

    Parameters
    ----------
    rig : Rig
        The rectified pair.
    side : {"left", "right"}
        The camera.
    x, row : (...) float
        Virtual column and row, pixels (sub-pixel; integers at virtual pixel centres).
    corrected : bool
        True: the model-less (EVM-corrected, real) rays; False: the pinhole rays from the camera's
        optical centre.

    Returns
    -------
    points : (..., 3) float64
        Where the rays cross the common plane, WCS mm.
    directions : (..., 3) float64
        Unit directions, WCS; NaN where blank.
    """
    p = rig.sensor.points(x, row)
    if corrected:
        d = bilinear(rig.camera(side).direction, x, row)
    else:
        d = p - rig.camera(side).centre
    return p, d / np.linalg.norm(d, axis=-1, keepdims=True)


def closest_points(o1: np.ndarray, d1: np.ndarray, o2: np.ndarray, d2: np.ndarray) -> Triangulation:
    """Midpoints and distances of the closest points of lines (o1, d1) and (o2, d2), (N, 3) each, d unit."""
    w = o1 - o2
    b = np.einsum("ij,ij->i", d1, d2)
    d = np.einsum("ij,ij->i", d1, w)
    e = np.einsum("ij,ij->i", d2, w)
    with np.errstate(divide="ignore", invalid="ignore"):
        den = 1.0 - b * b
        s = np.where(den > 1e-15, (b * e - d) / den, np.nan)
        t = np.where(den > 1e-15, (e - b * d) / den, np.nan)
    p1 = o1 + s[:, None] * d1
    p2 = o2 + t[:, None] * d2
    return Triangulation((p1 + p2) / 2, np.linalg.norm(p1 - p2, axis=-1))


def ray_distances(rig: Rig, x_left, row_left, x_right, row_right) -> np.ndarray:
    """Signed distances between the left ray at (x_left, row_left) and the right ray at (x_right,
    row_right), virtual pixels (broadcast to one shape; EVM-corrected rays, `rays_at`), mm: (o_r - o_l) .
    n / |n| with n = d_l x d_r (the sign tells on which side of the left ray the right one passes); NaN
    where a ray is blank or the two are parallel. A compiled kernel (matches in parallel, 0.1 us a match)."""
    arrays = np.broadcast_arrays(*(np.asarray(a, np.float64) for a in (x_left, row_left, x_right, row_right)))
    xl, rl, xr, rr = (np.ascontiguousarray(a, np.float64).ravel() for a in arrays)
    out = np.empty(xl.size)
    distances_all(xl, rl, xr, rr, *_plane(rig), out)
    return out.reshape(arrays[0].shape)


def _plane(rig: Rig) -> tuple[np.ndarray, ...]:
    """The kernels' view of the rig (float64, C-contiguous): the common plane's origin (3,) and its mm
    per virtual pixel along u and v (3,) each, WCS; the left and right rays' directions (H, W, 3)."""
    sensor = rig.sensor
    return tuple(np.ascontiguousarray(a, np.float64) for a in (
        sensor.origin, sensor.axis_u * sensor.pitch_mm[0], sensor.axis_v * sensor.pitch_mm[1], rig.left.direction,
        rig.right.direction))


def triangulate(rig: Rig, x_left, x_right, row, *, row_right=None, corrected: bool = True) -> Triangulation:
    """3D points of matched virtual positions (x_left, row) <-> (x_right, row_right).

    A compiled kernel (matches in parallel) that equals `closest_points(*rays_at(left), *rays_at(right))`.

    Parameters
    ----------
    rig : Rig
        The rectified pair.
    x_left, x_right, row : (...) float
        Matched virtual columns in the left and right images and the left row, pixels (sub-pixel;
        broadcast to one shape).
    row_right : (...) float, optional
        The right row, pixels, where it differs (non-central lenses); None: `row` (the rectified case).
    corrected : bool
        True: the EVM-corrected (real) rays; False: the pinhole rays (what the Q matrix computes).

    Returns
    -------
    triangulation : Triangulation
        ``points`` (..., 3) float64, WCS mm: the midpoints of the two rays' closest points; ``gap_mm``
        (...) float64: the rays' distance, mm. NaN where a ray is blank or the two are parallel.
    """
    x_left, x_right, row = np.broadcast_arrays(*(np.asarray(a, np.float64) for a in (x_left, x_right, row)))
    row_right = row if row_right is None else np.broadcast_to(np.asarray(row_right, np.float64), row.shape)
    shape = row.shape
    xl, xr, rl, rr = (np.ascontiguousarray(a, np.float64).ravel() for a in (x_left, x_right, row, row_right))
    points = np.empty((xl.size, 3))
    gap = np.empty(xl.size)
    triangulate_all(xl, rl, xr, rr, *_plane(rig), np.ascontiguousarray(rig.left.centre, np.float64),
                    np.ascontiguousarray(rig.right.centre, np.float64), corrected, points, gap)
    return Triangulation(points.reshape(shape + (3,)), gap.reshape(shape))

"""The specimen's frame and the rigid-body motion of each state of a stereo DIC result.

The specimen's frame (`specimen_frame`): the best-fit plane of the reference shape (state 0's points,
least squares by SVD), origin at the points' centroid or at a chosen pixel of the original left
reference image (projected on the plane), x along a chosen direction of the left image (projected on
the plane; default: the image's columns, left to right), z the plane's normal towards the cameras
(so that y points up the image), y = z x x. A point P of the rig's world frame is at
R (P - origin) in the specimen's (`SpecimenFrame.apply`).

Rigid-body motion (`rigid_motion`): the rotation and translation that best carry the reference points
onto a state's (least squares, Kabsch / Horn's closed form); the deformation-only displacement is what
is left once it is taken back out.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.errors import InputError


@dataclass(frozen=True)
class SpecimenFrame:
    """The specimen's frame in the rig's world frame: `origin` (3,) mm, `rotation` (3, 3) whose rows are
    the specimen's x, y, z axes (unit vectors, rig frame); `rms_mm` the reference points' RMS distance
    from the best-fit plane."""

    origin: np.ndarray
    rotation: np.ndarray
    rms_mm: float

    def apply(self, points: np.ndarray) -> np.ndarray:
        """Points (..., 3) of the rig's world frame, mm, in the specimen's frame, mm."""
        return (np.asarray(points, float) - self.origin) @ self.rotation.T

    def rotate(self, vectors: np.ndarray) -> np.ndarray:
        """Vectors (..., 3) (displacements) of the rig's world frame in the specimen's axes."""
        return np.asarray(vectors, float) @ self.rotation.T

    def record(self) -> dict:
        """The frame as JSON-ready numbers (what the outputs record)."""
        return {"frame": "specimen", "origin_mm": self.origin.tolist(), "axes": self.rotation.tolist(),
                "plane_rms_mm": self.rms_mm}


def _image_gradient(points: np.ndarray, image_px: np.ndarray) -> np.ndarray:
    """(3, 2): the points' change per pixel along the left image's columns and rows (a least-squares
    affine fit of points against their image positions)."""
    A = np.column_stack([np.ones(len(image_px)), image_px])
    coef, *_ = np.linalg.lstsq(A, points, rcond=None)
    return coef[1:].T


def specimen_frame(points_mm: np.ndarray, image_px: np.ndarray, *, origin_px: tuple[float, float] | None = None,
                   x_direction_px: tuple[float, float] = (1.0, 0.0)) -> SpecimenFrame:
    """The specimen's frame of a reference shape (module docstring).

    Parameters
    ----------
    points_mm : (N, 3) float
        The reference shape (state 0's points), rig world frame, mm; NaN rows are ignored.
    image_px : (N, 2) float
        Where each point is in the original left reference image, pixels (column, row).
    origin_px : (2,) float, optional
        The origin's position in the left reference image, pixels (default: the points' centroid).
    x_direction_px : (2,) float
        The direction of the specimen's x axis in the left image, pixels (default (1, 0): along the
        columns).

    Returns
    -------
    frame : SpecimenFrame
        InputError if fewer than 3 points span a plane, or the x direction is along the normal.
    """
    P = np.asarray(points_mm, float).reshape(-1, 3)
    uv = np.asarray(image_px, float).reshape(-1, 2)
    ok = np.isfinite(P).all(1) & np.isfinite(uv).all(1)
    P, uv = P[ok], uv[ok]
    if len(P) < 3:
        raise InputError("--frame", f"the reference shape has {len(P)} measured points: too few for a plane")
    centroid = P.mean(0)
    _, s, vt = np.linalg.svd(P - centroid, full_matrices=False)
    if s[1] <= 1e-9 * max(s[0], 1e-300):
        raise InputError("--frame", "the reference points lie on a line: no plane")
    normal = vt[2]
    grad = _image_gradient(P, uv)
    up = -grad[:, 1]                           # up the image: against the rows
    x = grad @ np.asarray(x_direction_px, float)
    x -= normal * (x @ normal)
    if np.linalg.norm(x) < 1e-12:
        raise InputError("--x-axis", "the direction is along the specimen's normal")
    x /= np.linalg.norm(x)
    if np.cross(grad[:, 0], up) @ normal < 0:  # the normal towards the viewer: image right x image up
        normal = -normal
    y = np.cross(normal, x)
    origin = centroid
    if origin_px is not None:
        at = np.asarray(origin_px, float)
        near = np.argsort(np.hypot(*(uv - at).T))[:min(len(uv), 16)]   # an affine fit of the nearest points
        A = np.column_stack([np.ones(len(near)), uv[near] - at])
        point = np.linalg.lstsq(A, P[near], rcond=None)[0][0]
        origin = point - normal * ((point - centroid) @ normal)
    rms = float(np.sqrt(np.mean(((P - centroid) @ normal) ** 2)))
    return SpecimenFrame(origin, np.stack([x, y, normal]), rms)


def rigid_motion(reference: np.ndarray, current: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rigid motion that best carries the reference points onto the current ones.

    Parameters
    ----------
    reference, current : (N, 3) float
        The same material points in the reference state and now, one frame, mm; rows with a NaN in
        either are ignored.

    Returns
    -------
    rotation : (3, 3) float
        R such that current ~ R reference + translation (least squares).
    translation : (3,) float
        mm. The identity and zero when fewer than 3 points are measured in both.
    """
    A, B = (np.asarray(a, float).reshape(-1, 3) for a in (reference, current))
    ok = np.isfinite(A).all(1) & np.isfinite(B).all(1)
    if ok.sum() < 3:
        return np.eye(3), np.zeros(3)
    A, B = A[ok], B[ok]
    ca, cb = A.mean(0), B.mean(0)
    u, _, vt = np.linalg.svd((A - ca).T @ (B - cb))
    d = np.sign(np.linalg.det(vt.T @ u.T))
    R = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    return R, cb - R @ ca

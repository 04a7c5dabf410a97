"""Starting poses for the joint estimation (`calib.poses`): a central camera model fitted to a subsample
of the dense correspondences, as one calibrates from a chessboard held in several poses (Zhang 2000:
homographies of the planar views, then OpenCV's `calibrateCamera` with a radial-tangential distortion).
A non-central or free-form lens is not that model, but its poses come out close enough (millimetres,
tenths of a degree) for the variable projection to converge from them.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

# correspondences per pose handed to OpenCV (its cost grows with them; the poses need few)
POINTS_PER_POSE = 1500


@dataclass
class CentralStart:
    """rotation (M, 3, 3), translation (M, 3): each display pose in the camera frame of the fitted
    central model (X_cam = R q + t, q display-frame mm); rms_px: its reprojection error."""

    rotation: np.ndarray
    translation: np.ndarray
    rms_px: float


def central_start(points_mm: np.ndarray, weights: np.ndarray, pixels: np.ndarray, width: int,
                  height: int, *, seed: int = 0) -> CentralStart:
    """Fit a central model to the correspondences and return its poses.

    points_mm: (M, N, 2) display-frame points (mm) seen by N pixels at M poses; weights: (M, N), 0 where
    a pixel did not see a pose; pixels: (N, 2) the pixels' (u, v). Raises ValueError when OpenCV
    cannot fit (too few points, degenerate views).
    """
    rng = np.random.default_rng(seed)
    obj, img = [], []
    for k in range(len(points_mm)):
        idx = np.flatnonzero(weights[k] > 0)
        if len(idx) < 20:
            raise ValueError(f"pose {k} has only {len(idx)} usable points")
        idx = rng.choice(idx, min(POINTS_PER_POSE, len(idx)), replace=False)
        obj.append(np.column_stack([points_mm[k, idx], np.zeros(len(idx))]).astype(np.float32))
        img.append(pixels[idx].astype(np.float32))
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-10)
    try:
        rms, _, _, rvecs, tvecs = cv2.calibrateCamera(obj, img, (width, height), None, None, criteria=crit)
    except cv2.error as exc:
        raise ValueError(f"OpenCV could not fit a central model ({str(exc).strip().splitlines()[-1]})") from None
    rot = np.stack([cv2.Rodrigues(r)[0] for r in rvecs])
    return CentralStart(rot, np.stack([t.ravel() for t in tvecs]), float(rms))

"""Pinhole cameras in OpenCV's model: bringing an existing OpenCV calibration into the PRVM, and the
OpenCV FileStorage YAML that holds one.

OpenCV's conventions: x_cam = R x_world + t; pixel = K * distort(x_cam / z_cam); distortion coefficients
(k1, k2, p1, p2[, k3[, k4, k5, k6[, s1..s4[, tau_x, tau_y]]]]). With the WCS of DESIGN.md the camera
must look along +z (towards the display), so that every ray has a positive z component.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from calib.errors import InputError
from calib.prvm_file import PRVM


@dataclass
class PinholeCamera:
    """An OpenCV camera: K (3, 3) pixels; dist (n,) OpenCV distortion coefficients; R (3, 3) and t (3,)
    the world-to-camera pose (t in mm); width, height in pixels."""

    K: np.ndarray
    dist: np.ndarray
    R: np.ndarray
    t: np.ndarray
    width: int
    height: int

    def __post_init__(self):
        self.K = np.asarray(self.K, np.float64).reshape(3, 3)
        self.dist = np.asarray(self.dist, np.float64).ravel()
        R = np.asarray(self.R, np.float64)
        self.R = cv2.Rodrigues(R.reshape(3, 1))[0] if R.size == 3 else R.reshape(3, 3)
        self.t = np.asarray(self.t, np.float64).reshape(3)
        self.width, self.height = int(self.width), int(self.height)

    @property
    def centre(self) -> np.ndarray:
        """(3,) the optical centre in the world frame (mm): -R^T t."""
        return -self.R.T @ self.t

    @property
    def rvec(self) -> np.ndarray:
        return cv2.Rodrigues(self.R)[0].ravel()


def prvm_from_opencv(K, dist, rvec, tvec, width: int, height: int, reference_z_mm: float = 0.0,
                     camera: str = "cam0") -> PRVM:
    """The PRVM of an OpenCV-calibrated camera: every pixel's ray through the optical centre.

    K: 3x3; dist: OpenCV distortion coefficients (any supported length, or None); rvec (3,) Rodrigues
    vector or 3x3 matrix and tvec (3,) mm: the world-to-camera pose. Ray origins on z = reference_z_mm.
    Pixels are undistorted with OpenCV's iterative inverse and then refined by Newton steps on
    cv2.projectPoints until they re-project within 1e-9 pixel (OpenCV's inverse alone is not exact for
    strong distortion).
    """
    cam = PinholeCamera(K, np.zeros(5) if dist is None else dist, rvec, tvec, width, height)
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    pix = np.stack([u.ravel(), v.ravel()], axis=-1)
    xy = undistort_exact(pix, cam.K, cam.dist)
    d_cam = np.concatenate([xy, np.ones((len(xy), 1))], axis=1)
    d = d_cam @ cam.R  # R^T d for each row: camera frame -> world frame
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    if not (np.isfinite(d).all() and (d[:, 2] > 1e-9).all()):
        raise InputError(None, "the OpenCV camera does not look along +z of the world frame (every ray must "
                               "move away from the camera in z)")
    c = cam.centre
    origin = c + ((reference_z_mm - c[2]) / d[:, 2])[:, None] * d
    meta = {"camera": camera, "width": width, "height": height, "reference_z_mm": float(reference_z_mm),
            "dataset": "imported from an OpenCV calibration",
            "opencv": {"K": cam.K.tolist(), "dist": cam.dist.tolist(), "rvec": cam.rvec.tolist(),
                       "tvec": cam.t.tolist()}}
    return PRVM(origin.reshape(height, width, 3), d.reshape(height, width, 3), np.ones((height, width), bool),
                None, meta)


def undistort_exact(pix: np.ndarray, K: np.ndarray, dist: np.ndarray, tol_px: float = 1e-9,
                    iterations: int = 8) -> np.ndarray:
    """(N, 2) normalised camera coordinates (x/z, y/z) that OpenCV projects onto pixels `pix` (N, 2)."""
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    xy = cv2.undistortPoints(pix.reshape(-1, 1, 2), K, dist, criteria=criteria).reshape(-1, 2)
    h = 1e-7
    for _ in range(iterations):
        f = _project(xy, K, dist)
        r = f - pix
        if np.abs(r).max() < tol_px:
            break
        jx = (_project(xy + [h, 0], K, dist) - f) / h
        jy = (_project(xy + [0, h], K, dist) - f) / h
        det = jx[:, 0] * jy[:, 1] - jx[:, 1] * jy[:, 0]
        xy = xy - np.stack([jy[:, 1] * r[:, 0] - jy[:, 0] * r[:, 1],
                            jx[:, 0] * r[:, 1] - jx[:, 1] * r[:, 0]], axis=-1) / det[:, None]
    return xy


def _project(xy: np.ndarray, K: np.ndarray, dist: np.ndarray) -> np.ndarray:
    pts = np.concatenate([xy, np.ones((len(xy), 1))], axis=1).reshape(-1, 1, 3)
    return cv2.projectPoints(pts, np.zeros(3), np.zeros(3), K, dist)[0].reshape(-1, 2)


def opencv_yaml(cam: PinholeCamera) -> str:
    """The camera as OpenCV FileStorage YAML: image_width, image_height, camera_matrix,
    distortion_coefficients, rotation_matrix (R), translation_vector (t, mm), rvec."""
    fs = cv2.FileStorage(".yaml", cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY)
    fs.write("image_width", cam.width)
    fs.write("image_height", cam.height)
    fs.write("camera_matrix", cam.K)
    fs.write("distortion_coefficients", cam.dist.reshape(1, -1))
    fs.write("rotation_matrix", cam.R)
    fs.write("translation_vector", cam.t.reshape(3, 1))
    fs.write("rvec", cam.rvec.reshape(3, 1))
    return fs.releaseAndGetString()


def read_opencv_yaml(path: str | os.PathLike) -> PinholeCamera:
    """A camera from OpenCV FileStorage YAML/XML/JSON as `opencv_yaml` writes it. Also accepted: K/D
    for the matrices, rvec or R for the rotation, tvec or T for the translation (identity pose when
    absent)."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "calibration file is missing")
    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except cv2.error:
        raise InputError(path, "not an OpenCV FileStorage file") from None

    def mat(*names):
        for name in names:
            node = fs.getNode(name)
            if not node.empty():
                m = node.mat()
                if m is None:
                    raise InputError(path, f"{name!r} is not a matrix")
                return m
        return None

    def real(name):
        node = fs.getNode(name)
        return None if node.empty() else node.real()

    K, dist = mat("camera_matrix", "K"), mat("distortion_coefficients", "D")
    rot, t = mat("rotation_matrix", "R", "rvec"), mat("translation_vector", "T", "tvec")
    w, h = real("image_width"), real("image_height")
    fs.release()
    if K is None or w is None or h is None:
        raise InputError(path, "needs camera_matrix (or K), image_width and image_height")
    return PinholeCamera(K, np.zeros(5) if dist is None else dist, np.eye(3) if rot is None else rot,
                         np.zeros(3) if t is None else t, int(w), int(h))

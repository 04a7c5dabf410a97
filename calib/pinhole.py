"""Pinhole cameras in OpenCV's model: bringing an existing OpenCV calibration into the PRVM, and the
OpenCV FileStorage YAML that holds one.

OpenCV's conventions: x_cam = R x_world + t; pixel = K * distort(x_cam / z_cam); distortion coefficients
(k1, k2, p1, p2[, k3[, k4, k5, k6[, s1..s4[, tau_x, tau_y]]]]); the model itself (projection and its
exact inverse) is `calib.camera_models`. With the WCS of DESIGN.md the camera must look along +z (towards
the display), so that every ray has a positive z component.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from calib.camera_models import CameraModel, prvm_of
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

    def model(self, name: str = "cam0") -> CameraModel:
        """The camera as a `calib.camera_models.CameraModel` (OpenCV lens, skew K[0, 1])."""
        return CameraModel(self.K[0, 0], self.K[1, 1], self.K[0, 2], self.K[1, 2], self.K[0, 1], "opencv",
                           self.dist, self.R, self.t, self.width, self.height, name)


def prvm_from_opencv(K, dist, rvec, tvec, width: int, height: int, *, reference_z_mm: float = 0.0,
                     camera: str = "cam0") -> PRVM:
    """The PRVM of an OpenCV-calibrated camera: every pixel's ray through the optical centre.

    Pixels are inverted exactly through the model (`calib.camera_models.unproject`, to 1e-10 pixel).

    Parameters
    ----------
    K : (3, 3) float
        The camera matrix, pixels (K[0, 1] is the skew, which OpenCV itself ignores).
    dist : (n,) float or None
        OpenCV distortion coefficients, any supported length; None: no distortion.
    rvec : (3,) float or (3, 3) float
        The world-to-camera rotation: a Rodrigues vector or a matrix.
    tvec : (3,) float
        The world-to-camera translation, mm (x_cam = R x_world + t).
    width, height : int
        The image size, pixels.
    reference_z_mm : float
        The plane of the rays' origins, world z, mm.
    camera : str
        The camera's name in the PRVM's metadata.

    Returns
    -------
    prvm : PRVM
        (height, width) rays in the world frame, which must have the camera looking along +z (InputError
        otherwise).
    """
    cam = PinholeCamera(K, np.zeros(5) if dist is None else dist, rvec, tvec, width, height)
    prvm = prvm_of(cam.model(camera), reference_z_mm=reference_z_mm,
                   dataset="imported from an OpenCV calibration")
    prvm.meta["opencv"] = {"K": cam.K.tolist(), "dist": cam.dist.tolist(), "rvec": cam.rvec.tolist(),
                           "tvec": cam.t.tolist()}
    return prvm


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


def read_filestorage(path: str | os.PathLike) -> dict:
    """The top-level nodes of an OpenCV FileStorage file (YAML, XML or JSON): matrices as float64 arrays,
    numbers as floats, sequences of numbers as 1-D arrays, strings as str (maps are skipped).
    InputError naming the file if it is missing or not a FileStorage file."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "calibration file is missing")
    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except cv2.error:
        raise InputError(path, "not an OpenCV FileStorage file") from None
    if not fs.isOpened():
        raise InputError(path, "not an OpenCV FileStorage file")
    out = {}
    for name in fs.root().keys():
        node = fs.getNode(name)
        if node.isString():
            out[name] = node.string()
        elif node.isReal() or node.isInt():
            out[name] = float(node.real())
        elif node.isSeq():
            vals = [node.at(i) for i in range(node.size())]
            if all(v.isReal() or v.isInt() for v in vals):
                out[name] = np.array([v.real() for v in vals], np.float64)
        elif node.isMap() and not node.getNode("dt").empty() and not node.getNode("data").empty():
            try:     # an !!opencv-matrix; other maps (no dt, or not a matrix) are skipped
                m = node.mat()
            except cv2.error:
                m = None
            if m is not None:
                out[name] = np.asarray(m, np.float64)
    fs.release()
    return out


def read_opencv_yaml(path: str | os.PathLike) -> PinholeCamera:
    """A camera from OpenCV FileStorage YAML/XML/JSON as `opencv_yaml` writes it.

    Parameters
    ----------
    path : path
        The file: camera_matrix (or K), distortion_coefficients (or D), rotation_matrix (or R, rvec),
        translation_vector (or T, tvec; mm), image_width, image_height; the pose is the identity when
        absent.

    Returns
    -------
    camera : PinholeCamera
        K (3, 3) pixels, dist (n,), the world-to-camera R (3, 3) and t (3,) mm, the image size. InputError
        naming the file if a matrix or the size is missing.
    """
    nodes = read_filestorage(path)

    def mat(*names):
        for name in names:
            if name in nodes:
                if not isinstance(nodes[name], np.ndarray) or nodes[name].size < 3:
                    raise InputError(path, f"{name!r} is not a matrix")
                return nodes[name]
        return None

    K, dist = mat("camera_matrix", "K"), mat("distortion_coefficients", "D")
    rot, t = mat("rotation_matrix", "R", "rvec"), mat("translation_vector", "T", "tvec")
    w, h = nodes.get("image_width"), nodes.get("image_height")
    if K is None or not isinstance(w, float) or not isinstance(h, float):
        raise InputError(path, "needs camera_matrix (or K), image_width and image_height")
    return PinholeCamera(K, np.zeros(5) if dist is None else dist, np.eye(3) if rot is None else rot,
                         np.zeros(3) if t is None else t, int(w), int(h))

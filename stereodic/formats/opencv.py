"""OpenCV FileStorage calibrations (YAML, XML or JSON).

One camera: `camera_matrix` (or K) and `distortion_coefficients` (or D; any of OpenCV's 4, 5, 8, 12 or
14 coefficients, thin prism and tilted sensor included), optional pose `rotation_matrix` / R / `rvec` and
`translation_vector` / T / `tvec` (world to camera, mm; identity when absent) - what
`calib.pinhole.opencv_yaml` writes.
A stereo pair (the stereo_calib sample, cv2.stereoCalibrate): M1 D1 M2 D2 R T with x_2 = R x_1 + T (the
world frame is camera 1's, unless R_wcs and T_wcs give camera 1's world pose, as `stereodic export
--format opencv` writes them). The sample writes intrinsics.yml (M1 D1 M2 D2) and extrinsics.yml (R T R1 R2
P1 P2 Q) apart: both files may be given. The structured-light sample's names (its
calibrationParameters.yml) are read as the same pair: cam1_intrinsics, cam1_distorsion (sic; or
cam1_distortion), cam1_size [width, height], cam2_*, and R, T (`_structured_light_names`), there camera
2's pose in camera 1's frame, x_1 = R x_2 + T (RT_cam1_2_cam2 the same 4x4): read the other way, the
GSoC 2015 statue scans put the torso behind the wall, 4 m away, and corresponding pixels miss their
epipolar lines by 40 px (3.6 px this way).
Image size: image_width and image_height, or image_size / imageSize [width, height]; else --size.
K[0, 1] is kept as the skew (OpenCV's own functions ignore it; it is 0 in what OpenCV writes).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from calib.camera_models import CameraModel
from calib.errors import InputError
from calib.pinhole import read_filestorage

STEREO_KEYS = ("M1", "D1", "M2", "D2", "R", "T")


def _size(nodes: dict) -> tuple[int | None, int | None]:
    if isinstance(nodes.get("image_width"), float) and isinstance(nodes.get("image_height"), float):
        return int(nodes["image_width"]), int(nodes["image_height"])
    for key in ("image_size", "imageSize"):
        v = nodes.get(key)
        if isinstance(v, np.ndarray) and v.size == 2:
            return int(v.ravel()[0]), int(v.ravel()[1])
    return None, None


def _rotation(m: np.ndarray, where, name: str) -> np.ndarray:
    m = np.asarray(m, np.float64)
    if m.size == 3:
        return cv2.Rodrigues(m.reshape(3, 1))[0]
    if m.size != 9:
        raise InputError(where, f"{name!r} is neither a 3x3 rotation nor a rotation vector")
    return m.reshape(3, 3)


def _camera(K, dist, R, t, size, name, where) -> CameraModel:
    K = np.asarray(K, np.float64)
    if K.shape != (3, 3):
        raise InputError(where, f"camera {name!r}: the camera matrix is {K.shape[0]}x{K.shape[1]}, not 3x3")
    dist = np.zeros(0) if dist is None else np.asarray(dist, np.float64).ravel()
    if dist.size not in (0, 4, 5, 8, 12, 14):
        raise InputError(where, f"camera {name!r}: {dist.size} distortion coefficients (OpenCV has 4, 5, 8, 12 "
                                f"or 14)")
    return CameraModel(K[0, 0], K[1, 1], K[0, 2], K[1, 2], K[0, 1], "opencv", dist, R,
                       np.asarray(t, np.float64).ravel(), size[0], size[1], name)


def _structured_light_names(nodes: dict) -> dict:
    """The nodes with OpenCV's structured-light sample's camera keys (cam1_intrinsics, cam1_distorsion,
    cam1_size, cam2_...) renamed to the stereo_calib sample's M1 D1 M2 D2 (and image_size)."""
    out = dict(nodes)
    for i in ("1", "2"):
        if f"cam{i}_intrinsics" in nodes:
            out[f"M{i}"] = nodes[f"cam{i}_intrinsics"]
        for key in (f"cam{i}_distorsion", f"cam{i}_distortion"):
            if key in nodes:
                out[f"D{i}"] = nodes[key]
    if "cam1_size" in nodes and "image_size" not in nodes:
        out["image_size"] = nodes["cam1_size"]
    if "cam1_intrinsics" in nodes and "R" in nodes and "T" in nodes:
        r = np.asarray(nodes["R"], np.float64)
        r = cv2.Rodrigues(r.reshape(3, 1))[0] if r.size == 3 else r.reshape(3, 3)
        out["R"], out["T"] = r.T, -r.T @ np.asarray(nodes["T"], np.float64).ravel()
    return out


def read(paths: list[Path]) -> list[CameraModel]:
    """The camera(s) of one FileStorage file, or of two read as one (module docstring)."""
    nodes = {}
    for p in paths:
        nodes.update(read_filestorage(p))
    where = paths[0]
    nodes = _structured_light_names(nodes)
    size = _size(nodes)
    if any(k in nodes for k in ("M1", "M2", "D1", "D2")):
        missing = [k for k in STEREO_KEYS if k not in nodes]
        if missing:
            raise InputError(paths[-1], f"a stereo calibration needs {' '.join(STEREO_KEYS)}; missing "
                                        f"{', '.join(missing)}")
        r0 = _rotation(nodes["R_wcs"], where, "R_wcs") if "R_wcs" in nodes else np.eye(3)
        t0 = np.asarray(nodes["T_wcs"], np.float64).ravel() if "T_wcs" in nodes else np.zeros(3)
        rel = _rotation(nodes["R"], where, "R")
        T = np.asarray(nodes["T"], np.float64).ravel()
        if T.size != 3:
            raise InputError(where, "'T' is not a 3-vector")
        return [_camera(nodes["M1"], nodes["D1"], r0, t0, size, "1", where),
                _camera(nodes["M2"], nodes["D2"], rel @ r0, rel @ t0 + T, size, "2", where)]
    K = nodes.get("camera_matrix", nodes.get("K"))
    if K is None:
        raise InputError(where, "an OpenCV calibration needs camera_matrix (one camera) or M1 D1 M2 D2 R T "
                                "(a stereo pair)")
    rot = next((nodes[k] for k in ("rotation_matrix", "R", "rvec") if k in nodes), np.eye(3))
    t = next((nodes[k] for k in ("translation_vector", "T", "tvec") if k in nodes), np.zeros(3))
    name = nodes["camera_name"] if isinstance(nodes.get("camera_name"), str) else "cam0"
    return [_camera(K, nodes.get("distortion_coefficients", nodes.get("D")), _rotation(rot, where, "rotation"),
                    t, size, name, where)]

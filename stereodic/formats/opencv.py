"""OpenCV FileStorage calibrations (YAML, XML or JSON), in the layouts OpenCV's own programs write.

One camera:
- `calib.pinhole.opencv_yaml`'s and OpenCV's calibration tutorial (camera_calibration.cpp): camera_matrix,
  distortion_coefficients, image_width, image_height, `flags`, `fisheye_model`; the tutorial's older
  spelling Camera_Matrix, Distortion_Coefficients, image_Width, image_Height, flagValue; the
  interactive-calibration app's dist_coeffs and cameraResolution;
- cv2.fisheye's K and D (4 coefficients), read as the fisheye model.
Optional pose rotation_matrix / R / rvec and translation_vector / T / tvec (world to camera, mm; identity
when absent).
A stereo pair: the stereo_calib sample's M1 D1 M2 D2 R T (x_2 = R x_1 + T), the same as K1 D1 K2 D2
(cv2.stereoCalibrate's and cv2.fisheye.stereoCalibrate's names), or cam1_intrinsics cam1_distorsion (sic;
or cam1_distortion) cam1_size cam2_... R T (OpenCV's structured-light sample data, its
calibrationParameters.yml; there R, T are camera 2's pose in camera 1's frame, x_1 = R x_2 + T: read the
other way, the GSoC 2015 statue scans put the torso 4 m away behind the wall, and corresponding pixels
miss their epipolar lines by 40 px, 3.6 px this way). The world frame is
camera 1's, unless R_wcs and T_wcs give camera 1's world pose (as `stereodic export --format opencv`
writes them). The stereo_calib sample writes intrinsics.yml (M1 D1 M2 D2) and extrinsics.yml (R T R1 R2
P1 P2 Q) apart: both files may be given.

The lens model, read from the content and never guessed silently:
- fisheye_model 1 (the tutorial's cv2.fisheye cameras): the equidistant model, 4 coefficients;
- fisheye_model absent, 4 coefficients named K/D (K1/D1...): cv2.fisheye's output (cv2.calibrateCamera
  gives 5 or more, never 4);
- otherwise OpenCV's full model with 4, 5, 8, 12 or 14 coefficients. `flags` / flagValue (the
  calibration flags of a pinhole camera) must agree with the length: CALIB_RATIONAL_MODEL needs 8,
  CALIB_THIN_PRISM_MODEL 12, CALIB_TILTED_MODEL 14; a file whose flags ask for more is refused.
Image size: image_width and image_height (any case), or image_size / imageSize / cameraResolution /
camN_size [width, height]; else --size. K[0, 1] is kept as the skew (OpenCV's own functions ignore it;
cv2.fisheye's alpha is K[0, 1] / fx).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from calib.camera_models import CameraModel
from calib.errors import InputError
from calib.pinhole import read_filestorage

CALIB_RATIONAL_MODEL, CALIB_THIN_PRISM_MODEL, CALIB_TILTED_MODEL = 1 << 14, 1 << 15, 1 << 18
# (camera matrix, distortion, image size) key names of camera i of a stereo file, i = 1, 2
STEREO_NAMES = (("M{i}", "D{i}", None), ("K{i}", "D{i}", None),
                ("cam{i}_intrinsics", "cam{i}_distorsion", "cam{i}_size"),
                ("cam{i}_intrinsics", "cam{i}_distortion", "cam{i}_size"))
SINGLE_NAMES = (("camera_matrix", "distortion_coefficients"), ("K", "D"), ("camera_matrix", "dist_coeffs"),
                ("cameraMatrix", "distCoeffs"))


def _get(nodes: dict, *names: str):
    """The node of the first of `names` present, matched without regard to case; None if none is."""
    lower = {k.lower(): v for k, v in nodes.items()}
    return next((lower[n.lower()] for n in names if n.lower() in lower), None)


def _size(nodes: dict, key: str | None = None) -> tuple[int | None, int | None]:
    w, h = _get(nodes, "image_width"), _get(nodes, "image_height")
    if isinstance(w, float) and isinstance(h, float):
        return int(w), int(h)
    for k in ((key,) if key else ()) + ("image_size", "imageSize", "cameraResolution"):
        v = _get(nodes, k)
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


def _lens(nodes: dict, dist: np.ndarray, kd_names: bool, name: str, where) -> str:
    """"equidistant" or "opencv" for a camera with coefficients `dist` (module docstring)."""
    fisheye = _get(nodes, "fisheye_model")
    if fisheye is not None and not isinstance(fisheye, float):
        raise InputError(where, "'fisheye_model' should be 0 or 1")
    if fisheye not in (None, 0.0, 1.0):
        raise InputError(where, f"'fisheye_model' is {fisheye:g}: OpenCV writes 0 (pinhole) or 1 (cv2.fisheye)")
    if fisheye == 1.0 or (fisheye is None and kd_names and dist.size == 4):
        if dist.size != 4:
            raise InputError(where, f"camera {name!r}: a cv2.fisheye camera has 4 distortion coefficients, the file "
                                    f"gives {dist.size}")
        return "equidistant"
    if dist.size not in (0, 4, 5, 8, 12, 14):
        raise InputError(where, f"camera {name!r}: {dist.size} distortion coefficients (OpenCV has 4, 5, 8, 12 "
                                f"or 14)")
    flags = _get(nodes, "flags", "flagValue")
    if isinstance(flags, float):
        f = int(flags)
        need, why = max(((14, "CALIB_TILTED_MODEL") if f & CALIB_TILTED_MODEL else (0, ""),
                         (12, "CALIB_THIN_PRISM_MODEL") if f & CALIB_THIN_PRISM_MODEL else (0, ""),
                         (8, "CALIB_RATIONAL_MODEL") if f & CALIB_RATIONAL_MODEL else (0, "")))
        if dist.size < need:
            raise InputError(where, f"camera {name!r}: the flags ({f}) say {why}, which has {need} distortion "
                                    f"coefficients; the file gives {dist.size}")
    return "opencv"


def _camera(nodes, K, dist, R, t, size, name, where, kd_names) -> CameraModel:
    K = np.asarray(K, np.float64)
    if K.shape != (3, 3):
        raise InputError(where, f"camera {name!r}: the camera matrix is {K.shape[0]}x{K.shape[1]}, not 3x3")
    dist = np.zeros(0) if dist is None else np.asarray(dist, np.float64).ravel()
    lens = _lens(nodes, dist, kd_names, name, where)
    return CameraModel(K[0, 0], K[1, 1], K[0, 2], K[1, 2], K[0, 1], lens, dist, R, np.asarray(t, np.float64).ravel(),
                       size[0], size[1], name)


def _stereo_names(nodes: dict) -> tuple[str, str, str | None] | None:
    """The key names (STEREO_NAMES) of a stereo file's cameras, or None for a single camera."""
    for names in STEREO_NAMES:
        if any(names[0].format(i=i) in nodes for i in (1, 2)):
            return names
    return STEREO_NAMES[0] if "D1" in nodes or "D2" in nodes else None




def read(paths: list[Path]) -> list[CameraModel]:
    """The camera(s) of one FileStorage file, or of two read as one (module docstring)."""
    nodes = {}
    for p in paths:
        nodes.update(read_filestorage(p))
    where = paths[0]
    names = _stereo_names(nodes)
    if names is not None:
        keys = [n.format(i=i) for i in (1, 2) for n in names[:2]] + ["R", "T"]
        missing = [k for k in keys if k not in nodes]
        if missing:
            raise InputError(paths[-1], f"a stereo calibration needs {' '.join(keys)}; missing {', '.join(missing)}")
        r0 = _rotation(nodes["R_wcs"], where, "R_wcs") if "R_wcs" in nodes else np.eye(3)
        t0 = np.asarray(nodes["T_wcs"], np.float64).ravel() if "T_wcs" in nodes else np.zeros(3)
        rel = _rotation(nodes["R"], where, "R")
        T = np.asarray(nodes["T"], np.float64).ravel()
        if T.size != 3:
            raise InputError(where, "'T' is not a 3-vector")
        if names[0] == "cam{i}_intrinsics":      # the structured-light sample: x_1 = R x_2 + T (docstring)
            rel, T = rel.T, -rel.T @ T
        kd = names[0] == "K{i}"
        cams = []
        for i, (R, t) in ((1, (r0, t0)), (2, (rel @ r0, rel @ t0 + T))):
            size = _size(nodes, names[2].format(i=i) if names[2] else None)
            cams.append(_camera(nodes, nodes[names[0].format(i=i)], nodes[names[1].format(i=i)], R, t, size, str(i),
                                where, kd))
        return cams
    pair = next(((k, d) for k, d in SINGLE_NAMES if _get(nodes, k) is not None), None)
    if pair is None:
        raise InputError(where, "an OpenCV calibration needs camera_matrix (or K: one camera) or M1 D1 M2 D2 R T "
                                "(or K1 D1 K2 D2 R T, cam1_intrinsics ...: a stereo pair)")
    K, dist = _get(nodes, pair[0]), _get(nodes, pair[1])
    if not isinstance(K, np.ndarray):
        raise InputError(where, f"{pair[0]!r} is not a matrix")
    rot = next((nodes[k] for k in ("rotation_matrix", "R", "rvec") if k in nodes), np.eye(3))
    t = next((nodes[k] for k in ("translation_vector", "T", "tvec") if k in nodes), np.zeros(3))
    name = nodes["camera_name"] if isinstance(nodes.get("camera_name"), str) else "cam0"
    return [_camera(nodes, K, dist, _rotation(rot, where, "rotation"), t, _size(nodes), name, where,
                    pair[0] == "K")]

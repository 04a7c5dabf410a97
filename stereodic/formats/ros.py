"""ROS camera_info YAML (camera_calibration_parsers; what ROS's camera_calibration writes as
ost.yaml and camera drivers load): one camera per file, a stereo pair as two files.

Keys: image_width, image_height, camera_name, camera_matrix / distortion_coefficients /
rectification_matrix / projection_matrix (maps of rows, cols, data), distortion_model: plumb_bob
(OpenCV's k1 k2 p1 p2 k3), rational_polynomial (OpenCV's 8 coefficients) or equidistant (the fisheye
model, k1..k4); other models are refused. One file: the camera's own frame is the world frame. Two files
(left, right of ROS's stereo calibration): each camera's rectification R_i turns its frame into its
rectified frame, and the projection P_i = [f' 0 c'x Tx; 0 f' c'y Ty; 0 0 1 0] shifts the rectified frames
by b_i = (Tx / f'x, Ty / f'y, 0) (Tx = -f'x baseline for the right camera): x_cam_i = R_i^T (Y + b_i)
for a point Y of the left rectified frame; the world frame is the first camera's. Translations in metres
(ROS's unit).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from calib.camera_models import CameraModel
from calib.errors import InputError

MODELS = {"plumb_bob": ("opencv", (5,)), "rational_polynomial": ("opencv", (8,)),
          "equidistant": ("equidistant", (4,))}


def _matrix(d: dict, key: str, shape: tuple[int, int], path: Path, required: bool = True) -> np.ndarray | None:
    node = d.get(key)
    if node is None and not required:
        return None
    try:
        m = np.asarray(node["data"], np.float64)
    except (TypeError, KeyError, ValueError):
        raise InputError(path, f"{key} should be a map with rows, cols and data") from None
    if shape[0] == 1:
        return m.ravel()
    if m.size != shape[0] * shape[1]:
        raise InputError(path, f"{key} should be {shape[0]}x{shape[1]}, the file gives {m.size} numbers")
    return m.reshape(shape)


def _read_one(path: Path) -> tuple[CameraModel, np.ndarray, np.ndarray]:
    """The camera of one file in its own frame, its rectification R (3, 3) and shift b (3,) (docstring)."""
    try:
        d = yaml.safe_load(path.read_text(errors="replace"))
    except yaml.YAMLError as exc:
        raise InputError(path, f"not readable YAML ({str(exc).splitlines()[0]})") from None
    if not isinstance(d, dict) or "camera_matrix" not in d or "distortion_model" not in d:
        raise InputError(path, "not a ROS camera_info YAML (needs camera_matrix and distortion_model)")
    model = str(d["distortion_model"])
    if model not in MODELS:
        raise InputError(path, f"ROS distortion model {model!r} is not supported (supported: {', '.join(MODELS)})")
    lens, counts = MODELS[model]
    K = _matrix(d, "camera_matrix", (3, 3), path)
    k = _matrix(d, "distortion_coefficients", (1, 0), path)
    if k.size not in counts and not (k.size == 0 or not k.any()):
        raise InputError(path, f"{model} has {counts[0]} distortion coefficients, the file gives {k.size}")
    if not k.any():
        k = np.zeros(0)
    R = _matrix(d, "rectification_matrix", (3, 3), path, required=False)
    P = _matrix(d, "projection_matrix", (3, 4), path, required=False)
    b = np.zeros(3) if P is None else np.array([P[0, 3] / P[0, 0], P[1, 3] / P[1, 1], 0.0])
    try:
        w, h = int(d["image_width"]), int(d["image_height"])
    except (KeyError, TypeError, ValueError):
        w = h = None
    name = str(d.get("camera_name") or path.stem)
    cam = CameraModel(K[0, 0], K[1, 1], K[0, 2], K[1, 2], K[0, 1], lens, k, np.eye(3), np.zeros(3), w, h, name)
    return cam, np.eye(3) if R is None else R, b


def read(paths: list[Path]) -> list[CameraModel]:
    """One camera per file; two files as a stereo pair in the first camera's frame (module docstring)."""
    got = [_read_one(p) for p in paths]
    if len(got) == 1:
        return [got[0][0]]
    (_, r1, b1) = got[0]
    cams = []
    for cam, r, b in got:
        cam.R, cam.t = r.T @ r1, r.T @ (b - b1)
        cams.append(cam)
    return cams

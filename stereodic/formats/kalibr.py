"""Kalibr camera chains (`camchain.yaml`, ethz-asl/kalibr's multi-camera calibration output).

Per camera `camN`: camera_model (pinhole), intrinsics [fu, fv, pu, pv] (pixels), distortion_model radtan
(k1, k2, r1, r2 = OpenCV's k1, k2, p1, p2) or equidistant (k1..k4, the fisheye model), distortion_coeffs,
resolution [width, height], and for N >= 1 T_cn_cnm1: the 4x4 transform from camera N-1's frame to camera
N's (x_N = T x_(N-1)), translation in metres; a camera-IMU chain (kalibr_calibrate_imu_camera's
camchain-imucam.yaml) may give instead every camera's T_cam_imu (x_cam = T x_imu), from which the cameras'
relative poses follow. The world frame is cam0's. Some files start with OpenCV's `%YAML:1.0` line (not YAML
1.1: it is skipped). Other camera models (omni, ds, eucm) and distortion models (fov) are refused.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import yaml

from calib.camera_models import CameraModel
from calib.errors import InputError

DISTORTIONS = {"radtan": "opencv", "equidistant": "equidistant", "equi": "equidistant", "none": "opencv"}


def _pose(m, path: Path, what: str) -> tuple[np.ndarray, np.ndarray]:
    """(R, t) of a 4x4 rigid transform given as a list of rows; InputError naming `what` if it is not one."""
    try:
        T = np.asarray(m, np.float64)
    except (TypeError, ValueError):
        T = np.zeros(0)
    if T.shape != (4, 4):
        raise InputError(path, f"{what} is not a 4x4 matrix")
    return T[:3, :3], T[:3, 3]


def read(path: Path) -> list[CameraModel]:
    """The cameras cam0, cam1, ... of a camchain, in cam0's frame (translations as in the file, metres:
    `stereodic.formats.read_calibration` converts)."""
    try:
        text = path.read_text(errors="replace")
        d = yaml.safe_load(re.sub(r"\A\ufeff?%YAML:[^\n]*\n", "", text))
    except yaml.YAMLError as exc:
        raise InputError(path, f"not readable YAML ({str(exc).splitlines()[0]})") from None
    names = sorted((k for k in (d or {}) if isinstance(k, str) and k.startswith("cam") and k[3:].isdigit()),
                   key=lambda k: int(k[3:])) if isinstance(d, dict) else []
    if not names:
        raise InputError(path, "not a Kalibr camchain (no cam0)")
    cams = []
    for i, name in enumerate(names):
        c = d[name]
        if not isinstance(c, dict):
            raise InputError(path, f"{name} is not a camera (a map of camera_model, intrinsics, ...)")
        need = [k for k in ("camera_model", "intrinsics", "distortion_model", "distortion_coeffs", "resolution")
                if k not in c]
        if need:
            raise InputError(path, f"{name} lacks {', '.join(need)}")
        if c["camera_model"] != "pinhole":
            raise InputError(path, f"{name}: Kalibr camera model {c['camera_model']!r} is not supported (pinhole)")
        if c["distortion_model"] not in DISTORTIONS:
            raise InputError(path, f"{name}: distortion model {c['distortion_model']!r} is not supported "
                                   f"(radtan, equidistant)")
        lens = DISTORTIONS[c["distortion_model"]]
        try:
            k = [float(v) for v in c["distortion_coeffs"] or []]
            fu, fv, pu, pv = (float(v) for v in c["intrinsics"])
            w, h = (int(v) for v in c["resolution"])
        except (TypeError, ValueError):
            raise InputError(path, f"{name}: intrinsics, distortion_coeffs and resolution must be lists of "
                                   f"numbers (4, the model's, 2)") from None
        if lens == "opencv" and len(k) not in (0, 4, 5, 8, 12, 14):
            raise InputError(path, f"{name}: radtan has 4 coefficients, got {len(k)}")
        if lens == "equidistant" and len(k) > 4:
            raise InputError(path, f"{name}: equidistant has 4 coefficients, got {len(k)}")
        if i > 0 and "T_cn_cnm1" in c:
            R, t = _pose(c["T_cn_cnm1"], path, f"{name}'s T_cn_cnm1")
            R, t = R @ cams[-1].R, R @ cams[-1].t + t
        elif i > 0 or "T_cam_imu" in c:
            if not all("T_cam_imu" in d[n] for n in names):
                raise InputError(path, f"{name} lacks T_cn_cnm1 (its pose relative to cam{i - 1}) and not every "
                                       f"camera gives T_cam_imu")
            r0, t0 = _pose(d[names[0]]["T_cam_imu"], path, f"{names[0]}'s T_cam_imu")
            ri, ti = _pose(c["T_cam_imu"], path, f"{name}'s T_cam_imu")
            R, t = ri @ r0.T, ti - ri @ r0.T @ t0       # x_i = Ti Tc0^-1 x_cam0
        else:
            R, t = np.eye(3), np.zeros(3)
        cams.append(CameraModel(fu, fv, pu, pv, 0.0, lens, k, R, t, w, h, name))
    return cams

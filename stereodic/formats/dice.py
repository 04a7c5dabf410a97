"""DICe camera systems (Sandia's Digital Image Correlation Engine, src/core/DICe_CameraSystem.cpp).

The XML `DICe_xml_camera_system_file` (a Teuchos ParameterList): sublists "CAMERA 0".."CAMERA 9" with CX
CY FX FY (pixels), FS (the skew K[0, 1], pixels, as DICe's projection and triangulation use it), K1..K6
P1 P2 S1..S4 T1 T2, LENS_DISTORTION_MODEL, IMAGE_HEIGHT_WIDTH "{ h, w }", the world-to-camera pose TX TY TZ
(mm) with either the Euler angles ALPHA BETA GAMMA (degrees, R = Rz(gamma) Ry(beta) Rx(alpha)) or a
rotation_3x3_matrix sublist (ROW 0..2); with extrinsics_relative_camera_to_camera true, the poses of
cameras 1.. are relative to camera 0 (x_i = R_i x_0 + t_i). Lens models (`calib.camera_models`):
NO_LENS_DISTORTION; OPENCV_LENS_DISTORTION (K1 K2 P1 P2 K3 K4 K5 K6 S1..S4 T1 T2 in OpenCV's order and
meaning); K1R1_K2R2_K3R3, K1R2_K2R4_K3R6, K1R3_K2R5_K3R7 (DICe's radial polynomials); VIC3D_LENS_DISTORTION
(VIC-3D's kappa model, K1 K2 K3 = kappa1..3 of r^2, r^4, r^6: what the coefficients of a VIC-3D calibration
mean; DICe's own code evaluates it as K1R1_K2R2_K3R3, marked there as unconfirmed).
The legacy `cal.txt`: one number per line ('#' comments): camera 0's and camera 1's CX CY FX FY FS K1 K2
K3, then camera 1's pose relative to camera 0 (ALPHA BETA GAMMA TX TY TZ, or the nine R entries by rows and
TX TY TZ), then the image height and width; its lens model is K1R1_K2R2_K3R3 and its world frame camera
0's.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from calib.camera_models import CameraModel
from calib.errors import InputError
from stereodic.formats.detect import legacy_dice_values, parse_xml, read_head
from stereodic.formats.vic3d import cardan_to_matrix

OPENCV_ORDER = ("K1", "K2", "P1", "P2", "K3", "K4", "K5", "K6", "S1", "S2", "S3", "S4", "T1", "T2")
RADIAL = {"K1R1_K2R2_K3R3": (0, 1, 2), "K1R2_K2R4_K3R6": (1, 3, 5), "K1R3_K2R5_K3R7": (2, 4, 6)}
NONE = ("NO_LENS_DISTORTION", "NONE")
OPENCV = ("OPENCV_LENS_DISTORTION", "OPENCV_DIS")
VIC3D = ("VIC3D_LENS_DISTORTION", "VIC3D_DIS")


def _params(node) -> dict[str, str]:
    return {p.get("name"): p.get("value", "") for p in node.findall("Parameter")}


def _lists(node) -> dict:
    return {p.get("name"): p for p in node.findall("ParameterList")}


def _vector(text: str, n: int, where, what: str) -> list[float]:
    try:
        vals = [float(v) for v in text.strip().strip("{}").replace(",", " ").split()]
    except ValueError:
        vals = []
    if len(vals) != n:
        raise InputError(where, f"{what} should be {n} numbers, got {text!r}")
    return vals


def _lens(model: str, p: dict[str, float], where, name: str) -> tuple[str, list[float], tuple]:
    if model in NONE:
        return "opencv", [], (2, 4, 6)
    if model in OPENCV:
        return "opencv", [p.get(k, 0.0) for k in OPENCV_ORDER], (2, 4, 6)
    if model in VIC3D:
        return "opencv", [p.get("K1", 0.0), p.get("K2", 0.0), 0.0, 0.0, p.get("K3", 0.0)], (2, 4, 6)
    if model in RADIAL:
        return "radial", [p.get("K1", 0.0), p.get("K2", 0.0), p.get("K3", 0.0)], RADIAL[model]
    raise InputError(where, f"{name}: unknown LENS_DISTORTION_MODEL {model!r} (known: "
                            f"{', '.join(NONE + OPENCV + VIC3D + tuple(RADIAL))})")


def _camera_xml(node, index: int, where) -> CameraModel:
    p = _params(node)
    name = p.get("CAMERA_ID", f"CAMERA {index}")
    num = {}
    for k, v in p.items():
        if k in ("CX", "CY", "FX", "FY", "FS", "TX", "TY", "TZ", "ALPHA", "BETA", "GAMMA") + OPENCV_ORDER:
            try:
                num[k] = float(v)
            except ValueError:
                raise InputError(where, f"{name}: {k} is not a number ({v!r})") from None
    if "FX" not in num or "FY" not in num:
        raise InputError(where, f"{name}: needs FX and FY")
    lens, coeffs, powers = _lens(p.get("LENS_DISTORTION_MODEL", "NO_LENS_DISTORTION"), num, where, name)
    rot = _lists(node).get("rotation_3x3_matrix")
    eulers = any(k in num for k in ("ALPHA", "BETA", "GAMMA"))
    if rot is not None and eulers:
        raise InputError(where, f"{name}: gives both Euler angles and a rotation matrix")
    if rot is not None:
        rows = _params(rot)
        missing = [f"ROW {j}" for j in range(3) if f"ROW {j}" not in rows]
        if missing:
            raise InputError(where, f"{name}: rotation_3x3_matrix lacks {', '.join(missing)}")
        R = np.array([_vector(rows[f"ROW {j}"], 3, where, f"{name}'s rotation ROW {j}") for j in range(3)])
    else:
        R = cardan_to_matrix(num.get("ALPHA", 0.0), num.get("BETA", 0.0), num.get("GAMMA", 0.0))
    w = h = None
    if "IMAGE_HEIGHT_WIDTH" in p:
        h, w = (int(v) for v in _vector(p["IMAGE_HEIGHT_WIDTH"], 2, where, f"{name}'s IMAGE_HEIGHT_WIDTH"))
    return CameraModel(num["FX"], num["FY"], num.get("CX", 0.0), num.get("CY", 0.0), num.get("FS", 0.0), lens,
                       coeffs, R, [num.get("TX", 0.0), num.get("TY", 0.0), num.get("TZ", 0.0)], w, h, name, powers)


def _relative(cams: list[CameraModel]) -> list[CameraModel]:
    """Cameras 1.. given relative to camera 0, moved to camera 0's world frame."""
    r0, t0 = cams[0].R, cams[0].t
    for c in cams[1:]:
        c.R, c.t = c.R @ r0, c.R @ t0 + c.t
    return cams


def _read_xml(path: Path) -> list[CameraModel]:
    root = parse_xml(path)
    top = _params(root)
    if top.get("xml_file_format") != "DICe_xml_camera_system_file":
        raise InputError(path, "not a DICe camera system file (xml_file_format is not DICe_xml_camera_system_file)")
    for custom in ("user_6_param_transform", "user_4x4_param_transform"):
        if custom in top or custom in _lists(root):
            raise InputError(path, f"has a {custom}: DICe's custom transforms are not supported")
    lists = _lists(root)
    cams = []
    for i in range(10):
        if f"CAMERA {i}" not in lists:
            break
        cams.append(_camera_xml(lists[f"CAMERA {i}"], i, path))
    if not cams:
        raise InputError(path, "has no CAMERA 0 sublist")
    if top.get("extrinsics_relative_camera_to_camera", "false").strip().lower() == "true":
        cams = _relative(cams)
    return cams


def _read_txt(path: Path) -> list[CameraModel]:
    vals = legacy_dice_values(read_head(path))
    if vals is None:
        raise InputError(path, "not a DICe cal.txt (24 or 30 numbers, one per line)")
    v = [float(x) for x in vals]
    h, w = int(v[-2]), int(v[-1])
    ext = v[16:-2]
    if len(ext) == 6:
        R, t = cardan_to_matrix(*ext[:3]), ext[3:]
    else:
        R, t = np.array(ext[:9]).reshape(3, 3), ext[9:]
    cams = []
    for i, (intr, pose) in enumerate(((v[0:8], (np.eye(3), np.zeros(3))), (v[8:16], (R, t)))):
        cx, cy, fx, fy, fs, k1, k2, k3 = intr
        cams.append(CameraModel(fx, fy, cx, cy, fs, "radial", [k1, k2, k3], pose[0], pose[1], w, h,
                                f"CAMERA {i}", RADIAL["K1R1_K2R2_K3R3"]))
    return cams


def read(path: Path) -> list[CameraModel]:
    """The cameras of a DICe camera system XML or legacy cal.txt (module docstring)."""
    head = read_head(path).lstrip()
    return _read_xml(path) if head.startswith("<") else _read_txt(path)

"""mrcal camera models (`.cameramodel`, mrcal's doc/cameramodels.org and lensmodels.org).

The file is a Python dict literal (read with `ast.literal_eval`, no code runs): 'lensmodel',
'intrinsics' (fx, fy, cx, cy, then the lens model's parameters), 'extrinsics' = rt_fromref (a Rodrigues
rotation r and a translation t: x_cam = R(r) x_ref + t, the reference frame being the world frame) and
'imagersize' [width, height]; other keys (optimization_inputs, valid_intrinsics_region, ...) are ignored.
One file holds one camera; a stereo pair is two files in one reference frame. Lens models read:
LENSMODEL_PINHOLE and LENSMODEL_OPENCV4/5/8/12 (OpenCV's model with that many coefficients; mrcal's
pixel coordinates are OpenCV's).
"""

from __future__ import annotations

import ast
from pathlib import Path

import cv2
import numpy as np

from calib.camera_models import CameraModel
from calib.errors import InputError
from stereodic.formats.detect import read_head

OPENCV_MODELS = {"LENSMODEL_PINHOLE": 0, "LENSMODEL_OPENCV4": 4, "LENSMODEL_OPENCV5": 5, "LENSMODEL_OPENCV8": 8,
                 "LENSMODEL_OPENCV12": 12}


def _read_one(path: Path, index: int) -> CameraModel:
    try:
        d = ast.literal_eval(read_head(path, 1 << 30))
    except (ValueError, SyntaxError, MemoryError, RecursionError):
        raise InputError(path, "not a mrcal .cameramodel (not a Python dict literal)") from None
    if not isinstance(d, dict) or "lensmodel" not in d or "intrinsics" not in d:
        raise InputError(path, "not a mrcal .cameramodel (needs 'lensmodel' and 'intrinsics')")
    model = str(d["lensmodel"])
    if model not in OPENCV_MODELS:
        raise InputError(path, f"mrcal lens model {model} is not supported (supported: {', '.join(OPENCV_MODELS)})")
    intr = np.asarray(d["intrinsics"], np.float64).ravel()
    if intr.size != 4 + OPENCV_MODELS[model]:
        raise InputError(path, f"{model} has {4 + OPENCV_MODELS[model]} intrinsics, the file gives {intr.size}")
    rt = np.asarray(d.get("extrinsics", np.zeros(6)), np.float64).ravel()
    if rt.size != 6:
        raise InputError(path, "'extrinsics' should be the 6 numbers of rt_fromref")
    w = h = None
    if "imagersize" in d:
        w, h = (int(v) for v in d["imagersize"])
    fx, fy, cx, cy = intr[:4]
    return CameraModel(fx, fy, cx, cy, 0.0, "opencv", intr[4:], cv2.Rodrigues(rt[:3].reshape(3, 1))[0], rt[3:],
                       w, h, path.stem if path.stem else f"cam{index}")


def read(paths: list[Path]) -> list[CameraModel]:
    """One camera per .cameramodel file, in the order given."""
    return [_read_one(p, i) for i, p in enumerate(paths)]


def write(cam: CameraModel) -> str:
    """The .cameramodel text of one camera (OpenCV lens without tilted sensor, no skew: mrcal has neither)."""
    k = cam.coefficients
    if cam.lens != "opencv" or k[12] != 0 or k[13] != 0:
        raise InputError(None, f"camera {cam.name!r}: mrcal's OpenCV models have no tilted sensor")
    if cam.skew != 0:
        raise InputError(None, f"camera {cam.name!r}: mrcal's lens models have no skew")
    n = next((m for m in (0, 4, 5, 8, 12) if not np.any(k[m:])), 12)
    model = "LENSMODEL_PINHOLE" if n == 0 else f"LENSMODEL_OPENCV{n}"
    rt = np.concatenate([cv2.Rodrigues(cam.R)[0].ravel(), cam.t])

    def vec(v):
        return "[ " + ", ".join(f"{x:.17g}" for x in v) + ",]"

    return "\n".join([f"# {cam.name}: written by stereodic", "{", f"    'lensmodel':  '{model}',",
                      "    # intrinsics are fx,fy,cx,cy,distortion0,distortion1,....",
                      f"    'intrinsics': {vec([cam.fx, cam.fy, cam.cx, cam.cy, *k[:n]])},",
                      "    # extrinsics are rt_fromref", f"    'extrinsics': {vec(rt)},",
                      f"    'imagersize': [ {cam.width}, {cam.height},],", "}"]) + "\n"

"""A rectified rig for legacy stereo software: the two virtual pinhole cameras, distortion zero (the
virtual images are distortion free), in the formats such software reads.

The virtual cameras (`stereodic.virtual.export.pinhole_of`) share the rotation R_v = [axis_u; axis_v; normal] and
the plane distance d, so their camera matrices differ only in cx (by |baseline| / pitch_u): the pair is
already rectified. In OpenCV's stereo terms (stereo_calib sample: x2 = R x1 + T, frames of camera 1):
  M1, M2 = the virtual camera matrices, D1 = D2 = 0, R = I, T = (-|b|, 0, 0) mm, R1 = R2 = I,
  P1 = [M1 | 0], P2 = [M2 | M2 T], Q = [[1, 0, 0, -cx1], [0, fx/fy, 0, -cy fx/fy], [0, 0, 0, fx],
  [0, 0, -1/Tx, (cx1 - cx2)/Tx]] for the disparity xL - xR (exact also for non-square pixels),
and the WCS pose of camera 1, R_wcs = R_v and T_wcs = -R_v C_L (x_cam1 = R_wcs X + T_wcs), which turns
the points of cv2.triangulatePoints / reprojectImageTo3D into the WCS. These reproduce the pinhole
triangulation exactly; the EVM (the real rays' correction) cannot be expressed in these formats.

Formats: opencv (FileStorage YAML with the keys above plus image_width, image_height, R_wcs, T_wcs);
dice (DICe camera system XML: CAMERA 0 / CAMERA 1 with CX CY FX FY FS, IMAGE_HEIGHT_WIDTH, no lens
distortion, world-to-camera rotation_3x3_matrix and TX TY TZ in the WCS, mm); vic3d (VIC-3D project XML:
cx cy fx fy skew and zero kappas, Cardan-Bryant orientation, image size; `stereodic.formats.vic3d`);
mrcal (a folder with left.cameramodel and right.cameramodel, LENSMODEL_PINHOLE, rt_fromref in mm;
`stereodic.formats.mrcal`); colmap (a text model folder: cameras.txt, images.txt with the two posed images
"left.png" and "right.png", empty points3D.txt); json (both cameras' sensor plane, centre and OpenCV
intrinsics/pose, and the stereo matrices).
Every pose is written in the rig's world frame: the rig's own frame moved by its `world_from_rig` (for a
rig made by `stereodic import`, the calibration file's world frame), so `stereodic import` of an export
gives back the same rays.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from xml.sax.saxutils import quoteattr

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from calib.atomic import write_text
from calib.errors import InputError
from calib.pinhole import PinholeCamera
from stereodic.virtual.export import camera_json, colmap_cameras, in_world, pinhole_of
from stereodic.formats import mrcal, vic3d
from stereodic.stereo.rig import SIDES, Rig, load_rig

FORMATS = ("opencv", "colmap", "dice", "json", "vic3d", "mrcal")


def rig_pinholes(rig: Rig) -> tuple[PinholeCamera, PinholeCamera]:
    """The left and right virtual pinhole cameras (K, zero distortion, pose in the rig's world frame)."""
    return tuple(in_world(pinhole_of(rig.virtual_camera(s)), rig.world_from_rig) for s in SIDES)


def stereo_matrices(rig: Rig) -> dict[str, np.ndarray]:
    """OpenCV's stereo matrices of the rig (module docstring).

    Parameters
    ----------
    rig : Rig
        The rectified pair (`build_rig`, `load_rig`).

    Returns
    -------
    matrices : dict of str to ndarray
        float64: M1, M2 (3, 3) camera matrices, virtual px; D1, D2 (1, 5) zeros; R (3, 3) and T (3, 1)
        mm, camera 1 -> camera 2; R1, R2 (3, 3) identity; P1, P2 (3, 4); Q (4, 4) for the disparity
        xL - xR; R_wcs (3, 3) and T_wcs (3, 1) mm, the world frame -> camera 1 (x_cam1 = R_wcs X + T_wcs).
    """
    left, right = rig_pinholes(rig)
    rot = right.R @ left.R.T
    t = right.t - rot @ left.t
    m1, m2 = left.K, right.K
    tx = t[0]
    fx, fy, cx1, cy, cx2 = m1[0, 0], m1[1, 1], m1[0, 2], m1[1, 2], m2[0, 2]
    q = np.array([[1, 0, 0, -cx1], [0, fx / fy, 0, -cy * fx / fy], [0, 0, 0, fx],
                  [0, 0, -1 / tx, (cx1 - cx2) / tx]])
    return {"M1": m1, "D1": np.zeros((1, 5)), "M2": m2, "D2": np.zeros((1, 5)), "R": rot, "T": t.reshape(3, 1),
            "R1": np.eye(3), "R2": np.eye(3), "P1": np.hstack([m1, np.zeros((3, 1))]),
            "P2": np.hstack([m2, (m2 @ t).reshape(3, 1)]), "Q": q, "R_wcs": left.R, "T_wcs": left.t.reshape(3, 1)}


def opencv_stereo_yaml(rig: Rig) -> str:
    """OpenCV FileStorage YAML of `stereo_matrices` with image_width and image_height."""
    fs = cv2.FileStorage(".yaml", cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY)
    fs.write("image_width", rig.sensor.width)
    fs.write("image_height", rig.sensor.height)
    for key, value in stereo_matrices(rig).items():
        fs.write(key, value)
    return fs.releaseAndGetString()


def dice_xml(rig: Rig) -> str:
    """DICe camera system file (XML ParameterList) of the two virtual cameras."""
    def param(name, kind, value):
        return f'  <Parameter name={quoteattr(name)} type="{kind}" value={quoteattr(str(value))} />'

    def vec(v):
        return "{ " + ", ".join(f"{x:.17g}" for x in v) + " }"

    lines = ["<ParameterList>", "<!-- stereodic rectified virtual stereo pair: distortion-free virtual images,",
             "     extrinsics world (stereodic WCS, mm) to camera -->",
             param("xml_file_format", "string", "DICe_xml_camera_system_file"),
             param("system_type_3D", "string", "OPENCV"),
             param("extrinsics_relative_camera_to_camera", "bool", "false")]
    for i, (side, cam) in enumerate(zip(SIDES, rig_pinholes(rig))):
        lines.append(f'  <ParameterList name="CAMERA {i}">')
        lines.append(param("CAMERA_ID", "string", f"{side} ({rig.camera(side).name}, virtual)"))
        for name, value in (("CX", cam.K[0, 2]), ("CY", cam.K[1, 2]), ("FX", cam.K[0, 0]), ("FY", cam.K[1, 1]),
                            ("FS", 0.0), ("TX", cam.t[0]), ("TY", cam.t[1]), ("TZ", cam.t[2])):
            lines.append("  " + param(name, "double", f"{value:.17g}"))
        lines.append("  " + param("LENS_DISTORTION_MODEL", "string", "NO_LENS_DISTORTION"))
        lines.append("  " + param("IMAGE_HEIGHT_WIDTH", "string", f"{{ {cam.height}, {cam.width} }}"))
        lines.append('    <ParameterList name="rotation_3x3_matrix">')
        lines += ["    " + param(f"ROW {j}", "string", vec(cam.R[j])) for j in range(3)]
        lines += ["    </ParameterList>", "  </ParameterList>"]
    return "\n".join(lines + ["</ParameterList>"]) + "\n"


def colmap_images(cameras: list[PinholeCamera], names: list[str]) -> str:
    """COLMAP `images.txt`: one posed image per camera (world-to-camera quaternion QW QX QY QZ and
    translation, mm), camera ids from 1, no 2D points."""
    lines = ["# Image list with two lines of data per image:",
             "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME", "#   POINTS2D[] as (X, Y, POINT3D_ID)",
             f"# Number of images: {len(cameras)}, mean observations per image: 0"]
    for i, (cam, name) in enumerate(zip(cameras, names), 1):
        q = _quaternion(cam.R)
        lines += [f"{i} " + " ".join(f"{v:.17g}" for v in (*q, *cam.t)) + f" {i} {name}", ""]
    return "\n".join(lines) + "\n"


def _quaternion(r: np.ndarray) -> np.ndarray:
    """(w, x, y, z) unit quaternion of a rotation matrix, w >= 0."""
    x, y, z, w = Rotation.from_matrix(r).as_quat()
    return np.array([w, x, y, z]) * (1.0 if w >= 0 else -1.0)


def rig_json(rig: Rig) -> dict:
    """The rig as JSON data: both virtual cameras and the OpenCV stereo matrices."""
    return {"format": "stereodic.stereo.rig-export/1", "model": rig.model, "baseline_mm": rig.baseline.tolist(),
            "working_distance_mm": rig.working_distance_mm, "world_from_rig": rig.world_from_rig.tolist(),
            "cameras": [camera_json(side, rig.virtual_camera(side)) for side in SIDES],
            "stereo": {k: v.tolist() for k, v in stereo_matrices(rig).items()}}


def export_rig(path: str | os.PathLike, out: str | os.PathLike, *, fmt: str) -> None:
    """Write the rig file at `path` to `out` in another program's format.

    Parameters
    ----------
    path : path
        A RIG.npz (`save_rig`).
    out : path
        The output file; a folder for ``mrcal`` (left/right.cameramodel) and ``colmap`` (cameras.txt,
        images.txt, points3D.txt).
    fmt : str
        One of FORMATS: ``opencv``, ``dice``, ``json``, ``vic3d``, ``mrcal``, ``colmap`` (module
        docstring); every pose in the rig's world frame, mm.

    Returns
    -------
    None
        The file (or folder) is written; an unknown `fmt` raises InputError.
    """
    rig = load_rig(path)
    if fmt == "opencv":
        write_text(out, opencv_stereo_yaml(rig))
    elif fmt == "dice":
        write_text(out, dice_xml(rig))
    elif fmt == "json":
        write_text(out, json.dumps(rig_json(rig), indent=1) + "\n")
    elif fmt == "vic3d":
        write_text(out, vic3d.write([p.model(f"camera {i}") for i, p in enumerate(rig_pinholes(rig))]))
    elif fmt == "mrcal":
        out = Path(out)
        if out.exists() and not out.is_dir():
            raise InputError(out, "the mrcal export of a rig is a folder (left.cameramodel, right.cameramodel)")
        for side, cam in zip(SIDES, rig_pinholes(rig)):
            write_text(out / f"{side}.cameramodel", mrcal.write(cam.model(side)))
    elif fmt == "colmap":
        out = Path(out)
        if out.exists() and not out.is_dir():
            raise InputError(out, "the colmap export is a folder (cameras.txt, images.txt, points3D.txt)")
        cams = list(rig_pinholes(rig))
        write_text(out / "cameras.txt", colmap_cameras(cams))
        write_text(out / "images.txt", colmap_images(cams, ["left.png", "right.png"]))
        write_text(out / "points3D.txt", "# 3D point list: empty (cameras only)\n")
    else:
        raise InputError(None, f"unknown export format {fmt!r} (known: {', '.join(FORMATS)})")

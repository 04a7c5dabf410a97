"""VIC-3D calibrations (Correlated Solutions): the project or calibration XML.

Per camera, `<camera id="N">cx cy fx fy skew kappa1 kappa2 kappa3<orientation>alpha beta gamma tx ty
tz</orientation></camera>` inside `<calibration>`: pixels; the radial distortion
x_d = x (1 + kappa1 r^2 + kappa2 r^4 + kappa3 r^6) of the normalised coordinates, then
u = fx x_d + skew y_d + cx, v = fy y_d + cy (Sutton, Orteu & Schreier, "Image Correlation for Shape, Motion
and Deformation Measurements", ch. 3); the world-to-camera pose x_cam = R x_world + t with the
Cardan-Bryant angles in degrees, R = Rz(gamma) Ry(beta) Rx(alpha) (DICe's reader, DICe_Camera.cpp
eulers_to_rotation_matrix), t in mm. The image size is the `<polygonmask width= height=>` of the project's
area of interest; a calibration without one needs --size. VIC-3D's world frame usually has the cameras
looking along -z: `calib.camera_models.prvms_of` handles that.
"""

from __future__ import annotations

from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np

from calib.camera_models import CameraModel
from calib.errors import InputError
from stereodic.formats.detect import parse_xml


def cardan_to_matrix(alpha: float, beta: float, gamma: float) -> np.ndarray:
    """(3, 3) R = Rz(gamma) Ry(beta) Rx(alpha), angles in degrees."""
    a, b, g = np.radians([alpha, beta, gamma])
    rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    ry = np.array([[np.cos(b), 0, np.sin(b)], [0, 1, 0], [-np.sin(b), 0, np.cos(b)]])
    rz = np.array([[np.cos(g), -np.sin(g), 0], [np.sin(g), np.cos(g), 0], [0, 0, 1]])
    return rz @ ry @ rx


def matrix_to_cardan(R: np.ndarray) -> tuple[float, float, float]:
    """(alpha, beta, gamma) degrees of R = Rz(gamma) Ry(beta) Rx(alpha), beta in [-90, 90]."""
    beta = np.arcsin(-np.clip(R[2, 0], -1.0, 1.0))
    if abs(np.cos(beta)) > 1e-12:
        alpha, gamma = np.arctan2(R[2, 1], R[2, 2]), np.arctan2(R[1, 0], R[0, 0])
    else:   # gimbal lock: put the whole rotation about x
        alpha, gamma = np.arctan2(-R[1, 2], R[1, 1]), 0.0
    return tuple(float(v) for v in np.degrees([alpha, beta, gamma]))


def _numbers(text: str | None, n: int, where, what: str) -> list[float]:
    try:
        vals = [float(v) for v in (text or "").split()]
    except ValueError:
        vals = []
    if len(vals) != n:
        raise InputError(where, f"{what} should be {n} numbers")
    return vals


def read(path: Path) -> list[CameraModel]:
    """The cameras of a VIC-3D project/calibration XML, by id order."""
    root = parse_xml(path)
    cal = root if root.tag == "calibration" else root.find(".//calibration")
    if cal is None or not cal.findall("camera"):
        raise InputError(path, "has no <calibration> with <camera> entries")
    mask = root.find(".//polygonmask")
    w = h = None
    if mask is not None and mask.get("width") and mask.get("height"):
        w, h = int(float(mask.get("width"))), int(float(mask.get("height")))
    cams = []
    for node in sorted(cal.findall("camera"), key=lambda c: int(c.get("id", "0"))):
        name = f"camera {node.get('id', len(cams))}"
        cx, cy, fx, fy, skew, k1, k2, k3 = _numbers(node.text, 8, path, f"{name}'s intrinsics")
        orient = node.find("orientation")
        if orient is None:
            raise InputError(path, f"{name} has no <orientation>")
        a, b, g, tx, ty, tz = _numbers(orient.text, 6, path, f"{name}'s orientation")
        cams.append(CameraModel(fx, fy, cx, cy, skew, "opencv", [k1, k2, 0, 0, k3], cardan_to_matrix(a, b, g),
                                [tx, ty, tz], w, h, name))
    return cams


def write(cams: list[CameraModel]) -> str:
    """VIC-3D project XML of `cams` (VIC-3D's lens model only: OpenCV lens with k1, k2, k3; one image size)."""
    lines = ['<?xml version="1.0" encoding="UTF-8"?>', "<!-- written by stereodic -->", "<project>",
             ' <calibration lri="calibration">']
    for i, c in enumerate(cams):
        k = c.coefficients
        if c.lens != "opencv" or np.any(k[[2, 3]] != 0) or np.any(k[5:] != 0):
            raise InputError(None, f"camera {c.name!r}: VIC-3D's lens model has kappa1..3 only")
        a, b, g = matrix_to_cardan(c.R)
        intr = " ".join(f"{v:.17g}" for v in (c.cx, c.cy, c.fx, c.fy, c.skew, k[0], k[1], k[4]))
        pose = " ".join(f"{v:.17g}" for v in (a, b, g, *c.t))
        lines.append(f'  <camera id="{i}">{intr}<orientation>{pose}</orientation>')
        lines.append("  </camera>")
    lines += [" </calibration>", ' <projectaois lri="projectaois">', '  <aoinode lri="aoinode">',
              f"   <polygonmask width={quoteattr(str(cams[0].width))} height={quoteattr(str(cams[0].height))} "
              f'lri="polygonmask"/>', "  </aoinode>", " </projectaois>", "</project>"]
    return "\n".join(lines) + "\n"

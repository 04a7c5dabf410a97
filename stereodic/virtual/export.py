"""Virtual cameras for other software: the pinhole model of a virtual pinhole camera (distortion
coefficients all zero: its images are distortion free) as OpenCV FileStorage YAML, COLMAP `cameras.txt`
or JSON.

The virtual pinhole camera with optical centre C and sensor plane (origin O, axes a_u, a_v, normal n,
pitches p_u, p_v) is the OpenCV camera R = [a_u; a_v; n] (rows), t = -R C, fx = d / p_u, fy = d / p_v,
cx = (F - O) . a_u / p_u, cy = (F - O) . a_v / p_v, with d = (O - C) . n the plane's distance and
F = C + d n the foot of the perpendicular from C (see `VirtualSensor.from_pinhole` for the reverse).
"""

from __future__ import annotations

import json

import numpy as np

from calib.errors import InputError
from calib.pinhole import PinholeCamera, opencv_yaml
from stereodic.formats import mrcal, vic3d
from stereodic.virtual.camera import VirtualCamera

FORMATS = ("opencv", "colmap", "json", "vic3d", "mrcal")


def pinhole_of(camera: VirtualCamera) -> PinholeCamera:
    """The OpenCV pinhole camera that is a pinhole virtual camera (module docstring).

    Parameters
    ----------
    camera : VirtualCamera
        A virtual camera of model "pinhole" (InputError otherwise), WCS mm.

    Returns
    -------
    pinhole : PinholeCamera
        K (3, 3) virtual pixels, distortion zero, the WCS-to-camera R (3, 3) and t (3,) mm, the virtual
        size. InputError if the sensor plane is behind the optical centre.
    """
    if camera.model != "pinhole":
        raise InputError(None, f"a {camera.model} virtual camera has no pinhole model (use the pinhole model)")
    s, c = camera.sensor, camera.centre
    R = np.stack([s.axis_u, s.axis_v, s.normal])
    d = (s.origin - c) @ s.normal
    if d <= 0:
        raise InputError(None, "the virtual sensor plane is behind the optical centre")
    foot = c + d * s.normal
    K = np.array([[d / s.pitch_mm[0], 0, (foot - s.origin) @ s.axis_u / s.pitch_mm[0]],
                  [0, d / s.pitch_mm[1], (foot - s.origin) @ s.axis_v / s.pitch_mm[1]],
                  [0, 0, 1]])
    return PinholeCamera(K, np.zeros(5), R, -R @ c, s.width, s.height)


def in_world(cam: PinholeCamera, world_from_rig: np.ndarray) -> PinholeCamera:
    """`cam` (posed in the rig's frame) posed in the world frame instead: x_cam = R x_rig + t and
    x_rig = A^T (x_world - b) for world_from_rig = [A | b] give R' = R A^T, t' = t - R A^T b."""
    m = np.asarray(world_from_rig, np.float64)
    rot = cam.R @ m[:3, :3].T
    return PinholeCamera(cam.K, cam.dist, rot, cam.t - rot @ m[:3, 3], cam.width, cam.height)


def colmap_cameras(cameras: list[PinholeCamera]) -> str:
    """COLMAP `cameras.txt`: one PINHOLE camera (fx fy cx cy) per line, ids from 1. COLMAP puts integer
    coordinates at pixel corners, so cx, cy are shifted by +0.5 from OpenCV's."""
    lines = ["# Camera list with one line of data per camera:",
             "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]", f"# Number of cameras: {len(cameras)}"]
    for i, cam in enumerate(cameras, 1):
        K = cam.K
        lines.append(f"{i} PINHOLE {cam.width} {cam.height} {K[0, 0]:.17g} {K[1, 1]:.17g} "
                     f"{K[0, 2] + 0.5:.17g} {K[1, 2] + 0.5:.17g}")
    return "\n".join(lines) + "\n"


def camera_json(name: str, camera: VirtualCamera) -> dict:
    """A virtual camera as JSON data: its model, sensor plane (WCS mm) and, for a pinhole camera, the
    OpenCV intrinsics and pose (K, dist, R, t: x_cam = R x_world + t, mm)."""
    d = {"name": name, **camera.to_dict()}
    if camera.model == "pinhole":
        p = pinhole_of(camera)
        d["opencv"] = {"width": p.width, "height": p.height, "K": p.K.tolist(), "dist": p.dist.tolist(),
                       "R": p.R.tolist(), "t": p.t.tolist()}
    return d


def export_text(cameras: dict[str, VirtualCamera], *, fmt: str, world_from_rig: np.ndarray | None = None) -> str:
    """Virtual cameras as the text of another program's camera file.

    Parameters
    ----------
    cameras : dict of str to VirtualCamera
        Name -> virtual camera (pinhole, except for "json").
    fmt : str
        One of FORMATS: "opencv" and "mrcal" hold one camera, "colmap", "json", "vic3d" any number.
    world_from_rig : (4, 4) float, optional
        Rig frame -> world frame, mm: the poses are written in the world frame; None: the identity.

    Returns
    -------
    text : str
        The file's text. InputError for an unknown format or too many cameras for it.
    """
    m = np.eye(4) if world_from_rig is None else np.asarray(world_from_rig, np.float64)
    if fmt == "json":
        return json.dumps({"format": "stereodic.virtual.camera-cameras/1", "world_from_rig": m.tolist(),
                           "cameras": [camera_json(n, c) for n, c in cameras.items()]}, indent=1) + "\n"
    pinholes = [in_world(pinhole_of(c), m) for c in cameras.values()]
    if fmt == "vic3d":
        return vic3d.write([p.model(n) for p, n in zip(pinholes, cameras)])
    if fmt == "mrcal":
        if len(pinholes) != 1:
            raise InputError(None, "a mrcal camera model holds one camera")
        return mrcal.write(pinholes[0].model(next(iter(cameras))))
    if fmt == "colmap":
        return colmap_cameras(pinholes)
    if fmt == "opencv":
        if len(pinholes) != 1:
            raise InputError(None, "the OpenCV YAML export holds one camera")
        return opencv_yaml(pinholes[0])
    raise InputError(None, f"unknown export format {fmt!r} (known: {', '.join(FORMATS)})")

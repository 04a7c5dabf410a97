"""Other programs' calibration files: one small reader (and, where we export to it, writer) per format.

Every reader returns the file's cameras as `calib.camera_models.CameraModel`s in file order, each in
the file's own world frame and with its own lens model exactly (`calib.camera_models`); the first two
cameras of a stereo file are the left (reference) and the right camera. `read_calibration` picks the
reader (`detect.detect_format` when the format is "auto") and fills in the image size from `size` where
the file has none.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from calib.camera_models import CameraModel
from calib.errors import InputError
from calib.prvm_file import PRVM

FORMATS = ("opencv", "vic3d", "dice", "mrcal", "kalibr", "ros")
UNITS = {"mm": 1.0, "m": 1000.0}
DEFAULT_UNITS = {"opencv": "mm", "vic3d": "mm", "dice": "mm", "mrcal": "mm", "kalibr": "m", "ros": "m"}
MULTI_FILE = ("mrcal", "opencv", "ros")    # formats whose stereo pair may be two files


def read_calibration(paths: list[str | os.PathLike], fmt: str = "auto", *, size: tuple[int, int] | None = None,
                     units: str | None = None) -> tuple[str, list[CameraModel]]:
    """(format, cameras) of the calibration in `paths` (one file; or two: a stereo pair of mrcal
    .cameramodel files or ROS camera_info files, or OpenCV's stereo_calib pair intrinsics.yml +
    extrinsics.yml), translations in mm.
    `size` (width, height) is used for cameras whose file gives no image size; `units` ("mm" or "m") is the
    unit of the file's translations (default: the format's, DEFAULT_UNITS: Kalibr and ROS write metres; OpenCV's
    and mrcal's are those of the calibration target, taken as mm). InputError naming the file when a size
    is needed and not given, or when the file is not a calibration of the format."""
    from stereodic.formats import dice, kalibr, mrcal, opencv, ros, vic3d
    from stereodic.formats.detect import detect_format
    paths = [Path(p) for p in paths]
    for p in paths:
        if not p.is_file():
            raise InputError(p, "calibration file is missing")
    if fmt == "auto":
        kinds = [detect_format(p) for p in paths]
        if len(set(kinds)) > 1:
            raise InputError(paths[1], f"is a {kinds[1]} file but {paths[0]} is {kinds[0]}")
        fmt = kinds[0]
    if fmt not in FORMATS:
        raise InputError("--format", f"unknown calibration format {fmt!r} (known: auto, {', '.join(FORMATS)})")
    if len(paths) > 2 or (len(paths) == 2 and fmt not in MULTI_FILE):
        raise InputError(paths[-1], f"a {fmt} calibration is one file" if fmt not in MULTI_FILE else
                         "at most two files make a calibration")
    reader = {"opencv": opencv.read, "vic3d": vic3d.read, "dice": dice.read, "mrcal": mrcal.read,
              "kalibr": kalibr.read, "ros": ros.read}[fmt]
    cams = reader(paths if fmt in MULTI_FILE else paths[0])
    for cam in cams:
        if cam.width is None or cam.height is None:
            if size is None:
                raise InputError(paths[0], f"the {fmt} file gives no image size for camera {cam.name!r}: "
                                           f"give it with --size WIDTHxHEIGHT")
            cam.width, cam.height = int(size[0]), int(size[1])
    units = units or DEFAULT_UNITS[fmt]
    if units not in UNITS:
        raise InputError("--units", f"unknown unit {units!r} (known: {', '.join(UNITS)})")
    for cam in cams:
        cam.t = cam.t * UNITS[units]
    return fmt, cams


def select(cams: list[CameraModel], names: list[str] | None, where) -> list[CameraModel]:
    """The cameras named in `names`, all of them when None. A name is matched exactly against the cameras'
    names in the file; "#N" is the camera at 0-based position N (the only way to pick an unnamed one).
    InputError naming `where` for a name the file does not have, or one that several cameras share."""
    if names is None:
        return cams
    listing = ", ".join(f"#{i} {c.name!r}" for i, c in enumerate(cams))
    out = []
    for n in names:
        if n.startswith("#") and n[1:].isdigit():
            if int(n[1:]) >= len(cams):
                raise InputError(where, f"has no camera {n} (it has {listing})")
            out.append(cams[int(n[1:])])
            continue
        hit = [c for c in cams if c.name == n]
        if not hit:
            raise InputError(where, f"has no camera named {n!r} (it has {listing}; #N picks by position)")
        if len(hit) > 1:
            raise InputError(where, f"has {len(hit)} cameras named {n!r} ({listing}): pick one by position, #N")
        out.append(hit[0])
    return out


GEOMETRY_PIXELS = 250_000   # a rig's plane and common field are placed on PRVMs of about this many pixels


@dataclass
class Imported:
    """What `import_calibration` made: the file's format, the cameras used, the result (the one camera's
    PRVM, or the rig: a `stereodic.stereo.rig.Rig`) and, on demand, every used camera's full PRVM (`prvms`, in
    the internal frame of `calib.camera_models.rig_frame`; a rig is built without them)."""

    format: str
    cameras: list[CameraModel]
    result: object
    where: object = None
    dataset: str = ""
    _prvms: list[PRVM] | None = field(default=None, repr=False)

    @property
    def prvms(self) -> list[PRVM]:
        """The used cameras' full PRVMs (every pixel's ray), computed on the first request."""
        if self._prvms is None:
            from calib.camera_models import prvms_of
            self._prvms = prvms_of(self.cameras, where=self.where, dataset=self.dataset)
        return self._prvms


def import_calibration(paths: list[str | os.PathLike], *, fmt: str = "auto", size=None, units=None,
                       cameras: list[str] | None = None, model: str = "pinhole", virtual_size=None,
                       pitch_mm=None, plane_z_mm: float | None = None) -> Imported:
    """The stereodic file of another program's calibration: one camera's PRVM, or two cameras' rig.

    The rays are in the internal frame of `calib.camera_models.prvms_of`; the rig's (or the PRVM's meta)
    world_from_rig leads back to the file's world frame.

    Parameters
    ----------
    paths : list of path
        One calibration file; or two: a stereo pair of mrcal .cameramodel files or ROS camera_info files,
        or OpenCV's stereo_calib intrinsics.yml + extrinsics.yml.
    fmt : str
        "auto" (`detect.detect_format`) or one of FORMATS.
    size : (int, int), optional
        (width, height) pixels, for cameras whose file gives no image size.
    units : {"mm", "m"}, optional
        The unit of the file's translations; None: the format's (DEFAULT_UNITS).
    cameras : list of str, optional
        One or two cameras by exact name, or by 0-based position as "#N" (`select`); None: all, which
        must be one or two.
    model, virtual_size, pitch_mm, plane_z_mm
        For two cameras, as `stereodic.stereo.rig.build_rig`'s model, (width, height), pitch_mm and plane_z_mm;
        plane_z_mm None: the cameras' working point.

    Returns
    -------
    imported : Imported
        The format, the cameras used, their PRVMs and ``result``: the one camera's `calib.prvm_file.PRVM`
        or the `stereodic.stereo.rig.Rig` (built exactly as ``stereodic rig`` builds one). InputError naming the
        file when it is not a calibration of the format, or holds more than two cameras.
    """
    from calib.camera_models import prvms_of
    from stereodic.stereo.rig import build_rig
    fmt, cams = read_calibration(paths, fmt, size=size, units=units)
    where = paths[-1] if len(paths) > 1 else paths[0]
    cams = select(cams, cameras, where)
    if len(cams) > 2:
        raise InputError(where, f"holds {len(cams)} cameras ({', '.join(repr(c.name) for c in cams)}): pick one "
                                f"(its PRVM) or two (a rig) with --camera A[,B] (names, or #N by position)")
    dataset = f"imported from {os.fspath(where)}"
    if len(cams) == 1:
        prvms = prvms_of(cams, where=where, dataset=dataset)
        return Imported(fmt, cams, prvms[0], where, dataset, prvms)
    step = max(1, int(np.ceil(np.sqrt(max(c.width * c.height for c in cams) / GEOMETRY_PIXELS))))
    coarse = prvms_of(cams, where=where, dataset=dataset, step=step)
    w, h = virtual_size if virtual_size else (None, None)
    rig = build_rig(coarse[0], coarse[1], model=model, width=w, height=h, pitch_mm=pitch_mm,
                    plane_z_mm=coarse[0].reference_z_mm if plane_z_mm is None else plane_z_mm,
                    where=(f"{where}#{cams[0].name}", f"{where}#{cams[1].name}"), cameras=(cams[0], cams[1]))
    return Imported(fmt, cams, rig, where, dataset, coarse if step == 1 else None)

"""Which program wrote a calibration file, from its content (the file name's extension only breaks
ties): OpenCV FileStorage (%YAML:1.0 header, <opencv_storage> root, or JSON with opencv-matrix nodes),
VIC-3D (XML with <calibration><camera id=...>), DICe (XML ParameterList with xml_file_format
DICe_xml_camera_system_file, or the legacy cal.txt of 24 or 30 numbers), mrcal (.cameramodel: a Python
dict literal with 'lensmodel'), Kalibr (camchain YAML: cam0 with camera_model and intrinsics, also
after OpenCV's %YAML:1.0 line), ROS camera_info YAML (camera_matrix and distortion_model)."""

from __future__ import annotations

import os
import re
import xml.etree.ElementTree as ET
from pathlib import Path

from calib.errors import InputError

_NUMBER = re.compile(r"^[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$")


def read_head(path: Path, limit: int = 1 << 20) -> str:
    """The file's first `limit` bytes as text; InputError if it is binary."""
    raw = path.read_bytes()[:limit]
    if b"\0" in raw:
        raise InputError(path, "not a calibration file (binary content)")
    return raw.decode("utf-8", errors="replace")


def parse_xml(path: Path):
    """The root element of an XML file; InputError naming it if it is not readable XML."""
    try:
        return ET.parse(path).getroot()
    except ET.ParseError as exc:
        raise InputError(path, f"not readable XML ({exc})") from None


def legacy_dice_values(text: str) -> list[str] | None:
    """The values of a DICe legacy cal.txt (one number per line, '#' comments), or None if it is not one."""
    vals = []
    for line in text.splitlines():
        tokens = line.split("#", 1)[0].split()
        if not tokens:
            continue
        if len(tokens) != 1 or not _NUMBER.match(tokens[0]):
            return None
        vals.append(tokens[0])
    return vals if len(vals) in (24, 30) else None


def detect_format(path: str | os.PathLike) -> str:
    """One of stereodic.formats.FORMATS; InputError naming the file if it is none of them."""
    path = Path(path)
    text = read_head(path)
    head = text.lstrip("\ufeff \t\r\n")
    if re.search(r"^cam\d+\s*:", text, re.M) and "intrinsics" in text and "camera_model" in text:
        return "kalibr"
    if re.search(r"^distortion_model\s*:", text, re.M) and re.search(r"^camera_matrix\s*:", text, re.M) \
            and not head.startswith("%YAML"):
        return "ros"
    if head.startswith("%YAML") or "<opencv_storage>" in head[:2000] or '"opencv-matrix"' in head:
        return "opencv"
    if "<ParameterList" in head[:2000] and "DICe_xml_camera_system_file" in text:
        return "dice"
    if head.startswith("<") and re.search(r"<calibration\b", text) and re.search(r"<camera\s+id=", text):
        return "vic3d"
    if "lensmodel" in text and (path.suffix == ".cameramodel" or re.search(r"^\s*\{", text, re.M)):
        return "mrcal"
    if legacy_dice_values(text) is not None:
        return "dice"
    raise InputError(path, "not a calibration file of a known format (OpenCV FileStorage YAML/XML, VIC-3D XML, "
                           "DICe XML or cal.txt, mrcal .cameramodel, Kalibr camchain.yaml, ROS camera_info YAML)")

"""Reading and writing grayscale images: 8/16-bit PNG and TIFF, and the frames of sequence files (videos,
TIFF stacks, .cine, .mraw: `calib.sequences`) named `FILE::K`.

Colour images are converted to monochrome (the seed: treat colour as monochrome); a single-channel Bayer
image keeps its raw pixels. Values are returned in their native dtype (uint8 or uint16).
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import cv2
import numpy as np

from calib.atomic import atomic_output
from calib.errors import InputError
from calib.sequences import frame_size, parse_frame_ref, read_frame

IMAGE_SUFFIXES = (".png", ".tif", ".tiff")
SUPPORTED_MODES = ("1", "L", "LA", "P", "RGB", "RGBA", "I;16", "I;16B", "I;16L", "I;16N", "I")  # PIL's names
MODE_NAMES = {"F": "float32", "I;16S": "int16", "CMYK": "CMYK colour", "YCbCr": "YCbCr colour", "LAB": "Lab colour",
              "HSV": "HSV colour"}  # the unsupported ones, in words
_TIFF_DATA = ((273, 279), (324, 325))  # TIFF tags (offsets, byte counts) of strips and of tiles


def _check_file(path: Path) -> None:
    if path.is_dir():
        raise InputError(path, "is a directory, not an image file")
    if not path.is_file():
        raise InputError(path, "image file is missing")


def image_size(path: str | os.PathLike) -> tuple[int, int]:
    """(width, height) from the file header alone; InputError naming the file if it is missing, not a
    readable image, of an unsupported pixel type, or shorter than its header says (a PNG's chunk
    checksums are verified, a TIFF's strips or tiles must lie inside the file), so that thousands of
    images are checked in seconds before any work."""
    from PIL import Image  # here: a command that reads its few images whole never needs it
    if parse_frame_ref(path) is not None:
        return frame_size(path)
    path = Path(path)
    _check_file(path)
    if path.stat().st_size == 0:
        raise InputError(path, "is empty, not an image")
    try:
        with warnings.catch_warnings():  # PIL warns of a damaged TIFF's EXIF: the checks below say it
            warnings.simplefilter("ignore")
            with Image.open(path) as im:
                size, mode, fmt = im.size, im.mode, im.format
                tags = dict(im.tag_v2) if fmt == "TIFF" else {}
    except Exception:  # PIL raises several types for unreadable files
        raise InputError(path, "not a readable image: not an 8/16-bit PNG or TIFF, or damaged") from None
    if fmt == "PNG":
        try:
            with Image.open(path) as im:
                im.verify()
        except Exception:
            raise InputError(path, "not a readable image: the PNG is damaged or cut short") from None
    if mode not in SUPPORTED_MODES:
        raise InputError(path, f"pixel type {MODE_NAMES.get(mode, repr(mode))} is not supported (8- or 16-bit "
                               "grey or colour)")
    for offsets, counts in _TIFF_DATA:
        if offsets in tags and counts in tags:
            o, c = (v if isinstance(v, tuple) else (v,) for v in (tags[offsets], tags[counts]))
            end = max(a + b for a, b in zip(o, c))
            if end > path.stat().st_size:
                raise InputError(path, f"the file is cut short ({path.stat().st_size} bytes; its image data "
                                       f"runs to byte {end})")
    return size


def check_size(path: str | os.PathLike, size: tuple[int, int], of: str) -> None:
    """InputError naming `path` unless it is a readable image (`image_size`: its header) of `size`
    (width, height in pixels); `of` names what sets the size in the message ("the reference a.png",
    "the rig's left camera", "camera 'cam0'")."""
    w, h = image_size(path)
    if (w, h) != tuple(size):
        raise InputError(path, f"image is {w}x{h} but {of} is {size[0]}x{size[1]}")


def read_gray(path: str | os.PathLike) -> np.ndarray:
    """Read an image as a 2-D uint8 or uint16 array (colour -> luminance, alpha dropped); InputError
    naming the file if it is missing or not a readable image. A frame reference `FILE::K` reads frame K of
    a video, TIFF stack, .cine or .mraw (`calib.sequences`)."""
    if parse_frame_ref(path) is not None:
        return read_frame(path)
    path = Path(path)
    _check_file(path)
    level = cv2.utils.logging.getLogLevel()
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)  # the InputError below says it, once
    try:
        img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    finally:
        cv2.utils.logging.setLogLevel(level)
    if img is None:
        image_size(path)  # says what is wrong (empty, cut short, not an image) where it can
        raise InputError(path, "not a readable image (8/16-bit PNG or TIFF)")
    if img.ndim == 3:
        code = cv2.COLOR_BGRA2GRAY if img.shape[2] == 4 else cv2.COLOR_BGR2GRAY
        img = cv2.cvtColor(img, code)
    if img.dtype not in (np.uint8, np.uint16):
        raise InputError(path, f"pixel type {img.dtype} is not supported (8- or 16-bit grayscale)")
    return img


def write_rgb(path: str | os.PathLike, img: np.ndarray) -> None:
    """Write an (H, W, 3) uint8 RGB image as PNG (or any format cv2 writes by extension), atomically."""
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
        raise ValueError(f"write_rgb wants an (H, W, 3) uint8 array, got {img.shape} {img.dtype}")
    with atomic_output(path) as tmp:
        if not cv2.imwrite(str(tmp), img[:, :, ::-1]):
            raise OSError(f"{path}: could not write image")


def write_gray(path: str | os.PathLike, img: np.ndarray) -> None:
    """Write a 2-D uint8/uint16 image as PNG or TIFF (by extension), atomically."""
    if img.ndim != 2 or img.dtype not in (np.uint8, np.uint16):
        raise ValueError(f"write_gray wants a 2-D uint8/uint16 array, got {img.shape} {img.dtype}")
    with atomic_output(path) as tmp:
        if not cv2.imwrite(str(tmp), img):
            raise OSError(f"{path}: could not write image")

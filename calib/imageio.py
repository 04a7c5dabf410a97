"""Reading and writing grayscale images: 8/16-bit PNG and TIFF.

Colour images are converted to monochrome (the seed: treat colour as monochrome); a single-channel Bayer
image keeps its raw pixels. Values are returned in their native dtype (uint8 or uint16).
"""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np
from PIL import Image

from calib.atomic import atomic_output
from calib.errors import InputError

IMAGE_SUFFIXES = (".png", ".tif", ".tiff")


def _check_file(path: Path) -> None:
    if path.is_dir():
        raise InputError(path, "is a directory, not an image file")
    if not path.is_file():
        raise InputError(path, "image file is missing")


def image_size(path: str | os.PathLike) -> tuple[int, int]:
    """(width, height) from the file header alone; InputError if missing or not an image."""
    path = Path(path)
    _check_file(path)
    try:
        with Image.open(path) as im:
            return im.size
    except Exception:  # PIL raises several types for unreadable files
        raise InputError(path, "not a readable image (8/16-bit PNG or TIFF)") from None


def read_gray(path: str | os.PathLike) -> np.ndarray:
    """Read an image as a 2-D uint8 or uint16 array (colour -> luminance, alpha dropped)."""
    path = Path(path)
    _check_file(path)
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise InputError(path, "not a readable image (8/16-bit PNG or TIFF)")
    if img.ndim == 3:
        code = cv2.COLOR_BGRA2GRAY if img.shape[2] == 4 else cv2.COLOR_BGR2GRAY
        img = cv2.cvtColor(img, code)
    if img.dtype not in (np.uint8, np.uint16):
        raise InputError(path, f"pixel type {img.dtype} is not supported (8- or 16-bit grayscale)")
    return img


def write_gray(path: str | os.PathLike, img: np.ndarray) -> None:
    """Write a 2-D uint8/uint16 image as PNG or TIFF (by extension), atomically."""
    if img.ndim != 2 or img.dtype not in (np.uint8, np.uint16):
        raise ValueError(f"write_gray wants a 2-D uint8/uint16 array, got {img.shape} {img.dtype}")
    with atomic_output(path) as tmp:
        if not cv2.imwrite(str(tmp), img):
            raise OSError(f"{path}: could not write image")

"""Image files named on the command line: shell-style patterns expanded by the program, in natural order
(runs of digits compare by value: img_2.tif before img_10.tif). `calib.imageio.image_size` checks each
file from its header."""

from __future__ import annotations

import glob
import os
import re
from pathlib import Path

from calib.errors import InputError
from calib.sequences import expand_sequence

_DIGITS = re.compile(r"(\d+)")


def natural_key(path: str | os.PathLike) -> tuple:
    """Sort key of a path: runs of digits compare as numbers, the rest case-insensitively."""
    parts = _DIGITS.split(os.fspath(path))
    return tuple((0, int(p), p) if p.isdigit() else (1, p.lower(), p) for p in parts)


def expand(pattern: str | os.PathLike) -> list[Path]:
    """The files a shell-style pattern (`*`, `?`, `[...]`, `**`) names, in natural order; a name without
    wildcards is itself, unless it names a sequence file (a video, a TIFF stack, a .cine, a .mraw; or
    FILE:left / FILE:right, the halves of a side-by-side stream): then its frames' references
    (`calib.sequences.expand_sequence`). InputError naming the pattern when it matches no file."""
    text = os.path.expanduser(os.fspath(pattern))
    frames = expand_sequence(text)
    if frames is not None:
        return frames
    if not glob.has_magic(text):
        return [Path(text)]
    files = [Path(p) for p in glob.glob(text, recursive=True) if os.path.isfile(p)]
    if not files:
        raise InputError(pattern, "the pattern matches no file")
    return sorted(files, key=natural_key)


def expand_datasets(pattern: str | os.PathLike) -> list[Path]:
    """The capture datasets a shell-style pattern names: folders holding capture.json, or capture.json
    files, in natural order; a name without wildcards is itself. InputError naming the pattern when it
    matches no dataset."""
    text = os.path.expanduser(os.fspath(pattern))
    if not glob.has_magic(text):
        return [Path(text)]
    found = [Path(p) for p in glob.glob(text, recursive=True)
             if (os.path.isdir(p) and os.path.isfile(os.path.join(p, "capture.json")))
             or (os.path.isfile(p) and os.path.basename(p) == "capture.json")]
    if not found:
        raise InputError(pattern, "the pattern matches no dataset (a folder holding capture.json)")
    return sorted(found, key=natural_key)

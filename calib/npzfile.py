"""Reading stereodic's `.npz` files: named arrays plus a 0-d `meta` string of JSON whose `format` names
the kind of file (stereodic.prvm/1, stereodic.rig/1, stereodic.undistort/1, ...). Writing is
`calib.atomic.write_npz`.
"""

from __future__ import annotations

import json
import os
import zipfile
from pathlib import Path

import numpy as np

from calib.errors import InputError
from calib.npz_stream import map_arrays


def read_npz(path: str | os.PathLike, fmt: str | tuple[str, ...], what: str,
             advice: dict[str, str] | None = None, keys: tuple[str, ...] | None = None, *,
             mapped: bool = False) -> tuple[dict, dict[str, np.ndarray]]:
    """(meta, arrays without meta) of the file at `path`, which must be a `fmt` file (or of one of the
    formats, a tuple); `keys`: read only these arrays (default all), e.g. the small ones of a large file;
    `mapped`: the arrays the file stores uncompressed memory-mapped read-only instead of read
    (`calib.npz_stream.map_arrays`: a large file opens at once, its pages read as they are used).

    what: the kind of file in messages ("PRVM", "rig", ...). advice: for formats a user may pass by
    mistake, a hint added to the message (e.g. {"stereodic.prvm/1": "a camera file: build a rig ..."}).
    Raises InputError naming the file: missing, not a readable .npz, no JSON meta, another format.
    """
    path = Path(path)
    if path.is_dir():
        raise InputError(path, f"is a directory, not a {what} file")
    if not path.is_file():
        raise InputError(path, f"{what} file is missing")
    try:
        with open(path, "rb") as f:
            head = f.read(4)
    except OSError as exc:
        raise InputError(path, f"cannot be read ({exc.strerror})") from None
    if not head:
        raise InputError(path, f"is empty, not a {what} file")
    if head != b"PK\x03\x04":
        raise InputError(path, f"not a readable {what} file: not an .npz (zip) archive")
    try:
        with zipfile.ZipFile(path) as archive:
            others = [n for n in archive.namelist() if not n.endswith(".npy")]
    except (zipfile.BadZipFile, OSError):
        raise InputError(path, f"not a readable {what} file: the .npz archive is damaged") from None
    if others:
        raise InputError(path, f"not a {what} file: a zip archive, but not of numpy arrays (it holds "
                               f"{others[0]})")
    try:
        maps = map_arrays(path) if mapped else {}
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: maps[k] if k in maps else z[k] for k in z.files if keys is None or k in keys or k == "meta"}
    except Exception:  # zipfile and numpy raise several types for a damaged archive
        raise InputError(path, f"not a readable {what} file: the .npz archive is damaged or holds other "
                               "than numpy arrays") from None
    if "meta" not in arrays:
        raise InputError(path, f"not a {what} file: lacks 'meta' (an .npz that stereodic did not write)")
    try:
        meta = json.loads(str(arrays.pop("meta")))
    except json.JSONDecodeError:
        raise InputError(path, "'meta' is not valid JSON") from None
    found = meta.get("format") if isinstance(meta, dict) else None
    formats = (fmt,) if isinstance(fmt, str) else fmt
    if found not in formats:
        hint = (advice or {}).get(str(found))
        expected = " or ".join(repr(f) for f in formats)
        raise InputError(path, f"format is {found!r}, expected {expected}" + (f" ({hint})" if hint else ""))
    return meta, arrays

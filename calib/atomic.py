"""Outputs that are never half-written.

Every file stereodic writes goes through `atomic_output`: the content is written to a temporary name in
the same folder and renamed over the target only when complete, so an existing output survives a crash
or an error untouched.
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from pathlib import Path
from typing import Iterator

import numpy as np


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def atomic_output(path: str | os.PathLike, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path beside `path`; rename it to `path` if the block completes.

    `suffix` is the temporary file's extension (default: the target's), so that writers that choose a
    format by extension (cv2.imwrite, np.savez, Open3D) still work.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=suffix if suffix is not None else path.suffix,
                               dir=path.parent)
    os.close(fd)
    tmp = Path(tmp)
    try:
        yield tmp
        os.chmod(tmp, 0o666 & ~_umask())     # mkstemp makes 0600; outputs get the usual permissions
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def write_json(path: str | os.PathLike, obj) -> None:
    """Write `obj` as indented JSON, atomically."""
    with atomic_output(path) as tmp:
        tmp.write_text(json.dumps(obj, indent=1) + "\n")


def write_npz(path: str | os.PathLike, **arrays) -> None:
    """Write arrays to an uncompressed `.npz`, atomically (np.savez would add `.npz` to a bare name)."""
    with atomic_output(path, suffix=".npz") as tmp:
        np.savez(tmp, **arrays)


def write_text(path: str | os.PathLike, text: str) -> None:
    """Write text, atomically."""
    with atomic_output(path) as tmp:
        tmp.write_text(text)

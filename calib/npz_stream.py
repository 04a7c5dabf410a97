"""Stacked `.npz` arrays written and read one slice at a time.

A long sequence's results are arrays of shape (S, ...) - one slice per state - that need not fit in
memory together. `write_stacked_npz` writes such a file from iterators of slices, `iter_slices` reads one
array back slice by slice. The files are ordinary uncompressed `.npz` files, byte for byte what
`np.savez` writes for the same arrays (np.load reads them); writing is atomic (`calib.atomic`).
`map_arrays` maps the arrays of any uncompressed `.npz` into memory instead of reading them.
"""

from __future__ import annotations

import os
import zipfile
from typing import Callable, Iterable, Iterator

import numpy as np

from calib.atomic import atomic_output


def write_stacked_npz(path: str | os.PathLike, arrays: dict[str, np.ndarray],
                      stacked: dict[str, Callable[[], Iterable[np.ndarray]]], count: int) -> None:
    """Write `arrays` as they are, then each `stacked[name]()` (an iterable of `count` slices of one shape
    and dtype) as the array `name` of shape (count,) + slice shape, in that order."""
    with atomic_output(path, suffix=".npz") as tmp:
        with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_STORED, allowZip64=True) as zf:
            for name, value in arrays.items():
                with zf.open(name + ".npy", "w", force_zip64=True) as f:
                    np.lib.format.write_array(f, np.asanyarray(value), allow_pickle=False)
            for name, slices in stacked.items():
                it = iter(slices())
                first = np.asarray(next(it))
                header = {"descr": np.lib.format.dtype_to_descr(first.dtype), "fortran_order": False,
                          "shape": (count,) + first.shape}
                with zf.open(name + ".npy", "w", force_zip64=True) as f:
                    np.lib.format.write_array_header_1_0(f, header)
                    n = 0
                    for sl in _chain(first, it):
                        sl = np.asarray(sl)
                        if sl.shape != first.shape or sl.dtype != first.dtype:
                            raise ValueError(f"{name}: slice {n} is {sl.shape} {sl.dtype}, expected "
                                             f"{first.shape} {first.dtype}")
                        f.write(np.ascontiguousarray(sl).tobytes())
                        n += 1
                if n != count:
                    raise ValueError(f"{name}: {n} slices, expected {count}")


def _chain(first, rest) -> Iterator:
    yield first
    yield from rest


def _stacked_header(f, name: str) -> tuple[tuple, np.dtype, int]:
    """(shape, dtype, bytes per slice) of the stacked array whose `.npy` member `f` is open at its start."""
    version = np.lib.format.read_magic(f)
    read = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
    shape, fortran, dtype = read(f)
    if fortran or not shape:
        raise ValueError(f"{name}: not a C-ordered stacked array")
    return shape, dtype, int(np.prod(shape[1:], dtype=np.int64)) * dtype.itemsize


def iter_slices(path: str | os.PathLike, name: str) -> Iterator[np.ndarray]:
    """The slices (along the first axis) of array `name` of an uncompressed `.npz`, one at a time."""
    with zipfile.ZipFile(path) as zf, zf.open(name + ".npy") as f:
        shape, dtype, size = _stacked_header(f, name)
        for _ in range(shape[0]):
            yield np.frombuffer(f.read(size), dtype).reshape(shape[1:]).copy()


def slice_count(path: str | os.PathLike, name: str) -> int:
    """How many slices array `name` of an uncompressed `.npz` has (its header alone is read)."""
    with zipfile.ZipFile(path) as zf, zf.open(name + ".npy") as f:
        return int(_stacked_header(f, name)[0][0])


def read_slice(path: str | os.PathLike, name: str, k: int) -> np.ndarray:
    """Slice `k` (along the first axis) of array `name` of an uncompressed `.npz`, read alone (a seek
    past the slices before it, not a read of them). IndexError if the array has no slice `k`."""
    with zipfile.ZipFile(path) as zf:
        info = zf.getinfo(name + ".npy")
    if info.compress_type != zipfile.ZIP_STORED:
        raise ValueError(f"{name}: compressed, not a stacked array")
    with open(path, "rb") as f:
        _seek_member(f, info)
        shape, dtype, size = _stacked_header(f, name)
        if not 0 <= k < shape[0]:
            raise IndexError(f"{name}: slice {k} of {shape[0]}")
        f.seek(k * size, os.SEEK_CUR)
        return np.frombuffer(f.read(size), dtype).reshape(shape[1:]).copy()


def _seek_member(f, info: zipfile.ZipInfo) -> None:
    """Move the open archive `f` to the first byte of the stored (uncompressed) member `info`."""
    f.seek(info.header_offset)
    local = f.read(30)                          # the member's local header: its name and extra field follow
    f.seek(info.header_offset + 30 + int.from_bytes(local[26:28], "little") + int.from_bytes(local[28:30], "little"))


def map_arrays(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """The arrays of an `.npz` that it stores uncompressed, memory-mapped read-only (`np.memmap` at each
    member's data): nothing is read until it is used, and then only the pages used. Members compressed,
    empty, 0-d or of an object dtype are left out (`np.load` reads those)."""
    out = {}
    with zipfile.ZipFile(path) as zf, open(path, "rb") as f:
        for info in zf.infolist():
            if info.compress_type != zipfile.ZIP_STORED or not info.filename.endswith(".npy"):
                continue
            _seek_member(f, info)
            version = np.lib.format.read_magic(f)
            read = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
            shape, fortran, dtype = read(f)
            if not shape or 0 in shape or dtype.hasobject:
                continue
            out[info.filename[:-4]] = np.memmap(path, dtype, mode="r", offset=f.tell(), shape=shape,
                                                order="F" if fortran else "C")
    return out

"""DIC results as a MATLAB file: the arrays of a result's NPZ (dic.npz, a dic2d NPZ, strain.npz) written to
a .mat (version 5, what `load` reads in MATLAB and Octave), one array at a time.

A version-5 MAT-file is a 128-byte header followed by one data element per variable, so the file is
built as `scipy.io.savemat` writes each array alone, less the header of all but the first: memory holds
one array, never the whole result. Names and shapes are the NPZ's ((S, ny, nx) per state; points and
displacement (S, ny, nx, 3)); `meta` is the NPZ's JSON text; bool arrays become MATLAB logicals.
"""

from __future__ import annotations

import io
import os
import zipfile

import numpy as np

from calib.atomic import atomic_output

HEADER_BYTES = 128


def write_mat(npz_path: str | os.PathLike, mat_path: str | os.PathLike) -> list[str]:
    """Write every array of an NPZ file to a MATLAB .mat file (module docstring), atomically.

    Parameters
    ----------
    npz_path : path
        The result's NPZ (uncompressed or compressed).
    mat_path : path
        The .mat file to write.

    Returns
    -------
    names : list of str
        The variables written, in the NPZ's order.
    """
    from scipy.io import savemat
    names = []
    with zipfile.ZipFile(npz_path) as zf, atomic_output(mat_path, suffix=".mat") as tmp, open(tmp, "wb") as out:
        for member in zf.namelist():
            if not member.endswith(".npy"):
                continue
            name = member[:-4]
            with zf.open(member) as f:
                value = np.lib.format.read_array(f, allow_pickle=False)
            if value.dtype.kind == "U" and value.ndim == 0:
                value = str(value)
            buf = io.BytesIO()
            savemat(buf, {name: value}, do_compression=False, oned_as="row")
            out.write(buf.getvalue() if not names else buf.getvalue()[HEADER_BYTES:])
            names.append(name)
    return names

"""VTK XML PolyData (.vtp) of a stereo DIC state, and a ParaView collection (.pvd) of the states.

Each state's file holds the measured surface: the converged points (mm, the rig's reporting frame, their
position in that state), quads between grid neighbours whose four corners converged, and point data:
displacement (3 components, mm), exx, eyy, exy (the run's strain measure, NaN where not valid),
zncc_left, zncc_right, gap_mm. Arrays in VTK's inline binary form (base64 of a UInt64 byte count and the
little-endian values: a state of 90,000 points in milliseconds, where decimal text took half a second),
written atomically; open the .pvd in ParaView to step through the
states (warp by `displacement` on state 0 to see the deformation).
"""

from __future__ import annotations

import base64
import os
from pathlib import Path
from typing import Iterable

import numpy as np

from calib.atomic import write_text
from stereodic.dic3d.stereo import StereoState


def _array(name: str, a: np.ndarray, ncomp: int = 1, kind: str = "Float64") -> str:
    """One DataArray: `a` as little-endian `kind` (Float64 or Int64), inline binary (module docstring)."""
    raw = np.ascontiguousarray(a, "<f8" if kind == "Float64" else "<i8").tobytes()
    body = base64.b64encode(np.uint64(len(raw)).astype("<u8").tobytes() + raw).decode("ascii")
    return f'<DataArray type="{kind}" Name="{name}" NumberOfComponents="{ncomp}" format="binary">{body}</DataArray>'


def polydata(state: StereoState) -> str:
    """The .vtp text of one state (module docstring)."""
    ok = state.converged
    index = np.full(ok.shape, -1, np.int64)
    index[ok] = np.arange(int(ok.sum()))
    quad = ok[:-1, :-1] & ok[1:, :-1] & ok[1:, 1:] & ok[:-1, 1:]
    conn = np.stack([index[:-1, :-1][quad], index[:-1, 1:][quad], index[1:, 1:][quad], index[1:, :-1][quad]], -1)
    data = [_array("displacement", state.displacement[ok], 3), _array("zncc_left", state.left.zncc[ok]),
            _array("zncc_right", state.right.zncc[ok]), _array("gap_mm", state.gap_mm[ok])]
    if state.measure is not None:
        data += [_array(c, getattr(state.measure, c)[ok]) for c in ("exx", "eyy", "exy")]
    ints = lambda name, a: _array(name, a, 1, "Int64")  # noqa: E731
    return ('<?xml version="1.0"?>\n<VTKFile type="PolyData" version="1.0" byte_order="LittleEndian" '
            'header_type="UInt64">\n<PolyData>\n'
            f'<Piece NumberOfPoints="{int(ok.sum())}" NumberOfPolys="{len(conn)}">\n'
            f'<PointData Vectors="displacement">\n' + "\n".join(data) + "\n</PointData>\n"
            f"<Points>{_array('points', state.points[ok], 3)}</Points>\n"
            f"<Polys>{ints('connectivity', conn)}{ints('offsets', 4 * np.arange(1, len(conn) + 1))}</Polys>\n"
            "</Piece>\n</PolyData>\n</VTKFile>\n")


def state_file(k: int) -> str:
    """The name of state k's file in a run's vtk folder (and in its collection)."""
    return f"state{k:03d}.vtp"


def write_state(folder: str | os.PathLike, state: StereoState) -> Path:
    """Write folder/state{k:03d}.vtp of one state; returns its path."""
    path = Path(folder) / state_file(state.state)
    write_text(path, polydata(state))
    return path


def write_collection(folder: str | os.PathLike, states: Iterable[int]) -> Path:
    """Write folder/states.pvd, the collection of the states' .vtp files (time = state index); returns
    its path."""
    entries = [f'<DataSet timestep="{k}" part="0" file="{state_file(k)}"/>' for k in states]
    pvd = Path(folder) / "states.pvd"
    write_text(pvd, '<?xml version="1.0"?>\n<VTKFile type="Collection" version="1.0">\n<Collection>\n'
               + "\n".join(entries) + "\n</Collection>\n</VTKFile>\n")
    return pvd

"""Strain recomputed from saved DIC results, without correlating again (`stereodic strain`).

Reads a `dic` result (its output folder, or the folder's dic.npz: per state the points and
displacements) or a `dic2d` NPZ (per image u, v on the reference grid) one state at a time
(`calib.npz_stream`), fits the strain over another window (`strain_3d` on the state-0 surface,
`strain_2d` on the image grid) in another measure (`strain_measures`) and returns, per state, the
measure on the result's grid.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator


from calib.errors import InputError
from calib.npz_stream import iter_slices
from calib.npzfile import read_npz
from stereodic.dic.grid import Grid
from stereodic.strain import strain_2d, strain_3d
from stereodic.strain_measures import StrainMeasure, measure_strain

FORMATS = {"stereodic.dic/1": "dic", "stereodic.dic2d/1": "dic2d"}


@dataclass
class DicResult:
    """A saved result: its file, kind ("dic" or "dic2d"), grid, number of states and meta."""

    path: Path
    kind: str
    grid: Grid
    states: int
    meta: dict


def open_result(path: str | os.PathLike) -> DicResult:
    """The result in a `dic` output folder (its dic.npz) or in a `dic` / `dic2d` NPZ file; InputError
    naming it otherwise."""
    path = Path(path)
    if path.is_dir():
        path = path / "dic.npz"
        if not path.is_file():
            raise InputError(path.parent, "holds no dic.npz (not a `stereodic dic` output folder)")
    meta, arrays = read_npz(path, tuple(FORMATS), "DIC result", keys=("x", "y", "active"))
    kind = FORMATS[meta["format"]]
    count = sum(1 for _ in iter_slices(path, "state")) if kind == "dic" else len(meta.get("images", []))
    if count == 0:
        raise InputError(path, "holds no state")
    return DicResult(path, kind, Grid(arrays["x"], arrays["y"], arrays["active"].astype(bool)), count, meta)


def strains(result: DicResult, window: int, measure: str) -> Iterator[StrainMeasure]:
    """The strain measure of every state of `result`, fitted over window x window grid points."""
    g = result.grid
    if result.kind == "dic2d":
        for u, v in zip(iter_slices(result.path, "u"), iter_slices(result.path, "v")):
            yield measure_strain(strain_2d(g.xs, g.ys, u, v, window), measure)
        return
    points = iter_slices(result.path, "points")
    reference = next(points)
    for disp in iter_slices(result.path, "displacement"):
        yield measure_strain(strain_3d(reference, disp, window), measure)

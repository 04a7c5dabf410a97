"""Strain recomputed from saved DIC results, without correlating again (`stereodic strain`).

Reads a `dic` result (its output folder, or the folder's dic.npz: per state the points and
displacements) or a `dic2d` NPZ (per image u, v on the reference grid) one state at a time
(`calib.npz_stream`), fits the strain over another window (`StrainFit` on the state-0 surface,
`strain_2d` on the image grid) in another measure (`strain_measures`) and returns, per state, the
measure on the result's grid.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator


import numpy as np

from calib.errors import InputError
from calib.npz_stream import iter_slices
from calib.npzfile import read_npz
from stereodic.dic.grid import Grid
from stereodic.dic.maps import MapAxes, pixel_axes, surface_axes
from stereodic.gauge.frame import SpecimenFrame, specimen_frame
from stereodic.strain.fit import StrainFit, strain_2d
from stereodic.strain.measures import StrainMeasure, measure_strain

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


def state_labels(result: DicResult) -> list[str]:
    """Each state (or deformed image) of `result` in words, for map titles: the names `stereodic dic`
    recorded ("state 3: tension", "state 3 (img_0003_0.tif)"), else "state k"; for a dic2d result
    "deformed image k (its file name)"."""
    if result.kind == "dic2d":
        return dic2d_state_labels(result.meta["images"])[1:]
    labels = result.meta.get("state_labels")
    return list(labels) if isinstance(labels, list) and len(labels) == result.states else \
        [f"state {k}" for k in range(result.states)]


def dic2d_state_labels(images: list[str]) -> list[str]:
    """The states of a dic2d result with deformed `images` (file names) in words, its reference first:
    state 0 "reference image", then state k + 1 "deformed image k (its file name)", the numbering of
    `stereodic gauge` and of the workspace."""
    return ["reference image"] + [f"deformed image {k} ({Path(name).name})" for k, name in enumerate(images)]


def map_axes(result: DicResult, *, frame: SpecimenFrame | None = None) -> MapAxes:
    """The axes of `result`'s maps: the reference surface's X, Y in mm for a stereo result (in `frame`,
    the specimen's, when given), the reference image's pixels for a dic2d one (stereodic.dic.maps)."""
    g = result.grid
    if result.kind == "dic2d":
        return pixel_axes(g.xs, g.ys, g.active)
    P0 = next(iter_slices(result.path, "points"))
    return surface_axes(g.xs, g.ys, P0 if frame is None else frame.apply(P0), g.active)


def specimen_frame_of(result: DicResult, *, origin_px=None, x_direction_px=(1.0, 0.0)) -> SpecimenFrame:
    """The specimen's frame of a stereo result (`stereodic.gauge.frame.specimen_frame` of state 0's points
    and their positions in the original left reference image); InputError for a dic2d result."""
    if result.kind != "dic":
        raise InputError("--frame", f"{result.path} is a 2-D result: the specimen's frame needs a stereo result")
    P0 = next(iter_slices(result.path, "points"))
    px = np.stack([next(iter_slices(result.path, "left_x0")), next(iter_slices(result.path, "left_y0"))], -1)
    ok = np.isfinite(P0).all(-1) & np.isfinite(px).all(-1)
    return specimen_frame(P0[ok], px[ok], origin_px=origin_px, x_direction_px=x_direction_px)


def strains(result: DicResult, window: int, measure: str, *, frame: SpecimenFrame | None = None
            ) -> Iterator[StrainMeasure]:
    """The strain measure of every state of `result`, fitted over window x window grid points; with
    `frame` (a stereo result), in the specimen's axes (e1: its x projected on the tangent plane)."""
    g = result.grid
    if result.kind == "dic2d":
        for u, v in zip(iter_slices(result.path, "u"), iter_slices(result.path, "v")):
            yield measure_strain(strain_2d(g.xs, g.ys, u, v, window=window), measure=measure)
        return
    surface = SurfaceStrains(next(iter_slices(result.path, "points")), window=window, measure=measure, frame=frame)
    for disp in iter_slices(result.path, "displacement"):
        yield surface(disp)


class SurfaceStrains:
    """The strain measure of a stereo result's displacement fields, fitted on its reference shape.

    Parameters
    ----------
    points0 : (ny, nx, 3) float
        State 0's points on the grid, the result's frame, mm; NaN where not measured.
    window : int
        Grid points per side of the fit (odd >= 3).
    measure : str
        Strain measure (`stereodic.strain.measures.MEASURES`).
    frame : SpecimenFrame, optional
        Fit in the specimen's axes: points and displacements turned into it, e1 its x axis projected on
        the local tangent plane (else the result's own x).

    Calling it with a state's displacement (ny, nx, 3), mm in the result's frame, gives that state's
    `StrainMeasure` (dimensionless); the fit's frames are shared between states (`StrainFit`).
    """

    def __init__(self, points0: np.ndarray, *, window: int, measure: str, frame: SpecimenFrame | None = None):
        self.frame, self.measure = frame, measure
        self._fit = StrainFit(points0 if frame is None else frame.apply(points0), window=window)

    def __call__(self, displacement: np.ndarray) -> StrainMeasure:
        d = displacement if self.frame is None else self.frame.rotate(displacement)
        return measure_strain(self._fit(d), measure=self.measure)

"""A saved DIC result read state by state in the frame a lab chooses, for gauges (`stereodic gauge`).

`open_gauge_result` opens a `stereodic dic` result (its folder or dic.npz) or a `stereodic dic2d --npz`
file; `GaugeResult.states()` then yields, one state at a time, every grid point's position and the
quantities on the grid (`GaugeState`). State 0 is the reference: for a dic2d result, the reference
image (zero displacement and strain), deformed image k being state k + 1.

Stereo quantities (mm, the chosen frame): X, Y, Z (the point in this state), dX, dY, dZ (from state 0)
and, with the rigid motion removed, dX_def, dY_def, dZ_def (the deformation-only displacement,
`frame.rigid_motion`); strains exx, eyy, exy, e_major, e_minor, e_vm (dimensionless) refitted in the
frame's axes over the run's strain window (`stereodic.strain.fit.StrainFit`; in the specimen's frame e1 is
its x axis projected on the local tangent plane). dic2d quantities: u, v (pixels), dX, dY (mm, with a
scale in mm per pixel) and the same strains, refitted on the image grid (e1 = the image's x).
Every grid point also has its place in the ORIGINAL left reference image (`image_px`), pixels, where
gauges are given: a stereo result's left_x0, left_y0 of state 0; a dic2d grid's own x, y.
"""

from __future__ import annotations

import itertools
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

import numpy as np

from calib.errors import InputError
from calib.npz_stream import iter_slices
from stereodic.dic.grid import Grid
from stereodic.gauge.frame import SpecimenFrame, rigid_motion
from stereodic.strain.fit import strain_2d
from stereodic.strain.measures import measure_strain
from stereodic.strain.results import (DicResult, dic2d_state_labels, open_result, specimen_frame_of, state_labels,
                                      strains)

STRAINS = ("exx", "eyy", "exy", "e_major", "e_minor", "e_vm")
_MEASURE_FIELD = {"exx": "exx", "eyy": "eyy", "exy": "exy", "e_major": "major", "e_minor": "minor",
                  "e_vm": "von_mises"}


@dataclass
class GaugeState:
    """One state on the result's grid: `position` (ny, nx, 3) every point in this state (mm in the
    chosen frame; a dic2d result's x + u, y + v, 0 in pixels, or mm with a scale), NaN where not
    measured; `quantities` name -> (ny, nx) (module docstring); `rigid` the state's rigid motion
    (rotation (3, 3), translation (3,) mm: position ~ R reference + t) when it is removed, else None."""

    state: int
    position: np.ndarray
    quantities: dict[str, np.ndarray]
    rigid: tuple[np.ndarray, np.ndarray] | None = None


@dataclass
class GaugeResult:
    """A saved result opened for gauges (`open_gauge_result`): `kind` "dic" or "dic2d", its `grid`,
    `count` states (the reference included), `labels` (one per state), `unit` of positions and lengths
    ("mm", or "px" for a dic2d result without a scale), `image_px` (ny, nx, 2) each grid point in the
    original left reference image (pixels, NaN where unknown), `frame` (the specimen's frame, or None:
    the rig's world frame or the image), `units` quantity -> unit."""

    path: Path
    kind: str
    grid: Grid
    count: int
    labels: list[str]
    unit: str
    image_px: np.ndarray
    frame: SpecimenFrame | None
    units: dict[str, str]
    window: int
    measure: str
    remove_rigid: bool = False
    scale_mm_per_px: float | None = None
    meta: dict = field(default_factory=dict)
    _result: DicResult | None = None

    def frame_record(self) -> dict:
        """The frame the quantities are in, as JSON-ready numbers (what outputs record)."""
        if self.frame is not None:
            return {**self.frame.record(), "rigid_motion_removed": self.remove_rigid}
        if self.kind == "dic2d":
            return {"frame": "image", "scale_mm_per_px": self.scale_mm_per_px}
        saved = self.meta.get("frame", {"frame": "rig"})      # the frame the result was saved in
        return {**saved, "world_from_rig": self.meta.get("world_from_rig"), "rigid_motion_removed": self.remove_rigid}

    def states(self) -> Iterator[GaugeState]:
        """Every state, from state 0, one in memory at a time (module docstring)."""
        return self._stereo_states() if self.kind == "dic" else self._image_states()

    def _strains(self, m) -> dict[str, np.ndarray]:
        return {q: getattr(m, _MEASURE_FIELD[q]) for q in STRAINS}

    def _stereo_states(self) -> Iterator[GaugeState]:
        f = self.frame
        to_frame = (lambda P: P) if f is None else f.apply
        rotate = (lambda D: D) if f is None else f.rotate
        P0 = None
        fields = zip(iter_slices(self.path, "points"), iter_slices(self.path, "displacement"),
                     strains(self._result, self.window, self.measure, frame=f))
        for k, (P, D, m) in enumerate(fields):
            P, D = to_frame(P), rotate(D)
            P0 = P if P0 is None else P0
            q = {"X": P[..., 0], "Y": P[..., 1], "Z": P[..., 2], "dX": D[..., 0], "dY": D[..., 1],
                 "dZ": D[..., 2]}
            rigid = None
            if self.remove_rigid:
                R, t = rigid_motion(P0, P)
                Dd = (P - t) @ R - P0           # R^T (P - t) - P0
                q.update(dX_def=Dd[..., 0], dY_def=Dd[..., 1], dZ_def=Dd[..., 2])
                rigid = (R, t)
            q.update(self._strains(m))
            yield GaugeState(k, P, q, rigid)

    def _image_states(self) -> Iterator[GaugeState]:
        g = self.grid
        s = self.scale_mm_per_px or 1.0
        x, y = np.meshgrid(g.xs, g.ys)
        ref = np.where(g.active, 0.0, np.nan)
        fields = zip(iter_slices(self.path, "u"), iter_slices(self.path, "v"), strains(self._result, self.window,
                                                                                       self.measure))
        zero = measure_strain(strain_2d(g.xs, g.ys, ref, ref, window=self.window), measure=self.measure)
        for k, (u, v, m) in enumerate(itertools.chain([(ref, ref, zero)], fields)):
            q = {"u": u, "v": v}
            if self.scale_mm_per_px:
                q.update(dX=u * s, dY=v * s)
            q.update(self._strains(m))
            yield GaugeState(k, np.stack([(x + u) * s, (y + v) * s, np.zeros_like(u)], -1), q)


def open_gauge_result(path: str | os.PathLike, *, frame: str = "rig", origin_px: tuple[float, float] | None = None,
                      x_direction_px: tuple[float, float] = (1.0, 0.0), remove_rigid: bool = False,
                      scale_mm_per_px: float | None = None, window: int | None = None,
                      measure: str | None = None) -> GaugeResult:
    """A saved `dic` or `dic2d` result, opened for gauges in the chosen frame.

    Parameters
    ----------
    path : path
        A `stereodic dic` output folder or its dic.npz, or a `stereodic dic2d --npz` file.
    frame : {"rig", "specimen"}
        "rig": the frame the result was saved in (the rig's world frame, or the specimen's for a
        `dic --frame specimen` run; a dic2d result: the image); "specimen": the best-fit plane of the
        reference shape (`frame.specimen_frame`; stereo results only).
    origin_px, x_direction_px
        With "specimen": the origin's position and the x axis's direction in the original left
        reference image, pixels (default: the centroid; the image's columns).
    remove_rigid : bool
        Also give each state's deformation-only displacement dX_def, dY_def, dZ_def (stereo results).
    scale_mm_per_px : float, optional
        A dic2d result's scale: positions and lengths in mm, displacements dX, dY in mm.
    window : int, optional
        Strain window, grid points (odd >= 3; default: the run's own, else 5).
    measure : str, optional
        Strain measure (`stereodic.strain.measures.MEASURES`; default: the run's own, else
        green-lagrange).

    Returns
    -------
    result : GaugeResult
        InputError naming the file or option when the result or an option does not fit.
    """
    res = open_result(path)
    meta = res.meta
    settings = meta.get("settings", {})
    own_window = settings.get("strain_window") if res.kind == "dic" else None
    window = window or own_window or 5
    if window < 3 or window % 2 == 0:
        raise InputError("--strain-window", f"must be an odd number >= 3, got {window}")
    measure = measure or (settings.get("strain_measure") if res.kind == "dic" else meta.get("strain_measure")) \
        or "green-lagrange"
    if frame not in ("rig", "specimen"):
        raise InputError("--frame", f"must be rig or specimen, got {frame!r}")
    g = res.grid
    strain_units = {q: "" for q in STRAINS}
    if res.kind == "dic2d":
        if frame == "specimen" or remove_rigid:
            raise InputError("--frame", f"{res.path} is a 2-D result: the specimen's frame and rigid motion need "
                                        f"a stereo (`stereodic dic`) result")
        if scale_mm_per_px is not None and not scale_mm_per_px > 0:
            raise InputError("--scale", f"must be > 0 mm per pixel, got {scale_mm_per_px}")
        x, y = np.meshgrid(g.xs, g.ys)
        image_px = np.where(g.active[..., None], np.stack([x, y], -1), np.nan)
        labels = dic2d_state_labels(res.meta["images"])
        units = {"u": "px", "v": "px"} | ({"dX": "mm", "dY": "mm"} if scale_mm_per_px else {}) | strain_units
        return GaugeResult(res.path, "dic2d", g, res.states + 1, labels, "mm" if scale_mm_per_px else "px",
                           image_px, None, units, window, measure, False, scale_mm_per_px, meta, res)
    if scale_mm_per_px is not None:
        raise InputError("--scale", f"{res.path} is a stereo result, already in mm")
    image_px = np.stack([next(iter_slices(res.path, "left_x0")), next(iter_slices(res.path, "left_y0"))], -1)
    P0 = next(iter_slices(res.path, "points"))
    ok = np.isfinite(P0).all(-1) & np.isfinite(image_px).all(-1)
    image_px = np.where(ok[..., None], image_px, np.nan)
    spec = None
    if frame == "specimen":
        spec = specimen_frame_of(res, origin_px=origin_px, x_direction_px=x_direction_px)
    units = {q: "mm" for q in ("X", "Y", "Z", "dX", "dY", "dZ")}
    if remove_rigid:
        units |= {q: "mm" for q in ("dX_def", "dY_def", "dZ_def")}
    return GaugeResult(res.path, "dic", g, res.states, state_labels(res), "mm", image_px, spec, units | strain_units,
                       window, measure, remove_rigid, None, meta, res)

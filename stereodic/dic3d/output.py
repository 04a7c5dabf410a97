"""Writing stereo DIC results: CSV rows, NPZ arrays and PNG maps, state by state (all atomic).

CSV, one row per active grid point and state (x, y: the point in the LEFT rectified reference image,
pixels; per camera the 2-D columns of `dic2d`, prefixed left_ / right_: u, v such that the point is at
(x + u, y + v) in that camera's rectified image of the state (so right_u includes the disparity), zncc,
converged, status; left_x0, left_y0, right_x0, right_y0: where the point is in each camera's original
(unrectified) image of the state, pixels; then X, Y, Z (mm, the point in this state, in the rig's
reporting frame), dX, dY, dZ (mm, from state 0), gap_mm (distance between the two rays), converged (both
cameras and the rays agree, and state 0 is measured), status (ok, left:<status>, right:<status>,
ray_gap, no_reference), incremental (1: the point is tracked state to state) and, with a strain window,
the strain measure's exx, eyy, exy on the tangent plane, its principal strains e_major, e_minor, the
major direction e_angle (degrees from e1) and the von Mises equivalent e_vm (`strain_measures`), and
strain_valid) and, with the rigid motion removed (`dic --remove-rigid`), dX_def, dY_def, dZ_def (mm: the
displacement less the state's best-fit rigid motion). Camera columns are NaN exactly where that camera's converged is 0; X..gap_mm exactly where
converged is 0; strains exactly where strain_valid is 0.

The writers take the states as an iterable (each state is formatted and written, then dropped), so a
sequence of thousands of states never needs more memory than one of them.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Callable, Iterable, Sequence

import numpy as np

from calib.atomic import atomic_output
from calib.npz_stream import write_stacked_npz
from stereodic.dic.grid import Grid
from stereodic.dic.icgn import OK, OUTSIDE, STATUS_NAMES
from stereodic.dic.maps import Backdrop, MapAxes, MapMovie, MapPainter, RunScales, save_map, value_range
from stereodic.dic.output import STRAIN_COLUMNS, format_rows_beside
from stereodic.dic3d.stereo import NO_REFERENCE, RAY_GAP, CameraMatch, StereoSettings, StereoState
from stereodic.strain.measures import StrainMeasure


def csv_columns(has_strain: bool, has_deformation: bool = False) -> list[str]:
    cols = ["state", "x", "y"]
    for cam in ("left", "right"):
        cols += [f"{cam}_{c}" for c in ("u", "v", "zncc", "converged", "status")]
    cols += ["left_x0", "left_y0", "right_x0", "right_y0"]
    cols += ["X", "Y", "Z", "dX", "dY", "dZ", "gap_mm", "converged", "status", "incremental"]
    if has_strain:
        cols += [c for c, _, _ in STRAIN_COLUMNS] + ["strain_valid"]
    if has_deformation:
        cols += ["dX_def", "dY_def", "dZ_def"]
    return cols


def csv_rows(grid: Grid, st: StereoState) -> str:
    """The CSV rows (module docstring) of one state, newline-terminated (on two threads:
    `stereodic.dic.output.format_rows_beside`)."""
    names = np.array(STATUS_NAMES, "S")
    act = grid.active.ravel()
    X, Y = grid.points()
    flat = lambda a: np.asarray(a).reshape((-1,) + np.shape(a)[2:])[act]  # noqa: E731
    cols = [(np.full(int(act.sum()), st.state), "%d"), (X[act], "%g"), (Y[act], "%g")]
    for m in (st.left, st.right):
        cols += [(flat(m.u), "%.6f"), (flat(m.v), "%.6f"), (flat(m.zncc), "%.6f"), (flat(m.ok), "%d"),
                 (names[flat(m.status)], "%s")]
    for m in (st.left, st.right):
        real = flat(m.real)
        cols += [(real[:, 0], "%.6f"), (real[:, 1], "%.6f")]
    pts, disp = flat(st.points), flat(st.displacement)
    cols += [(pts[:, i], "%.6f") for i in range(3)] + [(disp[:, i], "%.6f") for i in range(3)]
    cols += [(flat(st.gap_mm), "%.6f"), (flat(st.converged), "%d"), (flat(st.status), "%s"),
             (flat(st.incremental), "%d")]
    if st.measure is not None:
        cols += [(flat(getattr(st.measure, field)), f) for _, field, f in STRAIN_COLUMNS]
        cols += [(flat(st.measure.valid), "%d")]
    if st.deformation is not None:
        deformation = flat(st.deformation)
        cols += [(deformation[:, i], "%.6f") for i in range(3)]
    return format_rows_beside([c for c, _ in cols], [f for _, f in cols])


def write_csv(path: str | os.PathLike, rows: Iterable[str], *, has_strain: bool, has_deformation: bool = False) -> None:
    """The CSV of the module docstring from its rows, state by state (`csv_rows` of each state)."""
    with atomic_output(path) as tmp, open(tmp, "w") as out:
        out.write(",".join(csv_columns(has_strain, has_deformation)) + "\n")
        for text in rows:
            out.write(text)


def npz_keys(has_strain: bool, has_deformation: bool = False) -> list[str]:
    """The per-state arrays of dic.npz (and of the run folder's state files), in the file's order."""
    keys = ["state"] + [f"{c}_{k}" for c in ("left", "right") for k in ("u", "v", "zncc", "status")]
    keys += ["points", "displacement", "gap_mm", "converged"]
    if has_strain:
        keys += ["exx", "eyy", "exy", "strain_valid"]
    keys += [f"{c}_{k}" for c in ("left", "right") for k in ("x0", "y0", "noise_px")] + ["incremental"]
    if has_strain:
        keys += ["e_major", "e_minor", "e_angle", "e_vm"]
    if has_deformation:
        keys += ["deformation"]
    return keys


_MEASURE = {c: f for c, f, _ in STRAIN_COLUMNS} | {"strain_valid": "valid"}


_COMBINED = ("ok", RAY_GAP, NO_REFERENCE)  # status codes 0-2; 3: "left:<status>", 4: "right:<status>"


def _status_code(st: StereoState) -> np.ndarray:
    left = np.char.startswith(np.asarray(st.status, str), "left:")
    return np.select([st.status == "ok", st.status == RAY_GAP, st.status == NO_REFERENCE, left],
                     [0, 1, 2, 3], 4).astype(np.int8)


def _status_strings(code: np.ndarray, left_status: np.ndarray, right_status: np.ndarray) -> np.ndarray:
    """The combined statuses back from `_status_code` and the cameras' statuses: a camera's failure whose
    own match is ok is its subset taking in the blank band (`stereo.in_view`), "outside"."""
    names = np.array(STATUS_NAMES, dtype=object)
    out = np.array(_COMBINED, dtype=object)[np.minimum(code, 2)]
    for c, side, status in ((3, "left:", left_status), (4, "right:", right_status)):
        own = status[code == c]
        out[code == c] = side + names[np.where(own == OK, OUTSIDE, own)]
    return out


def state_arrays(st: StereoState) -> dict[str, np.ndarray]:
    """A state's arrays: those of dic.npz (`npz_keys`) and `status_code` (the combined status: 0 ok, 1
    ray_gap, 2 no_reference, 3 the left camera's, 4 the right camera's)."""
    out = {"state": np.array(st.state)}
    for cam in ("left", "right"):
        m = getattr(st, cam)
        out.update({f"{cam}_{k}": getattr(m, k) for k in ("u", "v", "zncc", "status", "noise_px")})
        out[f"{cam}_x0"], out[f"{cam}_y0"] = m.real[..., 0], m.real[..., 1]
    out.update(points=st.points, displacement=st.displacement, gap_mm=st.gap_mm, converged=st.converged,
               incremental=st.incremental, status_code=_status_code(st))
    if st.measure is not None:
        out.update({key: getattr(st.measure, f) for key, f in _MEASURE.items()})
    if st.deformation is not None:
        out["deformation"] = st.deformation
    return out


def state_from_arrays(a, measure: str | None) -> StereoState:
    """The StereoState of `state_arrays` (its strain fit is not kept: `strain` is None)."""
    def cam(c):
        return CameraMatch(*(np.array(a[f"{c}_{k}"]) for k in ("u", "v", "zncc", "status", "noise_px")),
                           np.stack([a[f"{c}_x0"], a[f"{c}_y0"]], -1))

    m = None
    if "strain_valid" in a:
        m = StrainMeasure(measure, *(np.array(a[key]) for key in _MEASURE))
    return StereoState(int(a["state"]), cam("left"), cam("right"), np.array(a["points"]),
                       np.array(a["displacement"]), np.array(a["gap_mm"]), np.array(a["converged"]),
                       _status_strings(np.array(a["status_code"]), np.array(a["left_status"]),
                                       np.array(a["right_status"])), None, np.array(a["incremental"]), m,
                       np.array(a["deformation"]) if "deformation" in a else None)


def write_npz(path: str | os.PathLike, grid: Grid, values: Callable[[str], Iterable[np.ndarray]], count: int,
              has_strain: bool, settings: StereoSettings, info: dict, has_deformation: bool = False) -> None:
    """Arrays x (nx,), y (ny,), active (ny, nx); per state (S, ny, nx): left_u, left_v, left_zncc,
    left_status, right_* the same, gap_mm, converged [, exx, eyy, exy, strain_valid], left_x0, left_y0,
    left_noise_px, right_* the same, incremental [, e_major, e_minor, e_angle, e_vm]; points and
    displacement (S, ny, nx, 3) mm [, deformation (S, ny, nx, 3) mm: the displacement less each state's
    rigid motion]; state (S,); meta: JSON with the settings, status names and `info` (rig, dataset,
    world_from_rig, frame, ...). `values(key)` iterates one array's per-state values."""
    meta = dict(format="stereodic.dic/1", status_names=list(STATUS_NAMES), units="pixels (rectified), mm",
                settings={"dic": settings.dic.__dict__, **{k: v for k, v in settings.__dict__.items() if k != "dic"}},
                **info)
    arrays = dict(meta=np.array(json.dumps(meta)), x=grid.xs, y=grid.ys, active=grid.active)
    write_stacked_npz(path, arrays, {key: (lambda key=key: values(key)) for key in npz_keys(has_strain, has_deformation)},
                      count)


def state_maps(st: StereoState) -> dict[str, tuple[np.ndarray, str, int]]:
    """The quantities of a state's maps: name -> (values (ny, nx), unit, decimals): Z, dX, dY, dZ (mm)
    [, dX_def, dY_def, dZ_def (mm, rigid motion removed)] [, exx, eyy, exy (microstrain)]."""
    maps = {"Z": (st.points[..., 2], "mm", 3), "dX": (st.displacement[..., 0], "mm", 4),
            "dY": (st.displacement[..., 1], "mm", 4), "dZ": (st.displacement[..., 2], "mm", 4)}
    if st.deformation is not None:
        maps.update({f"{c}_def": (st.deformation[..., i], "mm", 4) for i, c in enumerate(("dX", "dY", "dZ"))})
    if st.measure is not None:
        maps.update({c: (getattr(st.measure, c) * 1e6, "microstrain", 0) for c in ("exx", "eyy", "exy")})
    return maps


def state_ranges(st: StereoState, active: np.ndarray | None) -> dict[str, tuple[float, float] | None]:
    """Each map quantity's `maps.value_range` in state `st` at the grid's `active` points: what the run's
    colour scales take of it (`maps.RunScales.add_range`)."""
    return {name: value_range(values, active) for name, (values, _, _) in state_maps(st).items()}


STRAIN_FLOOR = 100.0   # microstrain: the least half-range of a strain map's colours (a run at rest)


def plot_state(folder: str | os.PathLike, st: StereoState, axes: MapAxes, label: str, *,
               scales: RunScales | None = None, image: np.ndarray | None = None, frame: str = "rig's frame",
               movies: dict[str, MapMovie] | None = None, painter: MapPainter | None = None,
               names: Sequence[str] | None = None) -> None:
    """PNG maps of one state k, named `label` (its load case): state{k}_{Z,dX,dY,dZ}.png [+ _exx, _eyy,
    _exy, microstrain] on `axes` (stereodic.dic.maps.surface_axes: the reference surface's X, Y in mm),
    titled with the reporting `frame`; with `scales`, the run's colour limits (`RunScales`); with
    `image` (the state's original left image), each map also drawn over it; `movies`: quantity ->
    the MapMovie each of its maps is added to; `painter`: the MapPainter whose figures are reused (one
    for the run), else a new one for the state; `names`: only these quantities' maps (None: all). State 0's
    strains are labelled: zero by definition (the measurement's noise floor shows in a second image of the
    specimen at rest). None for a state that measured no point (its diagnosis says why:
    `stereodic.dic3d.diagnose`)."""
    if not st.converged.any():
        return
    folder = Path(folder)
    painter = painter or MapPainter()
    backdrop = None if image is None else Backdrop(image, st.left.real[..., 0], st.left.real[..., 1])
    for name, (arr, unit, decimals) in state_maps(st).items():
        if names is not None and name not in names:
            continue
        what = f"{name}, {st.measure.measure} strain" if name.startswith("e") else name
        title = f"{label} - {what} ({frame})"
        if st.state == 0 and name.startswith("e"):
            title += "\nthe reference: strain 0 by definition (its noise floor shows in a second image at rest)"
        rgb = save_map(folder / f"state{st.state}_{name}.png", arr, axes, title=title, quantity=name, unit=unit,
                       decimals=decimals, signed=name != "Z", scale=None if scales is None else scales.scale(name),
                       backdrop=backdrop, painter=painter)
        if movies and name in movies:
            movies[name].add(rgb)

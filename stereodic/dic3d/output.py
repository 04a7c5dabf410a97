"""Writing stereo DIC results: CSV rows, NPZ arrays and PNG maps (all atomic).

CSV, one row per active grid point and state (x, y: the point in the LEFT rectified reference image,
pixels; per camera the 2-D columns of `dic2d`, prefixed left_ / right_: u, v such that the point is at
(x + u, y + v) in that camera's rectified image of the state (so right_u includes the disparity), zncc,
converged, status; then X, Y, Z (WCS mm, the point in this state), dX, dY, dZ (mm, from state 0), gap_mm
(distance between the two rays), converged (both cameras and the rays agree, and state 0 is measured),
status (ok, left:<status>, right:<status>, ray_gap, no_reference) and, with a strain window, the
Green-Lagrange strains exx, eyy, exy on the tangent plane and strain_valid). Camera columns are NaN
exactly where that camera's converged is 0; X..gap_mm exactly where converged is 0; strains exactly
where strain_valid is 0.
"""

from __future__ import annotations

import io
import json
import os
from pathlib import Path
from typing import Sequence

import numpy as np

from calib.atomic import write_npz as _write_npz, write_text
from stereodic.dic.grid import Grid
from stereodic.dic.icgn import STATUS_NAMES
from stereodic.dic.output import save_map
from stereodic.dic3d.stereo import StereoSettings, StereoState


def _fmt(a: np.ndarray, f: str) -> np.ndarray:
    return np.char.mod(f, a)


def write_csv(path: str | os.PathLike, grid: Grid, states: Sequence[StereoState]) -> None:
    """The CSV of the module docstring."""
    has_strain = any(s.strain is not None for s in states)
    cols = ["state", "x", "y"]
    for cam in ("left", "right"):
        cols += [f"{cam}_{c}" for c in ("u", "v", "zncc", "converged", "status")]
    cols += ["X", "Y", "Z", "dX", "dY", "dZ", "gap_mm", "converged", "status"]
    if has_strain:
        cols += ["exx", "eyy", "exy", "strain_valid"]
    out = io.StringIO()
    out.write(",".join(cols) + "\n")
    names = np.array(STATUS_NAMES)
    act = grid.active.ravel()
    X, Y = grid.points()
    for st in states:
        parts = [np.full(act.sum(), str(st.state)), _fmt(X[act], "%g"), _fmt(Y[act], "%g")]
        for m in (st.left, st.right):
            parts += [_fmt(m.u.ravel()[act], "%.6f"), _fmt(m.v.ravel()[act], "%.6f"), _fmt(m.zncc.ravel()[act], "%.6f"),
                      m.ok.ravel()[act].astype(int).astype(str), names[m.status.ravel()[act]]]
        pts, disp = st.points.reshape(-1, 3)[act], st.displacement.reshape(-1, 3)[act]
        parts += [_fmt(pts[:, i], "%.6f") for i in range(3)] + [_fmt(disp[:, i], "%.6f") for i in range(3)]
        parts += [_fmt(st.gap_mm.ravel()[act], "%.6f"), st.converged.ravel()[act].astype(int).astype(str),
                  st.status.ravel()[act].astype(str)]
        if has_strain:
            s = st.strain
            parts += [_fmt(getattr(s, c).ravel()[act], "%.7f") for c in ("exx", "eyy", "exy")]
            parts += [s.valid.ravel()[act].astype(int).astype(str)]
        rows = parts[0]
        for p in parts[1:]:
            rows = np.char.add(np.char.add(rows, ","), p)
        out.write("\n".join(rows.tolist()) + "\n")
    write_text(path, out.getvalue())


def write_npz(path: str | os.PathLike, grid: Grid, states: Sequence[StereoState], settings: StereoSettings,
              info: dict) -> None:
    """Arrays x (nx,), y (ny,), active (ny, nx); per state (S, ny, nx): left_u, left_v, left_zncc,
    left_status, right_* the same, gap_mm, converged [, exx, eyy, exy, strain_valid]; points and
    displacement (S, ny, nx, 3) WCS mm; state (S,); meta: JSON with the settings, status names and
    `info` (rig, dataset)."""
    arrays = dict(x=grid.xs, y=grid.ys, active=grid.active, state=np.array([s.state for s in states]))
    for cam in ("left", "right"):
        for c in ("u", "v", "zncc", "status"):
            arrays[f"{cam}_{c}"] = np.stack([getattr(getattr(s, cam), c) for s in states])
    for c in ("points", "displacement", "gap_mm", "converged"):
        arrays[c] = np.stack([getattr(s, c) for s in states])
    if states[0].strain is not None:
        for c in ("exx", "eyy", "exy"):
            arrays[c] = np.stack([getattr(s.strain, c) for s in states])
        arrays["strain_valid"] = np.stack([s.strain.valid for s in states])
    meta = dict(format="stereodic.dic/1", status_names=list(STATUS_NAMES), units="pixels (rectified), WCS mm",
                settings={"dic": settings.dic.__dict__, **{k: v for k, v in settings.__dict__.items() if k != "dic"}},
                **info)
    _write_npz(path, meta=np.array(json.dumps(meta)), **arrays)


def plot_states(folder: str | os.PathLike, grid: Grid, states: Sequence[StereoState]) -> None:
    """PNG maps per state k: state{k}_{Z,dX,dY,dZ}.png [+ _exx, _eyy, _exy] (axes: left reference pixels)."""
    folder = Path(folder)
    for st in states:
        maps = {"Z": (st.points[..., 2], "mm"), "dX": (st.displacement[..., 0], "mm"),
                "dY": (st.displacement[..., 1], "mm"), "dZ": (st.displacement[..., 2], "mm")}
        if st.strain is not None:
            maps.update({c: (getattr(st.strain, c) * 1e6, "microstrain") for c in ("exx", "eyy", "exy")})
        for name, (arr, unit) in maps.items():
            save_map(folder / f"state{st.state}_{name}.png", arr, grid, f"state {st.state}: {name}",
                     f"{name} ({unit})")

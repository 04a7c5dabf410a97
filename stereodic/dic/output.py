"""Writing 2D DIC results: CSV rows, NPZ arrays and PNG maps (all atomic).

CSV columns: image, x, y, u, v, zncc, converged, status, iterations, noise_px [, exx, eyy, exy,
strain_valid].
Only active grid points are written. u, v are NaN exactly where converged is 0 (status says why);
strains are NaN exactly where strain_valid is 0.
"""

from __future__ import annotations

import io
import json
import os
from pathlib import Path
from typing import TYPE_CHECKING, Sequence

import numpy as np

from calib.atomic import atomic_output, write_npz as _write_npz, write_text
from stereodic.dic.correlate import DicField, DicSettings
from stereodic.dic.icgn import STATUS_NAMES

if TYPE_CHECKING:  # strain (and its scipy) is loaded only by the commands that compute strain
    from stereodic.strain import Strain


def write_csv(path: str | os.PathLike, fields: Sequence[DicField], strains: Sequence[Strain | None]) -> None:
    """One row per active point and deformed image."""
    has_strain = any(s is not None for s in strains)
    cols = "image,x,y,u,v,zncc,converged,status,iterations,noise_px"
    row = "%d,%g,%g,%.6f,%.6f,%.6f,%d,%s,%d,%.5f"
    if has_strain:
        cols += ",exx,eyy,exy,strain_valid"
        row += ",%.7f,%.7f,%.7f,%d"
    out = io.StringIO()
    out.write(cols + "\n")
    names = np.array(STATUS_NAMES)
    for k, (f, s) in enumerate(zip(fields, strains)):
        act = f.grid.active.ravel()
        X, Y = f.grid.points()
        status = f.points.status[act]
        columns = [np.full(act.sum(), k), X[act], Y[act], f.u.ravel()[act], f.v.ravel()[act], f.points.zncc[act],
                   (status == 0).astype(int), names[status], f.points.iterations[act], f.noise_px.ravel()[act]]
        if has_strain:
            columns += [s.exx.ravel()[act], s.eyy.ravel()[act], s.exy.ravel()[act], s.valid.ravel()[act].astype(int)]
        # one %-format per row of Python values: 4x faster than numpy's per-column string arrays
        out.write("\n".join(row % r for r in zip(*(c.tolist() for c in columns))) + "\n")
    write_text(path, out.getvalue())


def write_npz(path: str | os.PathLike, fields: Sequence[DicField], strains: Sequence[Strain | None],
              settings: DicSettings, images: Sequence[str]) -> None:
    """Arrays x (nx,), y (ny,), active (ny, nx) and u, v, zncc, status, noise_px (n_images, ny, nx)
    [+ exx, eyy, exy]; meta: JSON with the settings, image names and status names."""
    g = fields[0].grid
    arrays = dict(x=g.xs, y=g.ys, active=g.active, u=np.stack([f.u for f in fields]),
                  v=np.stack([f.v for f in fields]), zncc=np.stack([f.zncc for f in fields]),
                  status=np.stack([f.status for f in fields]), noise_px=np.stack([f.noise_px for f in fields]))
    if strains[0] is not None:
        for c in ("exx", "eyy", "exy"):
            arrays[c] = np.stack([getattr(s, c) for s in strains])
    meta = dict(format="stereodic.dic2d/1", images=list(images), status_names=list(STATUS_NAMES),
                settings=settings.__dict__)
    _write_npz(path, meta=np.array(json.dumps(meta)), **arrays)


def save_map(path: str | os.PathLike, arr: np.ndarray, grid, title: str, label: str) -> None:
    """One PNG map (matplotlib, atomic) of a (ny, nx) array on `grid` (axes in reference pixels); NaN
    points are left blank."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    extent = (grid.xs[0], grid.xs[-1], grid.ys[-1], grid.ys[0])
    fig, ax = plt.subplots(figsize=(6, 5))
    im = ax.imshow(arr, extent=extent, cmap="viridis", interpolation="nearest")
    fig.colorbar(im, ax=ax, label=label)
    ax.set_title(title)
    ax.set_xlabel("x (px)")
    ax.set_ylabel("y (px)")
    with atomic_output(path) as tmp:
        fig.savefig(tmp, dpi=100)
    plt.close(fig)


def plot_fields(folder: str | os.PathLike, fields: Sequence[DicField], strains: Sequence[Strain | None]
                ) -> list[Path]:
    """PNG maps per deformed image k: image{k}_u.png, _v, _zncc [, _exx, _eyy, _exy]; returns their paths."""
    folder = Path(folder)
    paths = []
    for k, (f, s) in enumerate(zip(fields, strains)):
        maps = {"u": (f.u, "px"), "v": (f.v, "px"), "zncc": (np.where(f.ok, f.zncc, np.nan), "")}
        if s is not None:
            maps.update(exx=(s.exx, ""), eyy=(s.eyy, ""), exy=(s.exy, ""))
        for name, (arr, unit) in maps.items():
            paths.append(folder / f"image{k}_{name}.png")
            save_map(paths[-1], arr, f.grid, f"image {k}: {name}", f"{name} {unit}".strip())
    return paths

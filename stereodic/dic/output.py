"""Writing 2D DIC results image by image: CSV rows, NPZ arrays and PNG maps (all atomic).

CSV columns: image, x, y, u, v, zncc, converged, status, iterations, noise_px [, exx, eyy, exy, e_major,
e_minor, e_angle, e_vm, strain_valid] (the strain measure's components, principal strains, the major
direction in degrees from x, the von Mises equivalent: `stereodic.strain.measures`).
Only active grid points are written. u, v are NaN exactly where converged is 0 (status says why);
strains are NaN exactly where strain_valid is 0.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Iterable

import numpy as np

from calib.atomic import atomic_output
from calib.csv_text import format_rows
from calib.npz_stream import write_stacked_npz
from stereodic.dic.background import side_by_side, threads
from stereodic.dic.correlate import DicField, DicSettings
from stereodic.dic.icgn import STATUS_NAMES

if TYPE_CHECKING:  # strain measures (and scipy) are loaded only by the commands that compute strain
    from stereodic.strain.measures import StrainMeasure

SPLIT_ROWS = 20_000  # an image with more rows has its halves formatted on two threads at once
STRAIN_COLUMNS = (("exx", "exx", "%.7f"), ("eyy", "eyy", "%.7f"), ("exy", "exy", "%.7f"),
                  ("e_major", "major", "%.7f"), ("e_minor", "minor", "%.7f"), ("e_angle", "angle_deg", "%.4f"),
                  ("e_vm", "von_mises", "%.7f"))
ROW_FORMATS = ("%d", "%g", "%g", "%.6f", "%.6f", "%.6f", "%d", "%s", "%d", "%.5f")


def csv_header(has_strain: bool) -> str:
    cols = "image,x,y,u,v,zncc,converged,status,iterations,noise_px"
    if has_strain:
        cols += "," + ",".join(c for c, _, _ in STRAIN_COLUMNS) + ",strain_valid"
    return cols + "\n"


def csv_rows(k: int, f: DicField, m: StrainMeasure | None) -> str:
    """The rows of deformed image k (its field and strain measure), newline-terminated (on two threads:
    `format_rows_beside`)."""
    act = f.grid.active.ravel()
    X, Y = f.grid.points()
    status = f.points.status[act]
    columns = [np.full(act.sum(), k), X[act], Y[act], f.u.ravel()[act], f.v.ravel()[act], f.points.zncc[act],
               status == 0, np.array(STATUS_NAMES, "S")[status], f.points.iterations[act], f.noise_px.ravel()[act]]
    formats = ROW_FORMATS
    if m is not None:
        formats += tuple(ff for _, _, ff in STRAIN_COLUMNS) + ("%d",)
        columns += [getattr(m, field).ravel()[act] for _, field, _ in STRAIN_COLUMNS] + [m.valid.ravel()[act]]
    return format_rows_beside(columns, formats)


def format_rows_beside(columns: list[np.ndarray], formats: tuple[str, ...] | list[str]) -> str:
    """`calib.csv_text.format_rows(columns, formats)`; with more than one thread (`background.threads`) and
    more than SPLIT_ROWS rows, its halves formatted side by side (numpy's array operations release the
    interpreter's lock)."""
    n = len(columns[0]) if columns else 0
    if threads() < 2 or n < SPLIT_ROWS:
        return format_rows(columns, formats)
    return "".join(side_by_side(*(lambda part=part: format_rows([c[part] for c in columns], formats)
                                  for part in (slice(0, n // 2), slice(n // 2, n)))))


class CsvWriter:
    """The CSV (module docstring), written image by image to a temporary file that replaces `path` when
    the writer is closed without error (a context manager)."""

    def __init__(self, path: str | os.PathLike, has_strain: bool):
        self._ctx = atomic_output(path)
        self._tmp = Path(self._ctx.__enter__())
        self._file = open(self._tmp, "w")
        self._file.write(csv_header(has_strain))

    def write(self, k: int, f: DicField, m: StrainMeasure | None) -> None:
        """Image k's rows (`csv_rows`)."""
        self._file.write(csv_rows(k, f, m))

    def __enter__(self) -> "CsvWriter":
        return self

    def __exit__(self, *exc) -> None:
        self._file.close()
        self._ctx.__exit__(*exc)


NPZ_KEYS = ("u", "v", "zncc", "status", "noise_px")
NPZ_STRAIN_KEYS = ("exx", "eyy", "exy", "strain_valid", "e_major", "e_minor", "e_angle", "e_vm")
_MEASURE = {c: f for c, f, _ in STRAIN_COLUMNS} | {"strain_valid": "valid"}


def image_arrays(f: DicField, m: StrainMeasure | None) -> dict[str, np.ndarray]:
    """One deformed image's arrays of the NPZ file, (ny, nx) each."""
    out = {"u": f.u, "v": f.v, "zncc": f.zncc, "status": f.status, "noise_px": f.noise_px}
    if m is not None:
        out.update({key: getattr(m, field) for key, field in _MEASURE.items()})
    return out


def write_npz(path: str | os.PathLike, grid, values: Callable[[str], Iterable[np.ndarray]], count: int,
              has_strain: bool, settings: DicSettings, images: list[str], measure: str | None,
              times_s: list[float] | None = None, reference: str | None = None) -> None:
    """Arrays x (nx,), y (ny,), active (ny, nx) and u, v, zncc, status, noise_px (n_images, ny, nx)
    [+ exx, eyy, exy, strain_valid, e_major, e_minor, e_angle, e_vm]; meta: JSON with the settings, image
    names (the deformed ones; `reference`: the reference image's), strain measure and status names [,
    state_times_s: the reference's and each deformed image's timestamp, seconds, where the files record
    them (`calib.sequences`)]. `values(key)` iterates one array's per-image values."""
    meta = dict(format="stereodic.dic2d/1", images=list(images), reference=reference,
                status_names=list(STATUS_NAMES),
                settings=settings.__dict__, strain_measure=measure)
    if times_s is not None:
        meta["state_times_s"] = list(times_s)
    keys = NPZ_KEYS + (NPZ_STRAIN_KEYS if has_strain else ())
    write_stacked_npz(path, dict(meta=np.array(json.dumps(meta)), x=grid.xs, y=grid.ys, active=grid.active),
                      {key: (lambda key=key: values(key)) for key in keys}, count)


def image_maps(arrays: dict[str, np.ndarray]) -> dict[str, tuple[np.ndarray, str, int]]:
    """The quantities of a deformed image's maps from its arrays (`image_arrays`): name -> (values
    (ny, nx), unit, decimals): u, v (px), zncc (where converged) [, exx, eyy, exy (microstrain)]."""
    ok = arrays["status"] == 0
    maps = {"u": (arrays["u"], "px", 3), "v": (arrays["v"], "px", 3),
            "zncc": (np.where(ok, arrays["zncc"], np.nan), "", 4)}
    maps.update({c: (arrays[c] * 1e6, "microstrain", 0) for c in ("exx", "eyy", "exy") if c in arrays})
    return maps


def plot_image(folder: str | os.PathLike, k: int, arrays: dict[str, np.ndarray], grid, name: str,
               measure: str | None, *, scales=None, image: np.ndarray | None = None, axes=None, painter=None) -> None:
    """PNG maps of deformed image k, whose file is `name`, from its arrays (`image_arrays`):
    image{k}_u.png, _v, _zncc [, _exx, _eyy, _exy] (stereodic.dic.maps: axes in reference-image pixels,
    strains in microstrain); `scales`: the run's colour scales (`maps.RunScales`); `image`: the deformed
    image, each map also drawn over it (each point at x + u, y + v); `axes` (`maps.pixel_axes` of the
    grid) and `painter` (`maps.MapPainter`): made once for the run's images (default: here)."""
    from stereodic.dic.maps import Backdrop, pixel_axes, save_map
    folder = Path(folder)
    axes = axes or pixel_axes(grid.xs, grid.ys, grid.active)
    x, y = np.meshgrid(grid.xs, grid.ys)
    backdrop = None if image is None else Backdrop(image, x + arrays["u"], y + arrays["v"], "the deformed image")
    for q, (arr, unit, decimals) in image_maps(arrays).items():
        what = f"{q}, {measure} strain" if q.startswith("e") and measure else q
        save_map(folder / f"image{k}_{q}.png", arr, axes, title=f"deformed image {k} ({name}) - {what}", quantity=q,
                 unit=unit, decimals=decimals, signed=q != "zncc", scale=None if scales is None else scales.scale(q),
                 backdrop=backdrop, painter=painter)

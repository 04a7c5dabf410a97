"""A DIC result read for looking at, one state at a time: the points where they are in the ORIGINAL left
reference image, a quantity's values in one state, one point's history, and fixed colour limits.

Three sources: a `stereodic dic` run folder (`run.json` and `states/state{k:06d}.npz`, readable while
the run goes on: the states recorded done), a `dic` output's `dic.npz`, and a `dic2d` NPZ (one slice per
deformed image, `calib.npz_stream.read_slice`; its state 0 is the reference image, deformed image k
is state k + 1, as in `stereodic gauge`). Nothing is loaded whole: opening reads state 0, a redraw
reads one state's one array, a history one array per state.

Frames and units: positions are the points' places in the original (unrectified) left reference image,
pixels (a stereo result's left_x0, left_y0 of state 0; a dic2d result's grid, which is in the reference
image). Displacements dX, dY, dZ in mm in the result's reporting frame, or the specimen's (dic2d: u, v in
pixels); strains in microstrain (the result's measure) on the same frame's axes; ZNCC of the left camera;
status the combined status code.
"""

from __future__ import annotations

import json
import os
import threading
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calib.errors import InputError
from calib.npz_stream import read_slice, slice_count
from calib.npzfile import read_npz
from calib.sequences import parse_frame_ref
from stereodic.dic.output import STRAIN_COLUMNS


@dataclass(frozen=True)
class Quantity:
    """A quantity a map can show: its key in the result's arrays, its component (for a (..., 3) array),
    the factor to its unit, its unit, and whether its colour scale is centred on zero."""

    name: str
    key: str
    component: int | None
    scale: float
    unit: str
    signed: bool = True


_STRAINS = [Quantity(n, n, None, 1e6, "microstrain") for n in ("exx", "eyy", "exy", "e_major", "e_minor")] + \
    [Quantity("e_vm", "e_vm", None, 1e6, "microstrain", signed=False)]
STEREO = [Quantity(n, "displacement", i, 1.0, "mm") for i, n in enumerate(("dX", "dY", "dZ"))] + \
    [Quantity("Z", "points", 2, 1.0, "mm", signed=False)] + _STRAINS + \
    [Quantity("zncc", "left_zncc", None, 1.0, "", signed=False),
     Quantity("status", "status_code", None, 1.0, "code", signed=False)]
PLANAR = [Quantity("u", "u", None, 1.0, "px"), Quantity("v", "v", None, 1.0, "px")] + _STRAINS + \
    [Quantity("zncc", "zncc", None, 1.0, "", signed=False),
     Quantity("status", "status", None, 1.0, "code", signed=False)]
LIMIT_STATES = 24  # the colour limits come from at most this many states, evenly spread over the run
MEASURES_KEPT = 4  # states whose specimen-frame strains are kept (a quantity change refits nothing)
_FIELDS = {column: field for column, field, _ in STRAIN_COLUMNS if column != "e_angle"}  # quantity -> StrainMeasure


class DicSource:
    """A saved DIC result (module docstring), opened at `path`: a run folder, a dic.npz or a dic2d NPZ.

    Parameters
    ----------
    path : path
        The result; InputError naming it when it is none of the three, or holds no finished state.
    frame : SpecimenFrame, optional
        Report positions (Z), displacements (dX, dY, dZ) and strains in this frame (`stereodic.gauge.frame`:
        the specimen's) rather than the result's own: the strains refitted on state 0's shape in its axes
        over the run's strain window, in the run's measure (`stereodic.strain.results.SurfaceStrains`,
        what `stereodic dic --frame specimen` and `stereodic gauge --frame specimen` fit), one state at a
        time (the last few kept).
    """

    def __init__(self, path: str | os.PathLike, *, frame=None):
        path = Path(path)
        self.frame = frame
        self.path = path
        self.run_folder = None
        self.meta: dict = {}
        self._settings: dict | None = None
        if path.is_dir() and (path / "run.json").is_file():
            self.run_folder = path
            self.kind = "dic"
            self._count_states()
            if self.count == 0:
                raise InputError(path, "the run has no finished state yet")
            first = self._read(0, None)
            npz = path / "dic.npz"
            if npz.is_file():
                self.meta = read_npz(npz, "stereodic.dic/1", "DIC result", keys=())[0]
        else:
            if path.is_dir():
                path = path / "dic.npz"
                if not path.is_file():
                    raise InputError(self.path, "holds neither run.json nor dic.npz (not a `stereodic dic` output)")
            self.path = path
            self.meta, _ = read_npz(path, ("stereodic.dic/1", "stereodic.dic2d/1"), "DIC result", keys=())
            self.kind = "dic" if self.meta["format"] == "stereodic.dic/1" else "dic2d"
            # a dic2d result's state 0 is its reference image, deformed image k state k + 1, as for gauges
            self.count = slice_count(path, "state") if self.kind == "dic" else slice_count(path, "u") + 1
            first = None
        self.quantities = [q for q in (STEREO if self.kind == "dic" else PLANAR) if self._has(q.key)]
        if self.kind == "dic":
            x0 = first["left_x0"] if first is not None else read_slice(self.path, "left_x0", 0)
            y0 = first["left_y0"] if first is not None else read_slice(self.path, "left_y0", 0)
        else:
            with np.load(path) as z:
                xs, ys, active = z["x"], z["y"], z["active"].astype(bool)
            self._active = active      # where the reference state (state 0) measured
            x0, y0 = np.meshgrid(xs.astype(np.float64), ys.astype(np.float64))
            x0, y0 = np.where(active, x0, np.nan), np.where(active, y0, np.nan)
        self.shape = x0.shape
        self.index = np.flatnonzero(np.isfinite(x0.ravel()) & np.isfinite(y0.ravel()))
        self.x = x0.ravel()[self.index]
        self.y = y0.ravel()[self.index]
        self._limits: dict[str, tuple[float, float]] = {}
        self._surface = None                                  # the specimen frame's strain fit, made when asked
        self._measures: dict[int, object] = {}                # state -> its StrainMeasure in that frame
        self._strain_lock = threading.Lock()

    # ------------------------------------------------------------------ reading
    def _count_states(self) -> None:
        manifest = json.loads((self.run_folder / "run.json").read_text())
        self.count = int(manifest.get("done", 0))
        self.total = int(manifest.get("states", self.count))
        self.run_settings = manifest.get("settings", {})

    def refresh(self) -> int:
        """The number of finished states, read again while the run goes on (a run folder whose states are
        not all done); returns it."""
        if self.run_folder is not None and self.count < self.total:
            self._count_states()
        return self.count

    def _read(self, k: int, key: str | None):
        """State k's array `key` (None: the state file's arrays, a run folder only)."""
        if self.run_folder is not None:
            with np.load(self.run_folder / "states" / f"state{k:06d}.npz") as z:
                return {n: z[n] for n in z.files} if key is None else z[key]
        if self.kind == "dic2d":
            return self._reference_state(key) if k == 0 else read_slice(self.path, key, k - 1)
        return read_slice(self.path, key, k)

    def _reference_state(self, key: str) -> np.ndarray:
        """A dic2d result's state 0, the reference image against itself: at every active grid point zero
        displacement and strain, ZNCC 1 and status 0 (converged); NaN elsewhere (status -1)."""
        if key == "status":
            return np.where(self._active, 0, -1)
        return np.where(self._active, 1.0 if key == "zncc" else 0.0, np.nan)

    def _has(self, key: str) -> bool:
        if self.run_folder is not None:
            with np.load(self.run_folder / "states" / "state000000.npz") as z:
                return key in z.files
        with np.load(self.path) as z:
            return key in z.files

    def quantity(self, name: str) -> Quantity:
        """The quantity called `name`; InputError naming it if this result has none such."""
        for q in self.quantities:
            if q.name == name:
                return q
        raise InputError("quantity", f"{name!r} is not one of {', '.join(q.name for q in self.quantities)}")

    def values(self, k: int, name: str) -> np.ndarray:
        """(N,) float64: quantity `name` in state k at the points (`x`, `y`), in its unit (NaN: not
        measured); InputError naming the state when it is not finished."""
        if not 0 <= k < self.count:
            raise InputError("state", f"{k} is not one of the finished states 0..{self.count - 1}")
        q = self.quantity(name)
        if self.frame is not None and q.key in _FIELDS:
            a = getattr(self._frame_measure(k), _FIELDS[q.key])
        else:
            a = self._read(k, q.key)
        if self.frame is not None and q.key in ("points", "displacement"):
            a = self.frame.apply(a) if q.key == "points" else self.frame.rotate(a)
        a = a.reshape(-1, 3)[:, q.component] if q.component is not None else a.ravel()
        return a[self.index].astype(np.float64) * q.scale

    def strain_settings(self) -> tuple[int, str]:
        """(window in grid points, measure) of the run's strains: its own settings (the run folder's
        manifest, or dic.npz's meta), else 5 and green-lagrange, as `stereodic gauge`."""
        own = (self.run_settings.get("stereo") if self.run_folder is not None else self.meta.get("settings")) or {}
        return int(own.get("strain_window") or 5), str(own.get("strain_measure") or "green-lagrange")

    def _frame_measure(self, k: int):
        """State k's StrainMeasure refitted in `frame`'s axes (class docstring), the last few states kept."""
        from stereodic.strain.results import SurfaceStrains
        with self._strain_lock:
            if k not in self._measures:
                if self._surface is None:
                    window, measure = self.strain_settings()
                    self._surface = SurfaceStrains(self._read(0, "points"), window=window, measure=measure,
                                                   frame=self.frame)
                if len(self._measures) >= MEASURES_KEPT:
                    self._measures.pop(next(iter(self._measures)))
                self._measures[k] = self._surface(self._read(k, "displacement"))
            return self._measures[k]

    def history(self, point: int, name: str) -> np.ndarray:
        """(count,) float64: quantity `name` at point `point` (an index into `x`, `y`) in every finished
        state, read one state at a time."""
        if not 0 <= point < self.index.size:
            raise InputError("point", f"{point} is not one of the {self.index.size} points")
        return np.array([self.values(k, name)[point] for k in range(self.count)])

    def nearest(self, x: float, y: float) -> int:
        """The point nearest to (x, y) in the original left reference image (pixels)."""
        return int(np.argmin(np.hypot(self.x - x, self.y - y)))

    def limits(self, name: str) -> tuple[float, float]:
        """Fixed colour limits of quantity `name` over the run, in its unit: `stereodic.dic.maps.RunScales`
        (what the run's PNG maps use: the widest of each state's 1st-99th percentiles, symmetric about
        zero for a signed quantity, strains at least +-STRAIN_FLOOR) over up to LIMIT_STATES states spread
        over the finished ones; the status codes' own range for `status`. Strains in the specimen's frame
        take no refit here: their range is bounded by the principal strains the result holds (in-plane
        invariants): exx and eyy lie between e_minor and e_major, |exy| within (e_major - e_minor) / 2."""
        if name in self._limits:
            return self._limits[name]
        if name == "status":
            return (0.0, 4.0)
        from stereodic.dic.maps import RunScales
        from stereodic.dic3d.output import STRAIN_FLOOR
        q = self.quantity(name)
        scales = RunScales(floor={c: STRAIN_FLOOR for c in ("exx", "eyy", "exy")})    # microstrain, as the maps
        for k in np.unique(np.linspace(0, self.count - 1, min(self.count, LIMIT_STATES)).round().astype(int)):
            scales.add(name, self._limit_values(int(k), q), signed=q.signed)
        scale = scales.scale(name)
        lo, hi = (0.0, 1.0) if scale is None else (float(scale.lo), float(scale.hi))
        if hi - lo <= 1e-12 * max(1.0, abs(hi)):
            lo, hi = lo - 0.5, hi + 0.5
        self._limits[name] = (lo, hi)
        return lo, hi

    def _limit_values(self, k: int, q: Quantity) -> np.ndarray:
        """The values of state k that bound quantity `q`'s colour limits (`limits`), in its unit."""
        if self.frame is None or q.key not in _FIELDS or not all(self._has(n) for n in ("e_major", "e_minor")):
            return self.values(k, q.name)
        major, minor = (self._read(k, n).ravel()[self.index].astype(np.float64) * q.scale
                        for n in ("e_major", "e_minor"))
        if q.key == "exy":
            return np.concatenate([(major - minor) / 2, (minor - major) / 2])
        return np.concatenate([major, minor]) if q.key in ("exx", "eyy") else self._read(k, q.key).ravel()[
            self.index].astype(np.float64) * q.scale

    # ------------------------------------------------------------------ labels and images
    def labels(self) -> list[str]:
        """Each finished state in words ("state 3: tension", "deformed image 2 (b.png)")."""
        if self.kind == "dic2d":
            from stereodic.strain.results import dic2d_state_labels   # strain's imports: only when asked
            return dic2d_state_labels(self.meta.get("images", []))
        named = self.meta.get("state_labels") or self._workspace().get("state_labels")
        if isinstance(named, list) and len(named) >= self.count:
            return [str(s) for s in named[:self.count]]
        return [f"state {k}" for k in range(self.count)]

    def _workspace(self) -> dict:
        """The run's workspace.json (the settings a run started from the workspace saved), or {}; read once."""
        if self._settings is None:
            p = (self.run_folder or self.path.parent) / "workspace.json"
            self._settings = json.loads(p.read_text()) if p.is_file() else {}
        return self._settings

    def reference_image(self) -> Path | None:
        """The original left reference image's file, where the result names it (dic.npz's left_images, the
        workspace's settings, dic2d's reference), else None."""
        if self.kind == "dic2d":
            ref = self.meta.get("reference")
        else:
            ref = (self.meta.get("left_images") or self._workspace().get("left_images") or [None])[0]
        if not ref:
            return None
        frame = parse_frame_ref(ref)                  # a video's frame, FILE::K
        return Path(ref) if (frame[0] if frame else Path(ref)).is_file() else None

    def unit(self, name: str) -> str:
        return self.quantity(name).unit


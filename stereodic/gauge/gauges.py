"""Gauges over time on a saved DIC result: virtual extensometers, points, areas and lines, placed in the
ORIGINAL left reference image (pixels) as a lab places them on its picture of the specimen.

A gauge's place in the image is turned into a place on the result's grid (`Locator`: a linear
interpolation of the grid's indices over a Delaunay triangulation of the grid points' image positions,
`GaugeResult.image_px`); the grid's points are material points, so one place on the grid is one material
point in every state, and a value there is the bilinear interpolation of its four grid neighbours
(NaN if any of them is not measured in that state).

- extensometer (two points): its length in every state, |P1 - P0| of the two points' positions (3-D in
  mm for stereo, in-plane for 2-D), and its engineering strain L / L0 - 1 (L0: state 0's length);
- point: every quantity's history at the point;
- area (a polygon): per state the mean, standard deviation and count of each quantity over the grid
  points inside it;
- line (two points): each quantity's profile along it at chosen states, sampled every half grid step,
  against the distance along the line on the reference shape (mm, or px for a 2-D result without scale).

`measure_gauges` reads the result once, state by state, and measures every gauge (`Gauges`) on each.
Gauges can be read from a JSON file (`read_gauge_file`, format "stereodic.gauges/1"):
``{"format": "stereodic.gauges/1", "extensometers": [{"name": "E1", "start": [x, y], "end": [x, y]}],
"points": [{"name": "P1", "at": [x, y]}], "areas": [{"name": "A1", "polygon": [[x, y], ...]}],
"lines": [{"name": "L1", "start": [x, y], "end": [x, y]}]}`` (names optional), written by
`write_gauge_file`.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field

import numpy as np

from calib.errors import InputError
from calib.progress import progress
from stereodic.gauge.result import GaugeResult, GaugeState

GAUGES_FORMAT = "stereodic.gauges/1"


@dataclass(frozen=True)
class Extensometer:
    """A virtual extensometer between two points of the original left reference image, pixels."""

    name: str
    start_px: tuple[float, float]
    end_px: tuple[float, float]


@dataclass(frozen=True)
class PointGauge:
    """A point of the original left reference image, pixels."""

    name: str
    at_px: tuple[float, float]


@dataclass(frozen=True)
class AreaGauge:
    """A polygon (M >= 3 corners) of the original left reference image, pixels."""

    name: str
    polygon_px: tuple[tuple[float, float], ...]


@dataclass(frozen=True)
class LineGauge:
    """A line between two points of the original left reference image, pixels."""

    name: str
    start_px: tuple[float, float]
    end_px: tuple[float, float]


@dataclass
class Gauges:
    """Every gauge of a measurement, by kind."""

    extensometers: list[Extensometer] = field(default_factory=list)
    points: list[PointGauge] = field(default_factory=list)
    areas: list[AreaGauge] = field(default_factory=list)
    lines: list[LineGauge] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.extensometers) + len(self.points) + len(self.areas) + len(self.lines)

    def __add__(self, other: "Gauges") -> "Gauges":
        return Gauges(self.extensometers + other.extensometers, self.points + other.points,
                      self.areas + other.areas, self.lines + other.lines)


@dataclass
class ExtensometerSeries:
    """An extensometer's `length` (S,) (mm, or px for a 2-D result without scale; NaN where an end is not
    measured) and engineering `strain` (S,) = length / length[0] - 1, state by state."""

    gauge: Extensometer
    length: np.ndarray
    strain: np.ndarray


@dataclass
class PointSeries:
    """A point's `values`: quantity -> (S,) history (NaN where not measured)."""

    gauge: PointGauge
    values: dict[str, np.ndarray]


@dataclass
class AreaSeries:
    """An area's per-state `mean`, `std` (quantity -> (S,)) and `count` (quantity -> (S,) int: the
    measured grid points inside), over `points` grid points inside the polygon."""

    gauge: AreaGauge
    points: int
    mean: dict[str, np.ndarray]
    std: dict[str, np.ndarray]
    count: dict[str, np.ndarray]


@dataclass
class LineProfile:
    """A line's samples: `image_px` (P, 2) in the original left reference image, `distance` (P,) along
    the line on the reference shape (the result's unit, from its start); `states` (T,) the states
    profiled; `values` quantity -> (T, P)."""

    gauge: LineGauge
    image_px: np.ndarray
    distance: np.ndarray
    states: np.ndarray
    values: dict[str, np.ndarray]


@dataclass
class GaugeTables:
    """What `measure_gauges` measured: one series per gauge by kind, the result's `unit`, quantity
    `units`, state `labels`, and the `frame` record."""

    extensometers: list[ExtensometerSeries]
    points: list[PointSeries]
    areas: list[AreaSeries]
    lines: list[LineProfile]
    unit: str
    units: dict[str, str]
    labels: list[str]
    frame: dict


class Locator:
    """Places of the original left reference image on a result's grid.

    Parameters
    ----------
    image_px : (ny, nx, 2) float
        Each grid point's position in the original left reference image, pixels; NaN where unknown.
    """

    def __init__(self, image_px: np.ndarray):
        from scipy.interpolate import LinearNDInterpolator
        ny, nx = image_px.shape[:2]
        ok = np.isfinite(image_px).all(-1)
        if ok.sum() < 3:
            raise InputError(None, "the result has fewer than 3 measured reference points: no gauge can be placed")
        rows, cols = np.nonzero(ok)
        self.shape = (ny, nx)
        self._index = LinearNDInterpolator(image_px[ok], np.column_stack([cols, rows]).astype(float))

    def grid_index(self, xy_px: np.ndarray) -> np.ndarray:
        """(N, 2) fractional (column, row) grid indices of image positions (N, 2), pixels; NaN outside
        the measured area."""
        return np.atleast_2d(self._index(np.asarray(xy_px, float).reshape(-1, 2)))

    def sample(self, values: np.ndarray, index: np.ndarray) -> np.ndarray:
        """Bilinear values (N, ...) of a grid array (ny, nx, ...) at fractional indices (N, 2); NaN where
        a neighbour is NaN or the index is."""
        ny, nx = self.shape
        idx = np.asarray(index, float)
        bad = ~np.isfinite(idx).all(1)
        idx = np.where(bad[:, None], 0.0, idx)
        c0 = np.clip(np.floor(idx[:, 0]).astype(int), 0, max(nx - 2, 0))
        r0 = np.clip(np.floor(idx[:, 1]).astype(int), 0, max(ny - 2, 0))
        fc, fr = idx[:, 0] - c0, idx[:, 1] - r0
        c1, r1 = np.minimum(c0 + 1, nx - 1), np.minimum(r0 + 1, ny - 1)
        extra = (slice(None),) + (None,) * (values.ndim - 2)
        fc, fr = fc[extra], fr[extra]
        out = ((1 - fr) * ((1 - fc) * values[r0, c0] + fc * values[r0, c1])
               + fr * ((1 - fc) * values[r1, c0] + fc * values[r1, c1]))
        out[bad] = np.nan
        return out


def _inside(polygon: np.ndarray, xy: np.ndarray) -> np.ndarray:
    from matplotlib.path import Path
    ok = np.isfinite(xy).all(-1)
    flat = np.where(ok[..., None], xy, 0.0).reshape(-1, 2)
    return Path(polygon).contains_points(flat).reshape(ok.shape) & ok


def default_line_states(count: int, *, most: int = 11) -> np.ndarray:
    """The states a line is profiled at by default: all of them up to `most`, else `most` evenly spread
    from state 0 to the last."""
    return np.arange(count) if count <= most else np.unique(np.linspace(0, count - 1, most).round().astype(int))


def measure_gauges(result: GaugeResult, gauges: Gauges, *, line_states: list[int] | None = None) -> GaugeTables:
    """Every gauge on every state of a result, reading it once, state by state.

    Parameters
    ----------
    result : GaugeResult
        The result in its frame (`stereodic.gauge.result.open_gauge_result`).
    gauges : Gauges
        Positions in the ORIGINAL left reference image, pixels.
    line_states : list of int, optional
        The states the lines are profiled at (default `default_line_states`).

    Returns
    -------
    tables : GaugeTables
        One series per gauge (module docstring). InputError naming the gauge when it lies outside the
        measured area of the reference state (an area: holds no measured grid point), or a line state
        does not exist.
    """
    S = result.count
    states = np.asarray(default_line_states(S) if line_states is None else line_states, int)
    if states.size and (states.min() < 0 or states.max() >= S):
        raise InputError("--line-states", f"the result has states 0 to {S - 1}, got {states.tolist()}")
    loc = Locator(result.image_px)
    ext_idx = [loc.grid_index([e.start_px, e.end_px]) for e in gauges.extensometers]
    pt_idx = [loc.grid_index([p.at_px]) for p in gauges.points]
    area_masks = [_inside(np.asarray(a.polygon_px, float), result.image_px) for a in gauges.areas]
    line_px = []
    step = float(np.median(np.diff(result.grid.xs))) if len(result.grid.xs) > 1 else 1.0
    for ln in gauges.lines:
        a, b = np.asarray(ln.start_px, float), np.asarray(ln.end_px, float)
        n = max(2, int(np.ceil(np.hypot(*(b - a)) / (step / 2))) + 1)
        line_px.append(a + np.linspace(0, 1, n)[:, None] * (b - a))
    line_idx = [loc.grid_index(px) for px in line_px]

    ext_len = np.full((len(ext_idx), S), np.nan)
    pt_vals: list[dict[str, np.ndarray]] = [{} for _ in pt_idx]
    area_stats = [({}, {}, {}) for _ in area_masks]
    line_vals: list[dict[str, np.ndarray]] = [{} for _ in line_idx]
    line_dist: list[np.ndarray] = []
    row_of = {int(s): i for i, s in enumerate(states)}
    for st in progress(result.states(), "gauges", total=S, unit="state"):
        k = st.state
        if k == 0:
            _check_reference(st, gauges, loc, ext_idx, pt_idx, area_masks, line_idx)
            for idx in line_idx:
                P = loc.sample(st.position, idx)
                line_dist.append(np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(P, axis=0), axis=1))]))
        for i, idx in enumerate(ext_idx):
            P = loc.sample(st.position, idx)
            ext_len[i, k] = np.linalg.norm(P[1] - P[0])
        for i, idx in enumerate(pt_idx):
            for q, a in st.quantities.items():
                pt_vals[i].setdefault(q, np.full(S, np.nan))[k] = loc.sample(a, idx)[0]
        for i, mask in enumerate(area_masks):
            mean, std, count = area_stats[i]
            for q, a in st.quantities.items():
                v = a[mask]
                v = v[np.isfinite(v)]
                mean.setdefault(q, np.full(S, np.nan))[k] = v.mean() if v.size else np.nan
                std.setdefault(q, np.full(S, np.nan))[k] = v.std(ddof=1) if v.size > 1 else np.nan
                count.setdefault(q, np.zeros(S, int))[k] = v.size
        if k in row_of:
            for i, idx in enumerate(line_idx):
                for q, a in st.quantities.items():
                    line_vals[i].setdefault(q, np.full((len(states), len(idx)), np.nan))[row_of[k]] = loc.sample(a, idx)
    with np.errstate(invalid="ignore", divide="ignore"):
        exts = [ExtensometerSeries(e, ext_len[i], ext_len[i] / ext_len[i, 0] - 1.0)
                for i, e in enumerate(gauges.extensometers)]
    return GaugeTables(
        exts, [PointSeries(p, pt_vals[i]) for i, p in enumerate(gauges.points)],
        [AreaSeries(a, int(area_masks[i].sum()), *area_stats[i]) for i, a in enumerate(gauges.areas)],
        [LineProfile(ln, line_px[i], line_dist[i], states, line_vals[i]) for i, ln in enumerate(gauges.lines)],
        result.unit, result.units, result.labels, result.frame_record())


def _outside(what: str, name: str, xy) -> InputError:
    where = ", ".join(f"({x:g}, {y:g})" for x, y in np.atleast_2d(xy))
    return InputError(f"--{what} {name}", f"{where} px lies outside the measured area of the reference image")


def _check_reference(st: GaugeState, gauges: Gauges, loc: Locator, ext_idx, pt_idx, area_masks, line_idx) -> None:
    """InputError naming the first gauge that is not measured in the reference state."""
    def measured(idx):
        return np.isfinite(loc.sample(st.position, idx)).all(-1)

    for e, idx in zip(gauges.extensometers, ext_idx):
        if not measured(idx).all():
            raise _outside("extensometer", e.name, np.array([e.start_px, e.end_px])[~measured(idx)])
    for p, idx in zip(gauges.points, pt_idx):
        if not measured(idx).all():
            raise _outside("point", p.name, [p.at_px])
    for a, mask in zip(gauges.areas, area_masks):
        if not np.isfinite(st.position[mask]).all(-1).any():
            raise InputError(f"--area {a.name}", "the polygon holds no measured grid point of the reference image")
    for ln, idx in zip(gauges.lines, line_idx):
        ok = measured(idx)
        if not ok[[0, -1]].all():
            raise _outside("line", ln.name, np.array([ln.start_px, ln.end_px])[~ok[[0, -1]]])


def _pair(value, where: str, what: str) -> tuple[float, float]:
    try:
        x, y = (float(v) for v in value)
    except (TypeError, ValueError):
        raise InputError(where, f"{what} must be two numbers [x, y], got {value!r}") from None
    return x, y


def read_gauge_file(path: str | os.PathLike) -> Gauges:
    """The gauges of a JSON file (module docstring), positions in the original left reference image,
    pixels; unnamed gauges are named E1, P1, A1, L1... by kind; InputError naming the file otherwise."""
    try:
        with open(path) as f:
            doc = json.load(f)
    except json.JSONDecodeError as exc:
        raise InputError(path, f"is not valid JSON ({exc.msg}, line {exc.lineno})") from None
    except UnicodeDecodeError:
        raise InputError(path, "is not a text (JSON) file") from None
    if not isinstance(doc, dict) or doc.get("format", GAUGES_FORMAT) != GAUGES_FORMAT:
        raise InputError(path, f"is not a {GAUGES_FORMAT} file")
    out = Gauges()
    try:
        for i, e in enumerate(doc.get("extensometers", [])):
            out.extensometers.append(Extensometer(str(e.get("name", f"E{i + 1}")), _pair(e["start"], path, "start"),
                                                  _pair(e["end"], path, "end")))
        for i, p in enumerate(doc.get("points", [])):
            out.points.append(PointGauge(str(p.get("name", f"P{i + 1}")), _pair(p["at"], path, "at")))
        for i, a in enumerate(doc.get("areas", [])):
            corners = tuple(_pair(c, path, "a polygon corner") for c in a["polygon"])
            if len(corners) < 3:
                raise InputError(path, f"area {a.get('name', i + 1)}: a polygon needs 3 corners or more")
            out.areas.append(AreaGauge(str(a.get("name", f"A{i + 1}")), corners))
        for i, ln in enumerate(doc.get("lines", [])):
            out.lines.append(LineGauge(str(ln.get("name", f"L{i + 1}")), _pair(ln["start"], path, "start"),
                                       _pair(ln["end"], path, "end")))
    except (KeyError, TypeError, AttributeError) as exc:
        raise InputError(path, f"a gauge lacks its {exc} (see the format in `stereodic gauge --help`)") from None
    return out


def gauges_document(gauges: Gauges) -> dict:
    """`gauges` as the JSON document of a gauge file (module docstring)."""
    return {
        "format": GAUGES_FORMAT,
        "extensometers": [{"name": e.name, "start": list(e.start_px), "end": list(e.end_px)}
                          for e in gauges.extensometers],
        "points": [{"name": p.name, "at": list(p.at_px)} for p in gauges.points],
        "areas": [{"name": a.name, "polygon": [list(c) for c in a.polygon_px]} for a in gauges.areas],
        "lines": [{"name": ln.name, "start": list(ln.start_px), "end": list(ln.end_px)} for ln in gauges.lines]}


def write_gauge_file(path: str | os.PathLike, gauges: Gauges) -> None:
    """Write `gauges` as a JSON gauge file (module docstring; atomic), for `read_gauge_file`."""
    from calib.atomic import write_json
    write_json(path, gauges_document(gauges))

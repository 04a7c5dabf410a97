"""PNG maps of DIC fields that a lab engineer reads without the docs.

Each map says where its points are (2-D DIC: x, y in the reference image, pixels, rows downwards; stereo
DIC: X, Y of the reference surface in the reporting frame, mm, turned so that the map looks as the left
camera sees the specimen), which load case it shows (the dataset's state name, or the image's file name)
and what the colour is (the quantity and its unit on the colour bar, ticks to the precision the numbers
carry, never "-0"). The title adds the median, the range of the middle 90 % (5th to 95th percentile) and
how many of the grid's active points (its ROI and mask) were measured; the map shows the active points'
extent. The colour range spans the 1st-99th percentile (arrows on the bar where values go beyond);
a range across zero is centred on zero with a diverging colour map.

Over a run (`RunScales`), each quantity keeps one colour map and one range for every state, so that
states compare by eye: a change (displacement, strain) a diverging map centred on zero, spanning the
largest 1st-99th percentile magnitude of any state; a position or score viridis over the run's range.
With a `Backdrop` the map is drawn twice, plain and over the state's original left image
(semi-transparent, each point where the camera saw it). `MapMovie` writes a quantity's maps over the
run as an MP4 video.

How it is drawn, fast enough to write a run's maps beside its other files: each picture is one image
(a raster coloured through the colour map's table), not a patch per point. The raster's cells are placed
once among the grid's triangles (`grid_cells`: two per square of neighbouring points, so that a hole is
never bridged): once per run for the plain map (each cell the grid point nearest in the grid's rows and
columns), once per state for the map over the image (the values interpolated linearly, the image
averaged over the same cells). A `MapPainter` keeps its figures from map to map, with a fixed layout,
draws what stays (the axes, ticks and labels, the image panel's title) once and copies it for each map
(matplotlib's blitting), pastes the pictures into the figure's pixels, and the PNG is encoded by OpenCV.
"""

from __future__ import annotations

import functools
import os
from dataclasses import dataclass, field

import numpy as np

from calib.atomic import atomic_output
from calib.numbers import fixed


@dataclass(frozen=True)
class MapAxes:
    """Where each grid point of a map is: x, y (ny, nx) float arrays in `unit` ("px" or "mm"), named
    `names` on the axes; flip_x / flip_y: the axis runs right to left / top to bottom; active (ny, nx)
    bool: the grid points measured at all (the grid's ROI and mask), None = every one; token: names
    these axes in every copy of them (a worker process's, unpickled from a task)."""

    x: np.ndarray
    y: np.ndarray
    unit: str
    names: tuple[str, str]
    flip_x: bool
    flip_y: bool
    active: np.ndarray | None = None
    token: str = field(default_factory=lambda: os.urandom(8).hex(), compare=False, repr=False)
    _cache: dict = field(default_factory=dict, compare=False, repr=False)


def pixel_axes(xs: np.ndarray, ys: np.ndarray, active: np.ndarray | None = None) -> MapAxes:
    """The axes of a map on a grid of reference-image pixels: columns xs (nx,), rows ys (ny,); active
    (ny, nx) the grid's active points (None: all)."""
    x, y = np.meshgrid(np.asarray(xs, float), np.asarray(ys, float))
    return MapAxes(x, y, "px", ("x", "y"), False, True, active)


def surface_axes(xs: np.ndarray, ys: np.ndarray, points_mm: np.ndarray, active: np.ndarray | None = None) -> MapAxes:
    """The axes of a map of a stereo result: the X, Y (mm, reporting frame) of each grid point's reference
    position `points_mm` (ny, nx, 3; NaN where not measured), smoothed by a least-squares cubic in the
    grid's pixel positions (points more than 3 sigma off refitted without them) so that every cell, measured
    or not, has a place and neighbours stay in order; each axis is flipped where it runs against the left
    image's columns or rows; active (ny, nx) the grid's active points (None: all)."""
    px = pixel_axes(xs, ys, active)
    X, Y = (np.asarray(points_mm[..., i], float) for i in (0, 1))
    ok = np.isfinite(X) & np.isfinite(Y)
    if ok.sum() < 12:
        return px
    u, v = (a - a.mean() for a in (px.x, px.y))
    scale = max(np.abs(u).max(), np.abs(v).max(), 1.0)
    u, v = u / scale, v / scale
    terms = np.stack([u ** i * v ** j for n in range(4) for i in range(n, -1, -1) for j in [n - i]], -1)
    target = np.stack([X, Y], -1)
    for _ in range(2):
        coef, *_ = np.linalg.lstsq(terms[ok], target[ok], rcond=None)
        off = np.linalg.norm(terms @ coef - target, axis=-1)
        ok &= ~(off > 3 * np.sqrt(np.nanmean(off[ok] ** 2)))
    fit = terms @ coef
    X, Y = fit[..., 0], fit[..., 1]
    # which way X and Y run along the image's columns (coef[1]) and rows (coef[2])
    if abs(coef[1, 0]) >= abs(coef[1, 1]):
        return MapAxes(X, Y, "mm", ("X", "Y"), coef[1, 0] < 0, coef[2, 1] > 0, active)
    return MapAxes(Y, X, "mm", ("Y", "X"), coef[1, 1] < 0, coef[2, 0] > 0, active)   # the frame turned a quarter


def active_box(active: np.ndarray) -> tuple[slice, slice]:
    """The rows and columns (slices) of a grid that hold its active points (all of it if none is)."""
    rows, cols = np.flatnonzero(active.any(axis=1)), np.flatnonzero(active.any(axis=0))
    if not rows.size:
        return slice(None), slice(None)
    return slice(rows[0], rows[-1] + 1), slice(cols[0], cols[-1] + 1)


def _decimals(step: float) -> int:
    """The fewest decimals (up to 6) that write every multiple of the tick step `step` exactly."""
    for d in range(7):
        scaled = step * 10 ** d
        if abs(scaled - round(scaled)) <= 1e-6 * max(1.0, scaled):
            return d
    return 6


@dataclass(frozen=True)
class ColourScale:
    """A quantity's colour limits and map, fixed over a run."""

    lo: float
    hi: float
    cmap: str


def value_range(values: np.ndarray, active: np.ndarray | None = None) -> tuple[float, float] | None:
    """The 1st and 99th percentiles of a map's finite `values` at the `active` points (None: all), what
    a run's colour scale spans (`RunScales`); None where none is finite."""
    v = np.asarray(values, float)
    v = v[np.isfinite(v) & (True if active is None else active)]
    if not v.size:
        return None
    lo, hi = np.percentile(v, [1, 99])
    return float(lo), float(hi)


class RunScales:
    """The colour scales of a run's quantities (module docstring), gathered state by state: `add(name,
    values, signed=...)` for every state's map, then `scale(name)`. `given` fixes a quantity's limits
    (name -> (lo, hi), used as they are) instead of the run's percentiles; `floor` (name -> half-width) is the least range
    (a quantity that stays at zero, such as the reference state's strain, still gets readable ticks)."""

    def __init__(self, given: dict[str, tuple[float, float]] | None = None, floor: dict[str, float] | None = None):
        self.given, self.floor = dict(given or {}), dict(floor or {})
        self._range: dict[str, list[float]] = {}
        self._signed: dict[str, bool] = {}

    def add(self, name: str, values: np.ndarray, *, signed: bool, active: np.ndarray | None = None) -> None:
        """One state's map of quantity `name`: its values (NaN: not measured) at the `active` points."""
        self.add_range(name, value_range(values, active), signed=signed)

    def add_range(self, name: str, lo_hi: tuple[float, float] | None, *, signed: bool) -> None:
        """One state's map of quantity `name` by its `value_range` (None: nothing measured)."""
        self._signed[name] = signed
        if lo_hi is not None:
            lo, hi = lo_hi
            r = self._range.setdefault(name, [lo, hi])
            r[0], r[1] = min(r[0], lo), max(r[1], hi)

    def scale(self, name: str) -> ColourScale | None:
        """The quantity's scale, or None if no state measured it."""
        signed = self._signed.get(name, True)
        if name in self.given:
            lo, hi = self.given[name]
            return ColourScale(lo, hi, "RdBu_r" if signed and lo < 0 < hi else "viridis")
        elif name in self._range:
            lo, hi = self._range[name]
        else:
            return None
        if signed:
            half = max(abs(lo), abs(hi), self.floor.get(name, 0.0))
            return ColourScale(-half, half, "RdBu_r")
        if hi <= lo:
            lo, hi = lo - 1.0, hi + 1.0
        return ColourScale(lo, hi, "viridis")


# the pictures are drawn about 500 screen pixels across: their rasters no finer than this (cells across)
OVERLAY_PX = 600       # the map over the image: the image averaged down to it, the field on its cells
MAP_PX = 600           # the plain map
ALPHA = 0.55           # the field's opacity over the image


@dataclass(frozen=True)
class Cells:
    """The cells of a raster (`shape`: rows, columns) that fall in the triangles of a structured grid of
    points (`grid_cells`; `columns`: the grid's): cell `index` (m,) (flat) lies in the triangle of the
    grid points `vertices` (m, 3) (flat indices of the grid) with barycentric `weights` (m, 3)."""

    shape: tuple[int, int]
    columns: int
    index: np.ndarray
    vertices: np.ndarray
    weights: np.ndarray

    def linear(self, values: np.ndarray) -> np.ndarray:
        """The raster (rows, columns) of the grid's `values` interpolated linearly in each triangle; NaN
        outside the triangles and in a triangle with an unmeasured (NaN) corner."""
        out = np.full(self.shape[0] * self.shape[1], np.nan)
        out[self.index] = (np.asarray(values, float).ravel()[self.vertices] * self.weights).sum(1)
        return out.reshape(self.shape)

    def nearest(self, values: np.ndarray) -> np.ndarray:
        """The raster (rows, columns) of the grid's `values`, each cell that of the grid point nearest to
        it in the grid's rows and columns (the cell's row and column interpolated in its triangle and
        rounded: the grid's cells, as pcolormesh's "nearest" shading draws them); NaN outside."""
        out = np.full(self.shape[0] * self.shape[1], np.nan)
        out[self.index] = np.asarray(values, float).ravel()[self.corner]
        return out.reshape(self.shape)

    @functools.cached_property
    def corner(self) -> np.ndarray:
        """(m,) the grid point (flat index) nearest to each cell in the grid's rows and columns."""
        row, col = np.divmod(self.vertices, self.columns)
        near = lambda a: np.rint((a * self.weights).sum(1)).astype(np.intp)   # noqa: E731
        return near(row) * self.columns + near(col)


def grid_cells(x: np.ndarray, y: np.ndarray, *, origin: tuple[float, float], cell: float, shape: tuple[int, int],
               longest: float = np.inf) -> Cells:
    """The cells of a raster of `shape` (rows, columns) - cell (i, j) centred at origin + (j, i) * cell, in
    the units of x, y - that fall in the triangles of the grid points x, y (ny, nx; NaN: not placed): two
    triangles per square of neighbouring points whose corners are all placed, so that a hole in the grid
    is never bridged; a triangle with a side longer than `longest` (a stray point) is left out. A cell on
    a side shared by two triangles goes to the first of them in the grid's order (row by row; in a square,
    the triangle of its top-left corner first). Each triangle tests the cells of its bounding box (the
    compiled kernel `_kernels.grid_cells`, serial: the maps are drawn in worker processes)."""
    from stereodic.dic import _kernels

    ny, nx = np.shape(x)
    px = (np.asarray(x, np.float64).ravel() - origin[0]) / cell              # in cells
    py = (np.asarray(y, np.float64).ravel() - origin[1]) / cell
    triangle = np.full(tuple(shape), -1, np.int64)
    weights = np.empty((*shape, 2))
    _kernels.grid_cells(px, py, nx, float(longest) / cell, triangle, weights)
    index = np.flatnonzero(triangle.ravel() >= 0)
    square, second = np.divmod(triangle.ravel()[index], 2)
    r, c = np.divmod(square, max(nx - 1, 1))
    a = r * nx + c
    vertices = np.where(second[:, None] == 1, np.column_stack([a + 1, a + nx + 1, a + nx]),
                        np.column_stack([a, a + 1, a + nx]))
    w = weights.reshape(-1, 2)[index]
    return Cells(tuple(shape), nx, index, vertices, np.column_stack([w, 1.0 - w.sum(1)]))


def _spacing(x: np.ndarray, y: np.ndarray) -> float:
    """The median distance between neighbouring grid points (along rows and columns; inf if none)."""
    steps = np.concatenate([np.hypot(np.diff(x, axis=a), np.diff(y, axis=a)).ravel() for a in (0, 1)])
    steps = steps[np.isfinite(steps) & (steps > 0)]
    return float(np.median(steps)) if steps.size else np.inf


@dataclass(frozen=True)
class Backdrop:
    """The state's original left image (H, W) and where each grid point is in it, x, y (ny, nx) pixels
    (NaN where not seen), for the map over the image; `label` names the image in the panel's title."""

    image: np.ndarray
    x: np.ndarray
    y: np.ndarray
    label: str = "the left camera's image of the state"
    _cache: dict = field(default_factory=dict, compare=False, repr=False)

    def _cells(self) -> tuple[Cells, int]:
        """The raster's cells among the grid's triangles (`grid_cells`) and their size r (pixels): made
        once, for every quantity."""
        c = self._cache
        if "cells" not in c:
            h, w = self.image.shape[:2]
            r = max(1, -(-max(h, w) // OVERLAY_PX))
            centre = (r - 1) / 2                         # a cell is the mean of r x r pixels
            c["cells"] = grid_cells(self.x, self.y, origin=(centre, centre), cell=r, shape=(-(-h // r), -(-w // r)),
                                    longest=3 * _spacing(self.x, self.y)), r
        return c["cells"]

    def raster(self, values: np.ndarray) -> tuple[np.ndarray, tuple[float, float, float, float]]:
        """(field, extent): `values` (ny, nx) interpolated linearly between the points where the camera
        saw them - two triangles per square of neighbouring grid points - onto a raster of the image
        (cells of r x r pixels, at most OVERLAY_PX across; NaN outside the triangles, in a triangle with
        an unmeasured corner or a side longer than 3 grid spacings: a hole is not bridged), and the
        raster's extent in image pixels (imshow's: left, right, bottom, top)."""
        cells, r = self._cells()
        h, w = cells.shape
        return cells.linear(values), (-0.5, w * r - 0.5, h * r - 0.5, -0.5)

    def gray(self) -> np.ndarray:
        """The image on the raster's cells (each the mean of its r x r pixels), its 0.5-99.5 percentile
        range stretched to 0..255 (float32)."""
        c = self._cache
        if "gray" not in c:
            cells, r = self._cells()
            h, w = cells.shape
            img = np.asarray(self.image, np.float32)
            img = np.pad(img, ((0, h * r - img.shape[0]), (0, w * r - img.shape[1])), mode="edge")
            img = img.reshape(h, r, w, r).mean((1, 3))
            lo, hi = np.percentile(img, [0.5, 99.5])
            c["gray"] = np.clip((img - lo) * (255.0 / max(hi - lo, 1e-9)), 0, 255).astype(np.float32)
        return c["gray"]


@functools.lru_cache(maxsize=8)
def _table(cmap: str) -> np.ndarray:
    """(257, 3) float32: the colour map's 256 colours (matplotlib's table, 0..255) and white."""
    from matplotlib import colormaps
    table = np.rint(colormaps[cmap](np.linspace(0.0, 1.0, 256))[:, :3] * 255.0)
    return np.vstack([table, [[255.0] * 3]]).astype(np.float32)


def colours(values: np.ndarray, lo: float, hi: float, cmap: str) -> np.ndarray:
    """RGB (..., 3) float32 0..255 of `values` on the colour map `cmap` (matplotlib's 256-entry table, as
    matplotlib colours an image) from `lo` to `hi` (below / above: the ends' colours); NaN: white."""
    t = (np.asarray(values, np.float32) - np.float32(lo)) * np.float32(256 / (hi - lo if hi > lo else 1.0))
    with np.errstate(invalid="ignore"):
        index = np.where(np.isfinite(t), np.clip(t, 0, 255), 256).astype(np.intp)
    return _table(cmap)[index]


def _ring(a: np.ndarray, *, extend: bool) -> np.ndarray:
    """A grid array (ny, nx) with a ring of points half a spacing beyond its edges (`extend`: positions
    carried on linearly; else each edge's value repeated), along each axis of 2 points or more."""
    for axis in (0, 1):
        if a.shape[axis] < 2:
            continue
        first, second = np.take(a, [0], axis), np.take(a, [1], axis)
        last, before = np.take(a, [-1], axis), np.take(a, [-2], axis)
        if extend:
            first, last = first + (first - second) / 2, last + (last - before) / 2
        a = np.concatenate([first, a, last], axis)
    return a


def _line(x: np.ndarray, y: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A grid of one row or column (positions x, y and values, after `_ring`) doubled across its line,
    half a spacing to either side, so that its cells have a width; other grids as they are."""
    for axis in (0, 1):
        if x.shape[axis] == 1 and x.shape[1 - axis] > 1:
            dx, dy = x.ravel()[-1] - x.ravel()[0], y.ravel()[-1] - y.ravel()[0]
            f = _spacing(x, y) / 2 / max(float(np.hypot(dx, dy)), 1e-12)
            x, y = np.concatenate([x + dy * f, x - dy * f], axis), np.concatenate([y - dx * f, y + dx * f], axis)
            values = np.repeat(values, 2, axis)
    return x, y, values


def _plain_raster(axes: MapAxes, values: np.ndarray) -> tuple[np.ndarray, tuple[float, float, float, float]]:
    """The plain map's raster: each grid point of the active box (`active_box`) a cell about it of its
    value (as matplotlib's pcolormesh with shading "nearest" draws it on a curved grid), on cells about
    half the grid's spacing (at most MAP_PX across); NaN outside, at inactive points and where not
    measured; and its extent (left, right, bottom, top; rows run up the axis). The cells are made once
    per MapAxes (`_cache`), for every state and quantity."""
    active = np.ones(values.shape, bool) if axes.active is None else np.asarray(axes.active, bool)
    box = active_box(active)
    c = axes._cache
    x, y, values = _line(_ring(axes.x[box], extend=True), _ring(axes.y[box], extend=True),
                         _ring(np.where(active, values, np.nan)[box], extend=False))
    if "cells" not in c:
        x0, x1, y0, y1 = np.nanmin(x), np.nanmax(x), np.nanmin(y), np.nanmax(y)
        spacing = _spacing(axes.x[box], axes.y[box])
        cell = max(spacing / 2 if np.isfinite(spacing) else 0.0, max(x1 - x0, y1 - y0, 1e-9) / MAP_PX)
        # cells from the ring's edge: on a regular grid 2 x 2 a point, none half-way between two points
        shape = (max(1, int(np.ceil((y1 - y0) / cell))), max(1, int(np.ceil((x1 - x0) / cell))))
        c["cells"] = grid_cells(x, y, origin=(x0 + cell / 2, y0 + cell / 2), cell=cell, shape=shape)
        c["extent"] = (x0, x0 + shape[1] * cell, y0, y0 + shape[0] * cell)
        c["limits"] = (x0, x1, y0, y1)
    return c["cells"].nearest(values), c["extent"]


def _rgb(field: np.ndarray, lo: float, hi: float, cmap: str, under: np.ndarray | None = None) -> np.ndarray:
    """uint8 RGB (h, w, 3) of a raster `field` (NaN: white, or `under`): its colours (`colours`), over
    the gray image `under` (h, w; 0..255) with opacity ALPHA if given."""
    rgb = colours(field, lo, hi, cmap)
    if under is not None:
        alpha = np.where(np.isfinite(field), np.float32(ALPHA), np.float32(0.0))[..., None]
        rgb = alpha * rgb + (1 - alpha) * under[..., None]
    return np.rint(rgb).astype(np.uint8)


# the fixed layout (pixels at 100 dpi, from the bottom left): the plain map, its colour bar, the map over
# the image; the figure's height and the plain map's box are the same with and without the image
_HEIGHT, _MAP, _BAR, _OVER = 560, (75, 55, 500, 420), (15, 18), (770, 55, 510, 420)


@dataclass
class _Layout:
    """One of a MapPainter's figures and its parts: the plain map's axes and picture, a colour bar per
    kind of arrows, the picture over the image (None: no such panel), the words drawn per map, and the
    figure drawn without those (`background`) for the axes and image size it was drawn for (`drawn`);
    the colour bars drawn on that background, by what they show (`bar_pixels`: a quantity's bar is the
    same in every state of a run, and drawn once)."""

    figure: object
    canvas: object
    ax: object
    plain: object
    over: object
    bars: dict = field(default_factory=dict)
    words: list = field(default_factory=list)
    background: object = None
    drawn: tuple | None = None
    bar_key: tuple = ()                                     # what the visible colour bar shows, and where
    bar_pixels: dict = field(default_factory=dict)          # bar_key -> (rows, columns, pixels) as drawn


def load_matplotlib() -> None:
    """Import the parts of matplotlib that drawing a map takes (half a second) ahead of the first map: the
    start of the worker processes that draw a run's maps (`stereodic.dic.background.Background`'s
    `prepare`), beside the run's correlation, or a thread of a command that draws them itself."""
    import matplotlib.backends.backend_agg  # noqa: F401
    import matplotlib.figure  # noqa: F401
    from matplotlib import cm, colors, ticker  # noqa: F401


class MapPainter:
    """Draws maps (`map_figure`, `draw`) on matplotlib figures made once per layout - a plain map (720 x
    560 pixels), a map beside its copy over the image (1300 x 560) - and reused: a map sets the pictures'
    pixels (each a raster coloured by `colours`: one image, not a patch per point), the colour bar's
    range, map, arrows and ticks, and the words. The layout is fixed (no layout engine runs per map), and
    what stays over a run - the axes with their ticks and labels and the image panel's title, for one
    MapAxes and one image (its size and label) - is drawn once and copied (matplotlib's blitting): on it
    each map pastes its pictures (`_paste`) and draws its colour bar and titles."""

    def __init__(self):
        self._layouts: dict[bool, _Layout] = {}

    def _layout(self, over: bool) -> _Layout:
        if over not in self._layouts:
            from matplotlib.backends.backend_agg import FigureCanvasAgg
            from matplotlib.figure import Figure     # not pyplot: the caller's backend (a notebook's) stays

            width = _OVER[0] + _OVER[2] + 20 if over else _MAP[0] + _MAP[2] + _BAR[0] + _BAR[1] + 110
            fig = Figure(figsize=(width / 100, _HEIGHT / 100), dpi=100)
            frac = lambda l, b, w, h: (l / width, b / _HEIGHT, w / width, h / _HEIGHT)   # noqa: E731
            ax = fig.add_axes(frac(*_MAP))
            ax.set_aspect("equal", adjustable="box", anchor="E")
            plain = ax.imshow(np.zeros((2, 2, 3), np.uint8), origin="lower", interpolation="nearest")
            image = None
            if over:
                oax = fig.add_axes(frac(*_OVER))
                image = oax.imshow(np.zeros((2, 2, 3), np.uint8), interpolation="nearest")
                oax.set_xlabel("x (px)")
                oax.set_ylabel("y (px)")
            self._layouts[over] = _Layout(fig, FigureCanvasAgg(fig), ax, plain, image)
        return self._layouts[over]

    def figure(self, values: np.ndarray, axes: MapAxes, *, title: str, quantity: str, unit: str, decimals: int,
               signed: bool = True, scale: ColourScale | None = None, backdrop: Backdrop | None = None):
        """The matplotlib Figure of one map (`save_map`'s options), valid until the next map of this
        painter with the same layout (`draw` draws it faster than the figure's own savefig)."""
        return self._compose(values, axes, title=title, quantity=quantity, unit=unit, decimals=decimals,
                             signed=signed, scale=scale, backdrop=backdrop, bar_drawn=False)

    def _compose(self, values: np.ndarray, axes: MapAxes, *, title: str, quantity: str, unit: str, decimals: int,
                 signed: bool = True, scale: ColourScale | None = None, backdrop: Backdrop | None = None,
                 bar_drawn: bool = False):
        """`figure`; `bar_drawn`: the colour bar is left as it is where its pixels for this map were kept
        (`_Layout.bar_pixels`: `draw` pastes them; updating the bar, 7 ms a map, would draw nothing new)."""
        from matplotlib.cm import ScalarMappable
        from matplotlib.colors import Normalize
        from matplotlib.ticker import FuncFormatter, MaxNLocator

        values = np.asarray(values, float)
        active = np.ones(values.shape, bool) if axes.active is None else np.asarray(axes.active, bool)
        finite = values[np.isfinite(values) & active]
        if finite.size:
            lo, hi, median, p5, p95 = np.percentile(finite, [1, 99, 50, 5, 95])
            if hi <= lo:
                lo, hi = lo - 10.0 ** -decimals, hi + 10.0 ** -decimals
            cmap = "viridis"
            if signed and lo < 0 < hi:
                lo, hi, cmap = -max(-lo, hi), max(-lo, hi), "RdBu_r"
            units = f" {unit}" if unit else ""
            summary = (f"median {fixed(median, decimals)}{units}; 90 % within {fixed(p5, decimals)} .. "
                       f"{fixed(p95, decimals)}; {finite.size} of {active.sum()} points measured")
        else:
            lo, hi, cmap, summary = -1.0, 1.0, "viridis", f"no point measured of {active.sum()}"
        if scale is not None:
            lo, hi, cmap = scale.lo, scale.hi, scale.cmap
        lay = self._layout(backdrop is not None)
        fig, ax, plain, bars, image = lay.figure, lay.ax, lay.plain, lay.bars, lay.over

        field, extent = _plain_raster(axes, values)
        plain.set_data(_rgb(field, lo, hi, cmap))
        plain.set_extent(extent)
        x0, x1, y0, y1 = axes._cache["limits"]
        ax.set_xlim((x1, x0) if axes.flip_x else (x0, x1))
        ax.set_ylim((y1, y0) if axes.flip_y else (y0, y1))
        ax.set_xlabel(f"{axes.names[0]} ({axes.unit})")
        ax.set_ylabel(f"{axes.names[1]} ({axes.unit})")
        ax.apply_aspect()
        box = ax.get_position()          # the colour bar beside the map's box, 90 % of its height
        width = fig.bbox.width

        extend = {(False, False): "neither", (True, False): "min", (False, True): "max", (True, True): "both"}[
            (bool(finite.size and finite.min() < lo), bool(finite.size and finite.max() > hi))]
        if extend not in bars:            # a colour bar per kind of arrows (a bar's arrows are made with it)
            bars[extend] = fig.colorbar(ScalarMappable(Normalize(lo, hi), cmap), cax=fig.add_axes((0, 0, 1, 1)),
                                        extend=extend)
        for kind, other in bars.items():
            other.ax.set_visible(kind == extend)
        bar = bars[extend]
        tall = max(0.9 * box.height, 0.5 * _MAP[3] / _HEIGHT)         # a flat map's bar still readable
        position = (box.x1 + _BAR[0] / width, (box.y0 + box.y1 - tall) / 2, _BAR[1] / width, tall)
        bar.ax.set_position(position)
        locator = MaxNLocator(7)
        ticks = locator.tick_values(lo, hi)
        places = _decimals(float(np.min(np.diff(ticks)))) if len(ticks) > 1 else decimals
        lay.bar_key = (extend, float(lo), float(hi), cmap, quantity, unit, places, tuple(bar.ax.get_position().bounds))
        if not (bar_drawn and lay.bar_key in lay.bar_pixels):
            with bar.mappable.norm.callbacks.blocked():     # the bar redrawn once, by set_cmap
                bar.mappable.norm.vmin, bar.mappable.norm.vmax = lo, hi
            bar.mappable.set_cmap(cmap)
            bar.locator = locator
            bar.formatter = FuncFormatter(lambda v, _: fixed(v, places))
            bar.update_ticks()
            bar.set_label(f"{quantity} ({unit})" if unit else quantity)

        if backdrop is None:
            lay.words = [ax.set_title(f"{title}\n{summary}", fontsize=9.5)]
        else:
            over = image.axes
            field, extent = backdrop.raster(np.where(active, values, np.nan))
            image.set_data(_rgb(field, lo, hi, cmap, under=backdrop.gray()))
            image.set_extent(extent)
            h, w = backdrop.image.shape[:2]
            over.set_xlim(-0.5, w - 0.5)
            over.set_ylim(h - 0.5, -0.5)
            if over.get_title() != f"over {backdrop.label}":   # the same over a run: drawn with the background
                over.set_title(f"over {backdrop.label}", fontsize=9)
            lay.words = [fig.suptitle(f"{title}\n{summary}", fontsize=9.5, y=0.99, va="top")]
        return fig


    def draw(self, values: np.ndarray, axes: MapAxes, **options) -> np.ndarray:
        """One map (`figure`'s options) drawn: RGB (H, W, 3) uint8."""
        from matplotlib.backends.backend_agg import FigureCanvasAgg

        lay = self._layout(options.get("backdrop") is not None)
        if lay.figure.canvas is not lay.canvas:     # the caller gave the figure another canvas: draw afresh
            lay.canvas = lay.figure.canvas if isinstance(lay.figure.canvas, FigureCanvasAgg) else \
                FigureCanvasAgg(lay.figure)
            lay.drawn = None
        backdrop = options.get("backdrop")
        key = (axes, None if backdrop is None else (backdrop.image.shape[:2], backdrop.label))
        fresh = lay.drawn is None or lay.drawn[0] is not key[0] or lay.drawn[1] != key[1]
        if fresh:
            lay.bar_pixels.clear()                # drawn on the background before
        self._compose(values, axes, **options, bar_drawn=True)
        parts = [lay.plain] + ([] if lay.over is None else [lay.over]) + \
            [bar.ax for bar in lay.bars.values() if bar.ax.get_visible()] + lay.words
        if fresh:
            for part in parts:
                part.set_animated(True)           # left out of the background
            lay.canvas.draw()
            for part in parts:
                part.set_animated(False)
            lay.background, lay.drawn = lay.canvas.copy_from_bbox(lay.figure.bbox), key
        else:
            lay.canvas.restore_region(lay.background)
        buffer = np.asarray(lay.canvas.buffer_rgba())
        pictures = [lay.plain] + ([] if lay.over is None else [lay.over])
        for picture in pictures:
            _paste(buffer, picture)
        bar = next(bar for bar in lay.bars.values() if bar.ax.get_visible())
        if lay.bar_key in lay.bar_pixels:                   # the bar as drawn for an earlier map
            rows, cols, pixels = lay.bar_pixels[lay.bar_key]
            buffer[rows, cols] = pixels
        else:
            lay.figure.draw_artist(bar.ax)
            region = _bar_region(lay, bar, buffer.shape[:2])
            if region is not None:
                lay.bar_pixels[lay.bar_key] = (*region, buffer[region].copy())
        frames = [spine for picture in pictures for spine in picture.axes.spines.values()]
        for part in lay.words + frames:                     # the words, the frames over the pictures
            lay.figure.draw_artist(part)
        return buffer[..., :3].copy()


def _bar_region(lay: _Layout, bar, shape: tuple[int, int]) -> tuple[slice, slice] | None:
    """The rows and columns of the figure's pixels (shape: height, width) that colour bar `bar` was drawn
    in (its axes with the ticks, their labels and its label, and 2 pixels about them), None where they
    would reach a picture (drawn per map) or leave the figure."""
    box = bar.ax.get_tightbbox(lay.canvas.get_renderer())
    h, w = shape
    x0, x1, y0, y1 = int(np.floor(box.x0)) - 2, int(np.ceil(box.x1)) + 2, int(np.floor(box.y0)) - 2, int(np.ceil(box.y1)) + 2
    if x0 < 0 or y0 < 0 or x1 > w or y1 > h:
        return None
    for picture in [lay.plain] + ([] if lay.over is None else [lay.over]):
        p = picture.axes.get_window_extent()
        if x0 < p.x1 + 1 and p.x0 - 1 < x1 and y0 < p.y1 + 1 and p.y0 - 1 < y1:
            return None
    return slice(h - y1, h - y0), slice(x0, x1)


def _paste(buffer: np.ndarray, image) -> None:
    """Draw matplotlib's AxesImage `image` (RGB uint8 data, drawn with nearest interpolation) into the
    figure's pixels `buffer` (H, W, 4; Agg's) within its axes: each screen pixel the raster cell under
    its centre (what matplotlib's resampling gives, without its per-image pipeline: a tenth of the time)."""
    ax, rgb = image.axes, np.asarray(image.get_array())
    box = ax.get_window_extent()
    cols = np.arange(int(np.ceil(box.x0 - 0.5)), int(np.floor(box.x1 - 0.5)) + 1)   # pixels with centres inside
    rows = np.arange(int(np.ceil(box.y0 - 0.5)), int(np.floor(box.y1 - 0.5)) + 1)   # from the bottom
    inverse = ax.transData.inverted()
    x = inverse.transform(np.column_stack([cols + 0.5, np.full(cols.shape, box.y0)]))[:, 0]
    y = inverse.transform(np.column_stack([np.full(rows.shape, box.x0), rows + 0.5]))[:, 1]
    left, right, bottom, top = image.get_extent()
    first, last = (bottom, top) if image.origin == "lower" else (top, bottom)      # the rows' edges: row 0's first
    h, w = rgb.shape[:2]
    j = np.floor((x - left) / (right - left) * w).astype(np.intp)
    i = np.floor((y - first) / (last - first) * h).astype(np.intp)
    cin, rin = (j >= 0) & (j < w), (i >= 0) & (i < h)   # each a run of pixels: i, j are monotonic
    if cin.any() and rin.any():
        c, r = cols[cin], buffer.shape[0] - 1 - rows[rin]   # the buffer's rows from the top: descending
        buffer[r[-1]:r[0] + 1, c[0]:c[-1] + 1, :3] = rgb.take(i[rin][::-1], axis=0).take(j[cin], axis=1)


def write_png(path: str | os.PathLike, rgb: np.ndarray) -> None:
    """An RGB (H, W, 3) uint8 picture as a PNG (OpenCV's encoder: each row less the one above, fast
    compression: a map in 14 ms, a fifth of Pillow's time under matplotlib's savefig; atomic)."""
    import cv2
    options = [cv2.IMWRITE_PNG_COMPRESSION, 1, cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_UP]
    ok, data = cv2.imencode(".png", cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2BGR), options)
    if not ok:
        raise RuntimeError(f"{path}: the PNG could not be encoded")
    with atomic_output(path) as tmp:
        tmp.write_bytes(data.tobytes())


def map_figure(values: np.ndarray, axes: MapAxes, *, title: str, quantity: str, unit: str, decimals: int,
               signed: bool = True, scale: ColourScale | None = None, backdrop: Backdrop | None = None,
               painter: MapPainter | None = None):
    """The matplotlib Figure of one map (`save_map`), drawn by `painter` (reused: valid until its next
    map of the same layout), else by a new one."""
    return (painter or MapPainter()).figure(values, axes, title=title, quantity=quantity, unit=unit,
                                            decimals=decimals, signed=signed, scale=scale, backdrop=backdrop)


def save_map(path: str | os.PathLike, values: np.ndarray, axes: MapAxes, *, title: str, quantity: str,
             unit: str, decimals: int, signed: bool = True, scale: ColourScale | None = None,
             backdrop: Backdrop | None = None, painter: MapPainter | None = None) -> np.ndarray:
    """One map (PNG, atomic) of `values` (ny, nx; NaN where not measured, left blank) on `axes`; `title`
    names the load case, `quantity` and `unit` label the colour bar ("exx", "microstrain"; unit "" for a
    pure number), `decimals` is the precision of the title's figures; `signed`: a change (displacement,
    strain) whose range across zero is centred on zero, not a position or a score; `scale`: the run's
    colour limits and map (`RunScales`), else the map's own; `backdrop`: also drawn over the state's
    original left image, beside the plain map; `painter`: the MapPainter whose figures are reused (a
    run's maps: one for all). Returns the picture, RGB (H, W, 3) uint8 (a movie's frame)."""
    rgb = (painter or MapPainter()).draw(values, axes, title=title, quantity=quantity, unit=unit, decimals=decimals,
                                         signed=signed, scale=scale, backdrop=backdrop)
    write_png(path, rgb)
    return rgb


class MapMovie:
    """A quantity's maps over a run as an MP4 video (OpenCV's mp4v codec), one frame per state written as
    it comes (`add(picture)`: RGB (H, W, 3) uint8, as `save_map` returns it), so that memory holds one frame;
    `close()` finishes the file (atomic)."""

    def __init__(self, path: str | os.PathLike, *, fps: float = 4.0):
        self.path, self.fps = path, fps
        self._ctx = None
        self._writer = None
        self._size = None

    def add(self, rgb: np.ndarray) -> None:
        import cv2
        if self._writer is None:
            self._ctx = atomic_output(self.path, suffix=".mp4")
            tmp = self._ctx.__enter__()
            self._size = (rgb.shape[1] // 2 * 2, rgb.shape[0] // 2 * 2)
            self._writer = cv2.VideoWriter(str(tmp), cv2.VideoWriter_fourcc(*"mp4v"), self.fps, self._size)
        frame = np.zeros((self._size[1], self._size[0], 3), np.uint8)
        h, w = min(rgb.shape[0], self._size[1]), min(rgb.shape[1], self._size[0])
        frame[:h, :w] = rgb[:h, :w]
        self._writer.write(np.ascontiguousarray(frame[..., ::-1]))

    def close(self) -> None:
        if self._writer is not None:
            self._writer.release()
            self._ctx.__exit__(None, None, None)
            self._writer = None

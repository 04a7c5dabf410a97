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
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np

from calib.atomic import atomic_output
from calib.numbers import fixed


@dataclass(frozen=True)
class MapAxes:
    """Where each grid point of a map is: x, y (ny, nx) float arrays in `unit` ("px" or "mm"), named
    `names` on the axes; flip_x / flip_y: the axis runs right to left / top to bottom; active (ny, nx)
    bool: the grid points measured at all (the grid's ROI and mask), None = every one."""

    x: np.ndarray
    y: np.ndarray
    unit: str
    names: tuple[str, str]
    flip_x: bool
    flip_y: bool
    active: np.ndarray | None = None


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
        v = np.asarray(values, float)
        v = v[np.isfinite(v) & (True if active is None else active)]
        self._signed[name] = signed
        if v.size:
            lo, hi = np.percentile(v, [1, 99])
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


# the map over the image is drawn about 600 screen pixels across: its image and field no finer than this
OVERLAY_PX = 1000


@dataclass(frozen=True)
class Backdrop:
    """The state's original left image (H, W) and where each grid point is in it, x, y (ny, nx) pixels
    (NaN where not seen), for the map over the image; `label` names the image in the panel's title."""

    image: np.ndarray
    x: np.ndarray
    y: np.ndarray
    label: str = "the left camera's image of the state"
    _cache: dict = field(default_factory=dict, compare=False, repr=False)

    def raster(self, values: np.ndarray) -> tuple[np.ndarray, tuple[float, float, float, float]]:
        """(field, extent): `values` (ny, nx) interpolated linearly between the points where the camera
        saw them (their Delaunay triangles) onto a raster of the image (cells half the grid's spacing, at
        most OVERLAY_PX across; NaN outside the triangles, in a triangle with an unmeasured corner and
        farther than 1.5 spacings from any point), and the raster's extent in image pixels (for imshow).
        The triangles and the cells' weights depend on the points alone: made once, for every quantity."""
        c = self._cache
        if "weights" not in c:
            from scipy.spatial import Delaunay, cKDTree
            ok = np.isfinite(self.x) & np.isfinite(self.y)
            pts = np.column_stack([self.x[ok], self.y[ok]])
            tree = cKDTree(pts)
            spacing = float(np.median(tree.query(pts, k=2)[0][:, 1]))
            # cells half the grid's spacing, but no finer than a picture shows (OVERLAY_PX across)
            r = max(1, int(spacing // 2), -(-max(self.image.shape) // OVERLAY_PX))
            gy, gx = np.mgrid[0:self.image.shape[0]:r, 0:self.image.shape[1]:r].astype(float)
            cells = np.column_stack([gx.ravel(), gy.ravel()])
            tri = Delaunay(pts)
            found = tri.find_simplex(cells)
            inside = (found >= 0) & (tree.query(cells)[0] <= 1.5 * spacing)
            affine = tri.transform[np.maximum(found, 0)]              # barycentric coordinates, qhull's
            b = np.einsum("nij,nj->ni", affine[:, :2], cells - affine[:, 2])
            weights = np.column_stack([b, 1 - b.sum(1)])
            inside &= np.isfinite(weights).all(1)                     # a flat triangle: outside
            c.update(ok=ok, shape=gx.shape, vertices=tri.simplices[np.maximum(found, 0)],
                     weights=np.where(inside[:, None], weights, 0.0), inside=inside,
                     extent=(-r / 2, gx[0, -1] + r / 2, gy[-1, 0] + r / 2, -r / 2))
        v = values[c["ok"]]
        out = np.where(c["inside"], (v[c["vertices"]] * c["weights"]).sum(1), np.nan)
        return out.reshape(c["shape"]), c["extent"]


def map_figure(values: np.ndarray, axes: MapAxes, *, title: str, quantity: str, unit: str, decimals: int,
               signed: bool = True, scale: ColourScale | None = None, backdrop: Backdrop | None = None):
    """The matplotlib Figure of one map (`save_map`)."""
    from matplotlib.figure import Figure   # not pyplot: the caller's backend (a notebook's) stays as it is
    from matplotlib.ticker import FuncFormatter, MaxNLocator

    values = np.asarray(values, float)
    active = np.ones(values.shape, bool) if axes.active is None else np.asarray(axes.active, bool)
    finite = values[np.isfinite(values) & active]
    label = f"{quantity} ({unit})" if unit else quantity
    if finite.size:
        lo, hi = np.percentile(finite, [1, 99])
        if hi <= lo:
            lo, hi = lo - 10.0 ** -decimals, hi + 10.0 ** -decimals
        cmap = "viridis"
        if signed and lo < 0 < hi:
            lo, hi, cmap = -max(-lo, hi), max(-lo, hi), "RdBu_r"
        median, p5, p95 = np.percentile(finite, [50, 5, 95])
        units = f" {unit}" if unit else ""
        summary = (f"median {fixed(median, decimals)}{units}; 90 % within {fixed(p5, decimals)} .. "
                   f"{fixed(p95, decimals)}; {finite.size} of {active.sum()} points measured")
    else:
        lo, hi, cmap, summary = -1.0, 1.0, "viridis", f"no point measured of {active.sum()}"
    if scale is not None:
        lo, hi, cmap = scale.lo, scale.hi, scale.cmap
    box = active_box(active)
    fig = Figure(figsize=(7.2 if backdrop is None else 13.0, 5.6), layout="constrained")
    ax, over = (fig.subplots(), None) if backdrop is None else fig.subplots(1, 2)
    im = ax.pcolormesh(axes.x[box], axes.y[box], np.ma.masked_invalid(np.where(active, values, np.nan)[box]),
                       shading="nearest", cmap=cmap, vmin=lo, vmax=hi)
    extend = {(False, False): "neither", (True, False): "min", (False, True): "max", (True, True): "both"}[
        (bool(finite.size and finite.min() < lo), bool(finite.size and finite.max() > hi))]
    bar = fig.colorbar(im, ax=ax, label=label, extend=extend, shrink=0.9)
    bar.locator = MaxNLocator(7)
    ticks = bar.locator.tick_values(lo, hi)
    places = _decimals(float(np.min(np.diff(ticks)))) if len(ticks) > 1 else decimals
    bar.formatter = FuncFormatter(lambda v, _: fixed(v, places))
    bar.update_ticks()
    ax.set_aspect("equal")
    ax.set_xlabel(f"{axes.names[0]} ({axes.unit})")
    ax.set_ylabel(f"{axes.names[1]} ({axes.unit})")
    if axes.flip_x:
        ax.invert_xaxis()
    if axes.flip_y:
        ax.invert_yaxis()
    if over is None:
        ax.set_title(f"{title}\n{summary}", fontsize=9.5)
    else:
        _draw_over_image(over, backdrop, np.where(active, values, np.nan), lo, hi, cmap)
        fig.suptitle(f"{title}\n{summary}", fontsize=9.5)
    return fig


def _draw_over_image(ax, backdrop: Backdrop, values: np.ndarray, lo: float, hi: float, cmap: str) -> None:
    """The field over its image (`Backdrop.raster`), semi-transparent."""
    import cv2
    img = np.asarray(backdrop.image, np.float32)
    h, w = img.shape
    shown = img
    if max(h, w) > OVERLAY_PX:       # no finer than the picture shows: the image averaged down to it
        f = OVERLAY_PX / max(h, w)
        shown = cv2.resize(img, (max(1, round(w * f)), max(1, round(h * f))), interpolation=cv2.INTER_AREA)
    ax.imshow(shown, cmap="gray", vmin=np.percentile(shown, 0.5), vmax=np.percentile(shown, 99.5),
              interpolation="nearest", extent=(-0.5, w - 0.5, h - 0.5, -0.5))
    ok = np.isfinite(values) & np.isfinite(backdrop.x) & np.isfinite(backdrop.y)
    if ok.sum() >= 3:
        field, extent = backdrop.raster(values)
        ax.imshow(np.ma.masked_invalid(field), cmap=cmap, vmin=lo, vmax=hi, alpha=0.55, interpolation="nearest",
                  extent=extent)
    ax.set_xlim(-0.5, w - 0.5)
    ax.set_ylim(h - 0.5, -0.5)
    ax.set_xlabel("x (px)")
    ax.set_ylabel("y (px)")
    ax.set_title(f"over {backdrop.label}", fontsize=9)


def save_map(path: str | os.PathLike, values: np.ndarray, axes: MapAxes, *, title: str, quantity: str,
             unit: str, decimals: int, signed: bool = True, scale: ColourScale | None = None,
             backdrop: Backdrop | None = None) -> None:
    """One map (matplotlib PNG, atomic) of `values` (ny, nx; NaN where not measured, left blank) on
    `axes`; `title` names the load case, `quantity` and `unit` label the colour bar ("exx",
    "microstrain"; unit "" for a pure number), `decimals` is the precision of the title's figures;
    `signed`: a change (displacement, strain) whose range across zero is centred on zero, not a
    position or a score; `scale`: the run's colour limits and map (`RunScales`), else the map's own;
    `backdrop`: also drawn over the state's original left image, beside the plain map."""
    fig = map_figure(values, axes, title=title, quantity=quantity, unit=unit, decimals=decimals, signed=signed,
                     scale=scale, backdrop=backdrop)
    with atomic_output(path) as tmp:
        fig.savefig(tmp, dpi=100)


class MapMovie:
    """A quantity's maps over a run as an MP4 video (OpenCV's mp4v codec), one frame per state written as
    it comes (`add(figure)`), so that memory holds one frame; `close()` finishes the file (atomic)."""

    def __init__(self, path: str | os.PathLike, *, fps: float = 4.0):
        self.path, self.fps = path, fps
        self._ctx = None
        self._writer = None
        self._size = None

    def add(self, fig) -> None:
        import cv2
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        canvas = FigureCanvasAgg(fig)
        canvas.draw()
        rgb = np.asarray(canvas.buffer_rgba())[..., :3]
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

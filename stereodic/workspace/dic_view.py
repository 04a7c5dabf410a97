"""The results page: a DIC result state by state over the original left reference image.

The field is one heat map of cells about as large as the points' spacing over the original left
reference image (each cell shows its nearest grid point, `raster`; semi-transparent over the image; no
cell where no point is near), whose values alone change with the state or the quantity: a redraw sends one
array of the state's cell values (a Dash `Patch`), read from one state's file (`results.DicSource`). A
heat map is drawn on a 2-D canvas, which stays fast where WebGL falls back to software (a WebGL scatter
of 100,000 points took 2-4 s per recolouring in headless Chromium). The colour limits are fixed per quantity over the run; the colour bar carries the
unit. A click gives the point's history; the gauges (extensometer, line, area) drawn on the image give
their curves at once (`stereodic.gauge`, the `stereodic gauge` command's library); a testing machine's
load CSV gives the stress-strain curve; every curve downloads as CSV, every view as PNG (the graph's
camera button).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calib.errors import InputError
from stereodic.workspace.access import Access
from stereodic.workspace.page import GRAPH_WIDTH_PX, error_text, image_url
from stereodic.workspace.results import DicSource

_SOURCES: dict[tuple, DicSource] = {}
_LOCK = threading.Lock()
TOOLS = {"point": "pan", "extensometer": "drawline", "line": "drawline", "area": "drawclosedpath",
         "x-axis": "drawline"}


def x_axis(text: str | None) -> tuple[float, float, float, float] | None:
    """The specimen's x axis typed or drawn on the page, "X0,Y0,X1,Y1" (two pixels of the original left
    reference image, as `--x-axis`), or None for an empty text (the image's columns); InputError naming
    it otherwise."""
    if not text or not text.strip():
        return None
    try:
        values = tuple(float(v) for v in text.replace(" ", "").split(","))
    except ValueError:
        values = ()
    if len(values) != 4 or not np.isfinite(values).all() or values[:2] == values[2:]:
        raise InputError("x axis", f"{text!r}: needs X0,Y0,X1,Y1, two different pixels of the left image")
    return values


def source(path: str | Path, frame: str = "rig", axis: tuple | None = None) -> DicSource:
    """The opened result at `path`, its positions, displacements and strains in the rig's (the result's own)
    or the specimen's frame (`stereodic.strain.results.specimen_frame_of`, x along `axis` (X0, Y0, X1, Y1
    pixels of the left reference image; None: its columns); a finished stereo run only), opened once per
    server; a running run's finished states counted again each time."""
    key = (str(path), frame or "rig", axis if frame == "specimen" else None)
    with _LOCK:
        if key not in _SOURCES:
            specimen = None
            if key[1] == "specimen":
                from stereodic.strain.results import open_result, specimen_frame_of
                direction = (1.0, 0.0) if axis is None else (axis[2] - axis[0], axis[3] - axis[1])
                specimen = specimen_frame_of(open_result(path), x_direction_px=direction)
            _SOURCES[key] = DicSource(path, frame=specimen)
        src = _SOURCES[key]
    src.refresh()
    return src


def colour_scale(src: DicSource, name: str) -> str:
    if name == "status":
        return "Turbo"
    return "RdBu_r" if src.quantity(name).signed else "Viridis"


@dataclass
class Raster:
    """The field's cells over the original left image: `cell` px square cells (about the points' spacing),
    `index` (Hc, Wc) the point each cell shows (-1: none within reach), the image's `width` x `height`."""

    cell: int
    index: np.ndarray
    width: int
    height: int

    def values(self, values: np.ndarray) -> np.ndarray:
        """(Hc, Wc) float32 cell values of the points' `values` (NaN: no point, or not measured)."""
        out = np.full(self.index.shape, np.nan, np.float32)
        ok = self.index >= 0
        out[ok] = values[self.index[ok]]
        return out

    def encoded(self, values: np.ndarray) -> dict:
        """The cell values as plotly.js's typed-array spec (base64 float32 with its shape): what the
        browser decodes at once, where a 2-D array would otherwise travel as nested JSON lists."""
        from _plotly_utils.utils import to_typed_array_spec
        return to_typed_array_spec(self.values(values))


def raster(src: DicSource) -> Raster:
    """The cells of `src`'s field (`Raster`), made once per result: each cell shows its nearest point,
    where one lies within reach (0.75 of the points' median spacing, diagonal included, plus half a cell)."""
    cached = getattr(src, "_raster", None)
    if cached is not None:
        return cached
    from scipy.spatial import cKDTree

    from calib.imageio import image_size
    ref = src.reference_image()
    if ref is not None:
        w, h = image_size(ref)
    else:
        w, h = int(np.ceil(src.x.max())) + 1, int(np.ceil(src.y.max())) + 1
    tree = cKDTree(np.column_stack([src.x, src.y]))
    spacing = float(np.median(tree.query(tree.data, k=2)[0][:, 1])) if src.x.size > 1 else 1.0
    cell = max(1, int(round(spacing)))
    cy, cx = np.mgrid[0:int(np.ceil(h / cell)), 0:int(np.ceil(w / cell))]
    centres = np.column_stack([(cx.ravel() + 0.5) * cell - 0.5, (cy.ravel() + 0.5) * cell - 0.5])
    dist, idx = tree.query(centres, distance_upper_bound=0.75 * spacing * np.sqrt(2.0) + 0.5 * cell)
    idx = np.where(np.isfinite(dist), idx, -1).reshape(cx.shape)
    src._raster = Raster(cell, idx, w, h)
    return src._raster


def field_figure(src: DicSource, name: str, k: int):
    """The field figure of quantity `name` in state k (module docstring)."""
    import plotly.graph_objects as go
    r = raster(src)
    lo, hi = src.limits(name)
    q = src.quantity(name)
    fig = go.Figure(go.Heatmap(
        z=r.encoded(src.values(k, name)), x0=(r.cell - 1) / 2, dx=r.cell, y0=(r.cell - 1) / 2, dy=r.cell,
        zmin=lo, zmax=hi, colorscale=colour_scale(src, name), opacity=0.65, zsmooth=False,
        colorbar=dict(title=dict(text=_bar_title(src, name), side="right")),
        hovertemplate="x %{x:.0f} px, y %{y:.0f} px<br>%{z:.5g} " + q.unit + "<extra></extra>"))
    ref = src.reference_image()
    images = []
    if ref is not None:
        images = [dict(source=image_url(ref), xref="x", yref="y", x=-0.5, y=-0.5, sizex=r.width, sizey=r.height,
                       sizing="stretch", layer="below")]
    fig.update_layout(images=images, margin=dict(l=50, r=10, t=30, b=40),
                      height=int(GRAPH_WIDTH_PX * r.height / r.width) + 70, width=GRAPH_WIDTH_PX + 160, dragmode="pan",
                      plot_bgcolor="#222", uirevision="field", title=dict(text=_title(src, name, k), font=dict(size=13)),
                      newshape=dict(line=dict(color="#ff0", width=3)))
    fig.update_xaxes(range=[-0.5, r.width - 0.5], title="x, original left image (px)", showgrid=False)
    fig.update_yaxes(range=[r.height - 0.5, -0.5], title="y (px)", scaleanchor="x", showgrid=False)
    return fig


def _bar_title(src: DicSource, name: str) -> str:
    unit = src.unit(name)
    return f"{name} ({unit})" if unit else name


def _title(src: DicSource, name: str, k: int) -> str:
    labels = src.labels()
    own = (src.meta.get("frame") or {}).get("frame", "rig") if isinstance(src.meta.get("frame"), dict) else "rig"
    frame = "" if src.kind == "dic2d" else f", frame: {'specimen' if src.frame is not None else own}"
    return f"{name} - {labels[k] if k < len(labels) else f'state {k}'}{frame}"


def layout(path: Path, access: Access):
    from dash import dcc, html
    src = source(path)
    access.allow_files([p for p in [src.reference_image()] if p is not None])
    names = [q.name for q in src.quantities]
    start = "exx" if "exx" in names else names[0]
    running = src.run_folder is not None and src.count < src.total
    return html.Div([
        dcc.Store(id="dic-path", data=str(path)),
        dcc.Store(id="curve-data"), dcc.Store(id="ext-strain"),
        html.Div([
            html.Label("quantity "), dcc.Dropdown(names, start, id="quantity", clearable=False,
                                                  style={"width": "140px", "display": "inline-block"}),
            html.Button("play", id="play", n_clicks=0, style={"marginLeft": "12px"}),
            html.Span(id="state-label", style={"marginLeft": "12px"}),
            html.Span(f"  {src.x.size} points, {src.count} states", id="run-size", style={"color": "#666"}),
        ], style={"padding": "6px"}),
        html.Div(dcc.Slider(0, max(src.count - 1, 0), 1, value=0, id="state", updatemode="drag",
                            marks=None, tooltip={"placement": "bottom", "always_visible": True}),
                 style={"width": "900px", "padding": "0 8px"}),
        dcc.Interval(id="player", interval=400, disabled=True),
        dcc.Interval(id="poll", interval=2000, disabled=not running),
        html.Div([
            html.Div(dcc.Graph(id="field", figure=field_figure(src, start, 0),
                               config={"displaylogo": False, "scrollZoom": True,
                                       "modeBarButtonsToAdd": ["drawline", "drawclosedpath", "eraseshape"],
                                       "toImageButtonOptions": {"format": "png", "filename": "field"}}),
                     style={"flex": "none"}),
            html.Div([
                html.Div(["frame of the map and gauges: ", dcc.RadioItems(["rig", "specimen"], "rig", id="frame",
                                                                            inline=True),
                          " specimen's x axis ", dcc.Input(id="x-axis", value="", debounce=True,
                                                           placeholder="X0,Y0,X1,Y1 px (image columns)",
                                                           style={"width": "200px"})],
                         style={"display": "none"} if src.kind == "dic2d" else {}),
                dcc.RadioItems([{"label": " click a point: its history", "value": "point"},
                                {"label": " draw an extensometer (two ends)", "value": "extensometer"},
                                {"label": " draw a line: the profile", "value": "line"},
                                {"label": " draw an area: its mean", "value": "area"}] +
                               ([] if src.kind == "dic2d" else
                                [{"label": " draw the specimen's x axis (its frame's x)", "value": "x-axis"}]),
                               "point", id="tool"),
                dcc.Graph(id="curve", style={"height": "330px", "width": "520px"},
                          config={"displaylogo": False, "toImageButtonOptions": {"filename": "curve"}}),
                html.Button("curve as CSV", id="curve-csv", n_clicks=0), dcc.Download(id="download"),
                html.Hr(),
                html.Div(["load CSV of the testing machine: ",
                          dcc.Upload(html.Button("choose file"), id="load-upload"),
                          " cross-section ", dcc.Input(id="load-area", type="number", value=None, min=0,
                                                       placeholder="mm^2", style={"width": "80px"}), " mm^2"]),
                dcc.Graph(id="stress-strain", style={"height": "300px", "width": "520px"},
                          config={"displaylogo": False, "toImageButtonOptions": {"filename": "stress-strain"}}),
                html.Div(id="message", style={"color": "#b00", "whiteSpace": "pre-wrap"}),
                html.Div([html.Hr(), html.Button("rig health: epipolar error of state 0", id="health-button",
                                                 n_clicks=0),
                          html.Div(id="health-text"),
                          dcc.Graph(id="health", style={"height": "280px", "width": "520px"},
                                    config={"displaylogo": False})],
                         style={} if src.kind == "dic" else {"display": "none"}),
            ], style={"flex": "none", "marginLeft": "10px"}),
        ], style={"display": "flex", "alignItems": "flex-start"}),
    ])


def register(app, access: Access) -> None:
    from dash import Input, Output, Patch, State, ctx, dcc, no_update


    @app.callback(Output("field", "figure"), Output("state-label", "children"), Output("message", "children",
                                                                                       allow_duplicate=True),
                  Input("quantity", "value"), Input("state", "value"), Input("frame", "value"),
                  Input("x-axis", "value"), State("dic-path", "data"), prevent_initial_call=True)
    def redraw(name, k, frame, axis, path):
        try:
            src = source(access.resolve(path), frame, x_axis(axis))
            k = int(k)
            values = src.values(k, name)
            lo, hi = src.limits(name)
        except (InputError, TypeError, ValueError) as exc:
            return no_update, no_update, error_text(exc)
        patch = Patch()
        patch["data"][0]["z"] = raster(src).encoded(values)
        if ctx.triggered_id in ("quantity", "frame", "x-axis"):
            patch["data"][0]["zmin"] = lo
            patch["data"][0]["zmax"] = hi
            patch["data"][0]["colorscale"] = colour_scale(src, name)
            patch["data"][0]["colorbar"]["title"]["text"] = _bar_title(src, name)
            patch["data"][0]["hovertemplate"] = ("x %{x:.0f} px, y %{y:.0f} px<br>%{z:.5g} "
                                                 + src.unit(name) + "<extra></extra>")
        patch["layout"]["title"]["text"] = _title(src, name, k)
        return patch, src.labels()[k], ""

    @app.callback(Output("player", "disabled"), Output("play", "children"), Input("play", "n_clicks"),
                  State("player", "disabled"), prevent_initial_call=True)
    def play(_, disabled):
        return (False, "pause") if disabled else (True, "play")

    @app.callback(Output("state", "value"), Input("player", "n_intervals"), State("state", "value"),
                  State("state", "max"), prevent_initial_call=True)
    def step(_, k, last):
        return (int(k) + 1) % (int(last) + 1)

    @app.callback(Output("state", "max"), Output("run-size", "children"), Output("poll", "disabled"),
                  Input("poll", "n_intervals"), State("dic-path", "data"), prevent_initial_call=True)
    def grow(_, path):
        try:
            src = source(access.resolve(path))
        except InputError:
            return no_update, no_update, True
        return max(src.count - 1, 0), f"  {src.x.size} points, {src.count} of {src.total} states", \
            src.count >= src.total

    @app.callback(Output("field", "figure", allow_duplicate=True), Input("tool", "value"),
                  prevent_initial_call=True)
    def tool(value):
        patch = Patch()
        patch["layout"]["dragmode"] = TOOLS.get(value, "pan")
        return patch

    @app.callback(Output("curve", "figure"), Output("curve-data", "data"),
                  Output("message", "children", allow_duplicate=True),
                  Input("field", "clickData"), State("tool", "value"), State("quantity", "value"),
                  State("frame", "value"), State("x-axis", "value"), State("dic-path", "data"),
                  prevent_initial_call=True)
    def history(click, tool_, name, frame, axis, path):
        if tool_ != "point" or not click or not click.get("points"):
            return no_update, no_update, no_update
        try:
            src = source(access.resolve(path), frame, x_axis(axis))
            p = click["points"][0]
            i = src.nearest(float(p["x"]), float(p["y"]))
            values = src.history(i, name)
        except (InputError, KeyError, TypeError, ValueError) as exc:
            return no_update, no_update, error_text(exc)
        label = f"point at ({src.x[i]:.1f}, {src.y[i]:.1f}) px"
        table = {"columns": ["state", "x_px", "y_px", f"{name}_{src.unit(name) or 'value'}"],
                 "rows": [[k, float(src.x[i]), float(src.y[i]), float(v)] for k, v in enumerate(values)]}
        return curve_figure(np.arange(values.size), {label: values}, "state", _bar_title(src, name),
                            f"{name} history, {label}"), table, ""

    @app.callback(Output("curve", "figure", allow_duplicate=True), Output("curve-data", "data", allow_duplicate=True),
                  Output("ext-strain", "data"), Output("message", "children", allow_duplicate=True),
                  Input("field", "relayoutData"), State("tool", "value"), State("quantity", "value"),
                  State("frame", "value"), State("x-axis", "value"), State("dic-path", "data"),
                  prevent_initial_call=True)
    def gauge(relayout, tool_, name, frame, axis, path):
        if tool_ in ("point", "x-axis") or not relayout or not relayout.get("shapes"):
            return no_update, no_update, no_update, no_update
        try:
            figure, table, strain = gauge_curve(str(access.resolve(path)), relayout["shapes"][-1], tool_, name,
                                                frame, x_axis(axis))
        except (InputError, KeyError, TypeError, ValueError) as exc:
            return no_update, no_update, no_update, error_text(exc)
        return figure, table, strain, ""

    @app.callback(Output("x-axis", "value"), Output("frame", "value"), Input("field", "relayoutData"),
                  State("tool", "value"), prevent_initial_call=True)
    def draw_axis(relayout, tool_):
        """A line drawn with the x-axis tool: the specimen's frame, its x from the line's first end to its second."""
        shape = (relayout or {}).get("shapes", [None])[-1] if tool_ == "x-axis" else None
        if not shape or shape.get("type") != "line":
            return no_update, no_update
        return ",".join(f"{float(shape[k]):.2f}" for k in ("x0", "y0", "x1", "y1")), "specimen"

    @app.callback(Output("stress-strain", "figure"), Output("message", "children", allow_duplicate=True),
                  Input("load-upload", "contents"), Input("load-area", "value"), Input("ext-strain", "data"),
                  State("load-upload", "filename"), State("dic-path", "data"), prevent_initial_call=True)
    def stress_strain(contents, area, strain, filename, path):
        if not contents or not area or not strain:
            return no_update, ("load a CSV, give the cross-section and draw an extensometer for the stress-strain "
                               "curve" if contents else no_update)
        try:
            return stress_strain_figure(contents, filename or "load.csv", float(area), strain), ""
        except (InputError, TypeError, ValueError) as exc:
            return no_update, error_text(exc)

    @app.callback(Output("health", "figure"), Output("health-text", "children"), Input("health-button", "n_clicks"),
                  State("dic-path", "data"), prevent_initial_call=True)
    def health(_, path):
        try:
            return rig_health(source(access.resolve(path)))
        except InputError as exc:
            return no_update, error_text(exc)

    @app.callback(Output("download", "data"), Input("curve-csv", "n_clicks"), State("curve-data", "data"),
                  prevent_initial_call=True)
    def download(_, table):
        if not table:
            return no_update
        text = ",".join(table["columns"]) + "\n" + "".join(
            ",".join(f"{v:.9g}" if isinstance(v, float) else str(v) for v in row) + "\n" for row in table["rows"])
        return dcc.send_string(text, "curve.csv")


def rig_health(src: DicSource):
    """(histogram figure, one line) of the rig's epipolar error over state 0's matches of a stereo result
    (`stereodic.dic3d.epipolar`: right row minus where the left ray is seen, pixels; what the calibration
    allows; whether the rig looks bumped). InputError naming the result when it has no dic.npz or its rig
    file is gone."""
    import plotly.graph_objects as go

    from stereodic.dic3d.epipolar import check, epipolar_error
    from stereodic.stereo.rig import load_rig
    npz = src.path if src.run_folder is None else src.run_folder / "dic.npz"
    if not npz.is_file():
        raise InputError(src.path, "has no dic.npz yet: the rig's health is measured on a finished run")
    rig_name = src.meta.get("rig")
    candidates = [Path(rig_name), npz.parent / rig_name] if rig_name else []
    rig_path = next((p for p in candidates if p.is_file()), None)
    if rig_path is None:
        raise InputError(npz, f"names the rig {rig_name!r}, which is not there any more")
    rig = load_rig(rig_path)
    from calib.npz_stream import read_slice
    with np.load(npz) as z:
        xs, ys = z["x"].astype(np.float64), z["y"].astype(np.float64)
    X, Y = np.meshgrid(xs, ys)
    ru, rv, noise = (read_slice(npz, k, 0) for k in ("right_u", "right_v", "right_noise_px"))
    ok = np.isfinite(read_slice(npz, "left_u", 0)) & np.isfinite(ru)
    xl, yl, xr, yr = X[ok], Y[ok], (X + ru)[ok], (Y + rv)[ok]
    report = check(rig, xl, yl, xr, yr, noise[ok])
    if report is None:
        raise InputError(npz, "state 0 has no point matched in both cameras")
    e = epipolar_error(rig, xl, yl, xr, yr)
    fig = go.Figure(go.Histogram(x=e[np.isfinite(e)], nbinsx=60))
    for v in (-report.expected_p95, report.expected_p95):
        fig.add_vline(x=v, line=dict(color="red", dash="dash", width=1))
    fig.update_layout(title=dict(text="epipolar error of state 0 (red: the p95 the calibration allows)",
                                 font=dict(size=12)), xaxis_title="right row - where the left ray is seen (px)",
                      yaxis_title="points", margin=dict(l=60, r=10, t=35, b=40))
    verdict = ("the rig looks moved since its calibration" if report.bumped else
               "within what the calibration allows")
    return fig, f"{report.line()}: {verdict}"


_GAUGE_RESULTS: dict[tuple, object] = {}


def gauge_result(path: str, frame: str, axis: tuple | None = None):
    """The result opened for gauges (`stereodic.gauge.open_gauge_result`, in the specimen's frame x along
    `axis` as `source`'s), once per path, frame and axis."""
    from stereodic.gauge.result import open_gauge_result
    key = (path, frame, axis if frame == "specimen" else None)
    with _LOCK:
        if key not in _GAUGE_RESULTS:
            direction = (1.0, 0.0) if key[2] is None else (axis[2] - axis[0], axis[3] - axis[1])
            _GAUGE_RESULTS[key] = open_gauge_result(path, frame=frame, x_direction_px=direction)
        return _GAUGE_RESULTS[key]


def gauge_curve(path: str, shape: dict, tool: str, name: str, frame: str, axis: tuple | None = None):
    """(figure, CSV table, extensometer strain or None) of the gauge drawn as plotly `shape` with `tool`
    (extensometer, line, area), measured by `stereodic.gauge.measure_gauges` (what `stereodic gauge`
    writes) in the rig's or the specimen's frame (x along `axis`, as `source`)."""
    from stereodic.gauge.gauges import AreaGauge, Extensometer, Gauges, LineGauge, measure_gauges
    from stereodic.workspace.region import shape_polygon
    res = gauge_result(path, frame or "rig", axis)
    if tool in ("extensometer", "line"):
        if shape.get("type") != "line":
            raise InputError(tool, "draw it as a line from one end to the other")
        a, b = (float(shape["x0"]), float(shape["y0"])), (float(shape["x1"]), float(shape["y1"]))
        gauges = Gauges(extensometers=[Extensometer("E1", a, b)]) if tool == "extensometer" else \
            Gauges(lines=[LineGauge("L1", a, b)])
    else:
        corners = tuple(map(tuple, shape_polygon(shape).points.tolist()))
        gauges = Gauges(areas=[AreaGauge("A1", corners)])
    t = measure_gauges(res, gauges)
    states = np.arange(len(t.labels))
    where = f"({a[0]:.0f}, {a[1]:.0f}) - ({b[0]:.0f}, {b[1]:.0f}) px" if tool != "area" else ""
    if tool == "extensometer":
        e = t.extensometers[0]
        table = {"columns": ["state", "name", f"length_{t.unit}", "strain"],
                 "rows": [[int(k), "E1", float(L), float(s)] for k, L, s in zip(states, e.length, e.strain)]}
        fig = curve_figure(states, {"E1": e.strain * 1e6}, "state", "engineering strain (microstrain)",
                           f"extensometer {where}, L0 = {e.length[0]:.4g} {t.unit}")
        return fig, table, [float(v) for v in e.strain]
    unit = t.units.get(name, "")
    label = f"{name} ({'microstrain' if name in _STRAIN_NAMES else unit})" if (unit or name in _STRAIN_NAMES) \
        else name
    scale = 1e6 if name in _STRAIN_NAMES else 1.0
    if tool == "line":
        p = t.lines[0]
        if name not in p.values:
            raise InputError("quantity", f"{name} has no profile; choose one of {', '.join(p.values)}")
        series = {f"state {int(k)}": p.values[name][i] * scale for i, k in enumerate(p.states)}
        table = {"columns": ["state", f"distance_{t.unit}", name],
                 "rows": [[int(k), float(d), float(v)] for i, k in enumerate(p.states)
                          for d, v in zip(p.distance, p.values[name][i])]}
        return curve_figure(p.distance, series, f"distance along the line ({t.unit})", label,
                            f"{name} profile {where}"), table, None
    ar = t.areas[0]
    if name not in ar.mean:
        raise InputError("quantity", f"{name} has no area mean; choose one of {', '.join(ar.mean)}")
    table = {"columns": ["state", "name", f"{name}_mean", f"{name}_std", "count"],
             "rows": [[int(k), "A1", float(m), float(sd), int(c)] for k, m, sd, c in
                      zip(states, ar.mean[name], ar.std[name], ar.count[name])]}
    return curve_figure(states, {"mean": ar.mean[name] * scale}, "state", label,
                        f"{name} mean over the area ({ar.points} points)"), table, None


_STRAIN_NAMES = ("exx", "eyy", "exy", "e_major", "e_minor", "e_vm")


def stress_strain_figure(contents: str, filename: str, area_mm2: float, strain: list):
    """The stress-strain curve of an uploaded load CSV (a dcc.Upload data URL) joined to the states by its
    image index column (`stereodic.gauge.load`), against the last extensometer's engineering strain."""
    import base64
    import tempfile

    from stereodic.gauge.load import join_load, read_load, stress
    data = base64.b64decode(contents.split(",", 1)[1])
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / Path(filename).name
        path.write_bytes(data)
        load = read_load(path, need="index")
        at = join_load(load, len(strain), by="index")
    eng, _ = stress(at.force_n, area_mm2=area_mm2)
    fig = curve_figure(np.asarray(strain) * 1e6, {"stress": eng}, "engineering strain (microstrain)",
                       "engineering stress (MPa)", f"stress-strain ({filename}, A0 = {area_mm2:g} mm^2)")
    return fig


def curve_figure(x, series: dict, xlabel: str, ylabel: str, title: str):
    """A line plot of one or more curves against the state (or another x)."""
    import plotly.graph_objects as go
    fig = go.Figure([go.Scatter(x=x, y=y, mode="lines+markers", name=name) for name, y in series.items()])
    fig.update_layout(title=dict(text=title, font=dict(size=12)), margin=dict(l=60, r=10, t=35, b=40),
                      xaxis_title=xlabel, yaxis_title=ylabel, showlegend=len(series) > 1)
    return fig

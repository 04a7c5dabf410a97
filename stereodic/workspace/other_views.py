"""The pages of a calibration, a rig and a scan.

- PRVM file: the distortion map (each pixel's departure from the best pinhole view of a plane,
  `stereodic show`'s `distortion_px`, camera pixels), the 1-sigma ray uncertainty (camera pixels, where the
  calibration recorded it), the line-fit residual (micrometres, with three or more stage positions) and,
  for a simulated dataset's calibration, the ray error against its truth (camera pixels).
- RIG file: its model, baseline and working distance, and each camera's error vector matrix (the
  model-less rays' departure from the virtual pinhole's, mrad): where the pinhole model misses.
  The rig's health in use, its epipolar error on a measured pair, is on a DIC result's page.
- PLY point cloud: the points in 3D (WebGL), coloured by their signed distance to the plane or sphere
  fitted to them (`stereodic.scan.fit`), mm.
Maps are shown at most MAX_MAP_PX wide (every n-th pixel): enough to see, light to send.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from stereodic.workspace.access import Access

MAX_MAP_PX = 480
MAX_CLOUD_POINTS = 200_000


def _thin(a: np.ndarray) -> tuple[np.ndarray, int]:
    step = max(1, int(np.ceil(max(a.shape[:2]) / MAX_MAP_PX)))
    return a[::step, ::step], step


def map_figure(values: np.ndarray, title: str, unit: str, colorscale: str = "Viridis"):
    """A heat map of a camera-sized map (pixels) with its colour bar in `unit`."""
    import plotly.graph_objects as go
    thin, step = _thin(values)
    h, w = thin.shape
    fig = go.Figure(go.Heatmap(z=thin.astype(np.float32), x=np.arange(w) * step, y=np.arange(h) * step,
                               colorscale=colorscale, colorbar=dict(title=dict(text=unit, side="right")),
                               hovertemplate="x %{x} px, y %{y} px<br>%{z:.4g} " + unit + "<extra></extra>"))
    fig.update_layout(title=dict(text=title, font=dict(size=13)), width=620, height=520,
                      margin=dict(l=50, r=10, t=50, b=40))
    fig.update_yaxes(autorange="reversed", scaleanchor="x", title="y (px)")
    fig.update_xaxes(title="x (px)")
    return fig


def _graphs(figures: list):
    from dash import dcc, html
    return html.Div([html.Div(dcc.Graph(figure=f, config={"displaylogo": False}), className="map",
                              style={"display": "inline-block"}) for f in figures])


def prvm_layout(path: Path, access: Access):
    from dash import html

    from calib.evaluate import footprint_mm
    from calib.numbers import fixed
    from calib.prvm_file import load_prvm
    from stereodic.cli.show import distortion_px
    prvm = load_prvm(path)
    valid = prvm.valid
    z0 = float(prvm.meta.get("uncertainty_z_mm", [prvm.reference_z_mm])[0])
    d = distortion_px(prvm, z0)
    figures = [map_figure(np.where(valid, np.hypot(d[0], d[1]), np.nan),
                          f"distortion: departure from the best pinhole view of z = {fixed(z0, 3)} mm", "camera px")]
    unc = prvm.extra.get("uncertainty_mm")
    if unc is not None:
        figures.append(map_figure(np.where(valid, unc[..., 0] / footprint_mm(prvm, z0), np.nan),
                                  f"1-sigma ray uncertainty at z = {fixed(z0, 3)} mm (per axis)", "camera px",
                                  "Magma"))
    res = prvm.residual_mm
    if res is not None and np.nanmax(np.where(valid, res, np.nan), initial=0.0) > 0:   # a fit was made
        figures.append(map_figure(np.where(valid, res * 1000.0, np.nan), "line-fit residual (error of the rays' "
                                                                          "fit to the decoded points)", "um", "Magma"))
    truth = _truth_of(prvm)
    if truth is not None:
        from calib.evaluate import ErrorStats, ray_error_px, working_plane
        err = ray_error_px(prvm, truth)
        st = ErrorStats.of(err)
        figures.append(map_figure(err, f"ray error against the simulated truth on z = {fixed(working_plane(truth), 3)} "
                                       f"mm: RMS {fixed(st.rms, 4)} px", "camera px", "Magma"))
    h, w = valid.shape
    about = (f"PRVM of camera {prvm.meta.get('camera', '?')}, {w} x {h} px, {int(valid.sum())} pixels calibrated "
             f"({100 * valid.mean():.1f} %)")
    return html.Div([html.P(about, id="about"), _graphs(figures)])


def _truth_of(prvm):
    """The simulated truth of a calibration (its dataset's truth.npz, where the PRVM names a dataset folder
    that has one and it fits: `calib.evaluate.check_truth`), else None."""
    from calib.errors import InputError
    from calib.evaluate import check_truth
    from calib.prvm_file import load_prvm
    dataset = Path(str(prvm.meta.get("dataset", "")))
    path = (dataset.parent if dataset.name == "capture.json" else dataset) / "truth.npz"
    if not str(prvm.meta.get("dataset", "")) or not path.is_file():
        return None
    try:
        truth = load_prvm(path)
        check_truth(prvm, truth, "calibration", path)
    except InputError:
        return None
    return truth


def rig_layout(path: Path, access: Access):
    from dash import html

    from calib.numbers import fixed
    from stereodic.stereo.rig import load_rig
    rig = load_rig(path)
    figures = [map_figure(np.linalg.norm(rig.evm(side), axis=-1) * 1000.0,
                          f"{side} camera ({rig.camera(side).name}): error vector matrix", "mrad", "Magma")
               for side in ("left", "right")]
    about = (f"rig ({rig.model}): rectified sensor {rig.sensor.width} x {rig.sensor.height} px, baseline "
             f"{fixed(float(np.linalg.norm(rig.baseline)), 2)} mm, working distance "
             f"{fixed(rig.working_distance_mm, 1)} mm. Its epipolar error on a measured pair is on a DIC "
             f"result's page (rig health).")
    return html.Div([html.P(about, id="about"), _graphs(figures)])


def scan_layout(path: Path, access: Access):
    from dash import dcc, html
    return html.Div([
        dcc.Store(id="scan-path", data=str(path)),
        html.Div(["distance to the fitted ", dcc.RadioItems(["plane", "sphere"], "plane", id="scan-shape",
                                                             inline=True)]),
        html.P(id="about"),
        dcc.Graph(id="cloud", style={"height": "650px", "width": "900px"}, config={"displaylogo": False}),
    ])


def cloud_figure(points: np.ndarray, shape: str):
    """(figure, summary) of a point cloud coloured by the signed distance to its fitted `shape` (mm)."""
    import plotly.graph_objects as go

    from calib.numbers import fixed
    from stereodic.scan.fit import fit_plane, fit_sphere, trimmed_range
    if shape == "sphere":
        fit = fit_sphere(points)
        what = f"sphere of radius {fixed(fit.radius_mm, 3)} mm"
    else:
        fit = fit_plane(points)
        what = "plane"
    d = fit.residuals
    show = np.arange(len(points))
    if len(points) > MAX_CLOUD_POINTS:
        show = np.linspace(0, len(points) - 1, MAX_CLOUD_POINTS).astype(int)
    lim = max(trimmed_range(d) / 2, 1e-6)
    p = points[show]
    fig = go.Figure(go.Scatter3d(x=p[:, 0], y=p[:, 1], z=p[:, 2], mode="markers",
                                 marker=dict(size=1.5, color=d[show].astype(np.float32), colorscale="RdBu_r",
                                             cmin=-lim, cmax=lim,
                                             colorbar=dict(title=dict(text="distance (mm)", side="right")))))
    fig.update_layout(margin=dict(l=0, r=0, t=30, b=0), scene=dict(aspectmode="data", xaxis_title="X (mm)",
                                                                   yaxis_title="Y (mm)", zaxis_title="Z (mm)"))
    summary = (f"{len(points)} points ({len(show)} shown); distance to the fitted {what}: RMS "
               f"{fixed(float(np.sqrt(np.mean(d ** 2))), 4)} mm, 99.7 % within {fixed(trimmed_range(d), 4)} mm")
    return fig, summary


def read_cloud(path: str | Path) -> np.ndarray:
    """(N, 3) float64 points of a PLY file, mm; InputError naming it when it holds none."""
    import open3d as o3d

    from calib.errors import InputError
    pts = np.asarray(o3d.io.read_point_cloud(str(path)).points, np.float64)
    pts = pts[np.isfinite(pts).all(axis=1)]
    if len(pts) < 4:
        raise InputError(path, f"holds {len(pts)} points; a fit needs at least 4")
    return pts


def register(app, access: Access) -> None:
    from dash import Input, Output, State

    from stereodic.workspace.page import error_text

    @app.callback(Output("cloud", "figure"), Output("about", "children"), Input("scan-shape", "value"),
                  State("scan-path", "data"))
    def cloud(shape, path):
        from calib.errors import InputError
        try:
            return cloud_figure(read_cloud(access.resolve(path)), shape)
        except (InputError, ValueError) as exc:
            return {}, error_text(exc)

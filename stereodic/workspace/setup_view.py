"""The set-up page: from a `kind: dic` dataset, a folder of image pairs NAME_0 / NAME_1, or two shell-style
patterns or two videos (one per camera, as `stereodic dic --left --right` takes them; the page's address
carries them, `?path=FOLDER&left=PATTERN&right=PATTERN`, relative to FOLDER) and a rig to a running
`stereodic dic`. Without a rig the page first makes one: from two cameras' PRVM files (`stereodic rig`) or
from another program's calibration file (`stereodic import`, its format recognised from its content).

The left reference image is shown with the specimen's region found automatically (`region.automatic_region`
on the speckle's predicted noise); the user edits it in the ORIGINAL image: rectangles and polygons add
to it, polygons drawn as holes (red) cut it, the eraser removes one. Beside it, the predicted random
displacement error per subset size over the region (`stereodic.dic.speckle_quality`, what `stereodic
speckle` measures) to choose the subset and step. Start writes, in the output folder, the region
(`workspace.json`: the settings, the region's polygons in the original image, the command, the left
images) and its mask in the rectified image (`region_mask.png`, `--mask`), then runs the equivalent
`stereodic dic` command (shown on the page) as a child process whose output goes to `workspace.log`;
the page follows its progress from the run folder's manifest (states done, states/s, time left). The run
writes every file atomically and resumes where it stopped: a browser closed half-way, or the server
stopped, leaves a consistent folder (the same command resumes it).
"""

from __future__ import annotations

import json
import re
import shlex
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

from calib.errors import InputError
from stereodic.workspace.access import Access
from stereodic.workspace.page import GRAPH_WIDTH_PX, error_text, image_url
from stereodic.workspace.region import (HOLE_COLOUR, PART_COLOUR, Polygon, automatic_region, from_json, original_mask,
                                        polygon_shape, rectified_mask, shape_polygon, to_json)

RUN_FORMAT = "stereodic.workspace-run/1"
# `stereodic dic` options the page passes on as typed (none names a file: the run reads only what it serves)
EXTRA_OPTIONS = {"--vertical-search": 1, "--max-gap": 1, "--prefilter": 1, "--min-zncc": 1, "--disparity": 1,
                 "--search": 1, "--switch-zncc": 1, "--shape": 1, "--measure": 1, "--incremental": 0}
_RUNS: dict[str, dict] = {}     # output folder -> {"process", "started", "done0"}
_LOCK = threading.Lock()


def dataset_of(path: Path) -> Path:
    return path.parent if path.name == "capture.json" else path


def find_files(folders: list[Path], fmt: str, *, most: int = 200) -> list[Path]:
    """The .npz files of format `fmt` ("stereodic.rig/1", "stereodic.prvm/1") in the served folders and
    their sub-folders two levels down."""
    out = []
    for folder in folders:
        for p in sorted([*folder.glob("*.npz"), *folder.glob("*/*.npz"), *folder.glob("*/*/*.npz")])[:most]:
            try:
                with np.load(p) as z:
                    if "meta" in z.files and json.loads(str(z["meta"])).get("format") == fmt:
                        out.append(p)
            except (OSError, ValueError, EOFError):
                continue
    return out


def rig_maker(dataset: Path, access: Access):
    """The page where there is no rig yet: two calibrated cameras (PRVM files) picked, `stereodic rig`
    run to make DATASET/rig.npz, then the set-up page; InputError when there are not two PRVM files."""
    from dash import dcc, html
    cams = [str(p) for p in find_files(access.folders, "stereodic.prvm/1")]
    if len(cams) < 2:
        raise InputError(dataset, "no rig file (stereodic.rig/1) and fewer than two calibrated cameras (PRVM "
                                  "files) in the served folders: calibrate the cameras, or serve their folder too "
                                  "(stereodic view DATASET CALIBRATION_FOLDER)")
    return html.Div([
        dcc.Store(id="rig-dataset", data=str(dataset)),
        html.P("No rig yet: pick the left and the right camera's calibration; `stereodic rig` makes the rectified "
               "pair (rig.npz in the dataset's folder)."),
        html.Div(["left ", dcc.Dropdown(cams, cams[0], id="rig-left", clearable=False,
                                        style={"width": "520px", "display": "inline-block"})]),
        html.Div(["right ", dcc.Dropdown(cams, cams[1], id="rig-right", clearable=False,
                                         style={"width": "520px", "display": "inline-block"})]),
        html.Button("make the rig", id="make-rig", n_clicks=0),
        html.Pre(id="rig-command"), html.Div(id="rig-message", style={"color": "#b00", "whiteSpace": "pre-wrap"}),
    ])


def apply_relayout(shapes: list, relayout: dict) -> list:
    """The shapes after a plotly relayout event: a new list ("shapes"), or one shape's key edited
    ("shapes[2].path", "shapes[0].x0")."""
    if "shapes" in relayout:
        return list(relayout["shapes"] or [])
    shapes = [dict(s) for s in shapes]
    for key, value in relayout.items():
        m = re.fullmatch(r"shapes\[(\d+)\]\.(\w+)", key)
        if m and int(m.group(1)) < len(shapes):
            shapes[int(m.group(1))][m.group(2)] = value
    return shapes


def image_pattern(folder: Path, pattern: str, access: Access, side: str) -> str:
    """A camera's images typed on the page (a shell-style pattern, a video or other sequence file, or
    VIDEO:left / VIDEO:right for a half of a side-by-side stream), relative to `folder` unless absolute;
    InputError naming the side when it is empty, or the first file it names outside the served folders
    (checked before any file is read)."""
    import glob
    import os
    if not pattern or not pattern.strip():
        raise InputError(f"{side} images", "give a pattern (e.g. images/left_*.tif) or a video file")
    text = os.path.expanduser(pattern.strip())
    text = text if os.path.isabs(text) else str(folder / text)
    if glob.has_magic(text):
        for p in glob.glob(text, recursive=True):
            access.resolve(p)
    else:
        half = re.fullmatch(r"(.+):(left|right)", text)
        access.resolve(half.group(1) if half and not Path(text).exists() else text)
    return text


def _states(dataset: Path, rig_path: Path, images: dict | None = None):
    """(rig, the experiment's states) of a dataset folder, of a folder of image pairs NAME_0 / NAME_1, or of
    `images` {"left": pattern, "right": pattern} (`image_pattern`'s, checked)."""
    from stereodic.dic3d.dataset import load_states, states_from_folder, states_from_patterns
    from stereodic.stereo.rig import load_rig
    rig = load_rig(rig_path)
    if images:
        return rig, states_from_patterns(images["left"], images["right"], rig)
    if (dataset / "capture.json").is_file():
        return rig, load_states(dataset, rig)
    return rig, states_from_folder(dataset, "_0", "_1", rig)


def checked_images(dataset: Path, images: dict | None, access: Access) -> dict | None:
    """`images` ({"left", "right"} as typed, or None: the dataset or pairs) with each pattern made absolute
    and checked (`image_pattern`)."""
    if not images:
        return None
    return {side: image_pattern(dataset, images.get(side) or "", access, side) for side in ("left", "right")}


def automatic_shapes(image: Path) -> list[dict]:
    """The specimen's region found in `image` (`region.automatic_region` on the predicted noise of 21 px
    subsets) as editable plotly shapes."""
    from calib.imageio import read_gray
    from stereodic.dic.speckle_quality import speckle_quality
    noise = speckle_quality(read_gray(image), subset=21, sizes=(21,)).noise_map
    return [polygon_shape(p) for p in automatic_region(noise)]


def default_output(dataset: Path, access: Access) -> Path:
    """Where a run goes unless the user says otherwise: beside the dataset where that is served, else in it."""
    beside = dataset.parent / f"{dataset.name}-dic"
    try:
        return access.resolve(beside)
    except InputError:
        return dataset / "dic-run"


def reference_figure(ref: Path, shapes: list):
    import plotly.graph_objects as go

    from calib.imageio import image_size
    w, h = image_size(ref)
    fig = go.Figure()
    fig.update_layout(images=[dict(source=image_url(ref), xref="x", yref="y", x=-0.5, y=-0.5, sizex=w, sizey=h,
                                   sizing="stretch", layer="below")], shapes=shapes, dragmode="drawclosedpath",
                      newshape=dict(line=dict(color=PART_COLOUR, width=2), fillcolor=PART_COLOUR, opacity=0.25),
                      width=GRAPH_WIDTH_PX, height=int(GRAPH_WIDTH_PX * h / w) + 60, uirevision="ref",
                      margin=dict(l=50, r=10, t=30, b=40), title=dict(text=f"left reference image {ref.name}: "
                                                                         f"the specimen's region", font=dict(size=13)))
    fig.update_xaxes(range=[-0.5, w - 0.5], showgrid=False, title="x, original left image (px)")
    fig.update_yaxes(range=[h - 0.5, -0.5], scaleanchor="x", showgrid=False, title="y (px)")
    return fig


def layout(path: Path, access: Access):
    from dash import dcc, html
    dataset = dataset_of(path)
    rigs = find_files(access.folders, "stereodic.rig/1")
    default = next((r for r in rigs if r.parent == dataset), rigs[0] if rigs else None)
    if default is None:
        return rig_maker(dataset, access)
    rig, data = _states(dataset, default)
    shapes = automatic_shapes(data.left[0])
    return html.Div([
        dcc.Store(id="setup-dataset", data=str(dataset)), dcc.Store(id="shapes", data=shapes),
        html.Div(["rig ", dcc.Dropdown([str(r) for r in rigs], str(default), id="setup-rig", clearable=False,
                                       style={"width": "520px", "display": "inline-block"})]),
        html.Div([f"{len(data)} states ({data.source}); left reference {data.left[0].name}"], id="setup-about"),
        html.Div([
            html.Div([
                dcc.RadioItems([{"label": " polygon", "value": "drawclosedpath"},
                                {"label": " rectangle", "value": "drawrect"},
                                {"label": " cut a hole (polygon)", "value": "hole"}],
                               "drawclosedpath", id="region-tool", inline=True),
                html.Button("find the specimen again", id="auto-region", n_clicks=0),
                html.Button("clear the region", id="clear-region", n_clicks=0),
                dcc.Graph(id="ref-image", figure=reference_figure(data.left[0], shapes),
                          config={"displaylogo": False, "modeBarButtonsToAdd": ["drawclosedpath", "drawrect",
                                                                                 "eraseshape"]}),
            ], style={"flex": "none"}),
            html.Div([
                html.Div(["subset ", dcc.Input(id="setup-subset", type="number", value=21, min=5, step=2,
                                               style={"width": "60px"}), " px, step ",
                          dcc.Input(id="setup-step", type="number", value=5, min=1, style={"width": "50px"}),
                          " px, strain window ", dcc.Input(id="setup-window", type="number", value=5, min=0,
                                                           step=1, style={"width": "50px"}), " points"]),
                dcc.Graph(id="noise", style={"height": "300px", "width": "480px"}, config={"displaylogo": False}),
                html.Div(["further options ", dcc.Input(id="setup-options", value="", debounce=True,
                                                        placeholder="e.g. --vertical-search 50 --max-gap 100",
                                                        style={"width": "360px"})],
                         title=", ".join(EXTRA_OPTIONS) + " (stereodic dic --help)"),
                html.Div(["output folder ", dcc.Input(id="setup-output", value=str(default_output(dataset, access)),
                                                      style={"width": "380px"})]),
                html.Button("start the run", id="start", n_clicks=0, style={"marginTop": "6px"}),
                html.Pre(id="command", style={"whiteSpace": "pre-wrap", "maxWidth": "480px"}),
                html.Div(id="progress"), dcc.Interval(id="run-poll", interval=1000, disabled=True),
                html.Div(id="setup-message", style={"color": "#b00", "whiteSpace": "pre-wrap"}),
            ], style={"flex": "none", "marginLeft": "10px"}),
        ], style={"display": "flex", "alignItems": "flex-start"}),
    ])


def noise_figure(sizes, median, p95, subset: int):
    import plotly.graph_objects as go
    fig = go.Figure([go.Scatter(x=sizes, y=median, mode="lines+markers", name="median"),
                     go.Scatter(x=sizes, y=p95, mode="lines", name="95th percentile", line=dict(dash="dash"))])
    fig.add_vline(x=subset, line=dict(color="red", width=1))
    fig.update_layout(title=dict(text="predicted random displacement error over the region", font=dict(size=12)),
                      xaxis_title="subset size (px)", yaxis_title="error (px)", yaxis_type="log",
                      margin=dict(l=60, r=10, t=35, b=40), legend=dict(x=0.6, y=0.95))
    return fig


def extra_options(text: str | None) -> list[str]:
    """The further `stereodic dic` options typed on the page, as arguments; InputError naming the first
    that is not one of EXTRA_OPTIONS (with its value where it takes one)."""
    try:
        words = shlex.split(text or "")
    except ValueError as exc:
        raise InputError("further options", str(exc)) from None
    out, i = [], 0
    while i < len(words):
        name = words[i].split("=", 1)[0]
        if name not in EXTRA_OPTIONS:
            raise InputError("further options", f"{words[i]!r} is not one of {', '.join(EXTRA_OPTIONS)}")
        takes = 0 if "=" in words[i] else EXTRA_OPTIONS[name]
        if i + takes >= len(words):
            raise InputError("further options", f"{name} needs a value")
        out += words[i:i + 1 + takes]
        i += 1 + takes
    return out


def write_run_files(output: Path, rig_path: Path, dataset: Path, polygons: list[Polygon], settings: dict,
                    ) -> list[str]:
    """Write the region and settings into the output folder (module docstring); returns the command."""
    from calib.atomic import write_json
    from calib.imageio import write_gray
    rig, data = _states(dataset, rig_path)
    imm = rig.left.imm
    mask = rectified_mask(original_mask(polygons, imm.real_size), imm.map_x, imm.map_y, imm.valid)
    if not mask.any():
        raise InputError("region", "covers no pixel of the rectified left image: draw it on the specimen")
    output.mkdir(parents=True, exist_ok=True)
    write_gray(output / "region_mask.png", mask.astype(np.uint8) * 255)
    images = [str(dataset)] if (dataset / "capture.json").is_file() else ["--images", str(dataset)]
    command = ["stereodic", "dic", str(rig_path), *images, "-o", str(output),
               "--mask", str(output / "region_mask.png"), "--subset", str(settings["subset"]), "--step",
               str(settings["step"]), "--strain-window", str(settings["strain_window"]), "--no-vtk",
               *extra_options(settings.get("options"))]
    write_json(output / "workspace.json", {"format": RUN_FORMAT, "rig": str(rig_path), "dataset": str(dataset),
                                           "settings": settings, "region": to_json(polygons),
                                           "command": shlex.join(command), "left_images": [str(p) for p in data.left],
                                           "state_labels": [data.label(k) for k in range(len(data))]})
    return command


def start_run(output: Path, command: list[str]) -> None:
    """Run `command` (a `stereodic dic` command line) as a child process, its output into workspace.log."""
    with _LOCK:
        old = _RUNS.get(str(output))
        if old is not None and old["process"].poll() is None:
            raise InputError(output, "a run is already going on in this folder")
        log = open(output / "workspace.log", "w")
        proc = subprocess.Popen([sys.executable, "-m", "stereodic", *command[1:]], stdout=log,
                                stderr=subprocess.STDOUT)
        log.close()
        _RUNS[str(output)] = {"process": proc, "started": time.monotonic(), "done0": None}


def run_progress(output: Path) -> tuple[str, bool, bool]:
    """(a line of progress, finished, succeeded) of the run started in `output`."""
    run = _RUNS.get(str(output))
    if run is None:
        return "no run started here", True, False
    manifest = output / "run.json"
    done = total = 0
    if manifest.is_file():
        try:
            m = json.loads(manifest.read_text())
            done, total = int(m.get("done", 0)), int(m.get("states", 0))
        except (ValueError, OSError):
            pass
    if run["done0"] is None and manifest.is_file():
        run["done0"] = (done, time.monotonic())
    rc = run["process"].poll()
    if rc is not None:
        if rc == 0:
            said = [t for t in (output / "workspace.log").read_text().splitlines() if t.startswith(("state ",
                                                                                                  "stereodic dic"))]
            return f"finished: {total} states; {said[-1] if said else ''}", True, True
        lines = (output / "workspace.log").read_text().strip().splitlines()
        return f"the run stopped (exit status {rc}): {lines[-1] if lines else ''}", True, False
    text = f"{done} of {total or '?'} states done"
    if run["done0"] is not None and done > run["done0"][0]:
        rate = (done - run["done0"][0]) / (time.monotonic() - run["done0"][1])
        text += f", {rate:.2f} states/s, {(total - done) / rate:.0f} s left"
    return text, False, False


def register(app, access: Access) -> None:
    from dash import Input, Output, State, ctx, dcc, html, no_update


    @app.callback(Output("ref-image", "figure"), Output("shapes", "data"), Input("region-tool", "value"),
                  Input("auto-region", "n_clicks"), Input("clear-region", "n_clicks"),
                  Input("ref-image", "relayoutData"), State("shapes", "data"), State("setup-dataset", "data"),
                  State("setup-rig", "value"), prevent_initial_call=True)
    def region(tool, _auto, _clear, relayout, shapes, dataset, rig_path):
        from dash import Patch
        patch = Patch()
        trigger = ctx.triggered_id
        if trigger == "region-tool":
            hole = tool == "hole"
            colour = HOLE_COLOUR if hole else PART_COLOUR
            patch["layout"]["dragmode"] = "drawclosedpath" if hole else tool
            patch["layout"]["newshape"] = dict(line=dict(color=colour, width=2), fillcolor=colour, opacity=0.25)
            return patch, no_update
        if trigger == "clear-region":
            shapes = []
        elif trigger == "auto-region":
            try:
                _, data = _states(access.resolve(dataset), access.resolve(rig_path))
            except InputError:
                return no_update, no_update
            shapes = automatic_shapes(data.left[0])
        else:
            if not relayout or not any(k.startswith("shapes") for k in relayout):
                return no_update, no_update
            return no_update, apply_relayout(shapes or [], relayout)
        patch["layout"]["shapes"] = shapes
        return patch, shapes

    @app.callback(Output("noise", "figure"), Output("setup-message", "children", allow_duplicate=True),
                  Input("shapes", "data"), Input("setup-subset", "value"), State("setup-dataset", "data"),
                  State("setup-rig", "value"), prevent_initial_call="initial_duplicate")
    def noise(shapes, subset, dataset, rig_path):
        from calib.imageio import read_gray
        from stereodic.dic.speckle_quality import SIZES, speckle_quality
        try:
            polygons = [shape_polygon(s) for s in shapes or []]
            _, data = _states(access.resolve(dataset), access.resolve(rig_path))
            img = read_gray(data.left[0])
            h, w = img.shape
            mask = original_mask(polygons, (w, h)) if polygons else np.ones((h, w), bool)
            if not mask.any():
                raise InputError("region", "is empty")
            ys, xs = np.nonzero(mask)
            roi = (int(xs.min()), int(ys.min()), int(xs.max()), int(ys.max()))
            sizes = [s for s in SIZES if s <= min(w, h) // 2]
            q = speckle_quality(img, subset=int(subset or 21), roi=roi, sizes=sizes)
        except (InputError, ValueError) as exc:
            return no_update, error_text(exc)
        return noise_figure(q.sizes, q.median_px, q.p95_px, int(subset or 21)), ""

    @app.callback(Output("command", "children"), Output("run-poll", "disabled"),
                  Output("setup-message", "children", allow_duplicate=True),
                  Input("start", "n_clicks"), State("shapes", "data"), State("setup-dataset", "data"),
                  State("setup-rig", "value"), State("setup-output", "value"), State("setup-subset", "value"),
                  State("setup-step", "value"), State("setup-window", "value"), State("setup-options", "value"),
                  prevent_initial_call=True)
    def start(_, shapes, dataset, rig_path, output, subset, step, window, options):
        try:
            polygons = from_json(to_json([shape_polygon(s) for s in shapes or []]))   # checked: >= 3 vertices
            if not any(not p.hole for p in polygons):
                raise InputError("region", "has no part: draw the specimen's outline first")
            out = access.resolve(output)
            settings = {"subset": int(subset), "step": int(step), "strain_window": int(window),
                        "options": " ".join(extra_options(options))}
            if settings["subset"] < 5 or settings["subset"] % 2 == 0 or settings["step"] < 1:
                raise InputError("subset/step", f"subset must be odd and >= 5, step >= 1; got {subset}, {step}")
            command = write_run_files(out, access.resolve(rig_path), access.resolve(dataset), polygons, settings)
            start_run(out, command)
        except (InputError, TypeError, ValueError) as exc:
            return no_update, no_update, error_text(exc)
        return "the equivalent command:\n" + shlex.join(command), False, ""

    @app.callback(Output("rig-command", "children"), Output("rig-message", "children"),
                  Input("make-rig", "n_clicks"), State("rig-dataset", "data"), State("rig-left", "value"),
                  State("rig-right", "value"), prevent_initial_call=True)
    def make_rig(_, dataset, left, right):
        from urllib.parse import quote
        try:
            out = access.resolve(Path(dataset) / "rig.npz")
            command = ["stereodic", "rig", str(access.resolve(left)), str(access.resolve(right)), "-o", str(out)]
        except InputError as exc:
            return no_update, error_text(exc)
        done = subprocess.run([sys.executable, "-m", "stereodic", *command[1:]], capture_output=True, text=True)
        if done.returncode != 0:
            lines = (done.stderr or done.stdout).strip().splitlines()
            return shlex.join(command), lines[-1] if lines else f"exit status {done.returncode}"
        return html.Span([shlex.join(command), "\n", done.stdout.strip(), "\n",
                          dcc.Link("set up the run", href=f"/?path={quote(dataset)}", refresh=True,
                                   id="open-setup")]), ""

    @app.callback(Output("progress", "children"), Output("run-poll", "disabled", allow_duplicate=True),
                  Input("run-poll", "n_intervals"), State("setup-output", "value"), prevent_initial_call=True)
    def follow(_, output):
        from urllib.parse import quote
        try:
            out = access.resolve(output)
        except InputError as exc:
            return error_text(exc), True
        text, finished, ok = run_progress(out)
        if ok:
            return html.Span([text, " - ", dcc.Link("open the results", href=f"/?path={quote(str(out))}",
                                                    refresh=True, id="open-results")]), True
        return text, finished

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
                 "--search": 1, "--switch-zncc": 1, "--shape": 1, "--measure": 1, "--incremental": 0,
                 "--no-plot": 0}
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


CALIBRATION_SUFFIXES = (".xml", ".yml", ".yaml", ".json", ".txt", ".cameramodel")
CALIBRATION_MAX_BYTES = 4 << 20    # larger text files are not looked into for a calibration


def find_calibrations(folders: list[Path], *, most: int = 200) -> list[tuple[Path, str]]:
    """(file, format) of the other programs' calibration files that `stereodic import` reads (VIC-3D,
    DICe, OpenCV, mrcal, Kalibr, ROS; the format recognised from the content, `stereodic.formats.detect`)
    in the served folders and their sub-folders two levels down."""
    from stereodic.formats.detect import detect_format
    out = []
    for folder in folders:
        found = sorted(p for pattern in ("*", "*/*", "*/*/*") for p in folder.glob(pattern)
                       if p.suffix.lower() in CALIBRATION_SUFFIXES and p.is_file())
        for p in found[:most]:
            try:
                if p.stat().st_size <= CALIBRATION_MAX_BYTES:
                    out.append((p, detect_format(p)))
            except (InputError, OSError):
                continue
    return out


def first_image_size(dataset: Path, images: dict | None) -> tuple[int, int] | None:
    """(width, height) of the experiment's first left image (the dataset's, the pairs', or the first that
    `images`' left pattern names), for `stereodic import --size`; None when there is none to read."""
    from calib.capture import load_capture
    from calib.image_files import expand, natural_key
    from calib.imageio import IMAGE_SUFFIXES, image_size
    try:
        if images:
            return image_size(expand(images["left"])[0])
        if (dataset / "capture.json").is_file():
            return tuple(sorted(load_capture(dataset).cameras.items())[0][1])
        first = min((p for p in dataset.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES), key=natural_key)
        return image_size(first)
    except (InputError, ValueError, OSError):
        return None


def rig_maker(dataset: Path, access: Access, images: dict | None = None):
    """The page where there is no rig yet: `stereodic rig` from two calibrated cameras (PRVM files) picked,
    or `stereodic import` from another program's calibration file picked (`find_calibrations`), to make
    DATASET/rig.npz, then the set-up page; InputError when the served folders hold neither."""
    from dash import dcc, html
    cams = [str(p) for p in find_files(access.folders, "stereodic.prvm/1")]
    calibrations = find_calibrations(access.folders)
    if len(cams) < 2 and not calibrations:
        raise InputError(dataset, "no rig file (stereodic.rig/1), fewer than two calibrated cameras (PRVM files) "
                                  "and no other program's calibration file (VIC-3D, DICe, OpenCV, mrcal, Kalibr, "
                                  "ROS) in the served folders: calibrate the cameras, or serve their folder too "
                                  "(stereodic view DATASET CALIBRATION_FOLDER)")
    parts = [dcc.Store(id="rig-dataset", data=str(dataset)),
             html.P("No rig yet: make the rectified pair (rig.npz in the dataset's folder) from the two cameras' "
                    "calibrations or from another program's calibration file.")]
    if len(cams) >= 2:
        parts += [
            html.B("two calibrated cameras (PRVM files): stereodic rig"),
            html.Div(["left ", dcc.Dropdown(cams, cams[0], id="rig-left", clearable=False,
                                            style={"width": "520px", "display": "inline-block"})]),
            html.Div(["right ", dcc.Dropdown(cams, cams[1], id="rig-right", clearable=False,
                                             style={"width": "520px", "display": "inline-block"})]),
            html.Button("make the rig", id="make-rig", n_clicks=0), html.Hr()]
    if calibrations:
        size = first_image_size(dataset, images)
        parts += [
            html.B("another program's calibration file: stereodic import"),
            html.Div(["file ", dcc.Dropdown([{"label": f"{p} ({fmt})", "value": str(p)} for p, fmt in calibrations],
                                            str(calibrations[0][0]), id="import-file", clearable=False,
                                            style={"width": "620px", "display": "inline-block"})]),
            html.Div(["image size ", dcc.Input(id="import-size", value=f"{size[0]}x{size[1]}" if size else "",
                                               placeholder="WxH", style={"width": "100px"}),
                      " px (--size: used where the file gives none)"]),
            html.Button("import the calibration", id="import-rig", n_clicks=0)]
    return html.Div(parts + [html.Pre(id="rig-command", style={"whiteSpace": "pre-wrap"}),
                             html.Div(id="rig-message", style={"color": "#b00", "whiteSpace": "pre-wrap"})])


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


def image_pairs(folder: Path) -> bool:
    """Whether `folder` holds image pairs named as DICe and VIC-3D name them (NAME_0.tif, NAME_1.tif)."""
    from calib.imageio import IMAGE_SUFFIXES
    return any(p.suffix.lower() in IMAGE_SUFFIXES and p.stem.endswith("_0") and
               any((folder / f"{p.stem[:-2]}_1{s}").is_file() for s in (p.suffix, p.suffix.lower()))
               for p in folder.iterdir())


def holds_images(folder: Path) -> bool:
    """Whether `folder` or a sub-folder holds an image or a video (or other sequence file) to set a run up
    from with two patterns or two videos."""
    from calib.imageio import IMAGE_SUFFIXES
    from calib.sequences import SEQUENCE_SUFFIXES
    suffixes = set(IMAGE_SUFFIXES) | set(SEQUENCE_SUFFIXES)
    return any(p.suffix.lower() in suffixes for pattern in ("*", "*/*") for p in folder.glob(pattern))


def images_chooser(dataset: Path, images: dict | None):
    """The row where the images are chosen: the dataset or folder's pairs (both fields empty), or a pattern
    or a video per camera; "use these images" reloads the page with them in its address."""
    from dash import dcc, html
    typed = images or {}
    field = {"style": {"width": "300px"}, "debounce": False}
    return html.Div([
        "images: the folder's dataset or pairs (leave both empty), or per camera a pattern or a video: left ",
        dcc.Input(id="setup-left", value=typed.get("left", ""), placeholder="images/left_*.tif or left.mp4", **field),
        " right ", dcc.Input(id="setup-right", value=typed.get("right", ""),
                             placeholder="images/right_*.tif or right.mp4", **field),
        html.Button("use these images", id="use-images", n_clicks=0, style={"marginLeft": "6px"}),
    ], title=f"relative to {dataset}; a side-by-side video: VIDEO:left and VIDEO:right", style={"margin": "4px 0"})


def layout(path: Path, access: Access, images: dict | None = None):
    """The set-up page of the dataset or folder `path`, with the images `images` ({"left", "right"} as
    typed, relative to it) where given."""
    from dash import dcc, html
    dataset = dataset_of(path)
    rigs = find_files(access.folders, "stereodic.rig/1")
    default = next((r for r in rigs if r.parent == dataset), rigs[0] if rigs else None)
    typed = images
    try:
        images = checked_images(dataset, images, access)
        if default is None:
            return rig_maker(dataset, access, images)
        if images is None and not ((dataset / "capture.json").is_file() or image_pairs(dataset)):
            raise InputError(dataset, "is neither a dataset nor a folder of image pairs NAME_0 / NAME_1: give the "
                                      "left and right camera's images, a pattern or a video each")
        rig, data = _states(dataset, default, images)
    except InputError as exc:        # images that do not fit: say so beside the fields where they are typed
        if typed is None and default is not None and ((dataset / "capture.json").is_file() or image_pairs(dataset)):
            raise
        return html.Div([images_chooser(dataset, typed), html.Div(error_text(exc), id="setup-about",
                                                                  style={"color": "#b00"})])
    shapes = automatic_shapes(data.left[0])
    return html.Div([
        dcc.Store(id="setup-dataset", data=str(dataset)), dcc.Store(id="shapes", data=shapes),
        dcc.Store(id="setup-images", data=images),
        images_chooser(dataset, typed),
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
                    images: dict | None = None) -> list[str]:
    """Write the region and settings into the output folder (module docstring); returns the command.
    `images`: {"left", "right"} absolute patterns or videos (`checked_images`), else the dataset's or the
    folder's pairs."""
    from calib.atomic import write_json
    from calib.imageio import write_gray
    rig, data = _states(dataset, rig_path, images)
    imm = rig.left.imm
    mask = rectified_mask(original_mask(polygons, imm.real_size), imm.map_x, imm.map_y, imm.valid)
    if not mask.any():
        raise InputError("region", "covers no pixel of the rectified left image: draw it on the specimen")
    output.mkdir(parents=True, exist_ok=True)
    write_gray(output / "region_mask.png", mask.astype(np.uint8) * 255)
    named = ["--left", images["left"], "--right", images["right"]] if images else \
        [str(dataset)] if (dataset / "capture.json").is_file() else ["--images", str(dataset)]
    command = ["stereodic", "dic", str(rig_path), *named, "-o", str(output),
               "--mask", str(output / "region_mask.png"), "--subset", str(settings["subset"]), "--step",
               str(settings["step"]), "--strain-window", str(settings["strain_window"]), "--no-vtk",
               *extra_options(settings.get("options"))]
    write_json(output / "workspace.json", {"format": RUN_FORMAT, "rig": str(rig_path), "dataset": str(dataset),
                                           "images": images, "settings": settings, "region": to_json(polygons),
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
                  State("setup-rig", "value"), State("setup-images", "data"), prevent_initial_call=True)
    def region(tool, _auto, _clear, relayout, shapes, dataset, rig_path, images):
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
                folder = access.resolve(dataset)
                _, data = _states(folder, access.resolve(rig_path), checked_images(folder, images, access))
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
                  State("setup-rig", "value"), State("setup-images", "data"), prevent_initial_call="initial_duplicate")
    def noise(shapes, subset, dataset, rig_path, images):
        from calib.imageio import read_gray
        from stereodic.dic.speckle_quality import SIZES, speckle_quality
        try:
            polygons = [shape_polygon(s) for s in shapes or []]
            folder = access.resolve(dataset)
            _, data = _states(folder, access.resolve(rig_path), checked_images(folder, images, access))
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
                  State("setup-images", "data"), prevent_initial_call=True)
    def start(_, shapes, dataset, rig_path, output, subset, step, window, options, images):
        try:
            polygons = from_json(to_json([shape_polygon(s) for s in shapes or []]))   # checked: >= 3 vertices
            if not any(not p.hole for p in polygons):
                raise InputError("region", "has no part: draw the specimen's outline first")
            out = access.resolve(output)
            settings = {"subset": int(subset), "step": int(step), "strain_window": int(window),
                        "options": " ".join(extra_options(options))}
            if settings["subset"] < 5 or settings["subset"] % 2 == 0 or settings["step"] < 1:
                raise InputError("subset/step", f"subset must be odd and >= 5, step >= 1; got {subset}, {step}")
            folder = access.resolve(dataset)
            command = write_run_files(out, access.resolve(rig_path), folder, polygons, settings,
                                      checked_images(folder, images, access))
            start_run(out, command)
        except (InputError, TypeError, ValueError) as exc:
            return no_update, no_update, error_text(exc)
        return "the equivalent command:\n" + shlex.join(command), False, ""

    def run_rig_command(command: list[str], search: str | None):
        """Run a `stereodic rig` or `stereodic import` command line: (its line, its output and the link on to
        the set-up, keeping the address's images; or the line alone) and the error's last line."""
        done = subprocess.run([sys.executable, "-m", "stereodic", *command[1:]], capture_output=True, text=True)
        if done.returncode != 0:
            lines = (done.stderr or done.stdout).strip().splitlines()
            return shlex.join(command), lines[-1] if lines else f"exit status {done.returncode}"
        return html.Span([shlex.join(command), "\n", done.stdout.strip(), "\n",
                          dcc.Link("set up the run", href=f"/{search or ''}", refresh=True, id="open-setup")]), ""

    @app.callback(Output("rig-command", "children"), Output("rig-message", "children"),
                  Input("make-rig", "n_clicks"), State("rig-dataset", "data"), State("rig-left", "value"),
                  State("rig-right", "value"), State("url", "search"), prevent_initial_call=True)
    def make_rig(clicks, dataset, left, right, search):
        if not clicks:
            return no_update, no_update
        try:
            out = access.resolve(Path(dataset) / "rig.npz")
            command = ["stereodic", "rig", str(access.resolve(left)), str(access.resolve(right)), "-o", str(out)]
        except InputError as exc:
            return no_update, error_text(exc)
        return run_rig_command(command, search)

    @app.callback(Output("rig-command", "children", allow_duplicate=True),
                  Output("rig-message", "children", allow_duplicate=True),
                  Input("import-rig", "n_clicks"), State("rig-dataset", "data"), State("import-file", "value"),
                  State("import-size", "value"), State("url", "search"), prevent_initial_call=True)
    def import_rig(clicks, dataset, calibration, size, search):
        if not clicks:
            return no_update, no_update
        try:
            out = access.resolve(Path(dataset) / "rig.npz")
            command = ["stereodic", "import", str(access.resolve(calibration)), "-o", str(out)]
            if size and size.strip():
                if not re.fullmatch(r"\d+x\d+", size.strip()):
                    raise InputError("image size", f"{size!r}: needs WIDTHxHEIGHT in pixels, e.g. 1280x800")
                command += ["--size", size.strip()]
        except InputError as exc:
            return no_update, error_text(exc)
        return run_rig_command(command, search)

    @app.callback(Output("url", "search"), Input("use-images", "n_clicks"), State("setup-left", "value"),
                  State("setup-right", "value"), State("url", "search"), prevent_initial_call=True)
    def use_images(clicks, left, right, search):
        """The page again with the images typed in its address (both empty: the folder's own)."""
        from urllib.parse import parse_qs, urlencode
        if not clicks:                   # the button just drawn (Dash calls it as the page appears)
            return no_update
        query = {k: v[0] for k, v in parse_qs((search or "").lstrip("?")).items() if k not in ("left", "right")}
        if (left or "").strip() or (right or "").strip():
            query.update(left=(left or "").strip(), right=(right or "").strip())
        return "?" + urlencode(query)

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

"""The workspace's pages (Dash): what PATH is decides the page.

- a `dic` run folder, a `dic.npz` or a `dic2d` NPZ: the results (`dic_view`);
- a `kind: dic` dataset (its folder or capture.json), a folder of image pairs NAME_0 / NAME_1 (DICe's and
  VIC-3D's naming), or a folder holding images or videos named by two patterns or two videos
  (`?path=FOLDER&left=PATTERN&right=PATTERN`): setting up a run (`setup_view`);
- a PRVM file: its distortion, uncertainty and residual maps; a RIG file: its geometry and error vector
  matrices; a PLY point cloud: the cloud in 3D coloured by its distance to a fitted plane or sphere
  (`other_views`).

The page's address names the path, `/?path=P` (default: the first path the server was started on),
resolved under the served folders (`access`). Dash ships its browser code (React, plotly.js) inside its
Python package and serves it itself: the page works offline.
"""

from __future__ import annotations

import json
from pathlib import Path

from calib.errors import InputError
from stereodic.workspace.access import Access


def kind_of(path: Path) -> str:
    """What `path` holds: "dic", "setup", "prvm", "rig" or "scan"; InputError naming it otherwise."""
    if path.is_dir():
        if (path / "run.json").is_file() or (path / "dic.npz").is_file():
            return "dic"
        from stereodic.workspace.setup_view import holds_images, image_pairs
        if (path / "capture.json").is_file() or image_pairs(path) or holds_images(path):
            return "setup"
        raise InputError(path, "is neither a `stereodic dic` output folder nor a DIC dataset (no run.json, "
                               "dic.npz, capture.json, image pairs NAME_0 / NAME_1, images or videos)")
    if path.name == "capture.json":
        return "setup"
    if path.suffix.lower() == ".ply":
        return "scan"
    if path.suffix.lower() == ".npz":
        import zipfile

        import numpy as np
        try:
            with np.load(path) as z:
                fmt = json.loads(str(z["meta"])).get("format") if "meta" in z.files else None
        except (OSError, ValueError, EOFError, zipfile.BadZipFile, AttributeError):
            raise InputError(path, "is not a readable .npz file") from None
        kinds = {"stereodic.dic/1": "dic", "stereodic.dic2d/1": "dic", "stereodic.prvm/1": "prvm",
                 "stereodic.rig/1": "rig"}
        if fmt in kinds:
            return kinds[fmt]
        raise InputError(path, f"format {fmt!r} is not one the workspace shows (a DIC result, PRVM or rig)")
    raise InputError(path, "is not a DIC result, dataset, PRVM, rig or PLY file")


def make_app(access: Access):
    """The Dash application of the workspace, serving what `access` allows (module docstring)."""
    from dash import Dash, Input, Output, dcc, html

    from stereodic.workspace import dic_view, other_views, setup_view

    app = Dash(__name__, title="stereodic view", serve_locally=True, update_title=None,
               suppress_callback_exceptions=True)
    app.layout = html.Div([dcc.Location(id="url"),
                           html.Div([html.B("stereodic view"), html.Span(id="page-path")],
                                    style={"padding": "4px 8px", "borderBottom": "1px solid #ccc"}),
                           dcc.Loading(html.Div(id="page"), delay_show=300, target_components={"page": "children"})],
                          style={"fontFamily": "sans-serif", "fontSize": "14px"})

    @app.callback(Output("page", "children"), Output("page-path", "children"), Input("url", "search"))
    def page(search):
        from urllib.parse import parse_qs
        query = parse_qs((search or "").lstrip("?"))
        asked = query.get("path", [None])[0]
        try:
            path = access.resolve(asked) if asked else access.roots[0]
            if not path.exists():
                raise InputError(asked or path, "does not exist")
            kind = kind_of(path)
            if kind == "setup" and ("left" in query or "right" in query):     # two patterns or two videos
                images = {side: query.get(side, [""])[0] for side in ("left", "right")}
                return setup_view.layout(path, access, images), f"  {path}"
            return {"dic": dic_view.layout, "setup": setup_view.layout, "prvm": other_views.prvm_layout,
                    "rig": other_views.rig_layout, "scan": other_views.scan_layout}[kind](path, access), f"  {path}"
        except InputError as exc:
            return html.Div(f"stereodic view: {exc}", id="page-error", style={"color": "#b00", "padding": "8px"}), ""

    dic_view.register(app, access)
    setup_view.register(app, access)
    other_views.register(app, access)
    return app

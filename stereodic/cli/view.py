"""`stereodic view [PATH...] [--port N] [--host H --token T] [--no-browser]`: the workspace in the browser.

Serves `stereodic.workspace` on PATH (default: the current folder): a DIC run folder or result, a DIC
dataset, a folder of image pairs or a folder of images or videos to set a run up (its rig made on the page
from two PRVM files or another program's calibration file where there is none), a PRVM or rig file, or a
PLY scan; prints the address (with the token where
there is one) and opens it in the browser where there is one. Ctrl-C stops it. Bound to 127.0.0.1 unless
--host says otherwise, and then only with a token (`stereodic.workspace.access`).
"""

from __future__ import annotations

from stereodic.cli.common import add_input


def register(sub):
    p = sub.add_parser("view", help="the browser workspace: set up a run, look at results, gauges, calibrations",
                       description="Serve the workspace in the browser on PATH: a DIC run folder, dic.npz or "
                                   "dic2d NPZ (results state by state, points' histories, gauges, stress-strain), "
                                   "a DIC dataset or a folder of images or videos (pick the images, make the rig "
                                   "from a calibration, draw the region, start the run), a PRVM or rig file, or "
                                   "a PLY scan. Only the files under the PATHs are served.")
    add_input(p, "paths", kind="any", what="result, dataset, PRVM, rig or PLY", metavar="PATH", nargs="*",
              help="what to open (the first) and serve (all; default: the current folder)")
    p.add_argument("--port", type=int, default=0, help="TCP port (default: a free one)")
    p.add_argument("--host", default="127.0.0.1",
                   help="address to listen on (default 127.0.0.1: this machine only; another needs --token)")
    p.add_argument("--token", metavar="T",
                   help="a secret every request must carry (at least 16 characters; 'auto': a random one); "
                        "needed with --host other than localhost")
    p.add_argument("--no-browser", action="store_true", help="do not open a browser, only print the address")
    p.set_defaults(func=run)


def run(args) -> int:
    from pathlib import Path

    from calib.errors import InputError
    from stereodic.workspace.access import check_host, new_token
    from stereodic.workspace.app import kind_of
    from stereodic.workspace.server import open_browser, start

    if not 0 <= args.port <= 65535:
        raise InputError("--port", f"must be 0..65535, got {args.port}")
    token = new_token() if args.token == "auto" else args.token
    check_host(args.host, token)
    paths = [Path(p) for p in args.paths] or [Path.cwd()]
    if args.paths:
        kind_of(paths[0].resolve())       # a path it cannot show: refused here, not in the browser
    ws = start(paths, host=args.host, port=args.port, token=token)
    print(f"stereodic view: serving {', '.join(map(str, paths))} at {ws.url}", flush=True)
    if not args.no_browser and not open_browser(ws.url):
        print("stereodic view: no browser here; open the address above (through an SSH tunnel from a head "
              "node: ssh -L PORT:localhost:PORT HOST)", flush=True)
    try:
        ws.serve()
    except KeyboardInterrupt:
        print("stereodic view: stopped", flush=True)
    finally:
        ws.stop()
    return 0

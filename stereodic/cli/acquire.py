"""`stereodic acquire {calibration,scan,dic}`: drive the stage, the screen and the cameras
(scanners.acquire) and write a `stereodic.capture/1` dataset. A fault stops it with every frame taken
kept; running the same command again resumes where it stopped. See docs/real-bench.md.
"""

from __future__ import annotations

import contextlib
import time

from stereodic.cli.common import add_output, deprecated, display_pitch, open_devices, parse_floats, wrote

DEVICES = """devices:
  --stage URL
    - Zaber ASCII: zaber:///dev/ttyUSB0?device=1&axis=1&microstep_um=0.047625
    - GRBL 1.1: grbl:///dev/ttyACM0?axis=X&feed=600
    - the same over TCP: zaber+socket://HOST:PORT, grbl+socket://HOST:PORT
    - emulators (no hardware): emulated:zaber, emulated:grbl
    - you move it when asked: manual
    - serial options: baud, timeout (s), retries, move_timeout (s), home=auto|yes|no, tolerance_um;
      zaber: device, axis, microstep_um; grbl: axis, feed (mm/min)
    - emulated: speed (mm/s), travel (mm), transport=pty|socket, fault=KIND@MOVE, axis_deg=AX,AY
      (the simulated carriage's travel off the screen normal, degrees)
  --display SPEC
    - full screen on monitor N (0-based), 1:1 pixels (pygame): screen[:N]
    - write the patterns to DIR instead (headless): file:DIR?size=WxH
    - the simulated display: sim
  --camera SPEC (repeat it; cameras are named cam0, cam1, ... in the order given)
    - an OpenCV VideoCapture device: cv:INDEX[?exposure_ms=E&gain=G&size=WxH&discard=N]
    - photos taken by hand arriving in DIR: folder:DIR[?size=WxH&timeout=S]
    - the simulated camera (needs --display sim and an emulated stage; tilt/roll aim it, degrees):
      sim[:LENS][?size=WxH&seed=N&pixel_um=P&tilt=TX,TY&roll=R]
"""


def register(sub):
    p = sub.add_parser("acquire", help="drive the real stage, display and cameras; write a dataset",
                       description="Acquire a capture dataset on a bench (or on the simulated devices). "
                                   "Every frame is saved and listed as soon as it is taken; after a fault, "
                                   "run the same command again to resume.", epilog=DEVICES)
    modes = p.add_subparsers(dest="mode", metavar="MODE", required=True)

    c = modes.add_parser("calibration", help="fringes on a display moved by a stage",
                         description="At each stage position: flats (intensity), then x and y phase-shifting "
                                     "fringes of every period, taken by every camera.", epilog=DEVICES)
    c.add_argument("--stage", required=True, metavar="URL", help="the linear stage (see below)")
    c.add_argument("--positions-mm", type=parse_floats, default=[0.0, 50.0],
                   help="stage positions in mm (default 0,50)")
    c.add_argument("--display-pitch-mm", type=parse_floats, default=None, metavar="PX[,PY]",
                   help="display pixel pitch in mm (required for a real screen; the data sheet's value)")
    deprecated(c, "--positions", "--positions-mm")
    deprecated(c, "--pitch-mm", "--display-pitch-mm")
    c.add_argument("--gamma", type=float, default=None, help="display gamma, if known (recorded only)")
    _pattern_options(c, flats="0,32,64,96,128,160,192,224,255")
    _common_options(c, with_display=True)
    c.set_defaults(func=run_calibration)

    s = modes.add_parser("scan", help="projector patterns on an object, per state",
                         description="For each state (object pose): flats if asked, then projector fringes, "
                                     "taken by every camera. You are asked to set up each state.", epilog=DEVICES)
    s.add_argument("--axes", default="x", help="fringe axes on the projector: x, y or x,y (default x)")
    _pattern_options(s, flats="")
    _state_options(s)
    _common_options(s, with_display=True)
    s.set_defaults(func=run_scan)

    d = modes.add_parser("dic", help="every camera at every load step",
                         description="For each state (load step) one frame per camera, nothing shown. You are "
                                     "asked to apply each load step (or give --interval).", epilog=DEVICES)
    _state_options(d)
    _common_options(d, with_display=False)
    d.set_defaults(func=run_dic)


def _pattern_options(p, flats: str):
    p.add_argument("--periods", type=parse_floats, default=[60, 360, 1920],
                   help="fringe periods in display pixels; the longest should span the screen (default "
                        "60,360,1920)")
    p.add_argument("--steps", type=int, default=3, help="phase steps per period, >= 3 (default 3)")
    p.add_argument("--flat-levels", type=parse_floats, default=parse_floats(flats),
                   help=f"grey levels of the flat frames (default {flats or 'none'}; '' for none)")
    p.add_argument("--low", type=int, default=20, help="fringe minimum level (default 20, tip 1.7)")
    p.add_argument("--high", type=int, default=240, help="fringe maximum level (default 240)")


def _state_options(p):
    p.add_argument("--states", type=int, default=1, help="number of states to take (default 1)")
    p.add_argument("--first-state", type=int, default=0, help="number of the first state (default 0)")
    p.add_argument("--interval-s", type=float, default=None, metavar="S",
                   help="wait S seconds between states instead of asking (time-lapse)")
    deprecated(p, "--interval", "--interval-s")


def _common_options(p, with_display: bool):
    p.add_argument("--camera", action="append", required=True, metavar="SPEC",
                   help="a camera (repeat for several; see below)")
    if with_display:
        p.add_argument("--display", required=True, metavar="SPEC", help="where patterns are shown (see below)")
        p.add_argument("--settle-ms", type=float, default=150.0,
                       help="wait after showing a pattern before capturing (default 150 ms)")
        p.add_argument("--vsync", action="store_true", help="flip the screen on the vertical blank")
    p.add_argument("--average", type=int, default=1, metavar="K", help="frames averaged per image (default 1)")
    p.add_argument("--max-saturated", type=float, default=1e-4, metavar="FRACTION",
                   help="refuse a fringe frame with more saturated pixels than this (default 1e-4)")
    add_output(p, kind="dir", metavar="DIR", help="dataset folder (resumed if it exists)")


def _check(args):
    from calib.errors import InputError
    if args.average < 1:
        raise InputError("--average", f"must be >= 1, got {args.average}")
    if not 0 <= args.max_saturated < 1:
        raise InputError("--max-saturated", f"must be a fraction in [0, 1), got {args.max_saturated}")
    if getattr(args, "settle_ms", 0) < 0:
        raise InputError("--settle-ms", "must not be negative")
    if hasattr(args, "periods"):
        if not args.periods or min(args.periods) <= 0:
            raise InputError("--periods", f"expected positive periods, got {args.periods}")
        if args.steps < 3:
            raise InputError("--steps", f"need >= 3 phase steps, got {args.steps}")
        if not 0 <= args.low < args.high <= 255 or any(not 0 <= v <= 255 for v in args.flat_levels):
            raise InputError("--low/--high/--flat-levels", "levels must be 0..255 with low < high")
    if hasattr(args, "states") and args.states < 1:
        raise InputError("--states", f"must be >= 1, got {args.states}")


def _settings(args):
    from scanners.acquire import Settings
    return Settings(args.average, args.max_saturated)


def _open_devices(args, stack: contextlib.ExitStack, stage_url: str | None):
    """Stage (or None), screen (or None) and cameras, all closed when `stack` closes."""
    return open_devices(stack, stage_url, getattr(args, "display", None), args.camera,
                        getattr(args, "settle_ms", 0.0) / 1000, getattr(args, "vsync", False))


def _next_state(args):
    from scanners.acquire import ask_on_terminal
    if args.interval_s is None:
        return ask_on_terminal
    first = [True]

    def wait(state: int) -> None:
        if not first[0]:
            time.sleep(args.interval_s)
        first[0] = False
    return wait


def _provenance(args, stage_url: str | None) -> dict:
    d = {"cameras": {f"cam{i}": s for i, s in enumerate(args.camera)}, "average": args.average}
    if stage_url is not None:
        d["stage"] = stage_url
    if getattr(args, "display", None) is not None:
        d["display"] = args.display
    return {"acquisition": d}


def run_calibration(args) -> int:
    import numpy as np

    from calib.capture import Display
    from calib.errors import InputError
    from scanners.acquire import calibration_plan, open_writer, run
    from scanners.camera import SimulatedCamera
    from scanners.display import SimScreen
    _check(args)
    if not args.positions_mm or len(set(args.positions_mm)) != len(args.positions_mm):
        raise InputError("--positions-mm", f"expected distinct stage positions, got {args.positions_mm}")
    with contextlib.ExitStack() as stack:
        stage, screen, cameras = _open_devices(args, stack, args.stage)
        if isinstance(screen, SimScreen):
            display = screen.sim.record()
        else:
            display = Display(screen.size[0], screen.size[1], display_pitch(screen, args.display_pitch_mm), args.gamma)
        extra = _provenance(args, args.stage)
        sims = [c for c in cameras if isinstance(c, SimulatedCamera)]
        if sims:
            names = {c.name: _truth_file(c, len(sims)) for c in sims}
            extra["simulated"] = {"truth": names if len(sims) > 1 else names[sims[0].name]}
        writer = open_writer(args.output, "calibration", cameras, display, extra)
        for cam in sims:
            cam.set_exposure(args.high, args.positions_mm[0])
            truth = cam.sim.lens.true_prvm(camera=cam.name, dataset="capture.json")
            # the emulated stages are exact to the microstep (< 0.03 um): true = nominal positions
            truth.extra = {"stage_true_z_mm": np.array(args.positions_mm, float)}
            truth.save(writer.capture.root / _truth_file(cam, len(sims)))
        shots = calibration_plan(screen.size, args.positions_mm, args.periods, args.steps,
                                 [int(v) for v in args.flat_levels], args.low, args.high)
        n = run(writer, shots, cameras, stage, screen, _settings(args))
    _report(writer, n)
    return 0


def _truth_file(cam, count: int) -> str:
    return "truth.npz" if count == 1 else f"truth_{cam.name}.npz"


def run_scan(args) -> int:
    from calib.errors import InputError
    from scanners.acquire import open_writer, run, scan_plan
    _check(args)
    axes = [a.strip() for a in args.axes.split(",") if a.strip()]
    if not axes or any(a not in ("x", "y") for a in axes):
        raise InputError("--axes", f"expected x, y or x,y, got {args.axes!r}")
    with contextlib.ExitStack() as stack:
        _, screen, cameras = _open_devices(args, stack, None)
        extra = _provenance(args, None)
        extra["projector"] = {"width_px": screen.size[0], "height_px": screen.size[1]}
        writer = open_writer(args.output, "scan", cameras, extra=extra)
        states = range(args.first_state, args.first_state + args.states)
        shots = scan_plan(screen.size, states, args.periods, args.steps, [int(v) for v in args.flat_levels], axes,
                          args.low, args.high)
        n = run(writer, shots, cameras, None, screen, _settings(args), _next_state(args))
    _report(writer, n)
    return 0


def run_dic(args) -> int:
    from scanners.acquire import dic_plan, open_writer, run
    _check(args)
    with contextlib.ExitStack() as stack:
        _, _, cameras = _open_devices(args, stack, None)
        writer = open_writer(args.output, "dic", cameras, extra=_provenance(args, None))
        shots = dic_plan(range(args.first_state, args.first_state + args.states))
        n = run(writer, shots, cameras, None, None, _settings(args), _next_state(args))
    _report(writer, n)
    return 0


def _report(writer, taken: int) -> None:
    cap = writer.capture
    wrote(cap.manifest_path, f"{len(cap.frames)} frames in {cap.root} ({taken} taken now, "
                             f"{len(cap.frames) - taken} already there)")

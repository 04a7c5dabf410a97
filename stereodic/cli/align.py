"""`stereodic align`: the alignment aid. Shows quick fringe sets on the pattern display, reads the
camera's tilt, roll and distance (and, with a stage, the stage axis against the display's normal) and
shows the fused picture with the expected and the captured crosshair on the display, a few times a
second (scanners.align). See docs/real-bench.md, "Aligning with stereodic align".
"""

from __future__ import annotations

import contextlib
import sys

from stereodic.cli.common import add_input, add_output, deprecated, parse_floats

DEVICES = """devices (as for `stereodic acquire`):
  --display SPEC
    - full screen on monitor N (the live aid; Esc stops, s re-measures the stage): screen[:N]
    - write every image shown to DIR (headless): file:DIR?size=WxH
    - the simulated display (headless): sim
  --camera SPEC
    - an OpenCV VideoCapture device: cv:INDEX[?exposure_ms=E&gain=G&size=WxH&discard=N]
    - photos arriving in DIR: folder:DIR[?size=WxH&timeout=S]
    - the simulated camera, aimed at known tilts (needs --display sim):
      sim[:LENS][?size=WxH&seed=N&pixel_um=P&tilt=TX,TY&roll=R]
  --stage URL
    - any `stereodic acquire` stage URL; emulated:zaber?axis_deg=AX,AY tilts the simulated travel

intrinsics: a PRVM (.npz, from `stereodic calibrate`) is exact for any lens; an OpenCV pinhole file
(.yaml/.yml/.xml/.json, `stereodic export --format opencv` or your own); without one the camera is
estimated from the pattern alone (rougher: see the docs).

headless runs (file:, sim) need --frames and -o; -o DIR gets fused_NNNN.png, stage.png, readings.json
(and truth.json with a simulated camera)."""


def register(sub):
    p = sub.add_parser("align", help="live aid: camera square to the screen, stage axis along its normal",
                       description="Measure the camera's tilt, roll and distance against the pattern display "
                                   "(and the stage axis against the display's normal) from quick fringe sets, "
                                   "and show the fused crosshair picture on the display.", epilog=DEVICES)
    p.add_argument("--display", required=True, metavar="SPEC", help="the pattern display (see below)")
    p.add_argument("--camera", required=True, metavar="SPEC", help="the camera (see below)")
    p.add_argument("--stage", metavar="URL", help="also measure the stage axis (moves to --positions-mm)")
    p.add_argument("--positions-mm", type=parse_floats, default=[0.0, 50.0],
                   help="the two stage positions in mm for the stage axis; the camera is read at the first "
                        "(default 0,50)")
    add_input(p, "--intrinsics", what="intrinsics", metavar="FILE",
              help="the camera's PRVM (.npz) or OpenCV pinhole file")
    p.add_argument("--focal-px", type=float, metavar="F",
                   help="without --intrinsics: the focal length in pixels, if known (lens focal length / pixel "
                        "pitch)")
    p.add_argument("--display-pitch-mm", type=parse_floats, metavar="PX[,PY]",
                   help="display pixel pitch in mm (required for a real screen)")
    deprecated(p, "--positions", "--positions-mm")
    deprecated(p, "--pitch-mm", "--display-pitch-mm")
    p.add_argument("--tolerance-deg", type=float, default=0.2, help="squareness tolerance (default 0.2 deg)")
    p.add_argument("--frames", type=int, default=0, metavar="N",
                   help="stop after N updates (default: until Esc on the screen; required when headless)")
    p.add_argument("--periods", type=parse_floats, default=None,
                   help="fringe periods in display pixels (default: the display's longer side and 1/16 of it)")
    p.add_argument("--steps", type=int, default=3, help="phase steps per period (default 3)")
    p.add_argument("--full-every", type=int, default=4, metavar="N",
                   help="show the full fringe set every N updates, in between only the shortest period "
                        "(half the frames; default 4, 1 = always the full set)")
    p.add_argument("--low", type=int, default=20, help="fringe minimum level (default 20)")
    p.add_argument("--high", type=int, default=240, help="fringe maximum level (default 240)")
    p.add_argument("--settle-ms", type=float, default=100.0,
                   help="wait after showing a pattern before capturing (default 100 ms)")
    p.add_argument("--hold-ms", type=float, default=None,
                   help="how long the fused picture stays up after each update (default 600 ms on a screen, "
                        "0 headless)")
    p.add_argument("--vsync", action="store_true", help="flip the screen on the vertical blank")
    p.add_argument("--average", type=int, default=1, metavar="K", help="frames averaged per image (default 1)")
    add_output(p, kind="dir", default=None, metavar="DIR",
               help="write the fused pictures and readings.json here (a new or empty folder)")
    p.set_defaults(func=run)


def _check(args, headless: bool):
    from calib.errors import InputError
    if not args.tolerance_deg > 0:
        raise InputError("--tolerance-deg", f"must be positive, got {args.tolerance_deg}")
    if args.frames < 0:
        raise InputError("--frames", f"must be >= 0, got {args.frames}")
    if headless and (args.frames == 0 or args.output is None):
        raise InputError("--display", f"{args.display!r} is headless: give --frames N and -o DIR")
    if args.stage is not None and (len(args.positions_mm) != 2 or args.positions_mm[0] == args.positions_mm[1]):
        raise InputError("--positions-mm", f"expected two distinct stage positions, got {args.positions_mm}")
    if args.steps < 3:
        raise InputError("--steps", f"need >= 3 phase steps, got {args.steps}")
    if args.full_every < 1:
        raise InputError("--full-every", f"must be >= 1, got {args.full_every}")
    if not 0 <= args.low < args.high <= 255:
        raise InputError("--low/--high", "levels must be 0..255 with low < high")
    if args.periods is not None and (len(args.periods) < 2 or min(args.periods) <= 0):
        raise InputError("--periods", f"expected two or more positive periods, got {args.periods}")
    if args.average < 1 or args.settle_ms < 0 or (args.hold_ms is not None and args.hold_ms < 0):
        raise InputError("--average/--settle-ms/--hold-ms", "must be >= 1 / >= 0 / >= 0")
    if args.focal_px is not None and (args.intrinsics is not None or not args.focal_px > 0):
        raise InputError("--focal-px", "must be positive, and is only for a camera without --intrinsics")


def _intrinsics(path: str | None):
    """The camera's rays from a PRVM or an OpenCV pinhole file (None: none given)."""
    from pathlib import Path

    from calib.alignment import PinholeRays, PrvmRays
    from calib.errors import InputError
    if path is None:
        return None
    suffix = Path(path).suffix.lower()
    if suffix == ".npz":
        from calib.prvm_file import load_prvm
        from stereodic.virtual.camera import fit_optical_centre
        prvm = load_prvm(path)
        return PrvmRays(prvm, fit_optical_centre(prvm)[0])
    if suffix in (".yaml", ".yml", ".xml", ".json"):
        from calib.pinhole import read_opencv_yaml
        cam = read_opencv_yaml(path)
        return PinholeRays(cam.K, cam.dist, cam.width, cam.height)
    raise InputError(path, "--intrinsics: expected a PRVM (.npz) or an OpenCV pinhole file (.yaml, .xml, .json)")


def _truth(camera, screen, stage, z_mm: float) -> dict:
    """The simulated bench's true readings (scanners.sim), for truth.json."""
    import numpy as np

    from scanners.sim.aim import true_alignment
    a = np.asarray(camera.stage_axis, float)
    out = {"camera": true_alignment(camera.sim.lens, screen.sim, camera.true_pose(z_mm)),
           "stage_axis": {"axis": a.tolist(), "angle_x_deg": float(np.degrees(np.arctan2(a[0], a[2]))),
                          "angle_y_deg": float(np.degrees(np.arctan2(a[1], a[2])))}}
    if stage is None:
        del out["stage_axis"]
    return out


def run(args) -> int:
    from calib.atomic import write_json
    from calib.errors import InputError
    from scanners import align
    from scanners.camera import SimulatedCamera
    from scanners.display import PygameScreen
    from stereodic.cli.common import display_pitch, open_devices, wrote
    headless = args.display == "sim" or args.display.startswith("file:")
    _check(args, headless)
    model = _intrinsics(args.intrinsics)
    record = align.AlignRecord(args.output) if args.output is not None else None
    hold = (0.0 if headless else 0.6) if args.hold_ms is None else args.hold_ms / 1000
    with contextlib.ExitStack() as stack:
        stage, screen, (camera,) = open_devices(stack, args.stage, args.display, [args.camera],
                                                args.settle_ms / 1000, args.vsync, still_z_mm=0.0)
        pitch = display_pitch(screen, args.display_pitch_mm)
        periods = tuple(args.periods) if args.periods else align.default_periods(screen.size)
        settings = align.AlignSettings(periods, args.steps, args.low, args.high, tolerance_deg=args.tolerance_deg,
                                       average=args.average, hold_s=hold, full_every=args.full_every)
        try:
            session = align.AlignSession(screen, camera, pitch, model, settings=settings, focal_px=args.focal_px)
        except InputError as exc:
            if exc.where != "--intrinsics":
                raise
            raise InputError(args.intrinsics, exc.problem) from None   # another camera's: name the file
        described = {"prvm": f"PRVM {args.intrinsics}", "pinhole": f"pinhole {args.intrinsics}"}.get(
            getattr(model, "kind", ""), "")
        if isinstance(camera, SimulatedCamera):
            camera.set_exposure(args.high, args.positions_mm[0] if stage is not None else 0.0)
        if record is not None:
            record.header = {"camera": {"spec": args.camera, "width": camera.size[0], "height": camera.size[1]},
                             "display": {"spec": args.display, "width_px": screen.size[0],
                                         "height_px": screen.size[1], "pitch_mm": list(pitch)},
                             "intrinsics": {"kind": model.kind if model is not None else "pattern",
                                            "file": args.intrinsics, "focal_px": args.focal_px},
                             "stage_url": args.stage, "positions_mm": list(args.positions_mm) if stage else None,
                             "settings": settings.to_json()}
            if isinstance(camera, SimulatedCamera):
                write_json(record.folder / "truth.json",
                           _truth(camera, screen, stage, args.positions_mm[0] if stage is not None else 0.0))
        done = align.run(session, updates=args.frames, stage=stage, positions=args.positions_mm, record=record,
                         described=described, report=lambda line: print(line, file=sys.stderr),
                         interactive=isinstance(screen, PygameScreen))
    if record is not None:
        wrote(record.folder / "readings.json", f"{len(done)} update(s); fused pictures fused_NNNN.png in "
                                               f"{record.folder}")
    return 0

"""`stereodic patterns`: write the calibration patterns for a display (PNG at its exact resolution) and
their manifest `patterns.json` (calib.patterns)."""

from __future__ import annotations

from stereodic.cli.common import add_input, add_output, parse_floats, parse_size, wrote


def register(sub):
    p = sub.add_parser("patterns", help="write phase-shifting fringe patterns for a display",
                       description="Write the flat and phase-shifting fringe images of a calibration, at the "
                                   "display's exact resolution, with the manifest patterns.json that lists them "
                                   "in display order.")
    p.add_argument("--display", type=parse_size, required=True, metavar="WxH", help="display resolution, e.g. 1920x1080")
    p.add_argument("--periods", type=parse_floats, default=[60, 360, 1920],
                   help="fringe periods in display pixels (the longest must cover the display); default 60,360,1920")
    p.add_argument("--steps", type=int, default=3, help="phase steps per period (>= 3); default 3")
    p.add_argument("--axes", default="x,y", help="fringe axes: x, y or x,y (default)")
    p.add_argument("--low", type=float, default=20, help="darkest fringe code value (default 20)")
    p.add_argument("--high", type=float, default=240, help="brightest fringe code value (default 240)")
    p.add_argument("--flat-levels", type=parse_floats, default=[0, 32, 64, 96, 128, 160, 192, 224, 255],
                   help="grey levels of the flat frames for the intensity calibration ('' for none)")
    add_input(p, "--response", what="display response", metavar="FILE",
              help="measured display response (display_response.json from `stereodic calibrate --report`): "
                   "pre-compensate the fringes so the emitted luminance follows the cosine")
    add_output(p, kind="dir", metavar="DIR", help="folder of the pattern images and patterns.json")
    p.set_defaults(func=run)


def run(args) -> int:
    from calib.errors import InputError
    from calib.jsonfile import read_json
    from calib.patterns import DisplayResponse, calibration_sequence, write_patterns

    w, h = args.display
    axes = tuple(a.strip() for a in args.axes.split(",") if a.strip())
    if not axes or any(a not in ("x", "y") for a in axes):
        raise InputError("--axes", f"expected x, y or x,y, got {args.axes!r}")
    if args.steps < 3:
        raise InputError("--steps", f"phase shifting needs at least 3 steps, got {args.steps}")
    if not args.periods or min(args.periods) <= 0:
        raise InputError("--periods", "expected positive periods")
    if not 0 <= args.low < args.high <= 255:
        raise InputError("--low/--high", f"need 0 <= low < high <= 255, got {args.low}, {args.high}")
    extent = max(w if "x" in axes else 0, h if "y" in axes else 0)
    if max(args.periods) < extent:
        raise InputError("--periods", f"the longest period ({max(args.periods):g} px) must cover the display "
                                      f"({extent} px) for an absolute phase")
    response = None
    if args.response:
        d = read_json(args.response, "display response")
        if "levels" not in d or "luminance" not in d:
            raise InputError(args.response, "not a display response: lacks 'levels' and 'luminance' (write one "
                                            "with `stereodic calibrate --report`)")
        try:
            response = DisplayResponse.from_json(d)
        except (ValueError, TypeError) as exc:
            raise InputError(args.response, f"not a usable display response: {exc}") from None
    seq = calibration_sequence(w, h, periods=args.periods, steps=args.steps, axes=axes, low=args.low,
                               high=args.high, flat_levels=[int(v) for v in args.flat_levels], response=response)
    path = write_patterns(args.output, w, h, seq)
    wrote(path, f"{len(seq)} patterns for a {w}x{h} display, images in {args.output}")
    return 0

"""`stereodic patterns`: write the calibration patterns for a display (PNG at its exact resolution) and
their manifest `patterns.json` (calib.patterns); with --gray a scanner projector's Gray code (OpenCV's
GrayCodePattern order; with one --periods value, Gray code plus phase shifting)."""

from __future__ import annotations

from stereodic.cli.common import add_input, add_output, parse_floats, parse_size, wrote


def register(sub):
    p = sub.add_parser("patterns", help="write phase-shifting fringe patterns for a display",
                       description="Write the flat and phase-shifting fringe images of a calibration, at the "
                                   "display's exact resolution, with the manifest patterns.json that lists them "
                                   "in display order.")
    p.add_argument("--display", type=parse_size, required=True, metavar="WxH", help="display resolution, e.g. 1920x1080")
    p.add_argument("--periods", type=parse_floats, default=None,
                   help="fringe periods in display pixels (the longest must cover the display); default 60,360,1920; "
                        "with --gray one period (Gray code plus phase shifting) or none (Gray code alone)")
    p.add_argument("--steps", type=int, default=None, help="phase steps per period (>= 3); default 3, with --gray 16")
    p.add_argument("--gray", action="store_true",
                   help="Gray code of the --axes (each bit and its inverse, most significant first, then white "
                        "and black: OpenCV's GrayCodePattern order), instead of the calibration fringes")
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
    steps = args.steps if args.steps is not None else (16 if args.gray else 3)
    if steps < 3:
        raise InputError("--steps", f"phase shifting needs at least 3 steps, got {steps}")
    if not 0 <= args.low < args.high <= 255:
        raise InputError("--low/--high", f"need 0 <= low < high <= 255, got {args.low}, {args.high}")
    if args.gray:
        return _gray(args, w, h, axes, steps)
    periods = args.periods or [60, 360, 1920]
    if min(periods) <= 0:
        raise InputError("--periods", "expected positive periods")
    extent = max(w if "x" in axes else 0, h if "y" in axes else 0)
    if max(periods) < extent:
        raise InputError("--periods", f"the longest period ({max(periods):g} px) must cover the display "
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
    seq = calibration_sequence(w, h, periods=periods, steps=steps, axes=axes, low=args.low,
                               high=args.high, flat_levels=[int(v) for v in args.flat_levels], response=response)
    path = write_patterns(args.output, w, h, seq)
    wrote(path, f"{len(seq)} patterns for a {w}x{h} display, images in {args.output}")
    return 0


def _gray(args, w: int, h: int, axes: tuple[str, ...], steps: int) -> int:
    """The Gray-code sequence (`calib.patterns.gray_sequence`: the code black and white, a fringe between
    --low and --high) written with its manifest."""
    from calib.errors import InputError
    from calib.patterns import gray_sequence, write_patterns
    periods = args.periods or []
    if len(periods) > 1 or (periods and not 2 <= periods[0] <= max(w, h)):
        raise InputError("--periods", f"with --gray: one fringe period of 2 px or more (Gray code plus phase "
                                      f"shifting) or none, got {', '.join(f'{p:g}' for p in periods)}")
    seq = gray_sequence(w, h, axes=axes, period_px=periods[0] if periods else None, steps=steps,
                        fringe_low=args.low, fringe_high=args.high)
    path = write_patterns(args.output, w, h, seq)
    wrote(path, f"{len(seq)} Gray-code patterns for a {w}x{h} projector, images in {args.output}")
    return 0

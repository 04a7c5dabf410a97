"""`stereodic simulate MODE`: write a simulated dataset with its ground truth (scanners.sim).

Modes: `calibration` (fringes on a display moved by a stage, with truth.npz); `stereo` (two cameras,
stereodic/cli/simulate_stereo.py); `scan` (projector + two cameras, stereodic/cli/simulate_scan.py); `dic` (a
speckled plate under load, two cameras, stereodic/cli/simulate_dic.py); `dic2d` (a speckle image and a moved
copy, stereodic/cli/simulate_dic2d.py).
"""

from __future__ import annotations

from stereodic.cli import simulate_dic as dic_mode
from stereodic.cli import simulate_dic2d as dic2d_mode
from stereodic.cli import simulate_scan as scan_mode
from stereodic.cli import simulate_stereo as stereo_mode
from stereodic.cli.common import (add_flaw_options, add_handheld_options, add_simulation_options, deprecated, flaw_kwargs,
                                   handheld_from, parse_floats, wrote)


def register(sub):
    p = sub.add_parser("simulate", help="write a simulated dataset with its ground truth",
                       description="Write a simulated dataset (images + capture.json + truth.npz).")
    modes = p.add_subparsers(dest="mode", metavar="MODE", required=True)
    c = modes.add_parser("calibration", help="calibration dataset: flats and fringes at stage positions",
                         description="Render a calibration dataset on the simulated rig: flats, phase-shifting "
                                     "fringes (both axes, every period) and optionally chessboards at every "
                                     "stage position, with the true rays in truth.npz.")
    add_simulation_options(c, 1280, 1024, 3, "lens, pose, stage and noise")
    c.add_argument("--periods", type=parse_floats, default=[60, 360, 1920],
                   help="fringe periods in display pixels (default 60,360,1920)")
    c.add_argument("--steps", type=parse_floats, default=[3],
                   help="phase steps per period, >= 3: one number, or one per period (default 3)")
    c.add_argument("--positions-mm", type=parse_floats, default=[0.0, 50.0],
                   help="nominal stage positions in mm (default 0,50)")
    deprecated(c, "--positions", "--positions-mm")
    c.add_argument("--flat-levels", type=parse_floats, default=None,
                   help="grey levels of the flat frames (default 0,32,...,224,255)")
    c.add_argument("--low", type=int, default=20, help="fringe minimum level (default 20)")
    c.add_argument("--high", type=int, default=240, help="fringe maximum level (default 240)")
    c.add_argument("--bit-depth", type=int, default=None,
                   help="camera bit depth: 8, 10, 12, 14, 16 (default 8; 12 with --real-bench)")
    c.add_argument("--cover-glass", type=parse_floats, default=None, metavar="THICK,INDEX",
                   help="display cover glass thickness (mm) and refractive index, e.g. 0.7,1.5")
    c.add_argument("--stage-error-um", type=float, default=3.0, help="RMS stage position error (default 3 um)")
    c.add_argument("--bayer", choices=["RGGB", "BGGR", "GRBG", "GBRG"], default=None,
                   help="a colour camera with this raw Bayer mosaic (per-colour response and lateral "
                        "chromatic aberration); default monochrome")
    add_handheld_options(c)
    c.add_argument("--as-held", action="store_true",
                   help="hold the display as people hold a monitor (scanners.sim.handheld.as_held): pose 0 at "
                        "420 mm, the others 45 mm nearer to 25 mm farther, tipped 4-15 degrees about x or y, the "
                        "lens focused at 420 mm, a 0.5 mm cover glass (unless --cover-glass), 90 %% pixel fill; "
                        "--handheld N poses (default 7)")
    c.add_argument("--chessboard", action="store_true", help="also render chessboards (OpenCV comparison)")
    add_flaw_options(c)
    c.set_defaults(func=run_calibration)
    stereo_mode.register(modes)                         # `simulate stereo`: stereodic/cli/simulate_stereo.py
    scan_mode.register(modes)                           # `simulate scan`: stereodic/cli/simulate_scan.py
    dic_mode.register(modes)                            # `simulate dic`: stereodic/cli/simulate_dic.py
    dic2d_mode.register(modes)                          # `simulate dic2d`: stereodic/cli/simulate_dic2d.py


def run_calibration(args) -> int:
    from calib.errors import InputError
    from scanners.sim.calibration import DEFAULT_FLATS, simulate_calibration
    if args.cover_glass is not None and len(args.cover_glass) != 2:
        raise InputError("--cover-glass", f"expected THICKNESS_MM,INDEX, got {args.cover_glass}")
    from scanners.sim.bayer import BayerSensor
    steps = args.steps[0] if len(args.steps) == 1 else args.steps
    held, glass, lens_options, flaws = handheld_from(args), args.cover_glass, None, flaw_kwargs(args)
    if args.as_held:
        import dataclasses

        from scanners.sim.handheld import as_held
        options = as_held(poses=args.handheld or 7)
        held = dataclasses.replace(options["handheld"], disturbed=args.disturb)
        glass = options["cover_glass"] if glass is None else glass
        flaws["display"] = dataclasses.replace(flaws["display"], fill_factor=options["display"].fill_factor)
        lens_options = options["lens_options"]
    cap = simulate_calibration(
        args.output, lens=args.lens, width=args.width, height=args.height, seed=args.seed,
        periods=args.periods, steps=steps, z_positions=args.positions_mm,
        flat_levels=DEFAULT_FLATS if args.flat_levels is None else args.flat_levels, noise=args.noise,
        supersample=args.supersample, cover_glass=glass, low=args.low, high=args.high,
        chessboard=args.chessboard, stage_error_um=args.stage_error_um, handheld=held, lens_options=lens_options,
        bayer=None if args.bayer is None else BayerSensor(args.bayer), **flaws)
    wrote(cap.manifest_path, f"{len(cap.frames)} frames in {cap.root}, truth in {cap.root / 'truth.npz'}")
    return 0

"""`stereodic simulate stereo`: a simulated stereo calibration (scanners.sim.stereo), wired into
`stereodic simulate` by stereodic/cli/simulate.py."""

from __future__ import annotations

from stereodic.cli.common import (add_flaw_options, add_handheld_options, add_simulation_options, deprecated, flaw_kwargs,
                                   handheld_from, parse_floats, wrote)


def register(modes) -> None:
    from scanners.sim import LENS_FAMILIES
    s = modes.add_parser(
        "stereo", help="stereo calibration dataset: two cameras, one display and stage",
        description="Render a calibration dataset of two cameras in one WCS (same display, same stage "
                    "positions): cameras cam0 (left) and cam1 (right), with truth_cam0.npz and truth_cam1.npz. "
                    "--separate instead calibrates each camera on its own facing the display straight (left/, "
                    "right/), plus a registration dataset of both in the stereo pose (register/) and "
                    "registration_truth.json; see docs/stereo-rig.md.")
    s.add_argument("--left", choices=LENS_FAMILIES, metavar="LENS", default="brown", help="left lens family: " + ", ".join(LENS_FAMILIES) + " (default brown)")
    s.add_argument("--right", choices=LENS_FAMILIES, metavar="LENS", default="brown", help="right lens family (default brown)")
    s.add_argument("--lens", choices=LENS_FAMILIES, metavar="LENS", help="both lens families at once")
    s.add_argument("--camera-pitch-mm", type=float, default=None,
                   help="pixel pitch in mm (default: 0.0053 x 1280 / width, the same field of view); a larger "
                        "one widens the field beyond the display: 1.6 x the default leaves ~2 %% of each camera's "
                        "pixels unseen at stage position 0 and ~11 %% at 50")
    s.add_argument("--baseline-mm", type=float, default=200.0, help="distance between the cameras, mm (default 200)")
    s.add_argument("--distance-mm", type=float, default=400.0, help="distance to the display, mm (default 400)")
    s.add_argument("--separate", action="store_true",
                   help="each camera calibrated separately, then a registration dataset")
    s.add_argument("--periods", type=parse_floats, default=[60, 360, 1920],
                   help="fringe periods in display pixels (default 60,360,1920)")
    s.add_argument("--positions-mm", type=parse_floats, default=[0.0, 50.0],
                   help="nominal stage positions in mm (default 0,50)")
    for old, new in (("--pixel-mm", "--camera-pitch-mm"), ("--baseline", "--baseline-mm"),
                     ("--distance", "--distance-mm"), ("--positions", "--positions-mm")):
        deprecated(s, old, new)
    s.add_argument("--steps", type=parse_floats, default=[3],
                   help="phase steps per period, >= 3: one number, or one per period (default 3)")
    s.add_argument("--bit-depth", type=int, default=None,
                   help="camera bit depth: 8, 10, 12, 14, 16 (default 8; 12 with --real-bench)")
    add_handheld_options(s)
    add_flaw_options(s, unseen=False)
    add_simulation_options(s, 1280, 1024, None, "lenses, poses, stage and noise", lens=None,
                           supersample_help="sub-samples per pixel side (default max(3, 1280 / width, times "
                                            "the farthest hand-held distance / 400 mm): a sub-sample below a "
                                            "display pixel)")
    s.set_defaults(func=run)


def run(args) -> int:
    import numpy as np

    from scanners.sim.stereo import simulate_stereo
    left = args.lens or args.left
    right = args.lens or args.right
    held = handheld_from(args)
    # a sub-sample below a display pixel at the farthest display (the default rig's 400 mm, or a hand's)
    reach = 1.0 if held is None else max(held.distance_mm) / 400.0
    supersample = args.supersample or max(3, int(np.ceil(1280 / args.width * reach)))
    pixel_mm = args.camera_pitch_mm if args.camera_pitch_mm else 0.0053 * 1280 / args.width
    steps = args.steps[0] if len(args.steps) == 1 else args.steps
    out = simulate_stereo(args.output, left=left, right=right, width=args.width, height=args.height,
                          seed=args.seed, separate=args.separate, baseline_mm=args.baseline_mm,
                          distance_mm=args.distance_mm, lens_options={"pixel_mm": pixel_mm}, periods=args.periods,
                          z_positions=args.positions_mm, noise=args.noise, supersample=supersample, steps=steps,
                          handheld=held, **{k: v for k, v in flaw_kwargs(args).items() if k != "unseen"})
    what = "left/, right/ (own WCS each), register/ and registration_truth.json" if args.separate else \
        "capture.json (cam0, cam1), truth_cam0.npz, truth_cam1.npz"
    wrote(out, what)
    return 0

"""`stereodic simulate scan`: a simulated structured-light scan (scanners.sim.scan), wired into
`stereodic simulate` by stereodic/cli/simulate.py."""

from __future__ import annotations

from stereodic.cli.common import add_simulation_options, parse_floats, wrote

OBJECTS = ("sphere", "ballbar", "plane", "freeform")
KNOWN = OBJECTS + ("turntable",)     # turntable: a closed free-form part in 8 views all the way round


def register(modes) -> None:
    s = modes.add_parser(
        "scan", help="structured-light scan dataset: projector + two cameras, objects with known shape",
        description="Render a scan dataset: a fringe projector (own lens and gamma) between two cameras casts "
                    "multi-period N-step fringes on objects (spheres, ball bar in 7 poses, plane in 4 poses, a "
                    "free-form part; or, --objects turntable, a closed free-form part with a ball on top in 8 "
                    "views turned 45 degrees apart about the vertical axis through the target; with shadows, "
                    "occlusion, varying albedo, ambient light, sensor noise). "
                    "One state per object pose. Writes capture.json (kind scan), the images, truth.npz (the exact "
                    "surfaces), the true camera PRVMs truth_cam0/1.npz and rig.npz (their rectified pair), so "
                    "that `stereodic scan DIR/rig.npz DIR -o cloud.ply` runs at once. See docs/scanner.md.")
    s.add_argument("--objects", default=",".join(OBJECTS),
                   help=f"comma-separated objects to scan, of {','.join(KNOWN)} (default {','.join(OBJECTS)})")
    s.add_argument("--periods", type=parse_floats, default=None,
                   help="projector fringe periods in panel pixels, the longest >= 1280 (default 1280,160,32,8)")
    s.add_argument("--steps", type=parse_floats, default=None,
                   help="phase steps: one number for all periods or one per period (default 16 for the shortest "
                        "period, 3 for the others)")
    s.add_argument("--gray", action="store_true",
                   help="project the column Gray code first: with one --periods value Gray code plus phase "
                        "shifting, with --periods '' Gray code alone")
    add_simulation_options(s, 1280, 1024, 2, "lenses, poses and noise", lens="both cameras' lens family")
    s.set_defaults(func=run)


def run(args) -> int:
    from calib.errors import InputError
    from scanners.sim.scan import DEFAULT_PERIODS, default_scan_rig, simulate_scan, standard_scenes
    from stereodic.stereo.rig import rig_from_files, save_rig
    objects = [o.strip() for o in args.objects.split(",") if o.strip()]
    bad = sorted(set(objects) - set(KNOWN))
    if bad or not objects:
        raise InputError("--objects", f"unknown object(s) {', '.join(bad) or '(none)'}; known: {', '.join(KNOWN)}")
    if args.width < 16 or args.height < 16:
        raise InputError("--width/--height", f"sensor must be at least 16x16, got {args.width}x{args.height}")
    rig = default_scan_rig(width=args.width, height=args.height, seed=args.seed, lens=args.lens,
                           supersample=args.supersample)
    cap = simulate_scan(args.output, scenes=standard_scenes(objects=objects), rig=rig,
                        periods=(args.periods or []) if args.gray else (args.periods or DEFAULT_PERIODS), gray=args.gray,
                        steps=args.steps[0] if args.steps and len(args.steps) == 1 else args.steps,
                        seed=args.seed, noise=args.noise)
    save_rig(cap.root / "rig.npz", rig_from_files(cap.root / "truth_cam0.npz", cap.root / "truth_cam1.npz"))
    wrote(cap.manifest_path, f"{len(cap.frames)} frames of {len(cap.states('cam0'))} scan states in {cap.root}, "
                             f"with truth.npz and rig.npz")
    return 0

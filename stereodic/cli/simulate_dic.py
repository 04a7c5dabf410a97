"""`stereodic simulate dic`: a simulated stereo DIC experiment (scanners.sim.dic), wired into
`stereodic simulate` by stereodic/cli/simulate.py."""

from __future__ import annotations

from stereodic.cli.common import add_simulation_options, deprecated, wrote


def register(modes) -> None:
    s = modes.add_parser(
        "dic", help="stereo DIC dataset: a speckled plate with known deformation seen by two cameras",
        description="Render a stereo DIC dataset: a plate with a speckle pattern (Boolean model of blurred "
                    "dots, in material coordinates), tilted towards the cameras, in five states: reference, "
                    "rigid translation, rigid rotation, uniaxial tension (--strain, default 1 %) with Poisson contraction, an "
                    "out-of-plane bulge. Writes capture.json (kind dic), the images, rig.npz (the rectified "
                    "pair of the true camera models) and truth.npz (positions, displacements and "
                    "Green-Lagrange strains), so that `stereodic dic DIR/rig.npz DIR -o OUT` runs at once.")
    s.add_argument("--strain", type=float, default=0.01, help="uniaxial tension, engineering strain (default 0.01)")
    s.add_argument("--poisson", type=float, default=0.3, help="Poisson's ratio (default 0.3)")
    s.add_argument("--bulge-mm", type=float, default=2.0, help="bulge height towards the cameras, mm (default 2)")
    s.add_argument("--tilt-deg", type=float, default=10.0,
                   help="plate tilt about the vertical axis, degrees (default 10)")
    deprecated(s, "--bulge", "--bulge-mm")
    deprecated(s, "--tilt", "--tilt-deg")
    add_simulation_options(s, 640, 512, 2, "lenses, speckle and noise", lens="both cameras' lens family")
    s.set_defaults(func=run)


def run(args) -> int:
    from scanners.sim.dic import simulate_dic, standard_states
    from stereodic.stereo.rig import rig_from_files, save_rig
    cap = simulate_dic(args.output, standard_states(args.strain, args.poisson, args.bulge_mm), args.width, args.height,
                       args.seed, args.lens, args.supersample, args.noise, args.tilt_deg)
    save_rig(cap.root / "rig.npz", rig_from_files(cap.root / "truth_cam0.npz", cap.root / "truth_cam1.npz"))
    wrote(cap.manifest_path, f"{len(cap.frames)} images of {len(cap.states('cam0'))} states in {cap.root}, with "
                             f"truth.npz and rig.npz")
    return 0

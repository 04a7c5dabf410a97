"""`stereodic simulate dic`: a simulated stereo DIC experiment (scanners.sim.dic), wired into
`stereodic simulate` by stereodic/cli/simulate.py."""

from __future__ import annotations

import argparse


def register(modes) -> None:
    from scanners.sim.lenses import LENS_FAMILIES
    s = modes.add_parser(
        "dic", help="stereo DIC dataset: a speckled plate with known deformation seen by two cameras",
        description="Render a stereo DIC dataset: a plate with a speckle pattern (Boolean model of blurred "
                    "dots, in material coordinates), tilted towards the cameras, in five states: reference, "
                    "rigid translation, rigid rotation, 1 %% uniaxial tension with Poisson contraction, an "
                    "out-of-plane bulge. Writes capture.json (kind dic), the images, rig.npz (the rectified "
                    "pair of the true camera models) and truth.npz (positions, displacements and "
                    "Green-Lagrange strains), so that `stereodic dic DIR/rig.npz DIR -o OUT` runs at once.")
    s.add_argument("--lens", choices=LENS_FAMILIES, default="brown", help="both cameras' lens family (default brown)")
    s.add_argument("--width", type=int, default=640, help="sensor width in pixels (default 640)")
    s.add_argument("--height", type=int, default=512, help="sensor height in pixels (default 512)")
    s.add_argument("--strain", type=float, default=0.01, help="uniaxial tension, engineering strain (default 0.01)")
    s.add_argument("--poisson", type=float, default=0.3, help="Poisson's ratio (default 0.3)")
    s.add_argument("--bulge", type=float, default=2.0, help="bulge height towards the cameras, mm (default 2)")
    s.add_argument("--tilt", type=float, default=10.0, help="plate tilt about the vertical axis, degrees (default 10)")
    s.add_argument("--supersample", type=int, default=2, help="sub-samples per pixel side (default 2)")
    s.add_argument("--seed", type=int, default=0, help="random seed of lenses, speckle and noise")
    s.add_argument("--noise", action=argparse.BooleanOptionalAction, default=True, help="sensor noise (default on)")
    s.add_argument("-o", "--output", required=True, metavar="DIR", help="output folder")
    s.set_defaults(func=run)


def run(args) -> int:
    from scanners.sim.dic import simulate_dic, standard_states
    cap = simulate_dic(args.output, standard_states(args.strain, args.poisson, args.bulge), args.width, args.height,
                       args.seed, args.lens, args.supersample, args.noise, args.tilt)
    print(f"wrote {len(cap.frames)} images of {len(cap.states('cam0'))} states, {cap.manifest_path}, "
          f"{cap.root / 'truth.npz'} and {cap.root / 'rig.npz'}")
    return 0

"""`stereodic simulate dic2d`: a 2-D DIC pair with its truth (scanners.sim.speckle), for `stereodic dic2d`."""

from __future__ import annotations

import argparse

from stereodic.cli.common import add_output, parse_floats, wrote


def register(modes) -> None:
    s = modes.add_parser(
        "dic2d", help="2-D DIC pair: a speckle image and the same speckle moved by a known displacement",
        description="Render a speckle image (reference.png) and the same speckle moved (moved.png): a "
                    "uniaxial stretch along x with Poisson contraction, a rotation, both about the image "
                    "centre, then a translation. The dots are rendered where they move (no image "
                    "interpolation), so the truth is exact: truth.npz holds u and v (pixels) at every pixel "
                    "of the reference image. Then `stereodic dic2d DIR/reference.png DIR/moved.png -o "
                    "OUT.csv` measures it.")
    s.add_argument("--shift", type=parse_floats, default=[0.35, -0.20], metavar="DX,DY",
                   help="translation in pixels (default 0.35,-0.20)")
    s.add_argument("--strain", type=float, default=0.0, help="engineering strain along x (default 0)")
    s.add_argument("--poisson", type=float, default=0.3, help="Poisson's ratio (default 0.3)")
    s.add_argument("--rotation-deg", type=float, default=0.0, help="rotation in degrees (default 0)")
    s.add_argument("--width", type=int, default=512, help="image width in pixels (default 512)")
    s.add_argument("--height", type=int, default=512, help="image height in pixels (default 512)")
    s.add_argument("--seed", type=int, default=0, help="random seed of the speckle and the noise")
    s.add_argument("--noise", action=argparse.BooleanOptionalAction, default=True,
                   help="sensor noise, 1 grey level RMS (default on); --no-noise renders the expected images")
    add_output(s, kind="dir", metavar="DIR", help="output folder")
    s.set_defaults(func=run)


def run(args) -> int:
    from pathlib import Path

    import numpy as np

    from calib.atomic import write_npz
    from calib.errors import InputError
    from calib.imageio import write_gray
    from scanners.sim.speckle import affine_displacement, make_speckle, render
    if len(args.shift) != 2:
        raise InputError("--shift", f"expected DX,DY in pixels, got {args.shift}")
    if args.width < 32 or args.height < 32:
        raise InputError("--width", f"the image must be at least 32x32 pixels, got {args.width}x{args.height}")
    centre = ((args.width - 1) / 2, (args.height - 1) / 2)
    shift = (float(args.shift[0]), float(args.shift[1]))
    field = affine_displacement(shift, strain=args.strain, poisson=args.poisson, rotation_deg=args.rotation_deg,
                                centre=centre)
    translation = args.strain == 0 and args.rotation_deg == 0
    speckle = make_speckle(args.width, args.height, seed=args.seed + 1)
    sigma = 1.0 if args.noise else 0.0
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    write_gray(out / "reference.png", render(speckle, None, noise_sigma=sigma, seed=args.seed + 2))
    write_gray(out / "moved.png", render(speckle, shift if translation else field, noise_sigma=sigma,
                                         seed=args.seed + 3))
    y, x = np.mgrid[0:args.height, 0:args.width].astype(np.float64)
    u, v = field(x, y)
    write_npz(out / "truth.npz", u=u.astype(np.float32), v=v.astype(np.float32),
              shift_px=np.array(shift), strain=np.float64(args.strain), poisson=np.float64(args.poisson),
              rotation_deg=np.float64(args.rotation_deg), centre_px=np.array(centre))
    wrote(out / "reference.png", f"a rendered {args.width}x{args.height} speckle image")
    wrote(out / "moved.png", f"the same speckle moved by ({shift[0]:+.2f}, {shift[1]:+.2f}) px"
                             + ("" if translation else f", {args.strain:.2%} strain, {args.rotation_deg:g} deg"))
    wrote(out / "truth.npz", "the true displacement u, v (pixels) at every reference pixel")
    return 0

"""Small helpers shared by the sub-command modules."""

from __future__ import annotations

import argparse
import sys


def planned(sub, name: str, help_text: str, issue: int) -> argparse.ArgumentParser:
    """Register a command of DESIGN.md that this version does not have yet: it says so and exits 1."""
    p = sub.add_parser(name, help=f"{help_text} [not in this version yet]",
                       description=f"{help_text}\n\nNot in this version yet (tracked as issue {issue}).")
    p.add_argument("args", nargs=argparse.REMAINDER, help=argparse.SUPPRESS)

    def run(args) -> int:
        print(f"stereodic {name}: not in this version yet (issue {issue})", file=sys.stderr)
        return 1

    p.set_defaults(func=run)
    return p


def add_simulation_options(p: argparse.ArgumentParser, width: int, height: int, supersample: int | None,
                           seeded: str, lens: str | None = "the lens family",
                           supersample_help: str | None = None) -> None:
    """The options every `simulate` mode shares: --lens (unless `lens` is None: the mode names its lenses
    its own way), --width and --height (defaults in pixels), --seed (of what is `seeded`), --noise,
    --supersample (sub-samples per pixel side) and -o DIR."""
    from scanners.sim.lenses import LENS_FAMILIES
    if lens is not None:
        p.add_argument("--lens", choices=LENS_FAMILIES, default="brown", help=f"{lens} (default brown)")
    p.add_argument("--width", type=int, default=width, help=f"sensor width in pixels (default {width})")
    p.add_argument("--height", type=int, default=height, help=f"sensor height in pixels (default {height})")
    p.add_argument("--seed", type=int, default=0, help=f"random seed of {seeded}")
    p.add_argument("--noise", action=argparse.BooleanOptionalAction, default=True,
                   help="sensor noise (default on); --no-noise renders the expected images")
    p.add_argument("--supersample", type=int, default=supersample,
                   help=supersample_help or f"sub-samples per pixel side (default {supersample})")
    p.add_argument("-o", "--output", required=True, metavar="DIR", help="output folder")


def add_handheld_options(p: argparse.ArgumentParser) -> None:
    """The options of a hand-held (stage-free) simulated capture: --handheld N and how it is held."""
    p.add_argument("--handheld", type=int, default=None, metavar="N",
                   help="hold the display by hand in N random poses instead of moving it on the stage (frames "
                        "carry 'pose'; the truth is in the display's frame at pose 0)")
    p.add_argument("--hold-distance", type=parse_floats, default=[300.0, 600.0], metavar="NEAR,FAR",
                   help="with --handheld: range of the display's distance from the camera, mm (default 300,600)")
    p.add_argument("--max-tilt", type=float, default=35.0, metavar="DEG",
                   help="with --handheld: the largest tilt of the display, degrees (default 35)")
    p.add_argument("--disturb", type=int, default=None, metavar="POSE",
                   help="with --handheld: the display moves (0.2 mm, 0.1 deg) halfway through this pose's fringes")


def handheld_from(args):
    """The `scanners.sim.handheld.HandHeld` of the options of `add_handheld_options`, None without
    --handheld; InputError naming the option for one that does not fit."""
    from calib.errors import InputError
    from scanners.sim.handheld import HandHeld
    if args.handheld is None:
        if args.disturb is not None:
            raise InputError("--disturb", "needs --handheld")
        return None
    if len(args.hold_distance) != 2:
        raise InputError("--hold-distance", f"expected NEAR,FAR in mm, got {args.hold_distance}")
    return HandHeld(poses=args.handheld, distance_mm=tuple(args.hold_distance), max_tilt_deg=args.max_tilt,
                    disturbed=args.disturb)


def parse_size(text: str) -> tuple[int, int]:
    """'1920x1080' -> (1920, 1080); argparse type."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
        if w <= 0 or h <= 0:
            raise ValueError
        return w, h
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT, got {text!r}") from None


def parse_floats(text: str) -> list[float]:
    """'60,360,1920' -> [60.0, 360.0, 1920.0]; argparse type."""
    try:
        return [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") from None


def parse_ints(text: str, n: int, what: str) -> list[int]:
    """'10,20' -> [10, 20] (numbers rounded to whole pixels); InputError naming the option `what` unless
    there are exactly n of them."""
    from calib.errors import InputError
    try:
        vals = [int(round(float(t))) for t in text.split(",")]
    except ValueError:
        vals = []
    if len(vals) != n:
        raise InputError(what, f"expected {n} comma-separated numbers, got {text!r}")
    return vals


def dic_grid(args, width: int, height: int, image: str, source: str):
    """The DIC point grid and seeds from the options --subset, --step, --roi, --mask and --seed, for a
    reference image of width x height pixels (`image` names it in messages, `source` is the file blamed
    when no point fits). Returns (grid, seeds [(x, y), ...]); InputError for any option that does not fit.
    """
    from calib.errors import InputError
    from calib.imageio import read_gray
    from stereodic.dic import make_grid
    if args.subset < 5 or args.subset % 2 == 0:
        raise InputError("--subset", f"must be an odd number >= 5, got {args.subset}")
    if args.step < 1:
        raise InputError("--step", f"must be >= 1, got {args.step}")
    roi = None
    if args.roi:
        x0, y0, x1, y1 = parse_ints(args.roi, 4, "--roi")
        if not (0 <= x0 < x1 < width and 0 <= y0 < y1 < height):
            raise InputError("--roi", f"{args.roi} is not a region inside the {width}x{height} {image}")
        roi = (x0, y0, x1, y1)
    mask = None
    if args.mask:
        mask = read_gray(args.mask) > 0
        if mask.shape != (height, width):
            raise InputError(args.mask, f"mask is {mask.shape[1]}x{mask.shape[0]} but the {image} is "
                                        f"{width}x{height}")
    seeds = []
    for text in args.seed:
        x, y = parse_ints(text, 2, "--seed")
        if not (0 <= x < width and 0 <= y < height):
            raise InputError("--seed", f"{text} is outside the {width}x{height} {image}")
        if roi and not (roi[0] <= x <= roi[2] and roi[1] <= y <= roi[3]):
            raise InputError("--seed", f"{text} is outside the region of interest {args.roi}")
        if mask is not None and not mask[y, x]:
            raise InputError("--seed", "a seed lies outside the mask")
        seeds.append((x, y))
    grid = make_grid(width, height, args.subset, args.step, roi, mask)
    if not grid.active.any():
        raise InputError(args.roi and "--roi" or source,
                         f"no point of the grid has its {args.subset}-pixel subset inside the {image}")
    return grid, seeds

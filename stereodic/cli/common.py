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


def add_flaw_options(p: argparse.ArgumentParser, unseen: bool = True) -> None:
    """A real bench's flaws (`scanners.sim.flaws.Flaws`), each off by default, and --real-bench for all
    of them at `REAL_BENCH`'s sizes (an option given as well overrides its flaw's size)."""
    g = p.add_argument_group("a real bench's flaws (docs/simulator.md; each off by default)")
    g.add_argument("--real-bench", action="store_true",
                   help="every flaw below at the sizes of a careful user's bench (scanners.sim.flaws.REAL_BENCH)")
    g.add_argument("--bow-mm", type=float, help="display bow: its centre this far behind the plane of its corners")
    g.add_argument("--pitch-error", type=float, help="true pitch / stated pitch - 1, e.g. 1e-4")
    g.add_argument("--falloff", type=float, help="viewing angle: luminance x (1 - FALLOFF sin^2 angle)")
    g.add_argument("--gamma-tilt", type=float, help="viewing angle: gamma x (1 + GAMMA_TILT sin^2 angle)")
    g.add_argument("--hot-pixels", type=float, help="fraction of hot pixels")
    g.add_argument("--ambient", type=float, help="room light on the sensor, in units of a white display")
    g.add_argument("--ambient-variation", type=float, help="its +- variation across the image (fraction)")
    g.add_argument("--overexposure", type=float, help="fraction of the pixels seeing the display clipped at full scale")
    if unseen:
        g.add_argument("--unseen", type=float,
                       help="fraction of the image rows the display misses at the last stage position")
    g.add_argument("--stage-tilt-deg", type=float, help="RMS stage tilt per position (degrees)")
    g.add_argument("--stage-lateral-um", type=float, help="RMS stage run-out per position (um)")


def flaw_kwargs(args) -> dict:
    """`simulate_calibration` keyword arguments of the flaw options (`add_flaw_options`); an option
    not given keeps --real-bench's size, or off."""
    import dataclasses

    from scanners.sim.flaws import REAL_BENCH, Flaws
    base = REAL_BENCH if args.real_bench else Flaws(bit_depth=None)
    given = {f.name: getattr(args, f.name) for f in dataclasses.fields(Flaws)
             if f.name != "bit_depth" and getattr(args, f.name, None) is not None}
    flaws = dataclasses.replace(base, **given)
    out = flaws.kwargs()
    if args.real_bench and getattr(args, "bit_depth", None) is None:
        out["bit_depth"] = REAL_BENCH.bit_depth
    elif getattr(args, "bit_depth", None) is not None:
        out["bit_depth"] = args.bit_depth
    return out


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

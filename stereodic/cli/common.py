"""Small helpers shared by the sub-command modules."""

from __future__ import annotations

import argparse
import sys

# The library's defaults, repeated here so that building the parser imports nothing heavy (`--help`
# stays instant); tests/stereodic/test_cli.py checks that they equal stereodic.dic.sequence.SWITCH_ZNCC
# and stereodic.strain_measures.MEASURES.
SWITCH_ZNCC = 0.9
STRAIN_MEASURES = ("green-lagrange", "euler-almansi", "log", "engineering")


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


def open_devices(stack, stage_url: str | None, display_spec: str | None, camera_specs: list[str],
                 settle_s: float = 0.15, vsync: bool = False, still_z_mm: float | None = None):
    """The stage (or None), the screen (or None) and the cameras (named cam0, cam1, ...) from their
    command-line specs, each closed when `stack` (a contextlib.ExitStack) closes. A simulated camera sees
    the simulated display at the emulated stage's true position along its true travel direction; without
    a stage at stage position `still_z_mm` (None: it needs a stage)."""
    from scanners.camera import open_camera
    from scanners.display import open_screen
    from scanners.stage_url import open_stage
    stage = stack.enter_context(open_stage(stage_url)) if stage_url is not None else None
    screen = stack.enter_context(open_screen(display_spec, settle_s, vsync)) if display_spec is not None else None
    true_z, axis = (None if still_z_mm is None else (lambda: still_z_mm)), (0.0, 0.0, 1.0)
    if stage is not None:
        true_z = stage.emulator.true_position_mm if stage.emulator is not None else stage.position_mm
        axis = stage.emulator.travel_axis if stage.emulator is not None else axis
    cameras = [stack.enter_context(open_camera(spec, f"cam{i}", screen, true_z, axis))
               for i, spec in enumerate(camera_specs)]
    return stage, screen, cameras


def display_pitch(screen, pitch_mm: list[float] | None) -> tuple[float, float]:
    """The display's pixel pitch (x, y) in mm: the simulated display's own, else `--pitch-mm` (PX or
    PX,PY); InputError when a real screen has none."""
    from calib.errors import InputError
    from scanners.display import SimScreen
    if isinstance(screen, SimScreen):
        return screen.pitch_mm
    if not pitch_mm or len(pitch_mm) > 2 or min(pitch_mm) <= 0:
        raise InputError("--pitch-mm", "give the display's pixel pitch in mm (PX or PX,PY)")
    return tuple(float(p) for p in pitch_mm) * (2 // len(pitch_mm))


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


def parse_roi(text: str | None, width: int, height: int, image: str) -> tuple[int, int, int, int] | None:
    """The --roi option 'X0,Y0,X1,Y1' (inclusive pixel bounds) checked against a width x height `image`;
    None without one; InputError naming --roi if it is not a region inside the image."""
    from calib.errors import InputError
    if not text:
        return None
    x0, y0, x1, y1 = parse_ints(text, 4, "--roi")
    if not (0 <= x0 < x1 < width and 0 <= y0 < y1 < height):
        raise InputError("--roi", f"{text} is not a region inside the {width}x{height} {image}")
    return x0, y0, x1, y1


def output_folder(path):
    """The output folder `path` (a Path), created if needed; InputError naming it if it cannot be."""
    from pathlib import Path

    from calib.errors import InputError
    path = Path(path)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(path, f"cannot create the output folder ({exc.strerror})") from None
    return path


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
    roi = parse_roi(args.roi, width, height, image)
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


def check_output(path) -> None:
    """InputError naming the option's value unless `path` can be written as a file: not an existing folder,
    and its nearest existing parent a writable folder (checked before any work starts)."""
    import os
    from pathlib import Path

    from calib.errors import InputError
    p = Path(path)
    if p.is_dir():
        raise InputError(p, "is a folder; the output is a file")
    parent = p.parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir() or not os.access(parent, os.W_OK):
        raise InputError(p, f"cannot be written ({parent} is not a writable folder)")

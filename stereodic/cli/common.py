"""What the sub-command modules share: one spelling per option, paths checked before any work, one line
per output written, nothing left behind by a refused command, and small argument parsers.

Options: `SPELLINGS` is the one spelling of each option that more than one command has (the test
tests/stereodic/test_cli_options.py walks every sub-parser and fails on a second spelling of one meaning;
`SYNONYMS` are the spellings it refuses). Paths: a command declares each path option with `add_input` or
`add_output` (what it is: an image, a PRVM file, a folder, ...); `check_paths`, called by
`stereodic.cli.main` before the command runs, stops with one line (exit status 2) on a path that cannot
work - a missing input, a directory where a file is expected or the reverse, a parent that is a file, a
folder without write permission, an output that would overwrite an input - so that no command fails
after its work, or half-way; `new_folders`/`remove_empty` take away the folders a command created
before it was refused (files are written atomically, calib.atomic). Outputs: `wrote(path, summary)`
prints the one line per file written.
"""

from __future__ import annotations

import argparse
import os
from dataclasses import dataclass
from pathlib import Path

SPELLINGS = {  # argparse dest -> its option strings, wherever a command has it
    "output": ("-o", "--output"),
    "camera": ("--camera",),
    "subset": ("--subset",),
    "step": ("--step",),
    "roi": ("--roi",),
    "mask": ("--mask",),
    "roi_polygon": ("--roi-polygon",),
    "shape": ("--shape",),
    "min_zncc": ("--min-zncc",),
    "search": ("--search",),
    "strain_window": ("--strain-window",),
    "regularise_window": ("--regularise-window",),
    "start_point": ("--start-point",),
    "virtual_size": ("--virtual-size",),
    "virtual_pitch": ("--virtual-pitch-mm",),
    "display_pitch": ("--display-pitch-mm",),
    "incremental": ("--incremental",),
    "model": ("--model",),
    "size": ("--size",),
    "plane_z": ("--plane-z-mm",),
    "format": ("--format",),
    "no_intensity": ("--no-intensity",),
    "report": ("--report",),
    "state": ("--state",),
    "periods": ("--periods",),
    "steps": ("--steps",),
    "positions": ("--positions-mm",),
    "flat_levels": ("--flat-levels",),
    "low": ("--low",),
    "high": ("--high",),
    "lens": ("--lens",),
    "width": ("--width",),
    "height": ("--height",),
    "noise": ("--noise", "--no-noise"),
    "supersample": ("--supersample",),
    "scheduler": ("--scheduler",),
    "prefilter": ("--prefilter",),
}
# Spellings of earlier releases: each still works for one release, with a one-line note on stderr
# (`deprecated`); option -> its spelling now. tests/stereodic/test_cli_options.py checks both.
DEPRECATED = {
    "--window": "--strain-window (strain), --regularise-window (calibrate)", "--size": "--virtual-size",
    "--pitch": "--virtual-pitch-mm", "--pitch-mm": "--display-pitch-mm", "--pixel-mm": "--camera-pitch-mm",
    "--plane-z": "--plane-z-mm", "--cameras": "--camera", "--seed": "--start-point (dic, dic2d)",
    "--bulge": "--bulge-mm", "--tilt": "--tilt-deg", "--baseline": "--baseline-mm", "--distance": "--distance-mm",
    "--hold-distance": "--hold-distance-mm", "--max-tilt": "--max-tilt-deg", "--positions": "--positions-mm",
    "--interval": "--interval-s",
}
SYNONYMS = {  # second spellings of those meanings, refused by the test
    "--out": "output", "--outdir": "output", "--output-dir": "output", "--out-dir": "output", "-O": "output",
    "--cam": "camera", "--subset-size": "subset", "--window-size": "subset", "--grid-step": "step",
    "--spacing": "step", "--region": "roi", "--zncc": "min_zncc", "--min-cc": "min_zncc",
    "--flats": "flat_levels", "--levels": "flat_levels", "--period": "periods", "--phase-steps": "steps",
    "--nsteps": "steps", "--stage-positions": "positions", "--z": "positions", "--lens-family": "lens",
    "--resolution": "size", "--image-size": "size", "--reference-z": "plane_z",
}

INPUT_KINDS = ("file", "dir", "any", "dataset", "pattern")


class HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """--help wrapped to the terminal's width (80 columns where there is none). In a description or
    epilog, lines at the left margin are paragraphs, filled again; an indented line starts an item (a
    list entry, a table row: `  NAME  text`) wrapped under its text, and the more indented lines after
    it continue the item unless they are an item of their own (a list marker, or two spaces inside)."""

    def _fill_text(self, text, width, indent):
        import re
        import textwrap
        out, para, item = [], [], None        # item: (first-line prefix, hanging indent, words)

        def flush():
            nonlocal para, item
            if para:
                out.append(textwrap.fill(" ".join(para), width, initial_indent=indent, subsequent_indent=indent))
            if item:
                first, hang, words = item
                out.append(textwrap.fill(" ".join(words), width, initial_indent=indent + first,
                                         subsequent_indent=indent + " " * len(hang)))
            para, item = [], None

        for line in text.strip("\n").splitlines():
            lead = len(line) - len(line.lstrip())
            body = line.strip()
            if not body:
                flush()
                out.append("")
            elif lead == 0:
                if item:
                    flush()
                para.append(body)
            elif (item and lead >= len(item[1]) and not re.search(r"\S {2,}\S", body)
                  and not re.match(r"(\d+\.|-|\*) ", body)):
                item[2].append(body)
            else:
                flush()
                head = re.match(r"(\S+(?: \S+)?\s{2,}|(?:\d+\.|-|\*)\s+)", body)
                first = " " * lead + (head.group(0) if head else "")
                rest = body[len(head.group(0)):] if head else body
                item = (first, first if head else " " * (lead + 2), [rest])
        flush()
        return "\n".join(out)


class Parser(argparse.ArgumentParser):
    """Every parser of the command line: help by `HelpFormatter`, whatever a command asked for."""

    def __init__(self, *args, **kwargs):
        kwargs["formatter_class"] = HelpFormatter
        super().__init__(*args, **kwargs)



def deprecated(p: argparse.ArgumentParser, old: str, new: str) -> None:
    """Keep the earlier spelling `old` of `p`'s option `new` working for a release: it sets the same
    value, is left out of --help, and prints one line on stderr naming the spelling now."""
    import copy
    import sys
    target = next(a for a in p._actions if new in a.option_strings)
    alias = copy.copy(target)
    alias.option_strings, alias.help = [old], argparse.SUPPRESS
    base = type(target)

    def call(self, parser, namespace, values, option_string=None):
        print(f"stereodic: note: {old} is deprecated, use {new}", file=sys.stderr)
        base.__call__(self, parser, namespace, values, option_string)
    alias.__class__ = type(f"Deprecated{base.__name__}", (base,), {"__call__": call})
    p._add_action(alias)

OUTPUT_KINDS = ("file", "dir", "any")


@dataclass(frozen=True)
class PathOption:
    """A declared path option: argparse dest, its name in messages, input or output, kind (file, dir,
    dataset = a folder holding capture.json or the manifest itself) and what it holds ("image", "PRVM")."""

    dest: str
    name: str  # the option (-o/--output) or the positional's metavar (REF_IMG)
    output: bool
    kind: str
    what: str


def _declare(p: argparse.ArgumentParser, option: PathOption) -> None:
    declared = p.get_default("_paths")
    if declared is None:
        declared = []
        p.set_defaults(_paths=declared)
    declared.append(option)


def add_input(p: argparse.ArgumentParser, *flags: str, kind: str = "file", what: str = "", **kwargs):
    """Add a path argument (positional: one name; option: its flags) that the command reads; kind is
    'file', 'dir', 'any' (a file or a folder: the command tells which), 'dataset' (a folder holding
    capture.json or the manifest itself; a shell-style pattern names several:
    `calib.image_files.expand_datasets`) or 'pattern' (files, each named or given as a shell-style
    pattern that the program expands: `calib.image_files.expand`); `what` names its content in messages
    ("image", "PRVM", "rig"). Returns the argparse action."""
    assert kind in INPUT_KINDS, kind
    action = p.add_argument(*flags, **kwargs)
    name = "/".join(action.option_strings) if action.option_strings else (action.metavar or action.dest)
    _declare(p, PathOption(action.dest, name, False, kind, what))
    return action


def add_output(p: argparse.ArgumentParser, *flags: str, kind: str = "file", what: str = "", **kwargs):
    """Add a path option that the command writes (default flags -o/--output, required); kind is 'file',
    'dir' (a folder the command fills; it may exist) or 'any' (either, by another option: the command
    checks which). Returns the argparse action."""
    assert kind in OUTPUT_KINDS, kind
    flags = flags or SPELLINGS["output"]
    if flags == SPELLINGS["output"]:
        kwargs.setdefault("required", "default" not in kwargs)
    action = p.add_argument(*flags, **kwargs)
    _declare(p, PathOption(action.dest, "/".join(action.option_strings), True, kind, what))
    return action


def _values(args, option: PathOption) -> list[str]:
    value = getattr(args, option.dest, None)
    if value is None:
        return []
    return [os.fspath(v) for v in value] if isinstance(value, (list, tuple)) else [os.fspath(value)]


def _a(noun: str) -> str:
    return ("an " if noun[:1].lower() in "aeiou" else "a ") + noun


def _check_input(path: Path, option: PathOption) -> None:
    from calib.errors import InputError
    from calib.sequences import parse_frame_ref
    ref = parse_frame_ref(path)
    path = path if ref is None else ref[0]     # a frame of a sequence file (FILE::K): the file
    what = f"{option.what} " if option.what else ""
    if option.kind == "dataset":
        if not path.exists():
            raise InputError(path, "dataset is missing (a folder holding capture.json, or the manifest itself)")
    elif option.kind == "any":
        if not path.exists():
            raise InputError(path, f"{what or 'input '}is missing")
    elif option.kind == "dir":
        if path.is_file():
            raise InputError(path, f"is a file; {option.name} expects a folder")
        if not path.is_dir():
            raise InputError(path, f"{what}folder is missing")
    else:
        if path.is_dir():
            raise InputError(path, f"is a directory; {option.name} expects {_a(what + 'file')}")
        if not path.exists():
            raise InputError(path, f"{what}file is missing")
    if not os.access(path, os.R_OK):
        raise InputError(path, "cannot be read (no permission)")


def _check_output(path: Path, option: PathOption, inputs: set[Path]) -> None:
    from calib.errors import InputError
    if option.kind == "file":
        if path.is_dir():
            raise InputError(path, f"is a directory; {option.name} expects a file name")
        if path.resolve() in inputs:
            raise InputError(path, f"is also an input; {option.name} would overwrite it")
    elif option.kind == "dir" and path.exists() and not path.is_dir():
        raise InputError(path, f"is a file; {option.name} expects a folder")
    ancestor = path if option.kind == "dir" and path.is_dir() else path.parent
    while not ancestor.exists() and ancestor != ancestor.parent:
        ancestor = ancestor.parent
    if not ancestor.is_dir():
        raise InputError(path, f"cannot be written: {ancestor} is a file, not a folder")
    if not os.access(ancestor, os.W_OK | os.X_OK):
        raise InputError(path, f"cannot be written: no permission to write in {ancestor}")
    if option.kind == "file" and path.exists() and not os.access(path, os.W_OK):
        raise InputError(path, "exists and cannot be overwritten (no permission)")
    _probe(path, ancestor)


def _probe(path: Path, folder: Path) -> None:
    """InputError unless a file can be created in `folder`: the outputs' temporary files are created
    there (calib.atomic), and permissions alone do not tell (root writes past them; /proc, a read-only
    mount or a full disk refuse everyone)."""
    import tempfile
    from calib.errors import InputError
    try:
        with tempfile.NamedTemporaryFile(dir=folder, prefix=".stereodic-probe-"):
            pass
    except OSError as exc:
        raise InputError(path, f"cannot be written: {(exc.strerror or str(exc)).lower()} in {folder}") from None


def check_paths(args: argparse.Namespace) -> None:
    """InputError (one line, exit status 2) for the first declared path of `args` that cannot work:
    inputs first (they must exist, as the kind declared), then outputs (their folder must be one and
    writable; a file output must not be a directory, nor one of the inputs)."""
    declared = getattr(args, "_paths", None) or []
    inputs = set()
    for option in declared:
        if not option.output:
            values = [Path(v) for v in _values(args, option)]
            if option.kind == "pattern":
                from calib.image_files import expand
                from calib.sequences import parse_frame_ref
                values = [p for v in values for p in expand(v)]    # a sequence file's frames: the file
                values = list(dict.fromkeys(ref[0] if (ref := parse_frame_ref(p)) else p for p in values))
                option = PathOption(option.dest, option.name, False, "file", option.what)
            elif option.kind == "dataset":
                from calib.image_files import expand_datasets
                values = [p for v in values for p in expand_datasets(v)]
            for value in values:
                _check_input(value, option)
                inputs.add(value.resolve())
    for option in declared:
        if option.output:
            for value in _values(args, option):
                _check_output(Path(value), option, inputs)


def check_file_output(path: str | os.PathLike, name: str) -> None:
    """`check_paths`'s checks of a file output, for an output declared 'any' once the command knows that
    it names a file (one camera, one dataset): InputError naming it if it is a directory or cannot be
    written."""
    _check_output(Path(path), PathOption(name, name, True, "file", ""), set())


def new_folders(args: argparse.Namespace) -> list[Path]:
    """The folders that writing the declared outputs of `args` may create: each output folder and each
    missing parent, up to the nearest that exists (deepest first)."""
    folders = []
    for option in getattr(args, "_paths", None) or []:
        if option.output:
            for value in _values(args, option):
                p = Path(value) if option.kind != "file" else Path(value).parent
                while not p.exists() and p != p.parent:
                    folders.append(p)
                    p = p.parent
    return sorted(set(folders), key=lambda p: len(p.parts), reverse=True)


def remove_empty(folders: list[Path]) -> None:
    """Remove those of `folders` (deepest first) that exist and are empty: what a command that stopped on
    bad input created without writing into it."""
    for p in folders:
        if p.is_dir() and not any(p.iterdir()):
            p.rmdir()


M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3   # glibc's mallopt parameters (malloc.h)
MMAP_THRESHOLD_BYTES = 2 ** 30


def memory_reuse() -> None:
    """Keep freed memory in this process for the next array (a heavy command calls this first).

    glibc returns a freed block larger than its mmap threshold to the operating system at once, and
    trims the heap's freed top; an image-sized array allocated next is then faulted in again page by
    page (system time). Raising the mmap threshold to MMAP_THRESHOLD_BYTES and switching trimming off
    (`mallopt`) keeps the memory of the run's largest arrays for the next ones; the process holds its
    peak memory until it exits. Nothing happens outside glibc (other C libraries, macOS, Windows).
    """
    import ctypes
    import platform
    if platform.libc_ver()[0] != "glibc":
        return
    libc = ctypes.CDLL(None)
    libc.mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)
    libc.mallopt(M_TRIM_THRESHOLD, -1)      # size_t -1: never trim


def wrote(path: str | os.PathLike, summary: str = "") -> None:
    """Print the one line that reports an output: `wrote PATH` or `wrote PATH: summary`."""
    print(f"wrote {os.fspath(path)}" + (f": {summary}" if summary else ""), flush=True)

# The library's defaults, repeated here so that building the parser imports nothing heavy (`--help`
# stays instant); tests/stereodic/test_cli.py checks that they equal stereodic.dic.sequence.SWITCH_ZNCC
# and stereodic.strain.measures.MEASURES.
SWITCH_ZNCC = 0.9
STRAIN_MEASURES = ("green-lagrange", "euler-almansi", "log", "engineering")


def add_simulation_options(p: argparse.ArgumentParser, width: int, height: int, supersample: int | None,
                           seeded: str, lens: str | None = "the lens family",
                           supersample_help: str | None = None) -> None:
    """The options every `simulate` mode shares: --lens (unless `lens` is None: the mode names its lenses
    its own way), --width and --height (defaults in pixels), --seed (of what is `seeded`), --noise,
    --supersample (sub-samples per pixel side) and -o DIR."""
    from scanners.sim import LENS_FAMILIES
    if lens is not None:
        p.add_argument("--lens", choices=LENS_FAMILIES, metavar="LENS", default="brown", help=f"{lens}: {', '.join(LENS_FAMILIES)} (default brown)")
    p.add_argument("--width", type=int, default=width, help=f"sensor width in pixels (default {width})")
    p.add_argument("--height", type=int, default=height, help=f"sensor height in pixels (default {height})")
    p.add_argument("--seed", type=int, default=0, help=f"random seed of {seeded}")
    p.add_argument("--noise", action=argparse.BooleanOptionalAction, default=True,
                   help="sensor noise (default on); --no-noise renders the expected images")
    p.add_argument("--supersample", type=int, default=supersample,
                   help=supersample_help or f"sub-samples per pixel side (default {supersample})")
    add_output(p, kind="dir", metavar="DIR", help="output folder")


def add_grid_options(p: argparse.ArgumentParser, image: str, *, subset: int = 21) -> None:
    """The DIC grid's options (checked by `dic_grid`): --subset (default `subset`), --step, --roi, --mask,
    --start-point; `image` names the image whose pixels they refer to ("reference image", "left rectified
    image")."""
    p.add_argument("--subset", type=int, default=subset, help=f"subset side in pixels, odd (default {subset})")
    p.add_argument("--step", type=int, default=5, help="grid step in pixels (default 5)")
    p.add_argument("--roi", metavar="X0,Y0,X1,Y1", help=f"region of interest in the {image} (inclusive pixel "
                                                      "bounds; default, without --mask: the subsets with speckle, "
                                                      "leaving out a dark background or a blank fixture)")
    add_input(p, "--mask", what="mask image", metavar="PNG",
              help=f"image of the {image}'s size: points where it is non-zero")
    add_input(p, "--roi-polygon", what="polygon file", metavar="FILE",
              help=f"region of interest as polygons with holes in the {image}, pixels: JSON ([[x, y], ...], or "
                   f"{{\"outer\": [...], \"holes\": [[...], ...]}}, or a list of those) or CSV (x,y per line, a "
                   f"blank line between rings: outline first, then its holes; a line 'part' between parts)")
    p.add_argument("--start-point", action="append", default=[], metavar="X,Y",
                   help=f"start point of the propagation in the {image} (repeatable; default: automatic)")
    deprecated(p, "--seed", "--start-point")


def add_prefilter_option(p: argparse.ArgumentParser) -> None:
    """--prefilter SIGMA: the Gaussian low-pass (pixels) of the images before their B-spline
    interpolation (stereodic.dic.DicSettings.prefilter_sigma), checked by `check_prefilter`."""
    p.add_argument("--prefilter", type=float, default=0.7, metavar="SIGMA",
                   help="Gaussian low-pass of both images before interpolation, pixels (default 0.7, 0 = "
                        "none); lowers the interpolation bias")


def add_search_option(p: argparse.ArgumentParser, seeds: str) -> None:
    """--search PIXELS: an override of the automatic initial guess (stereodic.dic.DicSettings.feature_guess),
    checked and turned into settings by `search_settings`."""
    p.add_argument("--search", type=int, default=None, metavar="PIXELS",
                   help=f"override: search the {seeds} within this many pixels of no motion instead of "
                        "guessing every point's motion from feature matches (default: the guess, which finds "
                        "any motion the images allow)")


def search_settings(args) -> dict:
    """The DicSettings fields that --search sets: none by default, else the seeds' ZNCC search radius
    and no feature guess; an InputError for a radius below 1 pixel."""
    from calib.errors import InputError
    if args.search is None:
        return {}
    if args.search < 1:
        raise InputError("--search", f"must be >= 1 pixel, got {args.search}")
    return {"search_radius": args.search, "feature_guess": False}


def check_prefilter(args) -> None:
    """InputError naming --prefilter unless it is >= 0."""
    from calib.errors import InputError
    if args.prefilter < 0:
        raise InputError("--prefilter", f"must be >= 0, got {args.prefilter}")


def add_frame_options(p: argparse.ArgumentParser, rig: str) -> None:
    """--frame rig|specimen, --origin X,Y and --x-axis X0,Y0,X1,Y1 (the specimen's frame: the best-fit
    plane of the reference shape, `stereodic.gauge.frame`); `rig` says what "rig" means for the command."""
    p.add_argument("--frame", choices=["rig", "specimen"], default="rig",
                   help=f"rig: {rig} (default); specimen: the best-fit plane of the reference shape, x along the "
                        f"left image's columns (or --x-axis), z towards the cameras (recorded in the outputs)")
    p.add_argument("--origin", type=parse_floats, metavar="X,Y",
                   help="with --frame specimen: the origin's pixel in the left reference image (default: centroid)")
    p.add_argument("--x-axis", type=parse_floats, metavar="X0,Y0,X1,Y1",
                   help="with --frame specimen: the x axis's direction, two pixels of the left reference image")


def frame_options(args) -> tuple[tuple[float, float] | None, tuple[float, float]]:
    """(origin pixel or None, x direction in pixels) of `add_frame_options`' options; InputError naming
    the option when they do not fit."""
    from calib.errors import InputError
    if (args.origin or args.x_axis) and args.frame != "specimen":
        raise InputError("--origin/--x-axis", "go with --frame specimen")
    if args.origin is not None and len(args.origin) != 2:
        raise InputError("--origin", f"needs X,Y pixels, got {args.origin}")
    if args.x_axis is not None and len(args.x_axis) != 4:
        raise InputError("--x-axis", f"needs X0,Y0,X1,Y1 pixels, got {args.x_axis}")
    x = args.x_axis
    return (tuple(args.origin) if args.origin else None), ((x[2] - x[0], x[3] - x[1]) if x else (1.0, 0.0))


def add_scheduler_option(p: argparse.ArgumentParser, tasks: str) -> None:
    """--scheduler ADDRESS|local[:N]: run the `tasks` (what they are: "states", "scans") on a Dask
    cluster (stereodic.cluster; docs/cluster.md)."""
    p.add_argument("--scheduler", metavar="ADDRESS|local[:N]",
                   help=f"run the {tasks} on a Dask cluster: the address of a running `dask scheduler` "
                        f"(tcp://HOST:8786; images and outputs on storage every worker sees), or local[:N] for N "
                        f"worker processes on this machine (default: one per core); default: in this process")


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
        raise InputError("--display-pitch-mm", "give the display's pixel pitch in mm (PX or PX,PY)")
    return tuple(float(p) for p in pitch_mm) * (2 // len(pitch_mm))


def add_handheld_options(p: argparse.ArgumentParser) -> None:
    """The options of a hand-held (stage-free) simulated capture: --handheld N and how it is held."""
    p.add_argument("--handheld", type=int, default=None, metavar="N",
                   help="hold the display by hand in N random poses instead of moving it on the stage (frames "
                        "carry 'pose'; the truth is in the display's frame at pose 0)")
    p.add_argument("--hold-distance-mm", type=parse_floats, default=[300.0, 600.0], metavar="NEAR,FAR",
                   help="with --handheld: range of the display's distance from the camera, mm (default 300,600)")
    p.add_argument("--max-tilt-deg", type=float, default=35.0, metavar="DEG",
                   help="with --handheld: the largest tilt of the display, degrees (default 35)")
    deprecated(p, "--hold-distance", "--hold-distance-mm")
    deprecated(p, "--max-tilt", "--max-tilt-deg")
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
    if len(args.hold_distance_mm) != 2:
        raise InputError("--hold-distance-mm", f"expected NEAR,FAR in mm, got {args.hold_distance_mm}")
    return HandHeld(poses=args.handheld, distance_mm=tuple(args.hold_distance_mm), max_tilt_deg=args.max_tilt_deg,
                    disturbed=args.disturb)


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


def _region(args, width: int, height: int, image: str):
    """(roi, mask) of the options --roi, --mask and --roi-polygon in a width x height `image` (the mask
    and the polygons' inside combined; None where not given); InputError naming the option or file."""
    from calib.errors import InputError
    from calib.imageio import read_gray
    roi = parse_roi(args.roi, width, height, image)
    mask = None
    if args.mask:
        mask = read_gray(args.mask) > 0
        if mask.shape != (height, width):
            raise InputError(args.mask, f"mask is {mask.shape[1]}x{mask.shape[0]} but the {image} is "
                                        f"{width}x{height}")
    if args.roi_polygon:
        from stereodic.dic.region import polygon_mask, read_polygons
        inside = polygon_mask(read_polygons(args.roi_polygon), width, height, where=args.roi_polygon, image=image)
        mask = inside if mask is None else mask & inside
    return roi, mask


def dic_grid(args, width: int, height: int, image: str, source: str, *, reference=None, noise=None, original=None):
    """The DIC point grid and seeds from the options --subset, --step, --roi, --mask, --roi-polygon and
    --start-point, for a reference image of width x height pixels (`image` names it in messages, `source` is the
    file blamed when no point fits). `original`: the IMM (stereodic.virtual.imm.IMM) of a rectified reference
    image, whose --roi, --mask, --roi-polygon and --start-point are in the original image with --roi-frame
    original.
    Without any of them, `reference` (a callable giving the reference image) places the points where it
    has speckle (`stereodic.dic.texture.specimen_mask`; `noise`: its noise estimate, grey levels, where the
    caller has one, `stereodic.dic.ImageRef.sigma`). Returns (grid, seeds [(x, y), ...]); InputError
    for any option that does not fit.
    """
    import numpy as np

    from calib.errors import InputError
    from stereodic.dic import make_grid
    if args.subset < 5 or args.subset % 2 == 0:
        raise InputError("--subset", f"must be an odd number >= 5, got {args.subset}")
    if args.step < 1:
        raise InputError("--step", f"must be >= 1, got {args.step}")
    if original is not None and getattr(args, "roi_frame", "rectified") == "original":
        from stereodic.dic.region import to_rectified
        rw, rh = original.real_size
        roi, mask = _region(args, rw, rh, "original left image")
        if roi is not None or mask is not None:
            region = np.ones((rh, rw), bool) if mask is None else mask
            if roi is not None:
                box = np.zeros_like(region)
                box[roi[1]:roi[3] + 1, roi[0]:roi[2] + 1] = True
                region &= box
            roi, mask = None, to_rectified(region, original.map_x, original.map_y, original.valid)
            if not mask.any():
                raise InputError("--roi-frame", f"the region drawn in the original left image lies outside the "
                                                f"{image}")
    else:
        roi, mask = _region(args, width, height, image)
    if roi is None and mask is None and reference is not None:
        from stereodic.dic.texture import specimen_mask
        mask = specimen_mask(reference(), subset=args.subset, noise=noise)
        if not mask.any():
            raise InputError(source, f"the {image} has no speckle that a {args.subset}-pixel subset can register "
                                     f"(blank, dark or out of focus?); give --roi or --mask to measure anyway")
    seeds = []
    in_original = original is not None and getattr(args, "roi_frame", "rectified") == "original"
    for text in args.start_point:
        x, y = parse_ints(text, 2, "--start-point")
        if in_original:    # given in the original left image, like the region: moved onto the rectified one
            from stereodic.dic.region import point_to_rectified
            rw, rh = original.real_size
            moved = point_to_rectified(x, y, original.map_x, original.map_y, original.valid) \
                if 0 <= x < rw and 0 <= y < rh else None
            if moved is None:
                raise InputError("--start-point", f"{text} is outside the {rw}x{rh} original left image's part "
                                                  f"that the {image} shows")
            x, y = moved
        if not (0 <= x < width and 0 <= y < height):
            raise InputError("--start-point", f"{text} is outside the {width}x{height} {image}")
        if roi and not (roi[0] <= x <= roi[2] and roi[1] <= y <= roi[3]):
            raise InputError("--start-point", f"{text} is outside the region of interest {args.roi}")
        if mask is not None and not mask[y, x]:
            raise InputError("--start-point", "a start point lies outside the mask")
        seeds.append((x, y))
    grid = make_grid(width, height, subset=args.subset, step=args.step, roi=roi, mask=mask)
    if not grid.active.any():
        raise InputError(args.roi and "--roi" or source,
                         f"no point of the grid has its {args.subset}-pixel subset inside the {image}")
    return grid, seeds

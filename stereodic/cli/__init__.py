"""The `stereodic` command: one sub-command per module of this package.

Each sub-command module defines `register(subparsers)`, which adds its parser and sets `func` to the
function that runs it; the function returns an exit status (or None for 0). Path options are declared
with `stereodic.cli.common.add_input`/`add_output` and checked before the command runs. Heavy imports
happen inside the run functions, and only those the command uses, so that `stereodic --help` and a
command's own start-up stay fast (tests/stereodic/test_startup.py lists what may be imported).

Exit status: 0 success; 2 bad usage or bad input (one line naming the file and the problem); 1 an
internal error (with its traceback), a hardware fault or a cluster fault (`stereodic.cluster.ClusterFault`:
one line).
"""

from __future__ import annotations

import argparse
import gc
import importlib
import keyword
import os
import sys

from calib import __version__
from calib.errors import InputError

# In the order `stereodic --help` lists them.
COMMANDS = ["demo", "simulate", "patterns", "calibrate", "undistort", "rig", "rectify", "scan", "dic2d",
            "dic", "strain", "gauge", "speckle", "import", "export", "bench", "acquire", "align", "show", "view"]


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The parser of every command, or of `command` alone (what `main` builds for `stereodic COMMAND
    ...`: registering the other commands' parsers would cost start-up time and import their modules)."""
    from stereodic.cli.common import Parser
    parser = Parser(
        prog="stereodic",
        description="Per-pixel ray camera calibration, rectified virtual stereo, 3D scanning and DIC.")
    parser.add_argument("--version", action="version", version=f"stereodic {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMANDS if command is None else [command]:
        module = f"{name}_" if keyword.iskeyword(name) else name   # `import` lives in import_.py
        importlib.import_module(f"stereodic.cli.{module}").register(sub)
    return parser


# commands whose work is the project's own parallel kernels (OpenMP, numba): numpy's BLAS kept to one
# thread there (`thread_limits`)
OWN_KERNELS = ("dic", "dic2d")


def thread_limits(command: str | None = None) -> None:
    """OMP_NUM_THREADS, when set, for OpenCV's and numba's own thread pools too (OPENCV_FOR_THREADS_NUM,
    NUMBA_NUM_THREADS, unless set: both are read when the library loads, after this), so that a run
    told to use n threads (`stereodic.dic.background.threads`) uses n cores in every library. Where numba
    was loaded before (a notebook, a test session that ran a command earlier) its pool has its size:
    changing NUMBA_NUM_THREADS then would fail numba's next compilation, so the calling thread's share
    of the pool is limited instead (`numba.set_num_threads`).

    For the commands of OWN_KERNELS, numpy's OpenBLAS is kept to one thread (OPENBLAS_NUM_THREADS=1,
    unless set; read when numpy loads): there BLAS only serves a few least-squares fits (a map's axes over
    80k points), and after each threaded call OpenBLAS's threads spin on every core for a while, taking
    it from the correlation's kernels and the writing's children (0.18 CPU-s on 2 threads on the bench
    pair, 0.2-0.3 s of its wall time)."""
    n = os.environ.get("OMP_NUM_THREADS", "").strip()
    if command in OWN_KERNELS:
        os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    if n.isdigit() and int(n) > 0:
        os.environ.setdefault("OPENCV_FOR_THREADS_NUM", n)
        if "numba" in sys.modules:
            import numba
            numba.set_num_threads(min(int(n), numba.config.NUMBA_NUM_THREADS))
        else:
            os.environ.setdefault("NUMBA_NUM_THREADS", n)


def main(argv: list[str] | None = None) -> int:
    """Run one `stereodic` command, as the shell does (`stereodic COMMAND ARGS...`).

    Parameters
    ----------
    argv : list of str, optional
        The command and its arguments, e.g. ``["dic", "rig.npz", "data", "-o", "out"]``; None: the
        process's own (``sys.argv[1:]``).

    Returns
    -------
    status : int
        The exit status: 0 done, 2 bad input (one line on stderr naming the file or option; nothing
        written), 1 a hardware or cluster fault or an internal error, 130 interrupted.
    """
    if argv is not None:
        return _run(list(argv))
    try:
        return _run(sys.argv[1:])
    finally:
        # the process ends after this: its objects frozen (gc.freeze), the interpreter's shutdown does not
        # walk them again in each of its garbage collections (0.3 s after a `dic` run, on one core); a
        # caller in the same process (argv given: a test, a notebook) keeps its collector as it was
        gc.freeze()


def _run(argv: list[str]) -> int:
    """`main` of these arguments."""
    thread_limits(argv[0] if argv else None)
    parser = build_parser(argv[0] if argv and argv[0] in COMMANDS else None)
    args = parser.parse_args(argv)
    from stereodic.cli.common import check_paths, new_folders, remove_empty
    created = new_folders(args)
    try:
        check_paths(args)  # every path the command declared, before any work
        status = args.func(args)
    except InputError as exc:
        remove_empty(created)  # nothing left behind: the folders made for outputs never written
        print(f"stereodic: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("stereodic: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # an internal error: show where, for the bug report
        from scanners.errors import HardwareError
        from stereodic.cluster import ClusterFault
        if isinstance(exc, HardwareError):
            print(f"stereodic: hardware fault: {exc}", file=sys.stderr)
            return 1
        if isinstance(exc, ClusterFault):
            print(f"stereodic: cluster fault: {exc}", file=sys.stderr)
            return 1
        import traceback
        traceback.print_exc()
        print(f"stereodic: internal error: {exc}", file=sys.stderr)
        return 1
    return 0 if status is None else int(status)


if __name__ == "__main__":
    sys.exit(main())

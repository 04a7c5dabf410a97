"""Start-up figures: how long a command takes before (and besides) its work, each in a fresh process
(`python -m stereodic ...`, best of several runs; wall time and the process's user + system CPU time,
which depends less on other load).

- `stereodic --help` and every `stereodic COMMAND --help` (the slowest is reported): argparse only, no
  library imported (tests/stereodic/test_startup.py guards that by the modules imported).
- a 9-point `dic2d` on DIC Challenge sample 5: the command's own start-up (imports, reading two
  512x512 images, the B-spline prefilter, writing the CSV) with next to no correlation.
- the 9,025-point `dic2d` on sample 5 (subset 21, step 5, points 30..500 px): the whole process beside
  OpenCorr's FFT-CC + IC-GN sample on the same grid, whole process too. OpenCorr is not part of this
  project: built from its source for sample 5 (docs/dic.md says how) and named by the environment
  variable OPENCORR_SAMPLE5 (the program's path), it is timed in this run, one run of each in turn;
  otherwise the bench quotes the last figure measured that way (OPENCORR_SAMPLE5_S, docs/dic.md).
"""

from __future__ import annotations

import os
import statistics
import tempfile
from pathlib import Path

from stereodic.bench import Figure, stereodic_command, time_command, time_process
from stereodic.bench.dic import SAMPLE5

GOAL_HELP_S = 0.2
GOAL_DIC2D_STARTUP_S = 0.7
OPENCORR_SAMPLE5_S = 0.78   # the last side-by-side measurement on this machine, median of 10 (docs/dic.md)


def run(quick: bool = False) -> list[Figure]:
    from stereodic.cli import COMMANDS
    repeat = 3 if quick else 7
    figures = []
    wall, cpu = time_command(["--help"], repeat)
    figures.append(Figure("startup", "stereodic --help, wall", wall, "s", goal=f"<= {GOAL_HELP_S} s",
                          ok=wall <= GOAL_HELP_S))
    figures.append(Figure("startup", "stereodic --help, user + system CPU", cpu, "s"))
    slowest = max(((time_command([c, "--help"], repeat), c) for c in COMMANDS), key=lambda t: t[0][0])
    (wall, cpu), name = slowest
    figures.append(Figure("startup", f"stereodic COMMAND --help, the slowest ({name}), wall", wall, "s",
                          goal=f"<= {GOAL_HELP_S} s", ok=wall <= GOAL_HELP_S))
    if not SAMPLE5.is_dir():
        return figures
    ref, dfm = str(SAMPLE5 / "reference.tif"), str(SAMPLE5 / "shift_x0.10_y0.10.tif")
    with tempfile.TemporaryDirectory() as tmp:
        out = str(Path(tmp) / "out.csv")
        wall, cpu = time_command(["dic2d", ref, dfm, "--roi", "250,250,260,260", "-o", out], repeat)
        figures.append(Figure("startup", "dic2d, 9 points on sample 5 (the command's own start-up), wall", wall, "s",
                              goal=f"<= {GOAL_DIC2D_STARTUP_S} s", ok=wall <= GOAL_DIC2D_STARTUP_S))
        figures.append(Figure("startup", "dic2d, 9 points on sample 5, user + system CPU", cpu, "s"))
        ours = stereodic_command(["dic2d", ref, dfm, "--subset", "21", "--step", "5", "--roi", "30,30,500,500",
                                  "-o", out])
        opencorr = os.environ.get("OPENCORR_SAMPLE5")
        runs, theirs = [], []
        for _ in range(repeat if opencorr is None else max(repeat, 10)):   # in turn: both see the same load
            runs.append(time_process(ours))
            if opencorr is not None:
                theirs.append(time_process([opencorr], cwd=tmp))
        wall = statistics.median(w for w, _ in runs)
        if opencorr is None:
            ref_name, ref_wall = "OpenCorr FFT-CC + IC-GN sample, same grid, whole process (quoted: docs/dic.md)", \
                OPENCORR_SAMPLE5_S
        else:
            ref_name = f"OpenCorr FFT-CC + IC-GN sample, same grid, whole process, in turn (median of {len(theirs)})"
            ref_wall = statistics.median(w for w, _ in theirs)
        figures.append(Figure("startup", f"dic2d, 9025 points on sample 5 (subset 21, step 5), whole process, wall "
                                         f"(median of {len(runs)})", wall, "s", ref_name, ref_wall, "< OpenCorr",
                              wall < ref_wall))
        figures.append(Figure("startup", "dic2d, 9025 points on sample 5, user + system CPU (median)",
                              statistics.median(c for _, c in runs), "s",
                              *(("OpenCorr, user + system CPU (median)", statistics.median(c for _, c in theirs))
                                if theirs else ())))
    return figures

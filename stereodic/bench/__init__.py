"""`stereodic bench`: speed, memory and accuracy figures, each beside the reference it is compared with.

One module per group (`sim`, `calib`, `rectify`, `scan`, `dic`, `align`, `startup`, `cluster`, `view`), each with
`run(quick: bool) -> list[Figure]`. Benchmarks generate their data with the simulated rig, so this
package (like `stereodic.cli`) may import `scanners`.
"""

from __future__ import annotations

import importlib
import os
import subprocess
import sys
import time
from dataclasses import asdict, dataclass
from typing import Callable

GROUPS = ["sim", "calib", "rectify", "scan", "dic", "align", "startup", "cluster", "view"]
# fringe periods (display px) per lens family where the default (60, 360, 1920) is not the right choice
# (their pixels see ~0.35 display px): the calibration and hand-held groups' simulated benches
PERIODS = {"telecentric": (30, 240, 1920), "scheimpflug": (30, 240, 1920)}


@dataclass
class Figure:
    """One measured figure. `reference` names what it is compared with, `reference_value` its figure;
    `goal` is the bound the project set itself (text, e.g. '<= 2 s'), `ok` whether it is met."""

    group: str
    name: str
    value: float
    unit: str
    reference: str = ""
    reference_value: float | None = None
    goal: str = ""
    ok: bool | None = None

    def __post_init__(self):  # numpy scalars from the measurements -> plain Python (JSON, tables)
        self.value = float(self.value)
        self.reference_value = None if self.reference_value is None else float(self.reference_value)
        self.ok = None if self.ok is None else bool(self.ok)

    def as_dict(self) -> dict:
        return asdict(self)


def best_time(fn: Callable[[], object], repeat: int = 3, warmup: int = 1) -> float:
    """Best wall-clock time of `fn()` in seconds over `repeat` runs, after `warmup` runs."""
    for _ in range(warmup):
        fn()
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def time_process(cmd: list[str], *, cwd: str | None = None, env: dict | None = None) -> tuple[float, float]:
    """(wall seconds, user + system CPU seconds) of one run of the program `cmd` (its input empty), with
    the variables `env` added to this process's environment; RuntimeError if it fails."""
    before = os.times()
    t0 = time.perf_counter()
    done = subprocess.run(cmd, capture_output=True, text=True, stdin=subprocess.DEVNULL, cwd=cwd,
                          env=None if env is None else {**os.environ, **env})
    dt = time.perf_counter() - t0
    after = os.times()
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed: {done.stderr.strip()}")
    return dt, (after.children_user - before.children_user) + (after.children_system - before.children_system)


def stereodic_command(argv: list[str]) -> list[str]:
    """The program `stereodic ARGV` as this interpreter runs it."""
    return [sys.executable, "-m", "stereodic", *argv]


def time_command(argv: list[str], repeat: int) -> tuple[float, float]:
    """(best wall seconds, best user + system CPU seconds) of `stereodic ARGV` in fresh processes, over
    `repeat` runs; RuntimeError if it fails."""
    runs = [time_process(stereodic_command(argv)) for _ in range(repeat)]
    return min(w for w, _ in runs), min(c for _, c in runs)


def peak_rss_bytes() -> int:
    """Peak resident memory (bytes) of this process since it was started (its last exec): VmHWM of
    /proc/self/status on Linux, else getrusage's ru_maxrss. On Linux ru_maxrss also keeps the memory
    of the parent at fork, which a spawned child carries through its exec: a bench process grown to
    2 GiB would lend every child its 2 GiB."""
    import resource
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def _child(fn, args, conn):
    t0 = time.perf_counter()
    result = fn(*args)
    dt = time.perf_counter() - t0
    conn.send((dt, peak_rss_bytes(), result))
    conn.close()


def run_isolated(fn: Callable, *args):
    """Run `fn(*args)` in a fresh process; returns (seconds, peak resident memory in bytes, result).

    Peak memory is the child's whole-process maximum RSS, interpreter and libraries included.
    `fn` must be a module-level function and its result picklable.
    """
    import multiprocessing
    ctx = multiprocessing.get_context("spawn")
    parent, child = ctx.Pipe(duplex=False)
    p = ctx.Process(target=_child, args=(fn, args, child))
    p.start()
    child.close()
    out = parent.recv()
    p.join()
    return out


def run_groups(names: list[str], quick: bool = False) -> list[Figure]:
    figures: list[Figure] = []
    for name in names:
        figures += importlib.import_module(f"stereodic.bench.{name}").run(quick=quick)
    return figures


def _cells(f: Figure) -> tuple[str, ...]:
    return (f.group, f.name, f"{f.value:.4g} {f.unit}".strip(), f.reference,
            "" if f.reference_value is None else f"{f.reference_value:.4g} {f.unit}".strip(), f.goal,
            {True: "yes", False: "NO", None: ""}[f.ok])


def format_markdown(figures: list[Figure]) -> str:
    """A Markdown table (for the README), one row per figure."""
    head = ("group", "figure", "value", "reference", "ref. value", "goal", "met")
    rows = [head, ("---",) * len(head)] + [_cells(f) for f in figures]
    return "\n".join("| " + " | ".join(c.replace("|", "/") for c in r) + " |" for r in rows)


def format_table(figures: list[Figure]) -> str:
    """A plain-text table, one row per figure."""
    rows = [("group", "figure", "value", "reference", "ref. value", "goal", "ok")] + [_cells(f) for f in figures]
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    return "\n".join("  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in rows)

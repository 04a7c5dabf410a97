"""Long stereo DIC sequences (rows of `stereodic bench dic`): speed on large images, memory over thousands
of states, and the identity of a run killed half way and resumed.

- speed: a simulated 1920x1200 stereo sequence (a plate under growing tension and translation), subset
  25, step 10 (about 20,000 points): states per second of the per-state unit of work - reading the two
  images, rectifying them, the B-splines, the temporal and cross matches, triangulation, strain and the
  state's result file (`stereodic.dic3d.run.run_states`), state 0 and the JIT compilation excluded; and,
  apart, the rate of writing the combined dic.csv and dic.npz from the state files;
- memory: a 2,000-state sequence at 640x512 (subset 21, step 10; the images of 9 rendered states
  repeated, so that rendering stays affordable), `stereodic dic` run in a child process
  (`run_isolated`) that first was killed (SIGKILL) half way: its peak resident memory, interpreter and
  libraries included;
- identity: the files of that killed-and-resumed run against those of an uninterrupted one.
"""

from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from stereodic.bench import Figure, run_isolated

GOAL_STATES_PER_S = 2.0
GOAL_PEAK_BYTES = 1.5 * 2 ** 30


def _speed_sequence(root: Path, width: int, height: int, states: int) -> None:
    from scanners.sim.dic import DicState, simulate_dic
    from stereodic.stereo.rig import rig_from_files, save_rig
    seq = [DicState("reference")] + [DicState(f"load {k}", stretch=(1 + 0.0005 * k, 1 - 0.00015 * k),
                                              translation_mm=(0.03 * k, -0.02 * k, 0.05 * k)) for k in range(1, states)]
    simulate_dic(root, seq, width=width, height=height, supersample=1)
    save_rig(root / "rig.npz", rig_from_files(root / "truth_cam0.npz", root / "truth_cam1.npz"))


def _states_per_second(root: str) -> tuple[float, float, int]:
    """(states/s of the states after the first two, states/s of writing dic.csv + dic.npz, points)."""
    from stereodic.dic import DicSettings, make_grid
    from stereodic.dic3d.dataset import load_states
    from stereodic.dic3d.run import run_states, write_outputs
    from stereodic.dic3d.stereo import StereoSettings
    from stereodic.dic3d.store import RunStore
    from stereodic.stereo.rig import load_rig
    rig = load_rig(f"{root}/rig.npz")
    data = load_states(root, rig)
    grid = make_grid(rig.sensor.width, rig.sensor.height, subset=25, step=10)
    settings = StereoSettings(DicSettings(subset=25), strain_window=5)
    with tempfile.TemporaryDirectory(dir=root) as out:
        store = RunStore(out)
        store.open({}, {}, len(data))
        stamps = []
        run_states(store, data, rig, grid, [], settings, report=lambda st: stamps.append(time.perf_counter()))
        rate = (len(stamps) - 2) / (stamps[-1] - stamps[1])     # state 1 compiles what state 0 did not
        t0 = time.perf_counter()
        write_outputs(store, grid, out, settings, {}, vtk=False)
        writing = len(data) / (time.perf_counter() - t0)
    return rate, writing, int(grid.active.sum())


def _repeated_sequence(root: Path, count: int) -> Path:
    """A folder of `count` image pairs (hard links to 9 rendered states: reference, then 8 motions
    repeated) in DICe's naming."""
    from scanners.sim.dic import DicState, simulate_dic
    from stereodic.stereo.rig import rig_from_files, save_rig
    seq = [DicState("reference")] + [DicState(f"m{k}", translation_mm=(0.1 * k, -0.05 * k, 0.2 * k),
                                              stretch=(1 + 0.001 * k, 1 - 0.0003 * k)) for k in range(1, 9)]
    simulate_dic(root / "sim", seq, width=640, height=512, supersample=1)
    sim = root / "sim"
    save_rig(sim / "rig.npz", rig_from_files(sim / "truth_cam0.npz", sim / "truth_cam1.npz"))
    pairs = root / "pairs"
    pairs.mkdir()
    for k in range(count):
        src = 0 if k == 0 else 1 + (k - 1) % 8
        for cam in (0, 1):
            os.link(root / "sim" / f"s{src:03d}" / f"cam{cam}.png", pairs / f"img_{k:05d}_{cam}.png")
    return pairs


def _dic(argv: list[str]) -> int:
    """`stereodic dic argv` (its per-state lines dropped); the exit status."""
    import contextlib
    import io

    from stereodic.cli import main
    with contextlib.redirect_stdout(io.StringIO()):
        return main(argv)


def _digest(folder: Path) -> dict[str, str]:
    out = {}
    for p in sorted(folder.rglob("*")):
        if p.is_file():
            h = hashlib.sha256()
            with open(p, "rb") as f:
                for block in iter(lambda: f.read(1 << 22), b""):
                    h.update(block)
            out[str(p.relative_to(folder))] = h.hexdigest()
    return out


def _killed_and_resumed(argv: list[str], out: Path, states: int) -> int:
    """Run `stereodic dic argv` in a subprocess, SIGKILL it once half the states are done, then resume it
    in a child process; returns the peak resident memory (bytes) of the resumed run."""
    proc = subprocess.Popen([sys.executable, "-m", "stereodic", *argv], stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    manifest = out / "run.json"
    while proc.poll() is None:
        try:
            if json.loads(manifest.read_text()).get("done", 0) >= states // 2:
                proc.send_signal(signal.SIGKILL)
                break
        except (OSError, ValueError):
            pass
        time.sleep(0.2)
    proc.wait()
    _, peak, status = run_isolated(_dic, argv)
    if status != 0:
        raise RuntimeError(f"stereodic dic {' '.join(argv)} failed after its restart")
    return peak


def figures(quick: bool) -> list[Figure]:
    figs = []
    width, height = (960, 600) if quick else (1920, 1200)
    with tempfile.TemporaryDirectory() as tmp:
        _speed_sequence(Path(tmp), width, height, 5 if quick else 12)
        rate, writing, points = _states_per_second(tmp)
    label = f"stereo sequence {width}x{height}, 25x25, step 10 ({points} points)"
    figs.append(Figure("dic", f"{label}: per state read + rectify + match + triangulate + strain + save", rate,
                       "states/s", goal=f">= {GOAL_STATES_PER_S:g}", ok=rate >= GOAL_STATES_PER_S if not quick else None))
    figs.append(Figure("dic", f"{label}: writing dic.csv + dic.npz from the state files", writing, "states/s"))
    count = 60 if quick else 2000
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        pairs = _repeated_sequence(root, count)
        common = [str(root / "sim" / "rig.npz"), "--images", str(pairs), "--step", "10", "--no-vtk", "--no-plot"]
        peak = _killed_and_resumed(["dic", *common, "-o", str(root / "killed")], root / "killed", count)
        _, peak_whole, _ = run_isolated(_dic, ["dic", *common, "-o", str(root / "whole")])
        same = _digest(root / "killed") == _digest(root / "whole")
    label = f"{count}-state stereo sequence, 640x512, 21x21, step 10"
    peak = max(peak, peak_whole)
    figs.append(Figure("dic", f"{label}: peak memory (killed half way, then resumed; and uninterrupted)",
                       peak / 2 ** 20, "MiB", goal="< 1536", ok=peak < GOAL_PEAK_BYTES if not quick else None))
    figs.append(Figure("dic", f"{label}: files of the resumed run identical to an uninterrupted run's",
                       float(same), "", goal="1 (identical)", ok=same))
    return figs

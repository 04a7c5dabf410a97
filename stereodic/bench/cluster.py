"""`stereodic bench cluster`: the same work in this process and on a 2-worker local Dask cluster on the same
cores (`--scheduler`, stereodic.cluster): rates, what a task sends, and each worker's peak memory.

- a 200-state stereo DIC sequence (640x512, 21x21 subsets, step 10; the images of 9 rendered states
  repeated, as in `stereodic bench dic`): `stereodic dic --images` without maps or VTK (the chain alone:
  what the cluster cannot speed up on the same cores, so its cost shows), then with VTK files and the
  maps of every 10th state (which run beside the chain);
- a batch of 20 scans (10 datasets of 2 states, a sphere before its plate and a plate, 640x512, the images
  of one rendered pair of states linked into each): `stereodic scan RIG 'DIR/*' -o OUT`.
Each command runs in a fresh process, whole (start-up, state 0, the combined files included); the cluster
(`stereodic.cluster.local_cluster(2)`, one task thread per worker, OpenMP threads = cores) is started
before and shut down after each run, so a worker's peak memory (VmHWM) is that run's. "Sent per task":
the task's arguments and the result the client takes, as pickled (`stereodic.cluster.counting`), plus
the data Dask moved between workers (prepared pairs), divided by the tasks. The rate goal: the cluster
within 15 % of the in-process rate.
"""

from __future__ import annotations

import contextlib
import io
import os
import tempfile
import time
from pathlib import Path

from stereodic.bench import Figure, peak_rss_bytes, run_isolated

GOAL_RATIO = 0.85
SCAN_PERIODS = (1280, 160, 32)


def _command(argv: list[str], address: str | None) -> tuple[float, int, int, int]:
    """`stereodic ARGV [--scheduler ADDRESS]` in this process, its output dropped: (seconds, tasks, bytes
    of their arguments, bytes of their results)."""
    from stereodic.cli import main
    from stereodic.cluster import counting
    more = ["--scheduler", address] if address else []
    with counting() as t, contextlib.redirect_stdout(io.StringIO()):
        t0 = time.perf_counter()
        status = main(argv + more)
        seconds = time.perf_counter() - t0
    if status != 0:
        raise RuntimeError(f"stereodic {' '.join(argv + more)} failed (exit status {status})")
    return seconds, t.tasks, t.bytes, t.results


def _moved(dask_worker) -> int:
    return dask_worker.transfer_outgoing_bytes_total


def _peak(dask_worker) -> int:
    return peak_rss_bytes()


def _compare(label: str, unit_name: str, count: int, argv_for, rows: list[Figure]) -> None:
    """Rows comparing the command in-process and on a fresh 2-worker local cluster; `argv_for(name)` the
    command line writing into a fresh output named `name`."""
    from distributed import Client

    from stereodic.cluster import local_cluster
    here = count / run_isolated(_command, argv_for("here"), None)[2][0]
    t0 = time.perf_counter()
    with local_cluster(2) as cluster, Client(cluster) as client:
        startup = time.perf_counter() - t0
        _, client_peak, (seconds, tasks, sent, taken) = run_isolated(_command, argv_for("cluster"),
                                                                     cluster.scheduler_address)
        moved = sum(client.run(_moved).values())
        worker_peak = max(client.run(_peak).values())
    there = count / seconds
    rows += [
        Figure("cluster", f"{label}: in-process", here, f"{unit_name}/s"),
        Figure("cluster", f"{label}: 2-worker local cluster, same cores", there, f"{unit_name}/s",
               "in-process", here, f">= {GOAL_RATIO:g} x in-process", there >= GOAL_RATIO * here),
        Figure("cluster", f"{label}: sent per task ({tasks} tasks: arguments {sent / tasks / 1e3:.3g} kB, results "
                          f"{taken / tasks / 1e3:.3g} kB, between workers {moved / tasks / 1e3:.3g} kB)",
               (sent + taken + moved) / tasks / 1e3, "kB"),
        Figure("cluster", f"{label}: peak memory per worker (client {client_peak / 2 ** 20:.0f} MiB)",
               worker_peak / 2 ** 20, "MiB"),
        Figure("cluster", f"{label}: starting the 2-worker local cluster", startup, "s"),
    ]


def _scan_batch(root: Path, datasets: int, width: int, height: int) -> Path:
    """`datasets` scan datasets of 2 states in root/batch/ (images hard-linked from one rendering)."""
    import shutil

    from scanners.sim.scan import default_scan_rig, simulate_scan, standard_scenes
    from stereodic.stereo.rig import rig_from_files, save_rig
    sim = root / "sim"
    simulate_scan(sim, scenes=standard_scenes(objects=("sphere",))[:1] + standard_scenes(objects=("plane",))[:1],
                  rig=default_scan_rig(width=width, height=height), periods=SCAN_PERIODS)
    save_rig(root / "rig.npz", rig_from_files(sim / "truth_cam0.npz", sim / "truth_cam1.npz"))
    for d in range(datasets):
        folder = root / "batch" / f"line{d:02d}"
        shutil.copytree(sim, folder, copy_function=os.link, ignore=shutil.ignore_patterns("truth*"))
    return root / "batch"


def run(quick: bool = False) -> list[Figure]:
    from stereodic.bench.dic_sequence import _repeated_sequence
    rows: list[Figure] = []
    states = 20 if quick else 200
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        pairs = _repeated_sequence(root, states)
        base = ["dic", str(root / "sim" / "rig.npz"), "--images", str(pairs), "--step", "10"]
        _compare(f"stereo DIC, {states} states 640x512, 21x21, step 10, no maps", "states", states,
                 lambda name: base + ["--no-vtk", "--no-plot", "-o", str(root / f"chain-{name}")], rows)
        _compare(f"stereo DIC, {states} states 640x512, 21x21, step 10, VTK + maps of every 10th state", "states",
                 states, lambda name: base + ["--plot-every", "10", "-o", str(root / f"maps-{name}")], rows)
    scans = 4 if quick else 20
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        w, h = (320, 256) if quick else (640, 512)
        batch = _scan_batch(root, scans // 2, w, h)
        _compare(f"scan batch, {scans} scans {w}x{h}", "scans", scans,
                 lambda name: ["scan", str(root / "rig.npz"), str(batch / "*"), "-o", str(root / f"out-{name}")], rows)
    return rows

"""A stereo DIC run (`stereodic.dic3d.run`) on a Dask cluster (`stereodic.cluster`): the same run folder,
the same files, byte for byte.

The states form a chain: state k starts from the warps state k - 1 leaves (`StereoCarry`) and tracks its
incremental points from state k - 1's left image, so no two states can be solved at once. The chain
lives on one worker, its home (the one that solved the last state), which works as the in-process run
does: it keeps the carry and the pair of the state it solved, and prepares the next state's pair in a
thread while it solves a state, so that a link costs one round trip to the client and nothing else.
What can run beside the chain runs on the other workers:
- dic-solve k: `solve_state(run, k, pair k, carry, pair k - 1)` where the worker writes its state file
  and the carry after it into the run folder (`RunStore.write_result`), then the same for the states
  after k that the task was given: short states go several to a task, as many as take about `TASK_S`,
  so that the link's round trip is a small share of the work (a long state is a task of its own). It
  returns the states' summary lines and its own address. A solve that lands on another worker (its home
  died) reads the carry from the run folder, exactly as a resumed in-process run does, and prepares its
  pairs itself (a state that a task of an earlier, stopped client went on to solve is taken as it is: it
  is what this task would write). The client submits the next dic-solve as soon as one has finished and
  records its states done in the manifest: a Dask dependency between the solves instead would keep the
  chain's lineage, and a worker lost late in a long run would make Dask solve the whole chain again;
- dic-files k: state k's rows of dic.csv (kept in the run folder: `RunStore.write_rows`), VTK file and
  PNG maps from its state file (`run.write_state_files`), queued after dic-solve k and run on the other
  workers' threads (all but the chain's one while it runs).
The combined files (dic.csv from the kept rows, dic.npz, DICe's files, the VTK collection) are written
by the client from the run folder afterwards, as in-process.

What a task carries is a `RunSpec` (file names, the grid, the settings: a few kB) and a state number;
each worker builds the rig, the reference pair prepared and the reference points (read from state 0's
file) once, from shared storage (`stereodic.cluster.per_worker`), so the run folder and the images
must be on storage that every worker sees under the same path. A worker that dies takes its task with
it: Dask runs the task again on another worker (a prepared pair it held is prepared again); a client
that stops leaves the run folder as an in-process run would, and the same command resumes it.
"""

from __future__ import annotations

import collections
import hashlib
import os
import pickle
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterator

from calib.batch import fingerprint
from calib.progress import note, progress
from stereodic.cluster import ClusterFault, per_worker, result, run_id, submit, threads, worker_address
from stereodic.dic.grid import Grid
from stereodic.dic.maps import surface_axes
from stereodic.dic3d.dataset import DicStates
from stereodic.dic3d.output import csv_rows
from stereodic.dic3d.run import prepare_pair, write_state_files
from stereodic.dic3d.stereo import PreparedPair, StereoCarry, StereoRun, StereoSettings, StereoState, solve_state
from stereodic.dic3d.store import RunStore

SOLVE, FILES = 1, 0   # task priorities: the chain first
TASK_S = 1.0          # a solve task takes this many states where they are short (its overhead: one round trip)
MOST_STATES = 32      # ... at most this many


@dataclass(frozen=True)
class RunSpec:
    """What a task needs to find the run's data on a worker: the rig file (and its SHA-256), the run
    folder, the reference pair's image files, the grid, seeds and settings, `describe` (a state's
    summary line, a module-level function: pickled by name) and `token` (names the per-worker copy).
Paths are absolute: a worker's working folder is not the client's."""

    rig: str
    rig_sha256: str
    folder: str
    reference: tuple[str, str]
    grid: Grid
    seeds: tuple
    settings: StereoSettings
    describe: Callable[[StereoState], str]
    token: str = ""

    @classmethod
    def make(cls, rig: str, rig_sha256: str, folder: str, data: DicStates, grid: Grid, seeds, settings,
             describe) -> "RunSpec":
        spec = cls(os.path.abspath(rig), rig_sha256, os.path.abspath(folder),
                   (os.path.abspath(data.left[0]), os.path.abspath(data.right[0])), grid,
                   tuple(tuple(s) for s in seeds), settings, describe)
        ref = [fingerprint(p) for p in spec.reference]    # a long-lived worker may have seen other images there
        token = hashlib.sha1(pickle.dumps((spec.rig_sha256, spec.folder, spec.reference, ref, grid.xs, grid.ys,
                                           grid.active, spec.seeds, settings))).hexdigest()[:16]
        return cls(**{**spec.__dict__, "token": token})


# ------------------------------------------------------------------------------------- on a worker

def _rig(spec: RunSpec):
    from stereodic.stereo.rig import load_rig
    return per_worker(f"rig:{spec.rig}:{spec.rig_sha256}", lambda: load_rig(spec.rig))


def _reference(spec: RunSpec) -> tuple[StereoRun, PreparedPair]:
    """The run prepared from the reference pair (as `run_states` prepares it), and that pair."""
    def build():
        pair0 = _prepare(spec, *spec.reference)
        return StereoRun.prepare(_rig(spec), spec.grid, spec.settings, spec.seeds, pair0), pair0
    return per_worker(f"dic-run:{spec.token}", build)


def _referenced(spec: RunSpec) -> StereoRun:
    """The run with state 0's points (read from its state file, as a resumed run does)."""
    run, _ = _reference(spec)
    return per_worker(f"dic-run0:{spec.token}",
                      lambda: run.with_reference(RunStore(spec.folder).attach().read_state(0)))


def _prepare(spec: RunSpec, left: str, right: str) -> PreparedPair:
    return prepare_pair(DicStates([Path(left)], [Path(right)], ""), _rig(spec), spec.settings, 0)


class _Home:
    """What a worker keeps between the solves of a chain that lives on it (module docstring): the last
    state it solved, the carry after it and its pair, and the next state's pair being prepared in a
    thread while the state is solved."""

    def __init__(self):
        self.state = -1
        self.carry: StereoCarry | None = None
        self.pair: PreparedPair | None = None
        self.coming: tuple[int, object] | None = None   # (state, the concurrent.futures.Future of its pair)
        self.pool = ThreadPoolExecutor(1)

    def take(self, k: int) -> tuple[StereoCarry | None, PreparedPair | None, object]:
        """The carry and pair of state k - 1 and the future of state k's pair, where this worker holds them
        (else None); forgotten here, so that a solve that fails does not leave them for its next try."""
        held = (self.carry, self.pair) if self.state == k - 1 else (None, None)
        coming = self.coming[1] if self.coming is not None and self.coming[0] == k else None
        self.state, self.carry, self.pair, self.coming = -1, None, None, None
        return (*held, coming)

    def prefetch(self, k: int, prepare: Callable[[], PreparedPair]) -> None:
        """Start preparing state k's pair."""
        self.coming = (k, self.pool.submit(prepare))

    def keep(self, k: int, carry: StereoCarry, pair: PreparedPair) -> None:
        self.state, self.carry, self.pair = k, carry, pair


_homes: dict[str, _Home] = {}   # run token -> the chain of that run on this worker (one run at a time)


def _home(spec: RunSpec) -> _Home:
    if spec.token not in _homes:
        _homes.clear()
        _homes[spec.token] = _Home()
    return _homes[spec.token]


def solve_task(spec: RunSpec, first: int, files: list[tuple[str, str] | None]) -> tuple[list[str], str, float]:
    """dic-solve: states first, first + 1, ... one after the other from the carry state first - 1 left
    (module docstring), each saved as it is done; `files`: the image files of states first - 1 to the
    last one + 1 (None outside the sequence). Returns their summary lines, this worker's address and the
    seconds a state took."""
    store = RunStore(spec.folder).attach()
    home = _home(spec)
    t0 = time.perf_counter()
    lines = [_solve_state(spec, store, home, k, files[i:i + 3]) for i, k in enumerate(range(first, first + len(files) - 2))]
    return lines, worker_address(), (time.perf_counter() - t0) / len(lines)


def _solve_state(spec: RunSpec, store: RunStore, home: _Home, k: int, files: list[tuple[str, str] | None]) -> str:
    """State k, from the carry state k - 1 left; `files`: the image files of states k - 1, k and k + 1.
    Returns its summary."""
    carry, previous, coming = home.take(k)
    if files[2] is not None:   # the next state's pair, prepared while this one is solved
        home.prefetch(k + 1, lambda: _prepare(spec, *files[2]))
    if k == 0:
        run, pair = _reference(spec)
        state, carry = solve_state(run, 0, pair)
    else:
        carry = carry or store.read_carry()
        if carry.state >= k and store.state_path(k).is_file():   # solved already, by a task of an earlier client
            return spec.describe(store.read_state(k))
        if carry.state != k - 1:
            raise ClusterFault(f"{store.states_dir / 'carry.npz'} holds the carry of state {carry.state}, state "
                               f"{k} needs that of state {k - 1} (a task of an earlier run of this folder finished "
                               f"late?); the states done are kept, the same command resumes")
        pair = coming.result() if coming is not None else _prepare(spec, *files[1])
        if previous is None:
            previous = _reference(spec)[1] if k == 1 else _prepare(spec, *files[0])
        state, carry = solve_state(_referenced(spec), k, pair, carry, previous)
    store.write_result(state, carry)
    home.keep(k, carry, pair)
    return spec.describe(state)


def files_task(spec: RunSpec, k: int, csv: bool, vtk: bool, plot_every: int, label: str) -> None:
    """dic-files: state k's rows of dic.csv (with `csv`), VTK file and maps (titled `label`) from its
    state file; the maps' axes from state 0's, once per worker."""
    store = RunStore(spec.folder).attach()
    st = store.read_state(k)
    if csv:
        store.write_rows(k, csv_rows(spec.grid, st))
    axes = None
    if plot_every and k % plot_every == 0:
        axes = per_worker(f"{spec.token}-axes",
                          lambda: surface_axes(spec.grid.xs, spec.grid.ys, store.read_state(0).points,
                                                       spec.grid.active))
    write_state_files(spec.folder, st, vtk=vtk, plot_every=plot_every, axes=axes, label=label)


# ------------------------------------------------------------------------------------- the client

def run_states_on(client, store: RunStore, data: DicStates, spec: RunSpec, *, csv: bool, vtk: bool,
                  plot_every: int, labels: list[str]) -> StereoState:
    """`run.run_states` on the cluster of `client` (module docstring), and each state's own output files
    (its rows of dic.csv with `csv`, `run.write_state_files`; for every state, those done before a
    resume too): solves the states the store (opened by the client) has not finished, records each done
    as it finishes and prints its summary line (`calib.progress.note`) under the same progress bar;
    `labels`: the states' map titles. Returns state 0."""
    n = len(data)
    chain = _Chain(client, store, data)
    if store.done == 0:
        for _ in chain.states(spec, 0, 1):
            pass
    state0 = store.read_state(0)
    note(spec.describe(state0))
    files = _Files(client, spec, csv, vtk, plot_every, labels, range(n) if csv or vtk or plot_every else ())
    for line in progress(chain.states(spec, store.done, n), "dic", total=n, initial=store.done, unit="state"):
        files.feed(threads(client) - 1, chain.others)   # one thread kept for the chain
        note(line)
    files.finish()
    return state0


class _Chain:
    """The solves in order, on the chain's home worker once it has one; short states several to a task."""

    def __init__(self, client, store: RunStore, data: DicStates):
        self.client, self.store, self.data = client, store, data
        self.run = run_id()
        self.home: str | None = None      # the worker that solved the last state
        self.others: list[str] = []       # the workers beside it
        self.per_state = TASK_S           # seconds a state took, on the last task

    def _files(self, j: int) -> tuple[str, str] | None:
        if not 0 <= j < len(self.data):
            return None
        return os.path.abspath(self.data.left[j]), os.path.abspath(self.data.right[j])

    def _solve(self, spec: RunSpec, first: int, stop: int):
        """Submit the solve of state `first` (those before it done) and of the next ones, as many as take
        `TASK_S` (not beyond `stop`), to the home; (the future, the states it solves)."""
        count = max(1, min(MOST_STATES, stop - first, round(TASK_S / max(self.per_state, 1e-3))))
        job = submit(self.client, f"dic-solve-{first}-{self.run}", solve_task, spec, first,
                     [self._files(j) for j in range(first - 1, first + count + 1)], priority=SOLVE,
                     workers=[self.home] if self.home else None)
        return job, range(first, first + count)

    def states(self, spec: RunSpec, start: int, stop: int) -> Iterator[str]:
        """Solve states start to stop - 1 (those before done), recording them done; their summary lines.
        The next solve task is submitted as soon as one has finished, before anything else is done, even
        before its result is fetched from its worker."""
        from distributed import wait
        job, ks = self._solve(spec, start, stop) if start < stop else (None, range(0))
        while job is not None:
            wait(job)
            following = (self._solve(spec, ks.stop, stop) if ks.stop < stop and job.status == "finished" and self.home
                         else None)
            try:
                lines, home, self.per_state = result(job)
            except BaseException:
                self.store.record_saved()   # the states the task finished before it failed are kept
                raise
            if home != self.home:
                self.home, self.others = home, [w for w in self.client.nthreads() if w != home]
            self.store.record_done(ks[-1])
            job, ks = following or (self._solve(spec, ks.stop, stop) if ks.stop < stop else (None, ks))
            yield from lines


class _Files:
    """The dic-files tasks of `states`, run a few at a time while the chain runs (`feed`), then all."""

    def __init__(self, client, spec: RunSpec, csv: bool, vtk: bool, plot_every: int, labels: list[str], states):
        self.client, self.spec, self.labels = client, spec, labels
        self.what = (csv, vtk, plot_every)
        self.queue = collections.deque(states)
        self.run = run_id()
        self.running: list = []

    def feed(self, slots: int, workers: list[str] | None = None) -> None:
        """Submit queued tasks (to `workers`, if given) while fewer than `slots` run (the finished ones
        checked for errors)."""
        for f in [f for f in self.running if f.done()]:
            result(f)
            self.running.remove(f)
        while self.queue and len(self.running) < slots:
            k = self.queue.popleft()
            self.running.append(submit(self.client, f"dic-files-{k}-{self.run}", files_task, self.spec, k,
                                       *self.what, self.labels[k], priority=FILES, workers=workers))

    def finish(self) -> None:
        """Run the rest, all at once, under a "writing" progress bar."""
        from distributed import as_completed
        self.feed(len(self.queue) + len(self.running))
        for f in progress(as_completed(self.running), "writing", total=len(self.running), unit="state"):
            result(f)

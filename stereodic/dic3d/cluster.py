"""A stereo DIC run (`stereodic.dic3d.run`) on a Dask cluster (`stereodic.cluster`): the same run folder,
the same files, byte for byte.

The states form a chain: state k starts from the warps state k - 1 leaves (`StereoCarry`) and tracks its
incremental points from state k - 1's left image, so no two states can be solved at once. What can run
beside the chain is run beside it, as separate tasks:
- dic-prepare k: state k's pair read, rectified and prepared (`run.prepare_pair`), up to `window`
  states ahead of the chain, held in the memory of the worker that made it (Dask moves it to the worker
  that solves state k or k + 1 if that is another one);
- dic-solve k: `solve_state(run, k, pair k, carry, pair k - 1)` where the worker writes its state file
  and the carry after it into the run folder (`RunStore.write_result`), and returns the state's
  summary line; its carry is the one dic-solve k - 1 left in the run folder, exactly what a resumed
  in-process run reads (a state that a task of an earlier, stopped client went on to solve is taken as
  it is: it is what this task would write). The client submits dic-solve k when dic-solve k - 1 has finished and records
  it done in the manifest: a Dask dependency between the solves instead would keep the chain's
  lineage, and a worker lost late in a long run would make Dask solve the whole chain again;
- dic-files k: state k's VTK file and PNG maps from its state file (`run.write_state_files`), queued
  after dic-solve k and run on the threads the chain leaves free (all but one while it runs).
The combined files (dic.csv, dic.npz, DICe's files, the VTK collection) are written by the client from
the state files afterwards, as in-process.

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
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterator

from calib.batch import fingerprint
from calib.progress import note, progress
from stereodic.cluster import ClusterFault, per_worker, result, run_id, submit, threads
from stereodic.dic.grid import Grid
from stereodic.dic.maps import surface_axes
from stereodic.dic3d.dataset import DicStates
from stereodic.dic3d.run import prepare_pair, write_state_files
from stereodic.dic3d.stereo import PreparedPair, StereoRun, StereoSettings, StereoState, solve_state
from stereodic.dic3d.store import RunStore

SOLVE, PREPARE, FILES = 2, 1, 0   # task priorities: the chain first, then what feeds it, then the maps


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
    from stereodic.rig import load_rig
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


def prepare_task(spec: RunSpec, left: str, right: str) -> PreparedPair:
    """dic-prepare: one state's pair (module docstring)."""
    return _prepare(spec, left, right)


def solve_task(spec: RunSpec, k: int, pair: PreparedPair | None, previous: PreparedPair | None) -> str:
    """dic-solve: state k from the carry in the run folder (module docstring); `pair` None for state 0
    and `previous` None for state 1 (the reference pair, this worker's own copy). Returns its summary."""
    store = RunStore(spec.folder).attach()
    if k == 0:
        run, pair0 = _reference(spec)
        state, carry = solve_state(run, 0, pair0)
    else:
        carry = store.read_carry()
        if carry.state >= k and store.state_path(k).is_file():   # solved already, by a task of an earlier client
            return spec.describe(store.read_state(k))
        if carry.state != k - 1:
            raise ClusterFault(f"{store.states_dir / 'carry.npz'} holds the carry of state {carry.state}, state "
                               f"{k} needs that of state {k - 1} (a task of an earlier run of this folder finished "
                               f"late?); the states done are kept, the same command resumes")
        state, carry = solve_state(_referenced(spec), k, pair, carry,
                                   _reference(spec)[1] if previous is None else previous)
    store.write_result(state, carry)
    return spec.describe(state)


def files_task(spec: RunSpec, k: int, vtk: bool, plot_every: int, label: str) -> None:
    """dic-files: state k's VTK file and maps (titled `label`) from its state file; the maps' axes from
    state 0's, once per worker."""
    store = RunStore(spec.folder).attach()
    st = store.read_state(k)
    axes = None
    if plot_every and k % plot_every == 0:
        axes = per_worker(f"{spec.token}-axes",
                          lambda: surface_axes(spec.grid.xs, spec.grid.ys, store.read_state(0).points,
                                                       spec.grid.active))
    write_state_files(spec.folder, st, vtk=vtk, plot_every=plot_every, axes=axes, label=label)


# ------------------------------------------------------------------------------------- the client

def run_states_on(client, store: RunStore, data: DicStates, spec: RunSpec, *, vtk: bool, plot_every: int,
                  labels: list[str]) -> StereoState:
    """`run.run_states` on the cluster of `client` (module docstring), and each state's own output files
    (`run.write_state_files`, for every state, those done before a resume too): solves the states the
    store (opened by the client) has not finished, records each done as it finishes and prints its
    summary line (`calib.progress.note`) under the same progress bar; `labels`: the states' map titles.
    Returns state 0."""
    n = len(data)
    chain = _Chain(client, store, data, spec)
    if store.done == 0:
        for _ in chain.states(0, 1):
            pass
    state0 = store.read_state(0)
    note(spec.describe(state0))
    files = _Files(client, spec, vtk, plot_every, labels, range(n) if vtk or plot_every else ())
    for line in progress(chain.states(store.done, n), "dic", total=n, initial=store.done, unit="state"):
        files.feed(threads(client) - 1)              # one thread kept for the chain
        note(line)
    files.finish()
    return state0


class _Chain:
    """The solves in order, each fed by pairs prepared up to `window` states ahead."""

    def __init__(self, client, store: RunStore, data: DicStates, spec: RunSpec):
        self.client, self.store, self.data, self.spec = client, store, data, spec
        self.run = run_id()
        self.window = max(2, threads(client))
        self.pairs: dict[int, object] = {}

    def _pair(self, j: int):
        if j not in self.pairs:
            self.pairs[j] = submit(self.client, f"dic-prepare-{j}-{self.run}", prepare_task, self.spec,
                                   os.path.abspath(self.data.left[j]), os.path.abspath(self.data.right[j]),
                                   priority=PREPARE)
        return self.pairs[j]

    def _solve(self, k: int):
        """Submit state k's solve (the states before it done), and the pairs to come."""
        pair, previous = (None, None) if k == 0 else (self._pair(k), self._pair(k - 1) if k > 1 else None)
        job = submit(self.client, f"dic-solve-{k}-{self.run}", solve_task, self.spec, k, pair, previous,
                     priority=SOLVE)
        for j in range(max(1, k + 1), min(len(self.data), k + 1 + self.window)):
            self._pair(j)
        return job

    def states(self, start: int, stop: int) -> Iterator[str]:
        """Solve states start to stop - 1 (those before done), recording each done; their summary lines.
        The next solve is submitted as soon as one finishes, before anything else is done."""
        job = self._solve(start) if start < stop else None
        for k in range(start, stop):
            line = result(job)
            job = self._solve(k + 1) if k + 1 < stop else None
            self.pairs.pop(k - 1, None)
            self.store.record_done(k)
            yield line


class _Files:
    """The dic-files tasks of `states`, run a few at a time while the chain runs (`feed`), then all."""

    def __init__(self, client, spec: RunSpec, vtk: bool, plot_every: int, labels: list[str], states):
        self.client, self.spec, self.vtk, self.plot_every, self.labels = client, spec, vtk, plot_every, labels
        self.queue = collections.deque(states)
        self.run = run_id()
        self.running: list = []

    def feed(self, slots: int) -> None:
        """Submit queued tasks while fewer than `slots` run (the finished ones checked for errors)."""
        for f in [f for f in self.running if f.done()]:
            result(f)
            self.running.remove(f)
        while self.queue and len(self.running) < slots:
            k = self.queue.popleft()
            self.running.append(submit(self.client, f"dic-files-{k}-{self.run}", files_task, self.spec, k,
                                       self.vtk, self.plot_every, self.labels[k], priority=FILES))

    def finish(self) -> None:
        """Run the rest, all at once, under a "writing" progress bar."""
        from distributed import as_completed
        self.feed(len(self.queue) + len(self.running))
        for f in progress(as_completed(self.running), "writing", total=len(self.running), unit="state"):
            result(f)

"""A batch of independent tasks (scans, cameras to calibrate) run in this process or on a Dask cluster
(`stereodic.cluster`), each task writing its own output files where it runs, the driving process
recording each one done as it finishes (`calib.batch.BatchRecord`) and skipping those a rerun finds done.

A task is a module-level function and its arguments: file names and numbers, never data (a worker reads
the images, and builds what the tasks share - a rig - once: `stereodic.cluster.per_worker`). It returns
`Done`: the files it wrote, with a summary each, and its warnings; the driver yields them in the order
the tasks finish (in-process: the order given), under a progress bar.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator

from calib.batch import BatchRecord
from calib.progress import progress


@dataclass
class Done:
    """What a task did: outputs [(file, summary)], warnings (lines for the user)."""

    outputs: list[tuple[Path, str]]
    warnings: list[str] = field(default_factory=list)


@dataclass(frozen=True)
class Task:
    """One task: `name` (its entry in the record, unique in the batch), `inputs` (what its outputs
    depend on besides the batch's settings: fingerprints of its files), `args` (of the batch's
    function)."""

    name: str
    inputs: dict
    args: tuple


def run_batch(fn: Callable[..., Done], tasks: list[Task], record: BatchRecord | None, *, scheduler: str | None,
              desc: str, unit: str) -> Iterator[tuple[Task, Done]]:
    """fn(*task.args) for every task the record does not have done (all without a record), in this
    process (`scheduler` None) or on the cluster `scheduler` names; yields (task, Done) as each
    finishes, after recording it."""
    todo = [t for t in tasks if record is None or not record.done(t.name, t.inputs)]
    if scheduler is None:
        for t in progress(todo, desc, total=len(tasks), initial=len(tasks) - len(todo), unit=unit):
            yield t, _finished(record, t, fn(*t.args))
        return
    from distributed import as_completed

    from stereodic.cluster import connect, result, run_id, submit
    run = run_id()
    with connect(scheduler) as client:
        jobs = {submit(client, f"{desc}-{i}-{run}", fn, *t.args): t for i, t in enumerate(todo)}
        for f in progress(as_completed(jobs), desc, total=len(tasks), initial=len(tasks) - len(todo), unit=unit):
            yield jobs[f], _finished(record, jobs[f], result(f))


def _finished(record: BatchRecord | None, task: Task, done: Done) -> Done:
    if record is not None:
        record.record(task.name, task.inputs, [p for p, _ in done.outputs])
    return done

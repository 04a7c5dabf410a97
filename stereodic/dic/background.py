"""Work beside the caller: the threads a run may use (`threads`), work that releases the GIL (OpenCV,
numpy, the compiled kernels) spread over them (`thread_map`, `side_by_side`), and output work off the
critical path in forked child processes (`Background`).

Every pool here keeps to `threads()` busy threads, the caller's included, so that a run at
OMP_NUM_THREADS=1 uses one core (the command line passes the same limit to OpenCV's and numba's own
pools: `stereodic.cli.thread_limits`).

Formatting a CSV, drawing PNG maps with matplotlib and writing VTK files are Python work that holds the
interpreter's lock, so threads would not overlap them; forked processes do, each with a copy-on-write view
of the caller's arrays (nothing is pickled). `Background` keeps at most `workers` children running; when all
are busy the next task waits for the first child to finish, so that no task waits behind a long one while
a slot is free (the caller only hands out the tasks: give it `threads()` workers when it has nothing else
to do, `threads() - 1` beside work of its own). A task is a callable without arguments that writes its own
files (atomically, as every output); it returns nothing to the caller.

The children only format and write: they run no OpenMP kernel (a forked child of a process whose OpenMP
threads have run must not start its own), and leave by os._exit (multiprocessing's fork start), so the
caller's buffers and exit handlers are not run twice.
"""

from __future__ import annotations

import multiprocessing
import multiprocessing.connection
import os
from concurrent.futures import ThreadPoolExecutor
from typing import Callable, Iterable, TypeVar

T = TypeVar("T")


def threads() -> int:
    """The threads the run may use: OMP_NUM_THREADS if set, else the CPUs this process may run on."""
    try:
        return max(1, int(os.environ.get("OMP_NUM_THREADS", "")))
    except ValueError:
        return max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1)


def thread_map(func: Callable[..., T], items: Iterable) -> list[T]:
    """[func(item) for item in items], in order, on `threads()` threads (the caller waits; with one
    thread the caller runs them)."""
    n = threads()
    if n < 2:
        return [func(item) for item in items]
    with ThreadPoolExecutor(n) as pool:
        return list(pool.map(func, items))


def side_by_side(*tasks: Callable[[], T]) -> list[T]:
    """The results of `tasks` (callables without arguments), in order: the caller runs the first, at
    most `threads()` - 1 pool threads the others meanwhile (with one thread, the caller runs them all)."""
    n = min(threads(), len(tasks))
    if n < 2:
        return [task() for task in tasks]
    with ThreadPoolExecutor(n - 1) as pool:
        later = [pool.submit(task) for task in tasks[1:]]
        return [tasks[0]()] + [f.result() for f in later]


_BEFORE_FORK: list = []  # futures of threads that import modules: finished before any fork (`finish_before_fork`)


def finish_before_fork(future) -> None:
    """Make the next fork of this process (`Background.submit`) wait for `future` (a
    concurrent.futures.Future; its error, if any, ignored). A thread that imports modules holds import
    locks, which a child forked meanwhile would inherit held and never see released: the child would hang
    on its first import of such a module."""
    _BEFORE_FORK.append(future)


class Background:
    """Run tasks in at most `workers` forked children (module docstring), a task waiting for a free one;
    0 workers: every task in the caller, in order. Used as a context manager, which waits for every child
    on leaving; a child that failed raises RuntimeError then (its traceback went to stderr)."""

    def __init__(self, workers: int):
        self.workers = workers if hasattr(os, "fork") else 0
        self.running: list[tuple[str, multiprocessing.Process]] = []
        self.failed: list[str] = []

    def __enter__(self) -> "Background":
        return self

    def __exit__(self, *exc) -> None:
        self.wait()

    def _reap(self) -> None:
        still = []
        for name, proc in self.running:
            if proc.exitcode is None:
                still.append((name, proc))
            else:
                proc.join()
                if proc.exitcode != 0:
                    self.failed.append(name)
        self.running = still

    def submit(self, task: Callable[[], object], name: str) -> multiprocessing.Process | None:
        """Run `task` (named `name` in errors) in a new child once fewer than `workers` are running (with 0
        workers, here and now: None). Returns the child, for `wait_for`."""
        if self.workers == 0:
            task()
            return None
        self._reap()
        while len(self.running) >= self.workers:
            multiprocessing.connection.wait([proc.sentinel for _, proc in self.running])
            self._reap()
        while _BEFORE_FORK:
            _BEFORE_FORK.pop().exception()       # waits; the thread's own error is not this task's
        proc = multiprocessing.get_context("fork").Process(target=task, name=name, daemon=True)
        proc.start()
        self.running.append((name, proc))
        return proc

    def wait_for(self, children: Iterable[multiprocessing.Process | None]) -> None:
        """Wait for these children (`submit`'s; None: a task already run here) while the others go on; a
        failed one is reported when the context is left, with the others (`wait`)."""
        for proc in children:
            if proc is not None:
                proc.join()
        self._reap()

    def wait(self) -> None:
        """Wait for every child; RuntimeError naming the tasks that failed."""
        for _, proc in self.running:
            proc.join()
        self._reap()
        if self.failed:
            failed, self.failed = self.failed, []
            raise RuntimeError(f"writing {', '.join(failed)} failed (the error is above)")

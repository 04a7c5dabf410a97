"""Work beside the caller: the threads a run may use (`threads`), work that releases the GIL (OpenCV,
numpy, the compiled kernels) spread over them (`thread_map`, `side_by_side`), and output work off the
critical path in worker processes (`Background`).

Every pool here keeps to `threads()` busy threads, the caller's included, so that a run at
OMP_NUM_THREADS=1 uses one core (the command line passes the same limit to OpenCV's and numba's own
pools: `stereodic.cli.thread_limits`).

Formatting a CSV, drawing PNG maps with matplotlib and writing VTK files are Python work that holds the
interpreter's lock, so threads would not overlap them; processes do. `Background` forks its `workers`
processes once, when it is made: a command makes it early, while it is small and runs one thread, and
hands it the run's output tasks. A child forked per task from the grown, many-threaded run costs more
than its task's share: the copy of the run's page tables, a copy-on-write fault for every page either
side then writes, the other threads' CPUs told of every page made read-only (an interrupt between
processors, an exit from a virtual machine), the child's exit, and a fresh start of matplotlib's fonts and
figures in every child (on a 12-state 1920 x 1200 sequence on 2 threads, 3.3 CPU-s over one thread's run,
about half of it this). The workers keep their memory, fonts and figures from task to task.

A task is a picklable callable without arguments (a module-level function, or `functools.partial` of one
with picklable arguments) that writes its own files (atomically, as every output) and returns nothing to
the caller; what it needs of the run it reads from the run's files (a state from the run folder), not
from the caller's memory. `Background` keeps at most `workers` tasks running (`limit` fewer, beside work of
the caller's own) and the caller only hands them out: give it `threads()` workers when it has nothing
else to do. The workers run at a lower priority than the caller (`WORKER_NICE`): beside a run's
correlation they take the time its serial parts leave idle rather than slow it (the bench pair on 2
threads 4.27-4.35 -> 4.14-4.21 s, the 12-state sequence 6.87 -> 6.55 s, medians of 3-6 rounds in turn);
on a machine busy with other work they yield to it too.

The workers only format and write: they run no OpenMP kernel (a process forked from one whose OpenMP
threads have run must not start its own), and leave by os._exit (multiprocessing's fork start), so the
caller's buffers and exit handlers are not run twice.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import sys
import threading
import time
import traceback
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, ThreadPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
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


class Background:
    """Run tasks in `workers` processes forked now (module docstring); 0 workers: every task in the
    caller, when it is submitted. `prepare`, if given, runs first in each worker (e.g. imports its tasks
    will need, beside the caller's work). Used as a context manager, which waits for every task on leaving
    and ends the workers; a task that failed raises RuntimeError then (its traceback went to stderr), as
    does one whose worker died (killed: out of memory?), then or when the next task is submitted."""

    def __init__(self, workers: int, *, prepare: Callable[[], None] | None = None):
        self.workers = workers if hasattr(os, "fork") else 0
        self.running: list[tuple[str, Future]] = []
        self.failed: list[str] = []
        self._pool = None
        if self.workers:
            self._pool = ProcessPoolExecutor(self.workers, mp_context=multiprocessing.get_context("fork"),
                                             initializer=_start_worker, initargs=(os.getpid(), prepare))
            self._pool.submit(_nothing)              # a fork pool starts all of its workers at the first task

    def __enter__(self) -> "Background":
        return self

    def __exit__(self, kind, *exc) -> None:
        if kind is None:
            self.wait()
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=kind is not None)

    def _reap(self) -> None:
        still = []
        for name, future in self.running:
            if not future.done():
                still.append((name, future))
            elif isinstance(future.exception(), BrokenProcessPool):
                self.failed.append(f"{name} (a worker process died: out of memory?)")
            elif future.exception() is not None:
                self.failed.append(f"{name} (the error is above)")
        self.running = still

    def submit(self, task: Callable[[], object], name: str, *, limit: int | None = None) -> Future | None:
        """Run `task` (named `name` in errors) in a worker once fewer than `limit` (default: `workers`) of
        the tasks submitted are unfinished (with 0 workers, here and now: None). Returns its future, for
        `wait_for`."""
        if self._pool is None:
            task()
            return None
        self._reap()
        while len(self.running) >= min(limit or self.workers, self.workers):
            wait([future for _, future in self.running], return_when=FIRST_COMPLETED)
            self._reap()
        try:
            future = self._pool.submit(_run_task, task, name)
        except BrokenProcessPool:
            self.wait()                                  # names the task whose worker died
            raise
        self.running.append((name, future))
        return future

    def wait_for(self, futures: Iterable[Future | None]) -> None:
        """Wait for these tasks (`submit`'s; None: a task already run here) while the others go on; a
        failed one is reported when the context is left, with the others (`wait`)."""
        wait([future for future in futures if future is not None])
        self._reap()

    def wait(self) -> None:
        """Wait for every task; RuntimeError naming the tasks that failed."""
        self.wait_for(future for _, future in self.running)
        if self.failed:
            failed, self.failed = self.failed, []
            raise RuntimeError(f"writing {'; '.join(failed)} failed")


WORKER_NICE = 10   # how much lower the workers' scheduling priority is than the caller's (`nice`)


def _start_worker(caller: int, prepare: Callable[[], None] | None) -> None:
    """A worker's start: Ctrl-C is the caller's to handle (it ends the workers); the worker leaves when
    its caller (process id `caller`) is gone (`_follow`); a lower priority (WORKER_NICE), so that the
    output work yields the cores to the caller's (its correlation, the critical path) and takes what the
    caller leaves idle; then `prepare`."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    threading.Thread(target=_follow, args=(caller,), daemon=True).start()
    os.nice(WORKER_NICE)
    if prepare is not None:
        prepare()


def _follow(caller: int) -> None:
    """Leave this worker once its caller is gone (killed: a worker waiting for the next task would wait
    forever, as it holds the task queue's other end itself), checked twice a second."""
    while os.getppid() == caller:
        time.sleep(0.5)
    os._exit(1)


def _nothing() -> None:
    """The task that starts a fork pool's workers."""


def _run_task(task: Callable[[], object], name: str) -> None:
    """`task` in a worker, its traceback on stderr if it fails (the caller names the task)."""
    try:
        task()
    except BaseException:
        print(f"stereodic: writing {name} failed:\n{traceback.format_exc()}", file=sys.stderr, flush=True)
        raise

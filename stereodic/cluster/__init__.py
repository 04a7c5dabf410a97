"""Work on a Dask cluster (`--scheduler ADDRESS|local[:N]`): the connection, the per-worker copy of a run's
data, task submission, and a task's failure turned into the command's one-line errors.

- `connect(spec)`: "local" or "local:N" starts a cluster of N worker processes on this machine (loopback
  only; N defaults to the number of cores), each with one task thread and as many OpenMP threads as
  the machine has cores (the DIC kernels' threads; Dask's own default would be one); anything else is
  the address of a running `dask scheduler` (tcp://HOST:8786), which must answer within
  CONNECT_TIMEOUT_S and have a worker. A scheduler that does not answer is an `InputError` naming the
  option (exit status 2).
- `per_worker(key, build)`: the per-run data (a rig, a reference image's B-spline) built once in each
  worker process from shared storage and kept there, so that a task carries only file names and
  numbers (never the data itself), whichever worker it lands on, and a worker that replaces a dead one
  builds its own copy.
- `submit(client, name, fn, *args)`: a task named `name` (`run_id`), run through `call`, which turns an error of the task's input on the
  worker (an `InputError`, or an `OSError` such as an image the worker cannot read) into an `InputError`
  naming the file and the worker.
- `result(future)`: the task's result; a task whose workers kept dying (Dask retries a task elsewhere
  when its worker dies, up to `distributed.scheduler.allowed-failures` times) or a cluster gone away is
  a `ClusterFault` (exit status 1); what earlier tasks wrote stays on disk.

Dask is imported here only inside these functions: a command without --scheduler never loads it.
"""

from __future__ import annotations

import contextlib
import os
import pickle
import threading
from collections import OrderedDict
from typing import Callable, Iterator, TypeVar

from calib.errors import InputError

T = TypeVar("T")

LOCAL = "local"
CONNECT_TIMEOUT_S = 10.0     # a scheduler that has not answered by then is taken as not there
WORKER_TIMEOUT_S = 30.0      # a scheduler with no worker after this long cannot run anything
KEEP = 4                     # per-run data kept per worker (the runs last used)


class ClusterFault(RuntimeError):
    """The cluster failed during the run (workers died again and again, the scheduler went away)."""


def parse(spec: str) -> tuple[str | None, int]:
    """(address, 0) for a scheduler address, (None, workers) for local[:N]; InputError naming --scheduler
    for a malformed value."""
    text = spec.strip()
    if text == LOCAL or text.startswith(LOCAL + ":"):
        count = text[len(LOCAL) + 1:]
        if not count:
            return None, os.cpu_count() or 1
        if not count.isdigit() or int(count) < 1:
            raise InputError("--scheduler", f"expected local or local:N with N >= 1 workers, got {spec!r}")
        return None, int(count)
    if not text or any(c.isspace() for c in text):
        raise InputError("--scheduler", f"expected a scheduler address (tcp://HOST:PORT) or local[:N], got {spec!r}")
    return (text if "://" in text else f"tcp://{text}"), 0


@contextlib.contextmanager
def connect(spec: str) -> Iterator:
    """A `distributed.Client` of the cluster `spec` names (module docstring); the local cluster it
    started, if any, is shut down on leaving."""
    address, workers = parse(spec)
    from distributed import Client
    with contextlib.ExitStack() as stack:
        if address is None:
            client = stack.enter_context(Client(stack.enter_context(local_cluster(workers))))
        else:
            try:
                client = stack.enter_context(Client(address, timeout=CONNECT_TIMEOUT_S))
            except (OSError, TimeoutError) as exc:
                raise InputError("--scheduler", f"no Dask scheduler answers at {address} "
                                                f"({type(exc).__name__}: {exc})") from None
            try:
                client.wait_for_workers(1, timeout=WORKER_TIMEOUT_S)
            except (OSError, TimeoutError):
                raise InputError("--scheduler", f"the Dask scheduler at {address} has no worker "
                                                f"(none joined within {WORKER_TIMEOUT_S:g} s)") from None
        yield client


@contextlib.contextmanager
def local_cluster(workers: int) -> Iterator:
    """A `distributed.LocalCluster` of `workers` processes on the loopback interface (module docstring)."""
    import logging

    import dask
    from distributed import LocalCluster
    omp = str(os.environ.get("OMP_NUM_THREADS") or os.cpu_count() or 1)
    with dask.config.set({"distributed.nanny.pre-spawn-environ.OMP_NUM_THREADS": omp}):
        with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                          dashboard_address=None, silence_logs=logging.ERROR,
                          # no dashboard; its HTTP server (health routes) on a free port, not 8787
                          scheduler_kwargs={"dashboard_address": "127.0.0.1:0"}) as cluster:
            yield cluster


def threads(client) -> int:
    """The cluster's task threads, all workers together."""
    return max(1, sum(client.nthreads().values()))


_cache: OrderedDict = OrderedDict()
_lock = threading.Lock()
_building: dict[str, threading.Lock] = {}


def per_worker(key: str, build: Callable[[], T]) -> T:
    """This process's copy of the data `key` names, built by `build()` the first time it is asked for
    (one build at a time per key, whatever the worker's threads), the KEEP last used kept."""
    with _lock:
        if key in _cache:
            _cache.move_to_end(key)
            return _cache[key]
        gate = _building.setdefault(key, threading.Lock())
    with gate:
        with _lock:
            if key in _cache:
                return _cache[key]
        value = build()
        with _lock:
            _cache[key] = value
            while len(_cache) > KEEP:
                _cache.popitem(last=False)
            _building.pop(key, None)
        return value


def call(fn: Callable, *args):
    """`fn(*args)` on a worker, its input errors naming the worker (module docstring)."""
    try:
        return fn(*args)
    except InputError as exc:
        raise InputError(exc.where, f"{exc.problem} (on Dask worker {worker_address()})") from None
    except OSError as exc:
        where = exc.filename if exc.filename is not None else None
        raise InputError(where, f"{exc.strerror or exc} (on Dask worker {worker_address()}: is it on storage "
                                f"that every worker sees?)") from None


def worker_address() -> str:
    """The address of the Dask worker this task runs on."""
    from distributed import get_worker
    try:
        return get_worker().address
    except ValueError:
        return "(none: not on a worker)"


class Traffic:
    """While `counting` (for `stereodic bench`): tasks submitted, bytes of their arguments and of the
    results the client takes, as pickled for the wire (data that Dask moves between workers is counted
    by the workers themselves: `transfer_outgoing_bytes_total`)."""

    def __init__(self):
        self.tasks = 0
        self.bytes = 0
        self.results = 0


_traffic: list[Traffic] = []


@contextlib.contextmanager
def counting() -> Iterator[Traffic]:
    """Count what `submit` sends while the block runs."""
    t = Traffic()
    _traffic.append(t)
    try:
        yield t
    finally:
        _traffic.remove(t)


def run_id() -> str:
    """8 hex digits that make a run's task names its own on a shared scheduler (Dask's statistics group
    the tasks by the words before it: "dic-solve-12-3fa4b2c1" is a "dic-solve")."""
    import uuid
    return uuid.uuid4().hex[:8]


def submit(client, name: str, fn: Callable, *args, priority: int = 0, workers: list[str] | None = None):
    """The task fn(*args) on the cluster (through `call`), keyed `name` (unique: ending in a `run_id`);
    futures among `args` are its dependencies. `workers`: the addresses it should run on (another
    worker takes it if none of them can)."""
    for t in _traffic:
        import cloudpickle
        from distributed import Future
        t.tasks += 1
        t.bytes += len(cloudpickle.dumps((fn, [a for a in args if not isinstance(a, Future)]),
                                         protocol=pickle.HIGHEST_PROTOCOL))
    return client.submit(call, fn, *args, key=name, pure=False, priority=priority, workers=workers or None,
                         allow_other_workers=bool(workers))


def result(future):
    """The task's result; `ClusterFault` for a task that could not be run (module docstring)."""
    from distributed import KilledWorker
    from distributed.comm import CommClosedError
    try:
        value = future.result()
        for t in _traffic:
            import cloudpickle
            t.results += len(cloudpickle.dumps(value, protocol=pickle.HIGHEST_PROTOCOL))
        return value
    except KilledWorker as exc:
        raise ClusterFault(f"task {future.key} was running on workers that died, again and again: "
                           f"{exc}; the results so far are kept, the same command resumes") from None
    except (CommClosedError, OSError, TimeoutError) as exc:
        raise ClusterFault(f"lost the Dask cluster during task {future.key} ({type(exc).__name__}: {exc}); "
                           f"the results so far are kept, the same command resumes") from None

"""Work beside the caller (`stereodic.dic.background`): output work in worker processes, forked when the
Background is made, writes the files the caller would, and a task that fails is reported by name; the
thread pools keep to the run's threads, and so do OpenCV's and numba's own (`stereodic.cli.thread_limits`)."""

import functools
import operator
import os
import signal
import subprocess
import sys
import threading
import time

import pytest

from stereodic.dic.background import Background, side_by_side, thread_map, threads


def _write(path, text, seconds=0.0):
    time.sleep(seconds)
    path.write_text(f"{text} from {os.getpid()}")


def _write_started(path, seconds=0.0):
    """`_write` of the time the task started."""
    _write(path, repr(time.time()), seconds)


_MARK = "imported"


def _set_mark(text):
    global _MARK
    _MARK = text


def _write_mark(path):
    path.write_text(_MARK)


def _fail():
    raise OSError("disk full")


def test_tasks_run_in_the_workers_and_none_waits_behind_a_long_one(tmp_path):
    with Background(2) as bg:
        for k in range(4):
            bg.submit(functools.partial(_write, tmp_path / f"{k}.txt", f"{k} {time.time()!r}", 1.0 if k == 0 else 0.0),
                      f"file {k}")
    texts = [(tmp_path / f"{k}.txt").read_text() for k in range(4)]
    assert [t.split()[0] for t in texts] == ["0", "1", "2", "3"]
    pids = {int(t.split(" from ")[1]) for t in texts}
    assert os.getpid() not in pids and len(pids) == 2     # two workers for four tasks; the caller hands out
    # files 1-3 were written in the free worker while file 0's slept, not after it
    assert all(float(t.split()[1]) < os.path.getmtime(tmp_path / "0.txt") - 0.5 for t in texts[1:])


def test_the_workers_are_forked_when_it_is_made_and_prepared(tmp_path):
    """The workers are copies of the caller as it was when the Background was made (a command makes it
    early, while it is small): what the caller changes later is not in them; `prepare` ran in each."""
    _set_mark("before")
    try:
        with Background(2) as bg:
            _set_mark("after")
            bg.wait_for([bg.submit(functools.partial(_write_mark, tmp_path / "plain.txt"), "plain")])
        with Background(1, prepare=functools.partial(_set_mark, "prepared")) as bg:
            bg.submit(functools.partial(_write_mark, tmp_path / "prepared.txt"), "prepared")
    finally:
        _set_mark("imported")
    assert (tmp_path / "plain.txt").read_text() == "before"
    assert (tmp_path / "prepared.txt").read_text() == "prepared"


def _write_niceness(path):
    path.write_text(str(os.getpriority(os.PRIO_PROCESS, 0)))


def test_the_workers_yield_to_the_caller(tmp_path):
    """The workers run at a lower priority than the caller (WORKER_NICE higher a nice value, capped at
    19), so that a run's output work takes the cores its correlation leaves idle."""
    from stereodic.dic.background import WORKER_NICE

    with Background(1) as bg:
        bg.submit(functools.partial(_write_niceness, tmp_path / "nice.txt"), "nice")
    mine = os.getpriority(os.PRIO_PROCESS, 0)
    assert int((tmp_path / "nice.txt").read_text()) == min(mine + WORKER_NICE, 19) > mine or mine == 19


def test_the_caller_waits_for_some_tasks_while_the_others_go_on(tmp_path):
    with Background(2) as bg:
        slow = bg.submit(functools.partial(_write, tmp_path / "slow.txt", "slow", 1.0), "slow")
        quick = bg.submit(functools.partial(_write, tmp_path / "quick.txt", "quick", 0.1), "quick")
        bg.wait_for([quick, None])
        assert (tmp_path / "quick.txt").is_file() and not (tmp_path / "slow.txt").exists()
        assert not slow.done()                          # still running
    assert (tmp_path / "slow.txt").is_file()            # leaving the context waited for it
    with pytest.raises(RuntimeError, match="broken"):   # a failure among those waited for: named at the end
        with Background(1) as bg:
            bg.wait_for([bg.submit(functools.partial(operator.truediv, 1, 0), "broken")])


def test_a_limit_keeps_workers_free_for_the_callers_own_work(tmp_path):
    """With `limit` 1 of 2 workers (a run's state files beside its next state), a task waits for the one
    running: one worker stays free."""
    with Background(2) as bg:
        bg.submit(functools.partial(_write, tmp_path / "first.txt", "first", 0.6), "first", limit=1)
        bg.submit(functools.partial(_write_started, tmp_path / "second.txt"), "second", limit=1)
    started = float((tmp_path / "second.txt").read_text().split(" from ")[0])
    assert started >= os.path.getmtime(tmp_path / "first.txt") - 0.05


def test_one_worker_runs_the_tasks_one_after_the_other(tmp_path):
    with Background(1) as bg:
        for k in range(3):
            bg.submit(functools.partial(_write, tmp_path / f"{k}.txt", k, 0.2), f"file {k}")
    times = [os.path.getmtime(tmp_path / f"{k}.txt") for k in range(3)]
    assert times == sorted(times) and times[2] - times[0] >= 0.35   # each waited for the one before


def test_no_workers_runs_everything_here(tmp_path):
    with Background(0) as bg:
        bg.submit(lambda: _write(tmp_path / "a.txt", "a"), "a")
    assert (tmp_path / "a.txt").read_text() == f"a from {os.getpid()}"


def test_a_failed_task_is_named(tmp_path, capfd):
    with pytest.raises(RuntimeError, match="the maps of state 3"):
        with Background(1) as bg:
            bg.submit(_fail, "the maps of state 3")
    assert "disk full" in capfd.readouterr().err       # the worker's traceback


def _die():
    os.kill(os.getpid(), signal.SIGKILL)


def test_a_task_whose_worker_dies_is_named(tmp_path):
    """A worker killed in a task (the kernel's out-of-memory killer) is named with the task, when the
    next task is handed out or at the end: not a bare BrokenProcessPool."""
    with pytest.raises(RuntimeError, match=r"the maps of state 3 \(a worker process died"):
        with Background(2) as bg:
            bg.wait_for([bg.submit(_die, "the maps of state 3")])
            bg.submit(functools.partial(_write, tmp_path / "next.txt", "next"), "the next file")


def test_the_workers_leave_when_the_caller_is_killed(tmp_path):
    """A caller killed half way (SIGKILL: no shutdown) leaves no worker behind: each follows its caller and
    leaves within a second."""
    code = ("import functools, os, sys, time\n"
            "from stereodic.dic.background import Background\n"
            "bg = Background(2)\n"
            "bg.submit(functools.partial(time.sleep, 60), 'a long task')\n"
            "print(' '.join(str(p) for p in bg._pool._processes), flush=True)\n"
            "time.sleep(60)\n")
    caller = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    workers = [int(p) for p in caller.stdout.readline().split()]
    assert len(workers) == 2 and all(_alive(p) for p in workers)
    caller.kill()
    caller.wait()
    deadline = time.time() + 5
    while any(_alive(p) for p in workers) and time.time() < deadline:
        time.sleep(0.1)
    left = [p for p in workers if _alive(p)]
    for p in left:                              # none left behind by the test either
        os.kill(p, signal.SIGKILL)
    assert not left


def _alive(pid):
    """Whether process `pid` runs (not a zombie: its parent, init, reaps it)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(") ")[1][0] != "Z"
    except FileNotFoundError:
        return False


def test_threads_follow_omp_num_threads(monkeypatch):
    monkeypatch.setenv("OMP_NUM_THREADS", "3")
    assert threads() == 3
    monkeypatch.delenv("OMP_NUM_THREADS")
    assert threads() == len(os.sched_getaffinity(0))


def test_thread_pools_keep_to_the_runs_threads(monkeypatch):
    def square(x):
        seen.add(threading.get_ident())
        time.sleep(0.02)
        return x * x

    for n, most in (("2", 2), ("1", 1)):
        monkeypatch.setenv("OMP_NUM_THREADS", n)
        seen = set()
        assert thread_map(square, range(8)) == [x * x for x in range(8)]
        assert 1 <= len(seen) <= most
    assert seen == {threading.get_ident()}       # one thread: the caller's
    monkeypatch.setenv("OMP_NUM_THREADS", "2")
    me = threading.get_ident()
    first, second, third = side_by_side(threading.get_ident, threading.get_ident, threading.get_ident)
    assert first == me and second == third != me  # the caller runs the first, one pool thread the others


def test_one_thread_is_one_core_in_opencv_and_numba():
    code = ("from stereodic.cli import thread_limits; thread_limits(); import cv2, numba; "
            "print(cv2.getNumThreads(), numba.config.NUMBA_NUM_THREADS)")
    env = {k: v for k, v in os.environ.items() if k not in ("OPENCV_FOR_THREADS_NUM", "NUMBA_NUM_THREADS")}
    out = subprocess.run([sys.executable, "-c", code], env={**env, "OMP_NUM_THREADS": "1"}, capture_output=True,
                         text=True, timeout=120)
    assert out.stdout.split() == ["1", "1"], out.stderr


@pytest.mark.parametrize("command, blas", [("dic", 1), ("dic2d", 1), ("calibrate", 2)])
def test_the_dic_commands_keep_numpys_blas_to_one_thread(command, blas):
    """Asked for 2 threads, numpy's OpenBLAS (its own library, asked through ctypes) has one under the DIC
    commands, whose parallel work is their own kernels, and 2 under the others."""
    code = ("import ctypes, glob, os, sys\n"
            "from stereodic.cli import thread_limits\n"
            f"thread_limits({command!r})\n"
            "import numpy\n"
            "lib = ctypes.CDLL(glob.glob(os.path.dirname(numpy.__file__) + '.libs/*openblas*')[0])\n"
            "get = next(getattr(lib, n) for n in ('scipy_openblas_get_num_threads64_', 'openblas_get_num_threads64_',\n"
            "                                     'openblas_get_num_threads') if hasattr(lib, n))\n"
            "print(get())\n")
    env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS",)}
    out = subprocess.run([sys.executable, "-c", code], env={**env, "OMP_NUM_THREADS": "2"}, capture_output=True,
                         text=True, timeout=120)
    assert out.stdout.split() == [str(blas)], out.stderr[-500:]


def test_a_command_after_numba_started_keeps_its_pool_and_limits_its_threads(tmp_path):
    """numba loaded and its pool running before a command is told OMP_NUM_THREADS=1 (a notebook, a test
    session): numba compiles afresh afterwards (an empty cache) without the 'Cannot set
    NUMBA_NUM_THREADS' failure that changing its pool's size gave, and the caller uses one thread."""
    code = ("import os, numpy, numba\n"
            "numba.njit(parallel=True)(lambda a: a.sum())(numpy.ones(4))\n"
            "os.environ['OMP_NUM_THREADS'] = '1'\n"
            "from stereodic.cli import thread_limits\n"
            "thread_limits()\n"
            "print(numba.get_num_threads(), numba.njit(parallel=True, cache=True)(lambda a: 2 * a)(numpy.ones(3)).sum())\n")
    env = {k: v for k, v in os.environ.items() if k not in ("OPENCV_FOR_THREADS_NUM", "NUMBA_NUM_THREADS",
                                                             "OMP_NUM_THREADS")}
    script = tmp_path / "after_numba.py"
    script.write_text(code)
    out = subprocess.run([sys.executable, str(script)], env={**env, "NUMBA_CACHE_DIR": str(tmp_path / "cache")},
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0 and out.stdout.split() == ["1", "6.0"], out.stderr[-500:]

"""Output work in forked children (`stereodic.dic.background`): the files are those written in the caller,
and a task that fails is reported by name."""

import os
import time

import pytest

from stereodic.dic.background import Background, threads


def _write(path, text, seconds=0.0):
    time.sleep(seconds)
    path.write_text(f"{text} from {os.getpid()}")


def test_tasks_run_beside_the_caller_and_write_their_files(tmp_path):
    with Background(1) as bg:
        for k in range(4):
            bg.submit(lambda k=k: _write(tmp_path / f"{k}.txt", k, 0.5 if k == 0 else 0.0), f"file {k}")
    texts = [(tmp_path / f"{k}.txt").read_text() for k in range(4)]
    assert [t.split(" from ")[0] for t in texts] == ["0", "1", "2", "3"]
    pids = {int(t.split(" from ")[1]) for t in texts}
    assert os.getpid() in pids and len(pids) >= 2      # the child was busy with file 0: the caller did 1


def test_no_workers_runs_everything_here(tmp_path):
    with Background(0) as bg:
        bg.submit(lambda: _write(tmp_path / "a.txt", "a"), "a")
    assert (tmp_path / "a.txt").read_text() == f"a from {os.getpid()}"


def test_a_failed_child_is_named(tmp_path):
    def fail():
        raise OSError("disk full")

    with pytest.raises(RuntimeError, match="the maps of state 3"):
        with Background(1) as bg:
            bg.submit(fail, "the maps of state 3")


def test_threads_follow_omp_num_threads(monkeypatch):
    monkeypatch.setenv("OMP_NUM_THREADS", "3")
    assert threads() == 3
    monkeypatch.delenv("OMP_NUM_THREADS")
    assert threads() == len(os.sched_getaffinity(0))

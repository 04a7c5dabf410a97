"""`stereodic dic --scheduler` on a Dask cluster of worker processes on loopback: the run folder and every
output file byte-identical to the in-process run's (direct and incremental correlation), a worker killed
while it runs a task changes nothing, an interrupted run resumes (on the cluster or in-process), and a
scheduler that does not answer or an image a worker cannot read stops with one line."""

import json
import os
import signal
import threading
import time
from pathlib import Path

import pytest

from stereodic.cli import main

OPTS = ["--step", "12", "--plot-every", "2"]


def _files(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def _differing(a: Path, b: Path) -> list[str]:
    fa, fb = _files(a), _files(b)
    assert len(fa) >= 2 and fa.keys() == fb.keys()
    return [k for k in fa if fa[k] != fb[k]]


def _args(dic_sim, out, *extra):
    return ["dic", str(dic_sim / "rig.npz"), str(dic_sim), *OPTS, *extra, "-o", str(out)]


class _InProcess(dict):
    """The in-process runs, each made when first asked for: "direct", "incremental"."""

    def __init__(self, dic_sim, factory):
        super().__init__()
        self.dic_sim, self.factory = dic_sim, factory

    def __missing__(self, name):
        out = self.factory.mktemp(name) / "out"
        assert main(_args(self.dic_sim, out, *(["--incremental"] if name == "incremental" else []))) == 0
        self[name] = out
        return out


@pytest.fixture(scope="module")
def in_process(dic_sim, tmp_path_factory):
    return _InProcess(dic_sim, tmp_path_factory)


@pytest.mark.parametrize("name,extra", [("direct", []),
                                        pytest.param("incremental", ["--incremental"], marks=pytest.mark.slow)])
def test_the_cluster_run_writes_the_same_bytes(dic_sim, dask_cluster, in_process, tmp_path, capsys, name, extra):
    capsys.readouterr()
    assert main(_args(dic_sim, tmp_path / "out", *extra, "--scheduler", dask_cluster.scheduler_address)) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [ln.split(":")[0] for ln in lines if ln.startswith("state ")] == ["state 0", "state 1", "state 2"]
    assert _differing(in_process[name], tmp_path / "out") == []


def test_the_chain_stays_on_one_worker_and_the_maps_run_beside_it(dic_sim, dask_cluster, in_process, tmp_path):
    """Every solve on the worker that solved state 0 (its carry and pairs kept there, none moved between
    workers); the states' files (rows, maps) on the other one while the chain runs."""
    from distributed import Client, get_task_stream
    with Client(dask_cluster.scheduler_address) as client, get_task_stream(client) as stream:
        assert main(_args(dic_sim, tmp_path / "out", "--scheduler", dask_cluster.scheduler_address)) == 0
    where = {}
    for task in stream.data:
        name = str(task["key"]).split("-")
        where.setdefault(name[1], {})[int(name[2])] = task["worker"]
    assert min(where["solve"]) == 0 and len(where["solve"]) >= 2 and len(set(where["solve"].values())) == 1
    assert sorted(where["files"]) == [0, 1, 2] and where["files"][0] not in set(where["solve"].values())
    assert not any("transfer" in s["action"] for task in stream.data for s in task["startstops"])
    assert _differing(in_process["direct"], tmp_path / "out") == []


def test_a_worker_killed_during_a_task_loses_nothing(dic_sim, dask_cluster, in_process, tmp_path):
    """The worker running a task (a solve, or a state's maps) is killed; Dask runs it again elsewhere."""
    from distributed import Client
    out = tmp_path / "out"
    status = []
    run = threading.Thread(target=lambda: status.append(
        main(_args(dic_sim, out, "--scheduler", dask_cluster.scheduler_address))))
    killed = None
    with Client(dask_cluster.scheduler_address) as client:
        pids = client.run(os.getpid)
        run.start()
        deadline = time.monotonic() + 120
        while killed is None and run.is_alive() and time.monotonic() < deadline:
            for worker, keys in client.processing().items():
                if any(str(k).startswith(("dic-solve", "dic-files")) and not str(k).endswith("-0") for k in keys):
                    killed = (worker, sorted(map(str, keys)))
                    os.kill(pids[worker], signal.SIGKILL)
                    break
            time.sleep(0.01)
        run.join(300)
        client.wait_for_workers(2, timeout=120)                   # the nanny restarts it, for the next tests
    assert killed is not None, "no task was seen running"
    assert status == [0]
    assert _differing(in_process["direct"], out) == []


def _interrupt_after(monkeypatch, k: int):
    """Stop the client (KeyboardInterrupt) when state k's solve has finished, as it submits the next (one
    state to a task)."""
    import stereodic.dic3d.cluster as on_cluster
    real = on_cluster._Chain._solve

    def solve(self, spec, first, stop):
        if first == k + 1:
            raise KeyboardInterrupt
        return real(self, spec, first, stop)

    monkeypatch.setattr(on_cluster, "MOST_STATES", 1)
    monkeypatch.setattr(on_cluster._Chain, "_solve", solve)


@pytest.mark.parametrize("second", ["cluster", pytest.param("in-process", marks=pytest.mark.slow)])
def test_an_interrupted_cluster_run_resumes_to_the_same_bytes(dic_sim, dask_cluster, in_process, tmp_path,
                                                              monkeypatch, capsys, second):
    args = _args(dic_sim, tmp_path / "out", "--scheduler", dask_cluster.scheduler_address)
    _interrupt_after(monkeypatch, 1)
    assert main(args) == 130
    assert json.loads((tmp_path / "out" / "run.json").read_text())["done"] == 1   # state 1 solved, not recorded
    monkeypatch.undo()
    capsys.readouterr()
    assert main(args if second == "cluster" else args[:-4] + args[-2:]) == 0
    assert "resuming a run with 2 of 3 states done" in capsys.readouterr().out
    assert _differing(in_process["direct"], tmp_path / "out") == []


def test_a_scheduler_that_does_not_answer_is_one_line(dic_sim, tmp_path, monkeypatch, capsys):
    import socket

    import stereodic.cluster
    monkeypatch.setattr(stereodic.cluster, "CONNECT_TIMEOUT_S", 1.0)
    with socket.socket() as s:                                  # a free port that nothing listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    assert main(_args(dic_sim, tmp_path / "out", "--scheduler", f"tcp://127.0.0.1:{port}")) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--scheduler" in err and f"127.0.0.1:{port}" in err
    assert main(_args(dic_sim, tmp_path / "out", "--scheduler", "local:zero")) == 2
    assert "local:N" in capsys.readouterr().err


def test_an_image_a_worker_cannot_read_is_one_line_and_keeps_the_states_done(dic_sim, dask_cluster, tmp_path,
                                                                               monkeypatch, capsys):
    """The client sees every image; the workers find state 2's right image gone (as on a worker that does
    not mount the images' storage)."""
    import shutil

    from stereodic.dic3d.store import RunStore
    data = tmp_path / "data"
    shutil.copytree(dic_sim, data)
    gone = data / "s002" / "cam1.png"
    real = RunStore.open

    def open_then_lose(self, *args, **kwargs):
        done = real(self, *args, **kwargs)
        gone.rename(tmp_path / "elsewhere.png")
        return done

    monkeypatch.setattr(RunStore, "open", open_then_lose)
    out = tmp_path / "out"
    assert main(["dic", str(data / "rig.npz"), str(data), *OPTS, "-o", str(out), "--scheduler",
                 dask_cluster.scheduler_address]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(gone) in err and "worker tcp://127.0.0.1:" in err
    assert json.loads((out / "run.json").read_text())["done"] == 2
    assert (out / "states" / "state000001.npz").is_file()


@pytest.mark.parametrize("extra,scheduler", [([], "local:2"), pytest.param(["--incremental"], None,
                                                                           marks=pytest.mark.slow)],
                         ids=["direct", "incremental"])
def test_dic2d_on_the_cluster_writes_the_same_bytes(dic_sim, dask_cluster, tmp_path, extra, scheduler):
    """The left camera's images as a 2-D sequence: the reference, then two deformed images; once on a
    cluster that the command starts itself (local:2)."""
    images = [str(dic_sim / f"s00{k}" / "cam0.png") for k in range(3)]
    for name, more in (("here", []), ("cluster", ["--scheduler", scheduler or dask_cluster.scheduler_address])):
        assert main(["dic2d", *images, "--step", "8", "--strain-window", "5", *extra, *more, "-o",
                     str(tmp_path / name / "d.csv"), "--npz", str(tmp_path / name / "d.npz")]) == 0
    assert _differing(tmp_path / "here", tmp_path / "cluster") == []

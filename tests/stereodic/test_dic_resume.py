"""`stereodic dic` streams its results to a run folder state by state: a run stopped half way and started
again gives byte-identical files to an uninterrupted one; a run of other settings or inputs is refused."""

import gc
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

import stereodic.dic3d.run as dic_run
from stereodic.cli import main

OPTS = ["--step", "12", "--plot-every", "2"]


def _files(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def uninterrupted(dic_sim, tmp_path_factory):
    out = tmp_path_factory.mktemp("whole") / "out"
    assert main(["dic", str(dic_sim / "rig.npz"), str(dic_sim), *OPTS, "-o", str(out)]) == 0
    return out


def _interrupt_at(monkeypatch, state: int):
    real = dic_run.solve_state

    def solve(run, k, *args):
        if k == state:
            raise KeyboardInterrupt
        return real(run, k, *args)

    monkeypatch.setattr(dic_run, "solve_state", solve)


def test_a_run_stopped_half_way_resumes_to_the_same_bytes(dic_sim, uninterrupted, tmp_path, monkeypatch, capsys):
    args = ["dic", str(dic_sim / "rig.npz"), str(dic_sim), *OPTS, "-o", str(tmp_path / "out")]
    _interrupt_at(monkeypatch, 2)
    gc.unfreeze()
    assert main(args) == 130
    assert gc.get_freeze_count() == 0          # the run froze its imports' objects, and let them go when stopped
    manifest = json.loads((tmp_path / "out" / "run.json").read_text())
    assert manifest["done"] == 2 and manifest["states"] == 3
    assert not (tmp_path / "out" / "dic.csv").exists()
    monkeypatch.undo()
    capsys.readouterr()
    assert main(args) == 0
    assert "resuming a run with 2 of 3 states done" in capsys.readouterr().out
    whole, resumed = _files(uninterrupted), _files(tmp_path / "out")
    assert whole.keys() == resumed.keys() and len(whole) > 10
    assert [k for k in whole if whole[k] != resumed[k]] == []
    assert gc.get_freeze_count() == 0
    assert main(args) == 0                                      # all done: nothing to do
    assert "nothing to do" in capsys.readouterr().out


def test_a_state_file_written_without_its_carry_is_computed_again(dic_sim, uninterrupted, tmp_path, monkeypatch):
    """A stop between a state's file and the carry after it (the order the store writes them in)."""
    args = ["dic", str(dic_sim / "rig.npz"), str(dic_sim), *OPTS, "-o", str(tmp_path / "out")]
    _interrupt_at(monkeypatch, 1)
    assert main(args) == 130
    state1 = tmp_path / "out" / "states" / "state000001.npz"
    np.savez(state1, junk=np.zeros(3))                          # half a state that never got its carry
    monkeypatch.undo()
    assert main(args) == 0
    assert _files(uninterrupted) == _files(tmp_path / "out")


def test_other_settings_or_inputs_are_refused_in_one_line(dic_sim, uninterrupted, tmp_path, capsys):
    out = tmp_path / "out"
    shutil.copytree(uninterrupted, out)
    rig = str(dic_sim / "rig.npz")
    assert main(["dic", rig, str(dic_sim), *OPTS, "--subset", "25", "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "run.json" in err and "subset" in err and "--restart" in err
    data = tmp_path / "data"
    shutil.copytree(dic_sim, data)
    img = data / "s002" / "cam1.png"
    raw = bytearray(img.read_bytes())
    from calib.imageio import read_gray, write_gray
    a = read_gray(img)
    a[50, 60] ^= 1                                                # one grey level of one pixel
    write_gray(img, a)
    assert main(["dic", str(data / "rig.npz"), str(data), *OPTS, "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "inputs" in err and bytes(raw) != img.read_bytes()
    assert main(["dic", str(data / "rig.npz"), str(data), *OPTS, "--restart", "-o", str(out)]) == 0
    assert json.loads((out / "run.json").read_text())["done"] == 3


def test_a_state_file_keeps_every_combined_status():
    """The combined statuses of a state read back from its file (what a resumed run, a cluster's task and
    dic.csv's rows read) are those the run set, including a camera that matched but whose subset takes in
    the blank band ('left:outside' with the left match ok) - and so are its CSV rows."""
    from stereodic.dic.grid import make_grid
    from stereodic.dic.icgn import DIVERGED, LOW_ZNCC, OK
    from stereodic.dic3d.output import csv_rows, state_arrays, state_from_arrays
    from stereodic.dic3d.stereo import CameraMatch, StereoState

    grid = make_grid(50, 20, subset=5, step=10)
    shape = grid.shape
    combined = np.array(["ok", "ray_gap", "no_reference", "left:outside", "right:outside", "left:diverged",
                         "right:low_zncc", "ok", "ok", "ray_gap"], dtype=object).reshape(shape)
    left = np.full(shape, OK, np.int8)
    right = np.full(shape, OK, np.int8)
    left[combined == "left:diverged"] = DIVERGED
    right[combined == "right:low_zncc"] = LOW_ZNCC
    ones = np.ones(shape)
    cams = [CameraMatch(ones, ones, ones, s, ones, np.ones(shape + (2,))) for s in (left, right)]
    conv = combined == "ok"
    st = StereoState(1, cams[0], cams[1], np.ones(shape + (3,)), np.ones(shape + (3,)), ones, conv, combined, None,
                     np.zeros(shape, bool))
    back = state_from_arrays(state_arrays(st), None)
    assert back.status.tolist() == combined.tolist()
    assert csv_rows(grid, back) == csv_rows(grid, st)


@pytest.mark.parametrize("threads", ["1", "2"])
def test_the_vtk_files_made_beside_the_run_are_the_states_as_saved(dic_sim, tmp_path, monkeypatch, threads):
    """Each state's VTK file but the last is made while the next state is solved (by a worker process on
    two threads) and kept in the run folder, then moved into vtk/: the same bytes as the file made at the
    end from the saved state; none is left behind. With --frame specimen they are the specimen frame's."""
    from stereodic.dic3d.store import RunStore
    from stereodic.dic3d.vtk import polydata
    monkeypatch.setenv("OMP_NUM_THREADS", threads)
    made = []
    real = dic_run.RunStore.write_vtk
    monkeypatch.setattr(dic_run.RunStore, "write_vtk", lambda self, st: (made.append(st.state), real(self, st)))
    out = tmp_path / "out"
    assert main(["dic", str(dic_sim / "rig.npz"), str(dic_sim), "--step", "12", "--no-plot", "-o", str(out)]) == 0
    if threads == "1":                      # in this process: seen here (on two threads, in the children)
        assert made == [0, 1]
    store = RunStore(out).attach()
    for k in range(3):
        assert (out / "vtk" / f"state{k:03d}.vtp").read_text() == polydata(store.read_state(k))
    assert not list((out / "states").glob("*.vtp"))
    framed = tmp_path / "framed"
    assert main(["dic", str(dic_sim / "rig.npz"), str(dic_sim), "--step", "12", "--no-plot", "--frame", "specimen",
                 "-o", str(framed)]) == 0
    assert (framed / "vtk" / "state002.vtp").read_text() != (out / "vtk" / "state002.vtp").read_text()
    assert (framed / "vtk" / "state000.vtp").read_text() != (out / "vtk" / "state000.vtp").read_text()


def test_the_maps_scales_from_the_kept_ranges_are_those_of_the_states(dic_sim, tmp_path, monkeypatch):
    """Each state's maps' value ranges but the last are kept as the run goes (`RunStore.write_ranges`), so
    that the colour scales need not read the states again: the scales from them are exactly those from the
    states themselves; the files go once the maps are drawn."""
    from stereodic.dic3d.store import RunStore
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    out = tmp_path / "out"
    monkeypatch.setattr(dic_run.RunStore, "remove_kept", lambda self: None)
    assert main(["dic", str(dic_sim / "rig.npz"), str(dic_sim), "--step", "12", "--no-vtk", "-o", str(out)]) == 0
    store = RunStore(out).attach()
    assert sorted(p.name for p in (out / "states").glob("*.ranges.json")) == [
        "state000000.ranges.json", "state000001.ranges.json"]
    active = np.load(out / "dic.npz")["active"]
    kept = dic_run._run_scales(store, 1, active)
    states = [store.read_state(k) for k in range(3)]
    for q, values in (("Z", lambda st: st.points[..., 2]), ("dX", lambda st: st.displacement[..., 0]),
                      ("exx", lambda st: st.measure.exx * 1e6), ("eyy", lambda st: st.measure.eyy * 1e6)):
        ranges = [np.percentile(v[np.isfinite(v) & active], [1, 99]) for v in map(values, states)]
        assert kept._range[q] == [min(r[0] for r in ranges), max(r[1] for r in ranges)]   # numpy's own, per state
    for p in (out / "states").glob("*.ranges.json"):
        p.unlink()
    read = dic_run._run_scales(store, 1, active)
    names = ["Z", "dX", "dY", "dZ", "exx", "eyy", "exy"]
    assert all(kept.scale(q) == read.scale(q) and read.scale(q) is not None for q in names)
    monkeypatch.undo()
    store.remove_kept()
    assert not list((out / "states").glob("*.json"))


def test_the_specimens_points_placed_beside_the_rig_check_are_those_placed_after_it(dic_sim, tmp_path, monkeypatch):
    """On two threads the automatic specimen mask runs beside the rig check (on the reference as the rig
    rectifies it); on one, after it: the same points, the same dic.csv."""
    import threading

    import stereodic.cli.dic as dic_cli
    runs, placed_on = {}, {}
    real = dic_cli.dic_grid

    def spy(*args, reference=None, **kw):
        if reference is not None:
            placed_on[threads] = threading.current_thread() is threading.main_thread()
        return real(*args, reference=reference, **kw)

    monkeypatch.setattr(dic_cli, "dic_grid", spy)
    for threads in ("1", "2"):
        monkeypatch.setenv("OMP_NUM_THREADS", threads)
        out = tmp_path / threads
        assert main(["dic", str(dic_sim / "rig.npz"), str(dic_sim), "--step", "12", "--no-plot", "--no-vtk",
                     "-o", str(out)]) == 0
        runs[threads] = (np.load(out / "dic.npz")["active"], (out / "dic.csv").read_bytes())
    assert runs["1"][0].sum() > 50 and placed_on == {"1": True, "2": False}
    np.testing.assert_array_equal(runs["1"][0], runs["2"][0])
    assert runs["1"][1] == runs["2"][1]

"""Batches of independent tasks on a Dask cluster of worker processes on loopback: `stereodic scan` over
several datasets and `stereodic calibrate` of several cameras give files byte-identical to the in-process
run's, and a batch run again does only what is not done."""

import shutil

import pytest

from scanners.sim.scan import default_scan_rig, simulate_scan, standard_scenes
from stereodic.cli import main
from stereodic.stereo.rig import rig_from_files, save_rig

PERIODS = (1280, 160, 32)


def _files(folder):
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file() and p.suffix != ".json"}


@pytest.fixture(scope="module")
def scans(tmp_path_factory):
    """Two scan datasets of two states each (a sphere before its plate, a plate), 320 x 256, one rig."""
    root = tmp_path_factory.mktemp("scans")
    simulate_scan(root / "line_a",
                  scenes=standard_scenes(objects=("sphere",))[:1] + standard_scenes(objects=("plane",))[:1],
                  rig=default_scan_rig(width=320, height=256), periods=PERIODS)
    save_rig(root / "rig.npz", rig_from_files(root / "line_a" / "truth_cam0.npz", root / "line_a" / "truth_cam1.npz"))
    shutil.copytree(root / "line_a", root / "line_b")
    return root


@pytest.fixture(scope="module")
def scanned_in_process(scans, tmp_path_factory):
    out = tmp_path_factory.mktemp("scan_in_process")
    assert main(["scan", str(scans / "rig.npz"), str(scans / "line_*"), "-o", str(out)]) == 0
    return out


def test_a_scan_batch_on_the_cluster_writes_the_same_clouds(scans, scanned_in_process, dask_cluster, tmp_path, capsys):
    names = ["line_a_s000.ply", "line_a_s001.ply", "line_b_s000.ply", "line_b_s001.ply"]
    assert sorted(_files(scanned_in_process)) == names
    capsys.readouterr()
    assert main(["scan", str(scans / "rig.npz"), str(scans / "line_a"), str(scans / "line_b"), "-o",
                 str(tmp_path), "--scheduler", dask_cluster.scheduler_address]) == 0
    wrote = sorted(ln.split(":")[0] for ln in capsys.readouterr().out.splitlines() if ln.startswith("wrote "))
    assert wrote == [f"wrote {tmp_path / n}" for n in names]
    assert _files(tmp_path) == _files(scanned_in_process)


def test_a_scan_batch_run_again_does_only_what_is_not_done(scans, scanned_in_process, dask_cluster, tmp_path, capsys):
    shutil.copytree(scanned_in_process, tmp_path, dirs_exist_ok=True)
    (tmp_path / "line_b_s000.ply").unlink()                      # as if the run had stopped before it
    capsys.readouterr()
    args = ["scan", str(scans / "rig.npz"), str(scans / "line_*"), "-o", str(tmp_path)]
    assert main(args + ["--scheduler", dask_cluster.scheduler_address]) == 0
    out = capsys.readouterr().out
    assert [ln.split(":")[0] for ln in out.splitlines() if ln.startswith("wrote ")] == [
        f"wrote {tmp_path / 'line_b_s000.ply'}"]
    assert "3 of 4 scans were done already" in out
    assert _files(tmp_path) == _files(scanned_in_process)
    assert main(args + ["--no-evm"]) == 0                         # other settings: all done again
    assert sum(ln.startswith("wrote ") for ln in capsys.readouterr().out.splitlines()) == 4


@pytest.fixture(scope="module")
def stereo_capture(tmp_path_factory):
    """A two-camera calibration dataset, 160 x 128, 2 stage positions."""
    from scanners.sim.stereo import simulate_stereo
    return simulate_stereo(tmp_path_factory.mktemp("stereo_cal") / "cal", left="brown", right="freeform",
                           width=160, height=128,
                           lens_options={"pixel_mm": 0.0053 * 1280 / 160}, supersample=8)


def test_calibrating_cameras_on_the_cluster_writes_what_one_calibration_writes(stereo_capture, dask_cluster,
                                                                                tmp_path, capsys):
    single = tmp_path / "single"
    for cam in ("cam0", "cam1"):
        assert main(["calibrate", str(stereo_capture), "--camera", cam, "-o", str(single / f"{cam}.npz")]) == 0
    capsys.readouterr()
    batch = tmp_path / "batch"
    args = ["calibrate", str(stereo_capture), "--camera", "cam0", "--camera", "cam1", "-o", str(batch)]
    assert main(args + ["--scheduler", dask_cluster.scheduler_address]) == 0
    assert sorted(ln.split(":")[0] for ln in capsys.readouterr().out.splitlines() if ln.startswith("wrote ")) == [
        f"wrote {batch / 'cam0.npz'}", f"wrote {batch / 'cam1.npz'}"]
    assert _files(batch) == _files(single)
    (batch / "cam1.npz").unlink()
    assert main(args) == 0                                        # in-process, the rest only
    out = capsys.readouterr().out
    assert [ln.split(":")[0] for ln in out.splitlines() if ln.startswith("wrote ")] == [f"wrote {batch / 'cam1.npz'}"]
    assert "1 of 2 cameras were done already" in out
    assert _files(batch) == _files(single)

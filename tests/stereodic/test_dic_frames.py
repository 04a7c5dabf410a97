"""What post-processing expects of `stereodic dic`: each point's position in the original (unrectified)
images, against the simulator's true projection; results in the rig's reporting frame (world_from_rig)."""

import json
import shutil

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calib.errors import InputError
from scanners.sim.dic import dic_lenses, load_dic_truth, truth_at_pixels
from scanners.sim.stereo import project_true
from stereodic.cli import main
from stereodic.stereo.rig import load_rig, save_rig

OPTS = ["--step", "10", "--subset", "21", "--no-vtk", "--no-plot"]


@pytest.fixture(scope="module")
def run(dic_sim, tmp_path_factory):
    out = tmp_path_factory.mktemp("frames") / "out"
    assert main(["dic", str(dic_sim / "rig.npz"), str(dic_sim), *OPTS, "-o", str(out)]) == 0
    return out


def test_positions_in_the_original_images_against_the_true_projection(dic_sim, run):
    rig = load_rig(dic_sim / "rig.npz")
    lenses = dic_lenses(rig.sensor.width, rig.sensor.height)
    with np.load(run / "dic.npz") as z:
        # the material points: those the left camera sees where the run puts them in state 0
        truth = truth_at_pixels(load_dic_truth(dic_sim), np.stack([z["left_x0"][0], z["left_y0"][0]], -1))
        for k in (0, 1, 2):
            ok = z["converged"][k].ravel()
            for side, lens in zip(("left", "right"), lenses):
                true_uv = project_true(lens, truth["position"][k][ok])
                got = np.stack([z[f"{side}_x0"][k].ravel()[ok], z[f"{side}_y0"][k].ravel()[ok]], -1)
                err = np.linalg.norm(got - true_uv, axis=1)
                assert ok.sum() > 300 and np.sqrt(np.mean(err ** 2)) < 0.05 and err.max() < 0.3, (k, side)
            for side in ("left", "right"):                  # NaN exactly where the camera's match failed
                matched = z[f"{side}_status"][k] == 0
                assert np.isfinite(z[f"{side}_x0"][k][matched]).all() and np.isnan(z[f"{side}_x0"][k][~matched]).all()


def test_rig_transform_round_trip_and_bad_ones(dic_sim, tmp_path):
    rig = load_rig(dic_sim / "rig.npz")
    assert np.array_equal(rig.world_from_rig, np.eye(4))
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("xyz", [170, 5, -20], degrees=True).as_matrix()
    T[:3, 3] = (10.0, -250.0, 900.0)
    rig.world_from_rig = T
    save_rig(tmp_path / "w.npz", rig)
    assert np.array_equal(load_rig(tmp_path / "w.npz").world_from_rig, T)
    for bad in (np.eye(3), np.diag([1.0, 1.0, -1.0, 1.0]), np.diag([2.0, 2.0, 2.0, 1.0])):
        rig.world_from_rig = bad
        save_rig(tmp_path / "bad.npz", rig)
        with pytest.raises(InputError) as e:
            load_rig(tmp_path / "bad.npz")
        assert "bad.npz" in str(e.value) and "world_from_rig" in str(e.value)


def test_results_in_the_reporting_frame(dic_sim, run, tmp_path):
    """A rig carrying a transform to another world frame: X, Y, Z moved by it, dX, dY, dZ turned by its
    rotation, principal strains unchanged; nothing else."""
    data = tmp_path / "data"
    shutil.copytree(dic_sim, data)
    rig = load_rig(data / "rig.npz")
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("xyz", [180, 0, 30], degrees=True).as_matrix()   # z towards the cameras
    T[:3, 3] = (5.0, 20.0, 300.0)
    rig.world_from_rig = T
    save_rig(data / "rig.npz", rig)
    assert main(["dic", str(data / "rig.npz"), str(data), *OPTS, "-o", str(tmp_path / "w")]) == 0
    with np.load(run / "dic.npz") as a, np.load(tmp_path / "w" / "dic.npz") as b:
        assert np.allclose(b["points"], a["points"] @ T[:3, :3].T + T[:3, 3], atol=1e-9, equal_nan=True)
        assert np.allclose(b["displacement"], a["displacement"] @ T[:3, :3].T, atol=1e-9, equal_nan=True)
        for k in ("e_major", "e_minor", "e_vm", "strain_valid", "left_u", "right_x0", "converged"):
            assert np.allclose(a[k], b[k], atol=1e-9, equal_nan=True), k
        assert json.loads(str(b["meta"]))["world_from_rig"] == T.tolist()

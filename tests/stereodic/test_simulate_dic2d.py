"""`stereodic simulate dic2d`: a speckle pair with its exact displacement, measured back by `dic2d`."""

import csv

import numpy as np

from scanners.sim.speckle import affine_displacement
from stereodic.cli import main


def test_affine_displacement_is_the_stretch_the_rotation_and_the_shift():
    field = affine_displacement((3.0, -2.0), strain=0.1, poisson=0.5, rotation_deg=90.0, centre=(10.0, 20.0))
    # (11, 20): 1 px right of the centre, stretched to 1.1 px, turned 90 degrees onto +y, then shifted
    u, v = field(np.array([11.0]), np.array([20.0]))
    np.testing.assert_allclose([11 + u[0], 20 + v[0]], [10 + 3.0, 20 + 1.1 - 2.0], atol=1e-12)
    # (10, 21): 1 px below, contracted to 0.95 px, turned onto -x
    u, v = field(np.array([10.0]), np.array([21.0]))
    np.testing.assert_allclose([10 + u[0], 21 + v[0]], [10 - 0.95 + 3.0, 20 - 2.0], atol=1e-12)


def test_dic2d_measures_the_simulated_pair(tmp_path, capsys):
    out = tmp_path / "pair"
    assert main(["simulate", "dic2d", "--shift", "1.25,-0.4", "--strain", "0.01", "--width", "160",
                 "--height", "128", "-o", str(out)]) == 0
    assert {p.name for p in out.iterdir()} == {"reference.png", "moved.png", "truth.npz"}
    assert main(["dic2d", str(out / "reference.png"), str(out / "moved.png"), "--step", "10",
                 "-o", str(tmp_path / "r.csv")]) == 0
    truth = np.load(out / "truth.npz")
    with open(tmp_path / "r.csv") as f:
        rows = [r for r in csv.DictReader(f) if r["converged"] == "1"]
    assert len(rows) > 60
    x = np.array([int(float(r["x"])) for r in rows])
    y = np.array([int(float(r["y"])) for r in rows])
    du = np.array([float(r["u"]) for r in rows]) - truth["u"][y, x]
    dv = np.array([float(r["v"]) for r in rows]) - truth["v"][y, x]
    assert abs(du.mean()) < 0.01 and abs(dv.mean()) < 0.01
    assert np.sqrt(np.mean(du ** 2 + dv ** 2)) < 0.03

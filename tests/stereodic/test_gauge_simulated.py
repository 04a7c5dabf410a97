"""The materials test end to end on the simulator (slow): a plate tilted 10 degrees to the rig, a rigid
motion, 1 % tension with the same rigid motion and a bulge, through `stereodic dic --frame specimen
--mat` and `stereodic gauge`, against the simulator's truth (scanners.sim.dic.truth_at_pixels)."""

from __future__ import annotations

import csv

import numpy as np
import pytest
from scipy.io import loadmat

from scanners.sim.dic import DicState, load_dic_truth, truth_at_pixels
from stereodic.cli import main
from stereodic.gauge.frame import SpecimenFrame
from stereodic.gauge.result import open_gauge_result
from stereodic.rig import load_rig
from tests.stereodic.dic_cases import simulate_dic_with_rig

ROTATION, TRANSLATION = (0.3, -0.4, 0.6), (0.6, -0.4, 1.2)
STATES = [DicState("reference"), DicState("rigid", rotation_deg=ROTATION, translation_mm=TRANSLATION),
          DicState("tension", stretch=(1.01, 0.997), rotation_deg=ROTATION, translation_mm=TRANSLATION),
          DicState("bulge", bulge_mm=0.3, bulge_radius_mm=25.0)]


@pytest.mark.slow
def test_tilted_plate_in_the_specimen_frame(tmp_path):
    simulate_dic_with_rig(tmp_path / "data", STATES, width=480, height=384, supersample=2)
    run = tmp_path / "run"
    assert main(["dic", str(tmp_path / "data" / "rig.npz"), str(tmp_path / "data"), "--subset", "31", "--step", "8",
                 "--strain-window", "7", "--frame", "specimen", "--mat", "-o", str(run)]) == 0
    truth = load_dic_truth(tmp_path / "data")
    res = open_gauge_result(run, remove_rigid=True)
    rec = res.frame_record()
    assert rec["frame"] == "specimen"
    frame = SpecimenFrame(np.array(rec["origin_mm"]), np.array(rec["axes"]), rec["plane_rms_mm"])
    plate = truth.specimen.frame                                       # columns e1, e2, n (away from the rig)
    assert frame.rotation[2] @ plate[:, 2] < -0.99999 and frame.rotation[0] @ plate[:, 0] > 0.9999
    ok = np.isfinite(res.image_px).all(-1)
    t = truth_at_pixels(truth, res.image_px[ok])
    rig = load_rig(tmp_path / "data" / "rig.npz")
    fov = rig.sensor.width * rig.sensor.pitch_mm[0]
    for st in res.states():
        k, q = st.state, st.quantities
        if STATES[k].bulge_mm == 0:                                    # rigid motion removed: no dZ left
            assert abs(np.nanmedian(q["dZ_def"][ok])) < 0.005
            assert np.sqrt(np.nanmean(q["dZ_def"][ok] ** 2)) < fov / 10000
        assert abs(np.nanmean(q["exx"][ok] - t["exx"][k])) < 50e-6       # strain in the specimen's axes
    # the extensometer across the gauge section and a line across the bulge, placed in the left image
    cx, cy = (float(np.nanmedian(res.image_px[..., i])) for i in (0, 1))
    half = 0.55 * float(np.nanmax(res.image_px[..., 0]) - cx)
    ext, line = [cx - half, cy, cx + half, cy], [cx - half, cy + 5, cx + half, cy + 5]
    assert main(["gauge", str(run), "--extensometer", ",".join(map(str, ext)), "--line", ",".join(map(str, line)),
                 "--no-plot", "-o", str(tmp_path / "g")]) == 0
    with open(tmp_path / "g" / "extensometers.csv") as f:
        strain = np.array([float(r["strain"]) for r in csv.DictReader(f)])
    ends = truth_at_pixels(truth, np.array([ext[:2], ext[2:]]))["position"]
    length = np.linalg.norm(ends[:, 1] - ends[:, 0], axis=1)
    assert np.abs(strain - (length / length[0] - 1)).max() < 50e-6
    with open(tmp_path / "g" / "lines.csv") as f:
        rows = [r for r in csv.DictReader(f) if r["state"] == "3"]
    dz = np.array([float(r["dZ"]) for r in rows])
    px = np.array([[float(r["x_px"]), float(r["y_px"])] for r in rows])
    true_dz = frame.rotate(truth_at_pixels(truth, px)["displacement"][3])[:, 2]
    assert true_dz.max() > 0.25 and np.sqrt(np.nanmean((dz - true_dz) ** 2)) < fov / 10000   # the bulge
    mat = loadmat(run / "dic.mat")
    assert np.allclose(mat["points"], np.load(run / "dic.npz")["points"], equal_nan=True)

"""`stereodic gauge` end to end on a saved result with an analytic truth: the files the contract names,
the specimen's frame recorded, a load joined by time and the modulus."""

from __future__ import annotations

import csv
import json

import numpy as np

from stereodic.cli import main
from tests.stereodic import gauge_cases as gc
from tests.stereodic.test_gauge_load import AREA, CAMERA_HZ, CAMERA_START, E_MPA, _strain_at, write_machine_csv


def _px(a, b):
    return ",".join(f"{v:.4f}" for v in gc.project(gc.place(a, b, gc.State())))


def _rows(path):
    with open(path) as f:
        return list(csv.DictReader(f))


def test_gauge_command_writes_every_kind_in_the_specimen_frame(tmp_path, capsys):
    gc.write_tension_result(tmp_path / "dic.npz")
    area = ";".join(_px(a, b) for a, b in ((-10, -5), (10, -5), (10, 5), (-10, 5)))
    status = main(["gauge", str(tmp_path / "dic.npz"), "--extensometer", f"clip={_px(-12, 0)},{_px(12, 0)}",
                   "--point", _px(-8, 2), "--area", area, "--line", f"{_px(-5, 1)},{_px(15, 1)}",
                   "--frame", "specimen", "--remove-rigid", "--line-states", "0,4", "-o", str(tmp_path / "g")])
    assert status == 0
    ext = _rows(tmp_path / "g" / "extensometers.csv")
    assert list(ext[0])[:4] == ["state", "name", "length_mm", "delta_mm"] and "strain" in ext[0]
    for row in ext:
        st = gc.STATES[int(row["state"])]
        if not st.bulge_mm:
            assert abs(float(row["strain"]) - st.strain) < 50e-6 and row["name"] == "clip"
    assert len(_rows(tmp_path / "g" / "points.csv")) == len(gc.STATES)
    areas = _rows(tmp_path / "g" / "areas.csv")
    assert abs(float(areas[3]["exx_mean"]) - 0.01005) < 10e-6
    lines = _rows(tmp_path / "g" / "lines.csv")
    assert {r["state"] for r in lines} == {"0", "4"}
    peak = max(float(r["dZ"]) for r in lines if r["state"] == "4")
    assert abs(peak - 0.2) < 0.005                   # the line crosses the bulge's top
    record = json.loads((tmp_path / "g" / "gauge.json").read_text())
    assert record["frame"]["frame"] == "specimen" and record["frame"]["rigid_motion_removed"]
    assert np.allclose(np.abs(np.array(record["frame"]["axes"])[2] @ gc.N), 1, atol=1e-6)
    for name in ("extensometers", "points", "areas", "lines"):
        assert (tmp_path / "g" / f"{name}.png").stat().st_size > 10_000
    # the gauges written are the gauges read back
    (tmp_path / "gauges.json").write_text(json.dumps(record["gauges"]))
    assert main(["gauge", str(tmp_path / "dic.npz"), "--gauges", str(tmp_path / "gauges.json"), "--no-plot",
                 "-o", str(tmp_path / "again")]) == 0
    assert _rows(tmp_path / "again" / "extensometers.csv")[3]["strain"] == ext[3]["strain"]


def test_gauge_command_joins_the_load_and_fits_the_modulus(tmp_path, capsys):
    times = CAMERA_START + np.arange(12) / CAMERA_HZ
    gc.write_tension_result(tmp_path / "dic.npz", states=tuple(gc.State(float(_strain_at(t))) for t in times),
                            noise_mm=5e-5, nx=41, ny=21)
    write_machine_csv(tmp_path / "machine.csv")
    assert main(["gauge", str(tmp_path / "dic.npz"), "--extensometer", f"{_px(-8, 0)},{_px(8, 0)}",
                 "--load", str(tmp_path / "machine.csv"), "--join", "time", "--frame-rate", str(CAMERA_HZ),
                 "--start-time", str(CAMERA_START), "--section", str(AREA), "-o", str(tmp_path / "g")]) == 0
    load = _rows(tmp_path / "g" / "load.csv")
    truth = E_MPA * _strain_at(times)
    got = np.array([float(r["stress_mpa"]) for r in load])
    assert np.all(np.abs(got - truth) <= 1e-3 * truth + 1e-9)
    record = json.loads((tmp_path / "g" / "gauge.json").read_text())
    assert abs(record["load"]["modulus_mpa"] / E_MPA - 1) < 0.01
    assert (tmp_path / "g" / "stress_strain.png").is_file() and (tmp_path / "g" / "stress_strain.csv").is_file()
    assert "modulus" in capsys.readouterr().out


def test_bad_gauges_and_loads_are_one_line_and_write_nothing(tmp_path, capsys):
    gc.write_tension_result(tmp_path / "dic.npz", nx=21, ny=11)
    (tmp_path / "machine.csv").write_text("t,F\n0,1\n1,2\n")
    inside = _px(-5, 0)
    cases = [(["--extensometer", f"E1={inside},5,5"], "--extensometer E1: (5, 5) px lies outside the measured area"),
             (["--area", "A=0,0;3,0;3,3"], "--area A: the polygon holds no measured grid point"),
             (["--point", inside, "--load", str(tmp_path / "machine.csv")], "machine.csv: has no force column"),
             (["--point", inside, "--load", str(tmp_path / "machine.csv"), "--load-force", "Kraft"],
              "machine.csv: has no column 'Kraft'"),
             (["--point", "1,2,3"], "--point: '1,2,3': needs X,Y"),
             ([], "give at least one gauge")]
    for k, (extra, message) in enumerate(cases):
        out = tmp_path / f"out{k}"
        assert main(["gauge", str(tmp_path / "dic.npz"), *extra, "-o", str(out)]) == 2, extra
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and message in err[0], (err, message)
        assert not out.exists() or not any(out.iterdir())

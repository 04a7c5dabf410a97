"""Load data joined to the states: a machine with its own clock, stress and the modulus against the
simulated truth."""

from __future__ import annotations

import numpy as np
import pytest

from calib.errors import InputError
from stereodic.gauge.gauges import Extensometer, Gauges, measure_gauges
from stereodic.gauge.load import join_load, modulus, read_load, state_times, stress
from stereodic.gauge.result import open_gauge_result
from tests.stereodic import gauge_cases as gc

E_MPA, AREA = 70_000.0, 12.5          # the simulated material and cross-section
CAMERA_START, CAMERA_HZ = 3.7, 2.0    # the cameras' first image, in the machine's clock; frame rate
STRAIN_RATE = 0.001                   # per second, from the machine's t = 4 s (after the first image)


def _strain_at(t):
    return np.clip((t - 4.0) * STRAIN_RATE, 0, None)


def write_machine_csv(path, *, rate_hz=47.0, units_row=True):
    """The machine's log: its own clock from 0 s at `rate_hz`, force of the elastic tension, a
    crosshead, semicolons and a units row as machines write them."""
    t = np.arange(0, 20, 1 / rate_hz)
    force = E_MPA * _strain_at(t) * AREA
    lines = ["Time [s];Standard force [N];Crosshead [mm]"] + (["s;N;mm"] if units_row else [])
    lines += [f"{a:.5f};{b:.4f};{c:.5f}" for a, b, c in zip(t, force, 0.5 * t)]
    path.write_text("\n".join(lines) + "\n")


def test_load_with_its_own_clock_gives_stress_and_modulus(tmp_path):
    times = CAMERA_START + np.arange(12) / CAMERA_HZ
    states = tuple(gc.State(float(_strain_at(t))) for t in times)
    gc.write_tension_result(tmp_path / "dic.npz", states=states, noise_mm=5e-5, nx=41, ny=21)
    write_machine_csv(tmp_path / "machine.csv")
    load = read_load(tmp_path / "machine.csv", need="time")
    assert load.columns == {"force": "Standard force [N]", "time": "Time [s]", "crosshead": "Crosshead [mm]"}
    at = join_load(load, len(states), by="time", times_s=state_times(len(states), start_s=CAMERA_START,
                                                                       rate_hz=CAMERA_HZ))
    eng, _ = stress(at.force_n, area_mm2=AREA)
    truth = E_MPA * np.array([s.strain for s in states])
    nz = truth > 0
    assert np.all(np.abs(eng[nz] / truth[nz] - 1) < 1e-3)
    assert np.allclose(at.crosshead_mm, 0.5 * times, atol=1e-6)
    res = open_gauge_result(tmp_path / "dic.npz")
    px = [tuple(gc.project(gc.place(a, 0.0, gc.State())).tolist()) for a in (-8.0, 8.0)]
    strain = measure_gauges(res, Gauges([Extensometer("E", *px)])).extensometers[0].strain
    E, _, n = modulus(strain, eng)
    assert n >= 3 and abs(E / E_MPA - 1) < 0.01
    _, true = stress(at.force_n, area_mm2=AREA, strain=strain)
    assert np.allclose(true, eng * (1 + strain))


def test_join_by_index_and_by_recorded_timestamps(tmp_path):
    (tmp_path / "l.csv").write_text("image,load\n" + "".join(f"{k},{10.0 * k}\n" for k in range(5)))
    load = read_load(tmp_path / "l.csv")
    assert np.allclose(join_load(load, 3, by="index", index_offset=1).force_n, [10, 20, 30])
    (tmp_path / "t.csv").write_text("time,force\n2026-12-04T10:00:00,0\n2026-12-04T10:00:10,100\n")
    load = read_load(tmp_path / "t.csv")
    stamps = [state_times(1, recorded=[0.0])[0] + load.time_s[0] + s for s in (2.5, 5.0)]
    assert np.allclose(join_load(load, 2, by="time", times_s=stamps).force_n, [25, 50])


def test_load_file_without_the_named_columns(tmp_path):
    (tmp_path / "l.csv").write_text("a,b\n1,2\n3,4\n")
    with pytest.raises(InputError, match="l.csv: has no force column"):
        read_load(tmp_path / "l.csv")
    (tmp_path / "m.csv").write_text("time,force\n1,2\n3,4\n")
    with pytest.raises(InputError, match="m.csv: has no column 'Kraft'"):
        read_load(tmp_path / "m.csv", force_column="Kraft")
    with pytest.raises(InputError, match="m.csv: has no image index column"):
        read_load(tmp_path / "m.csv", need="index")

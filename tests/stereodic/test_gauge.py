"""Gauges and the specimen's frame on saved results with an analytic truth (tests/stereodic/gauge_cases)."""

from __future__ import annotations

import numpy as np
import pytest

from calib.errors import InputError
from stereodic.gauge.gauges import (AreaGauge, Extensometer, Gauges, LineGauge, PointGauge, measure_gauges,
                                    read_gauge_file, write_gauge_file)
from stereodic.gauge.result import open_gauge_result
from tests.stereodic import gauge_cases as gc


@pytest.fixture(scope="module")
def tension(tmp_path_factory):
    path = tmp_path_factory.mktemp("gauge") / "dic.npz"
    gc.write_tension_result(path)
    return path


def _px(a, b):
    return tuple(gc.project(gc.place(a, b, gc.State())).tolist())


def test_specimen_frame_is_the_plate(tension):
    res = open_gauge_result(tension, frame="specimen")
    R = res.frame.rotation
    # x along the image's columns: the plate's e1, to the perspective's slant of the rows (under 0.2 deg here)
    assert np.degrees(np.arccos(abs(R[0] @ gc.E1))) < 0.2
    assert R[2] @ gc.N < -0.9999                                  # z towards the camera
    assert np.linalg.norm(res.frame.origin - gc.CENTRE) < 0.01    # the centroid of a symmetric grid


def test_tension_in_the_specimen_frame_against_truth(tension):
    res = open_gauge_result(tension, frame="specimen", remove_rigid=True)
    for st in res.states():
        truth = gc.STATES[st.state]
        if truth.bulge_mm:
            continue
        q = st.quantities
        assert np.nanmax(np.abs(q["dZ_def"])) < 0.005                      # rigid motion removed
        exx = 0.5 * ((1 + truth.strain) ** 2 - 1)                          # Green-Lagrange of the stretch
        err = np.abs(q["exx"] - exx)
        assert np.nanpercentile(err, 95) < 50e-6, (st.state, np.nanpercentile(err, 95))
    rig = open_gauge_result(tension)                                        # the rig's frame: dZ of the tilt
    last = list(rig.states())[3]
    assert np.nanmax(np.abs(last.quantities["dZ"])) > 0.1


def test_extensometer_point_area_against_truth(tension):
    res = open_gauge_result(tension, frame="specimen", remove_rigid=True)
    e0, e1 = _px(-15.0, 3.0), _px(15.0, -2.0)
    gauges = Gauges([Extensometer("E1", e0, e1)], [PointGauge("P1", _px(-8.0, 2.0))],
                    [AreaGauge("A1", (_px(-10, -5), _px(10, -5), _px(10, 5), _px(-10, 5)))])
    t = measure_gauges(res, gauges)
    (a0, b0), (a1, b1) = gc.material_at([e0, e1])
    for k, st in enumerate(gc.STATES):
        if st.bulge_mm:
            continue
        da, db = (a1 - a0) * (1 + st.strain), (b1 - b0) * (1 - gc.POISSON * st.strain)
        truth = np.hypot(da, db) / np.hypot(a1 - a0, b1 - b0) - 1
        assert abs(t.extensometers[0].strain[k] - truth) < 50e-6, k
        assert abs(t.extensometers[0].length[k] - np.hypot(da, db)) < 0.002
        area = t.areas[0]
        assert abs(area.mean["exx"][k] - 0.5 * ((1 + st.strain) ** 2 - 1)) < 10e-6
        assert area.count["exx"][k] == area.points > 300
    p = t.points[0].values
    (pa, pb), = gc.material_at([_px(-8.0, 2.0)])
    assert abs(p["dX_def"][3] - pa * 0.01) < 0.001                      # the specimen's y is up the image: -e2
    assert abs(p["dY_def"][3] - pb * gc.POISSON * 0.01) < 0.001


def test_line_profile_across_the_bulge(tension):
    res = open_gauge_result(tension, frame="specimen")
    start, end = _px(-5.0, 1.0), _px(15.0, 1.0)
    t = measure_gauges(res, Gauges(lines=[LineGauge("L1", start, end)]), line_states=[0, 4])
    prof = t.lines[0]
    ab = gc.material_at(prof.image_px)
    truth = gc.bulge(ab[:, 0], ab[:, 1], 0.2)
    assert truth.max() > 0.19
    assert np.max(np.abs(prof.values["dZ"][1] - truth)) < 0.005
    assert np.max(np.abs(prof.values["dZ"][0])) < 0.001
    length = np.hypot(*(ab[-1] - ab[0]))
    assert abs(prof.distance[-1] - length) < 0.01


def test_image_result_extensometer_in_px_and_mm(tmp_path):
    path = tmp_path / "d2.npz"
    gc.write_image_result(path)
    gauges = Gauges([Extensometer("E", (40.0, 60.0), (160.0, 60.0))])
    px = measure_gauges(open_gauge_result(path), gauges)
    mm = measure_gauges(open_gauge_result(path, scale_mm_per_px=0.02), gauges)
    assert px.unit == "px" and mm.unit == "mm"
    assert np.allclose(px.extensometers[0].strain, [0, 0.0025, 0.005, 0.01], atol=1e-9)
    assert np.allclose(mm.extensometers[0].length, px.extensometers[0].length * 0.02)


def test_gauge_outside_the_measured_area_names_it(tension):
    res = open_gauge_result(tension)
    with pytest.raises(InputError, match="extensometer E9.*outside the measured area"):
        measure_gauges(res, Gauges([Extensometer("E9", _px(-15, 0), (5.0, 5.0))]))
    with pytest.raises(InputError, match="area A9.*no measured grid point"):
        measure_gauges(res, Gauges(areas=[AreaGauge("A9", ((0, 0), (3, 0), (3, 3)))]))


def test_gauge_file_round_trip(tmp_path):
    g = Gauges([Extensometer("E1", (1, 2), (3, 4))], [PointGauge("P", (5, 6))],
               [AreaGauge("A", ((0, 0), (1, 0), (1, 1)))], [LineGauge("L", (0, 1), (2, 3))])
    write_gauge_file(tmp_path / "g.json", g)
    assert read_gauge_file(tmp_path / "g.json") == g
    (tmp_path / "bad.json").write_text('{"points": [{"name": "P"}]}')
    with pytest.raises(InputError, match="bad.json"):
        read_gauge_file(tmp_path / "bad.json")


def test_specimen_x_axis_along_a_chosen_image_direction(tension, tmp_path):
    """x along the image's rows (down): the specimen's exx is the plate's strain along e2 (Poisson), its
    eyy the tension; `stereodic strain --frame specimen` writes the same and records the frame."""
    from stereodic.cli import main
    res = open_gauge_result(tension, frame="specimen", x_direction_px=(0.0, 1.0))
    assert res.frame.rotation[0] @ gc.E2 > 0.9999
    last = list(res.states())[3].quantities
    e = 0.01
    assert abs(np.nanmedian(last["exx"]) - 0.5 * ((1 - gc.POISSON * e) ** 2 - 1)) < 20e-6
    assert abs(np.nanmedian(last["eyy"]) - 0.5 * ((1 + e) ** 2 - 1)) < 20e-6
    assert main(["strain", str(tension), "--frame", "specimen", "--no-plot", "-o", str(tmp_path / "s")]) == 0
    with np.load(tmp_path / "s" / "strain.npz") as z:
        import json
        assert json.loads(str(z["meta"]))["frame"]["frame"] == "specimen"
        assert abs(np.nanmedian(z["exx"][3]) - 0.5 * ((1 + e) ** 2 - 1)) < 20e-6

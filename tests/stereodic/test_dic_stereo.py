"""Stereo 3D-DIC (stereodic.dic3d) against the simulated truth (scanners.sim.dic): shape, rigid motion,
uniaxial tension, bulge; outputs and bad input of `stereodic dic`."""

import csv
import json
import shutil

import numpy as np
import pytest

from scanners.sim.dic import DicState, load_dic_truth, standard_states, truth_at_pixels
from stereodic.cli import main
from stereodic.dic import DicSettings, make_grid
from stereodic.dic3d.dataset import load_states
from stereodic.dic3d.stereo import StereoDic, StereoSettings
from stereodic.stereo.rig import load_rig
from tests.stereodic.dic_cases import simulate_dic_with_rig


def _run(root, subset=21, step=5, window=9, incremental=False):
    rig = load_rig(root / "rig.npz")
    data = load_states(root, rig)
    W, H = rig.sensor.width, rig.sensor.height
    grid = make_grid(W, H, subset=subset, step=step, roi=(15, 15, W - 16, H - 16))
    settings = StereoSettings(DicSettings(subset=subset), strain_window=window, incremental=incremental)
    states = list(StereoDic(rig, grid, settings=settings).run(list(data.rectified(rig))))
    X, Y = grid.points()
    return rig, grid, states, truth_at_pixels(load_dic_truth(root), rig.left.imm.real_position(X, Y))


def _errors(state, truth):
    c = state.converged.ravel()
    k = state.state
    pos = state.points.reshape(-1, 3)[c] - truth["position"][k][c]
    disp = state.displacement.reshape(-1, 3)[c] - truth["displacement"][k][c]
    sv = state.strain.valid.ravel()
    strain = {e: getattr(state.strain, e).ravel()[sv] - truth[e][k][sv] for e in ("exx", "eyy", "exy")}
    return pos, disp, strain


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    root = tmp_path_factory.mktemp("dic_small")
    states = [DicState("reference"), DicState("translation", translation_mm=(0.8, -0.5, 1.5)),
              DicState("tension", stretch=(1.01, 0.997))]
    simulate_dic_with_rig(root, states, width=320, height=256, supersample=2)
    return root


def test_shape_rigid_motion_and_tension_against_truth(small):
    rig, grid, states, truth = _run(small)
    fov = rig.sensor.width * rig.sensor.pitch_mm[0]
    for st in states:
        assert st.converged[grid.active].mean() > 0.85
        # NaN exactly where not converged
        assert np.isfinite(st.points[st.converged]).all() and np.isnan(st.points[~st.converged]).all()
        pos, disp, strain = _errors(st, truth)
        assert np.sqrt(np.mean(pos ** 2)) < fov / 10000                    # the shape, every state
        assert np.abs(disp).max() < fov / 1000                              # no outlier
        assert np.sqrt(np.mean(disp[:, 2] ** 2)) < fov / 10000
        assert max(abs(e.mean()) for e in strain.values()) < 100e-6
    mean_t = states[1].displacement[states[1].converged].mean(0)
    assert np.allclose(mean_t, (0.8, -0.5, 1.5), atol=fov / 50000)            # rigid translation recovered
    assert np.nanmean(states[2].strain.exx) == pytest.approx(0.5 * (1.01 ** 2 - 1), abs=100e-6)


def test_incremental_mode_agrees(small):
    _, grid, states, truth = _run(small, incremental=True)
    pos, disp, strain = _errors(states[2], truth)
    assert states[2].converged[grid.active].mean() > 0.85
    assert abs(strain["exx"].mean()) < 100e-6 and np.abs(disp).max() < 0.5


def test_each_images_noise_maps_are_made_once(small, monkeypatch):
    """Incremental points take the noise maps (SSSIG) of the image they step from: the previous state's
    left image, whose maps that state made for its stereo matches, and for the first state the reference,
    which the run keeps: each image's maps are made once, not again by the next state."""
    import stereodic.dic.correlate as correlate

    made = []

    def spy(bspline, half):
        made.append((bspline, half))       # kept alive here: no id of a dead image is reused
        return sssig(bspline, half)

    sssig = correlate.sssig
    monkeypatch.setattr(correlate, "sssig", spy)
    _, grid, states, _ = _run(small, incremental=True)
    assert states[2].incremental[grid.active].all()
    assert len(made) >= 3 and len({(id(b), half) for b, half in made}) == len(made)  # the reference's, each state's


@pytest.mark.slow
def test_goals_on_640x512(tmp_path):
    """The issue's goals: 1 % tension, mean strain error <= 50 microstrain, out-of-plane displacement
    error (RMS) <= 1/20000 of the field of view; every state within its noise."""
    simulate_dic_with_rig(tmp_path, standard_states(), width=640, height=512, supersample=2)
    rig, grid, states, truth = _run(tmp_path)
    fov = rig.sensor.width * rig.sensor.pitch_mm[0]
    for st in states:
        pos, disp, strain = _errors(st, truth)
        assert np.sqrt(np.mean(disp[:, 2] ** 2)) <= fov / 20000
        assert max(abs(e.mean()) for e in strain.values()) <= 50e-6
        assert np.abs(disp).max() < fov / 5000


# ------------------------------------------------------------------------------------- command line

def _rows(path):
    with open(path) as fh:
        return list(csv.DictReader(fh))


def _vtp_arrays(path) -> dict:
    """The DataArrays of a VTK XML file in inline binary form, read as VTK's file format describes it
    (base64 of a header_type byte count, then the values in byte_order), by name."""
    import base64
    import xml.etree.ElementTree as ET
    root = ET.parse(path).getroot()
    assert root.get("byte_order") == "LittleEndian" and root.get("header_type") == "UInt64"
    out = {}
    for a in root.iter("DataArray"):
        assert a.get("format") == "binary"
        raw = base64.b64decode(a.text)
        n = int(np.frombuffer(raw[:8], "<u8")[0])
        out[a.get("Name")] = np.frombuffer(raw[8:8 + n], {"Float64": "<f8", "Int64": "<i8"}[a.get("type")])
    return out


def test_command_writes_csv_npz_vtk_png(small, tmp_path):
    out = tmp_path / "out"
    assert main(["dic", str(small / "rig.npz"), str(small), "--step", "10", "--strain-window", "5",
                 "-o", str(out)]) == 0
    rows = _rows(out / "dic.csv")
    assert {r["state"] for r in rows} == {"0", "1", "2"}
    for r in rows:
        for cam in ("left", "right"):
            assert (r[f"{cam}_u"] == "nan") == (r[f"{cam}_converged"] == "0")
        assert all((r[c] == "nan") == (r["converged"] == "0") for c in ("X", "Y", "Z", "dX", "dY", "dZ"))
        assert all((r[c] == "nan") == (r["strain_valid"] == "0") for c in ("exx", "eyy", "exy"))
    ok = [r for r in rows if r["state"] == "1" and r["converged"] == "1"]
    assert len(ok) > 0.8 * len(rows) / 3
    assert np.mean([float(r["dZ"]) for r in ok]) == pytest.approx(1.5, abs=0.01)
    with np.load(out / "dic.npz") as z:
        assert z["points"].shape[0] == 3 and json.loads(str(z["meta"]))["format"] == "stereodic.dic/1"
    arrays = _vtp_arrays(out / "vtk" / "state001.vtp")
    with np.load(out / "dic.npz") as z:
        ok = z["converged"][1]
        assert np.array_equal(arrays["points"].reshape(-1, 3), z["points"][1][ok])
        assert np.array_equal(arrays["displacement"].reshape(-1, 3), z["displacement"][1][ok])
        assert np.array_equal(arrays["exx"], z["exx"][1][ok], equal_nan=True)
    quads = (ok[:-1, :-1] & ok[1:, :-1] & ok[1:, 1:] & ok[:-1, 1:]).sum()
    assert arrays["connectivity"].size == 4 * quads and arrays["offsets"][-1] == 4 * quads
    assert arrays["connectivity"].max() == ok.sum() - 1
    assert (out / "vtk" / "states.pvd").read_text().count("<DataSet") == 3
    assert (out / "maps" / "state2_exx.png").stat().st_size > 1000


def test_specimen_frame_and_rigid_motion_removed(small, tmp_path):
    """`dic --frame specimen --remove-rigid`: z along the plate's normal towards the rig, recorded in the
    meta; the translation state's deformation-only displacement is zero where its full one is not; the
    strains refitted in the specimen's axes still give the tension."""
    out = tmp_path / "out"
    assert main(["dic", str(small / "rig.npz"), str(small), "--step", "10", "--strain-window", "5", "--frame",
                 "specimen", "--remove-rigid", "--no-vtk", "--no-plot", "--mat", "-o", str(out)]) == 0
    truth = load_dic_truth(small)
    with np.load(out / "dic.npz") as z:
        meta = json.loads(str(z["meta"]))
        assert meta["frame"]["frame"] == "specimen" and meta["frame"]["rigid_motion_removed"]
        axes = np.array(meta["frame"]["axes"])
        assert axes[2] @ truth.specimen.frame[:, 2] < -0.99999
        full, deformation = z["displacement"][1], z["deformation"][1]
        ok = z["converged"][1]
        assert np.linalg.norm(np.median(full[ok], 0)) > 1.0                       # the translation, turned
        assert np.abs(np.median(deformation[ok], 0)).max() < 0.005
        assert np.nanmean(z["exx"][2]) == pytest.approx(0.5 * (1.01 ** 2 - 1), abs=100e-6)
    rows = _rows(out / "dic.csv")
    assert {"dX_def", "dY_def", "dZ_def"} <= set(rows[0])
    assert (out / "dic.mat").is_file()


@pytest.mark.parametrize("extra, message", [(["--limits", "foo=1,2"], "--limits: 'foo=1,2': needs a map's quantity"),
                                            (["--limits", "exx=5,1"], "LO < HI"),
                                            (["--animate", "dZ_def"], "--animate: no map of dZ_def"),
                                            (["--origin", "3,4"], "--origin/--x-axis: go with --frame specimen")])
def test_bad_map_and_frame_options(small, tmp_path, capsys, extra, message):
    assert main(["dic", str(small / "rig.npz"), str(small), *extra, "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0]
    assert not (tmp_path / "out").exists()


def _copy(src, dst):
    shutil.copytree(src, dst)
    return dst


def test_bad_input_is_one_clear_line(small, tmp_path, capsys):
    from PIL import Image
    rig = str(small / "rig.npz")
    assert main(["dic", rig, str(small), "--start-point", "5000,10", "-o", str(tmp_path / "o")]) == 2
    assert "--start-point" in capsys.readouterr().err
    for option, value in (("--vertical-search", "-1"), ("--max-gap", "0"), ("--prefilter", "-0.5")):
        assert main(["dic", rig, str(small), option, value, "-o", str(tmp_path / "o")]) == 2
        err = capsys.readouterr().err
        assert option in err and value in err and len(err.strip().splitlines()) == 1
    bad = _copy(small, tmp_path / "size")
    Image.fromarray(np.zeros((100, 120), np.uint8)).save(bad / "s001" / "cam1.png")
    assert main(["dic", rig, str(bad), "-o", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "cam1.png" in err and "120x100" in err and len(err.strip().splitlines()) == 1
    gap = _copy(small, tmp_path / "gap")
    manifest = json.loads((gap / "capture.json").read_text())
    manifest["frames"] = [f for f in manifest["frames"] if f["state"] != 1]
    (gap / "capture.json").write_text(json.dumps(manifest))
    assert main(["dic", rig, str(gap), "-o", str(tmp_path / "o")]) == 2
    assert "state 1" in capsys.readouterr().err


def test_textureless_region_is_flagged_never_nan(small, tmp_path):
    from PIL import Image
    blank = _copy(small, tmp_path / "blank")
    for cam in ("cam0", "cam1"):
        for s in range(3):
            p = blank / f"s{s:03d}" / f"{cam}.png"
            img = np.array(Image.open(p))
            img[100:160, 120:200] = 90
            Image.fromarray(img).save(p)
    out = tmp_path / "out"
    # by default no point is placed on the blank patch; a region that takes it in flags its points
    assert main(["dic", str(blank / "rig.npz"), str(blank), "--no-vtk", "--no-plot", "-o", str(out)]) == 0
    rows = _rows(out / "dic.csv")
    assert rows and not any("texture" in r["status"] for r in rows)
    sensor = load_rig(blank / "rig.npz").sensor
    roi = f"0,0,{sensor.width - 1},{sensor.height - 1}"
    assert main(["dic", str(blank / "rig.npz"), str(blank), "--roi", roi, "--no-vtk", "--no-plot", "-o",
                 str(tmp_path / "roi")]) == 0
    rows = _rows(tmp_path / "roi" / "dic.csv")
    flagged = {r["status"] for r in rows if r["converged"] == "0"}
    assert any("no_texture" in s or "low_texture" in s for s in flagged)
    assert all(r["X"] != "nan" for r in rows if r["converged"] == "1")


def test_subsets_reaching_a_blank_band_are_outside_not_matched(small):
    """On a grid over the whole rectified image, the subsets that take in the band where the virtual
    image lies beyond the real one are flagged 'outside' (they registered the band's edge: 0.10-0.17 mm
    off on this rig, the worst points); every converged point is then within 0.09 mm of the truth."""
    rig = load_rig(small / "rig.npz")
    data = load_states(small, rig)
    grid = make_grid(rig.sensor.width, rig.sensor.height, subset=21, step=5)
    settings = StereoSettings(DicSettings(subset=21), strain_window=9)
    states = list(StereoDic(rig, grid, settings=settings).run(list(data.rectified(rig))))
    X, Y = grid.points()
    truth = truth_at_pixels(load_dic_truth(small), rig.left.imm.real_position(X, Y))
    for st in states[1:]:
        c = st.converged.ravel()
        err = np.linalg.norm(st.displacement.reshape(-1, 3)[c] - truth["displacement"][st.state][c], axis=1)
        assert err.max() < 0.09                                            # mm
        assert (st.status == "right:outside").sum() > 0.02 * grid.active.sum()

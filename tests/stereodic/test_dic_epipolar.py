"""The rig's epipolar error at every `stereodic dic` run: small for the rig the images were taken with, and
a warning for a rig whose right camera turned after its calibration (a bumped rig), by as much as the
turn predicts."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calib.prvm_file import PRVM
from scanners.sim.dic import dic_lenses
from scanners.sim.stereo import CAMERAS
from stereodic.cli import main
from stereodic.dic3d.epipolar import epipolar_error
from stereodic.stereo.rig import build_rig, load_rig, save_rig


def _turned(prvm: PRVM, centre: np.ndarray, axis: np.ndarray, angle_rad: float) -> PRVM:
    """The PRVM of the camera turned by `angle_rad` about `axis` through its optical centre."""
    R = Rotation.from_rotvec(axis / np.linalg.norm(axis) * angle_rad).as_matrix()
    d = prvm.direction @ R.T
    p = centre + (prvm.origin - centre) @ R.T
    o = p - (p[..., 2:3] - prvm.reference_z_mm) / d[..., 2:3] * d
    return PRVM(o, d, prvm.valid, prvm.residual_mm, dict(prvm.meta))


def _rig(path, dic_sim, angle_rad):
    true = load_rig(dic_sim / "rig.npz")
    left, right = dic_lenses(true.sensor.width, true.sensor.height)
    prvms = [ln.true_prvm(camera=n, dataset="bumped", wcs="bumped") for n, ln in zip(CAMERAS, (left, right))]
    baseline = right.centre_mm - left.centre_mm
    prvms[1] = _turned(prvms[1], right.centre_mm, baseline, angle_rad)     # a turn about the baseline: rows move
    rig = build_rig(*prvms, width=true.sensor.width, height=true.sensor.height, where=tuple(CAMERAS))
    save_rig(path, rig)
    return rig


def test_the_error_of_the_true_rig_is_zero_on_its_rows(dic_sim):
    rig = load_rig(dic_sim / "rig.npz")
    x = np.linspace(20, 200, 7)
    y = np.linspace(20, 170, 7)
    # same row: no error whatever the disparity (to the bilinear interpolation of the rays between pixels)
    assert np.abs(epipolar_error(rig, x, y, x - 30, y)).max() < 1e-4
    assert np.allclose(epipolar_error(rig, x, y, x - 30, y + 0.25), 0.25, atol=2e-4)


def test_a_bumped_rig_is_reported(dic_sim, tmp_path, capsys):
    args = ["--step", "12", "--no-vtk", "--no-plot", "--strain-window", "0"]
    assert main(["dic", str(dic_sim / "rig.npz"), str(dic_sim), *args, "-o", str(tmp_path / "good")]) == 0
    out = capsys.readouterr()
    line = next(ln for ln in out.out.splitlines() if ln.startswith("epipolar error"))
    median = float(line.split("median ")[1].split(" px")[0])
    assert abs(median) < 0.01 and "warning" not in out.err
    angle = 0.8e-3                                              # 0.046 degrees
    rig = _rig(tmp_path / "bumped.npz", dic_sim, angle)
    shift_px = angle * rig.working_distance_mm / rig.sensor.pitch_mm[1]  # the rows move by about this
    assert 0.2 < shift_px < 0.6
    assert main(["dic", str(tmp_path / "bumped.npz"), str(dic_sim), *args, "-o", str(tmp_path / "bumped")]) == 0
    out = capsys.readouterr()
    line = next(ln for ln in out.out.splitlines() if ln.startswith("epipolar error"))
    median = float(line.split("median ")[1].split(" px")[0])
    assert abs(median) == pytest.approx(shift_px, rel=0.2)
    assert "warning" in out.err and "moved" in out.err and len(out.err.strip().splitlines()) == 1


def test_a_rig_far_off_its_images_needs_the_wider_search(dic_sim, tmp_path, capsys):
    """A right camera turned after its calibration by ~15 rows' worth (as in the dice-stereo-list case):
    the seeds' search along the row finds nothing; --vertical-search finds the matches, whose rays no
    longer meet (flagged ray_gap) until --max-gap admits them; the translation state's displacement is
    then the simulated one to the rig's error (the rays' midpoints of a turned camera)."""
    true = load_rig(dic_sim / "rig.npz")
    rig = _rig(tmp_path / "moved.npz", dic_sim, 15 * true.sensor.pitch_mm[1] / true.working_distance_mm)
    args = [str(tmp_path / "moved.npz"), str(dic_sim), "--step", "12", "--no-vtk", "--no-plot", "--strain-window", "0"]
    runs = {"row": [], "band": ["--vertical-search", "25"], "band_gap": ["--vertical-search", "25", "--max-gap", "100"]}
    found = {}
    for name, extra in runs.items():
        assert main(["dic", *args, *extra, "-o", str(tmp_path / name)]) == 0
        with np.load(tmp_path / name / "dic.npz") as z:
            found[name] = {k: z[k] for k in ("converged", "right_status", "displacement", "gap_mm", "active")}
    capsys.readouterr()
    n = found["row"]["active"].sum()
    assert not found["row"]["converged"].any() and not (found["row"]["right_status"][0] == 0).any()
    matched = found["band"]["right_status"][0] == 0
    assert matched.sum() > 0.7 * n and not found["band"]["converged"].any()      # every one a ray gap
    gap_px = np.nanmedian(found["band_gap"]["gap_mm"][0]) / rig.sensor.pitch_mm[0]
    assert 1 < gap_px < 100
    c = found["band_gap"]["converged"]
    assert (c.sum(axis=(1, 2)) > 0.6 * n).all()     # less the subsets reaching the rows it no longer sees
    mean = found["band_gap"]["displacement"][1][c[1]].mean(axis=0)
    assert np.abs(mean - (0.6, -0.4, 1.2)).max() < 0.05            # mm, of a 1.4 mm translation

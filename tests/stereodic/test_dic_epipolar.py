"""The rig's epipolar error at every `stereodic dic` run: small for the rig the images were taken with, and
a warning for a rig whose right camera turned after its calibration (a bumped rig), by as much as the
turn predicts."""

import json

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


def _correction(out: str) -> tuple[float, float, float, float]:
    """(turn about the baseline, about the viewing direction (degrees), epipolar median before, after (px))
    from the correction line of a run's output."""
    line = next(ln for ln in out.splitlines() if "does not fit these images" in ln)
    about = [float(line.split(" deg (")[1].split(" about the baseline")[0]),
             float(line.split("the baseline, ")[1].split(" about the viewing")[0])]
    medians = [float(part.split(" px")[0]) for part in line.split("median ")[1:3]]
    return about[0], about[1], medians[0], medians[1]


def test_a_bumped_rig_is_re_oriented(dic_sim, tmp_path, capsys):
    """A right camera turned by 0.046 degrees about the baseline after its calibration: the rows move by
    ~0.38 px; by default the run finds the turn and corrects it; with --keep-rig it warns and keeps it."""
    args = ["--step", "12", "--no-vtk", "--no-plot", "--strain-window", "0"]
    assert main(["dic", str(dic_sim / "rig.npz"), str(dic_sim), *args, "-o", str(tmp_path / "good")]) == 0
    out = capsys.readouterr()
    line = next(ln for ln in out.out.splitlines() if ln.startswith("epipolar error"))
    median = float(line.split("median ")[1].split(" px")[0])
    assert abs(median) < 0.01 and "warning" not in out.err and "does not fit" not in out.out
    angle = 0.8e-3                                              # 0.046 degrees
    rig = _rig(tmp_path / "bumped.npz", dic_sim, angle)
    shift_px = angle * rig.working_distance_mm / rig.sensor.pitch_mm[1]  # the rows move by about this
    assert 0.2 < shift_px < 0.6
    assert main(["dic", str(tmp_path / "bumped.npz"), str(dic_sim), *args, "-o", str(tmp_path / "bumped")]) == 0
    out = capsys.readouterr()
    about_baseline, about_view, before, after = _correction(out.out)
    assert abs(before) == pytest.approx(shift_px, rel=0.2) and abs(after) < 0.02
    assert about_baseline == pytest.approx(-np.degrees(angle), abs=0.003) and abs(about_view) < 0.003
    assert (tmp_path / "bumped" / "rig_refit.npz").is_file()
    keep = ["--keep-rig", "-o", str(tmp_path / "kept")]
    assert main(["dic", str(tmp_path / "bumped.npz"), str(dic_sim), *args, *keep]) == 0
    out = capsys.readouterr()
    assert "warning" in out.err and "moved" in out.err and len(out.err.strip().splitlines()) == 1


def test_a_turned_rig_is_recovered(dic_sim, tmp_path, capsys):
    """A right camera turned after its calibration by 0.3 degrees (about an axis between the baseline
    and the viewing direction: its rows move by ~2.5 px and tilt): with the defaults the run finds the
    turn, re-orients the rig and measures the translation state's displacement as with the true rig;
    --keep-rig refuses a rig that far off its images (one line naming the option, exit status 2)."""
    true = load_rig(dic_sim / "rig.npz")
    left, right = dic_lenses(true.sensor.width, true.sensor.height)
    e1 = (right.centre_mm - left.centre_mm) / np.linalg.norm(right.centre_mm - left.centre_mm)
    n = true.sensor.normal - (true.sensor.normal @ e1) * e1
    n /= np.linalg.norm(n)
    angle, mix = np.radians(0.3), np.radians(30)              # 0.26 deg about the baseline, 0.15 about the view
    axis = np.cos(mix) * e1 + np.sin(mix) * n
    prvms = [ln.true_prvm(camera=c, dataset="bumped", wcs="bumped") for c, ln in zip(CAMERAS, (left, right))]
    prvms[1] = _turned(prvms[1], right.centre_mm, axis, angle)
    save_rig(tmp_path / "turned.npz", build_rig(*prvms, width=true.sensor.width, height=true.sensor.height,
                                                where=tuple(CAMERAS)))
    args = [str(tmp_path / "turned.npz"), str(dic_sim), "--step", "12", "--no-vtk", "--no-plot", "--strain-window", "0"]
    assert main(["dic", *args, "-o", str(tmp_path / "out")]) == 0
    about_baseline, about_view, before, after = _correction(capsys.readouterr().out)
    print(about_baseline, about_view, before, after)
    assert abs(before) > 1.5 and abs(after) < 0.05
    assert about_baseline == pytest.approx(-np.degrees(angle * np.cos(mix)), abs=0.005)
    assert about_view == pytest.approx(-np.degrees(angle * np.sin(mix)), abs=0.005)
    assert main(["dic", str(dic_sim / "rig.npz"), *args[1:], "-o", str(tmp_path / "true")]) == 0
    with np.load(tmp_path / "true" / "dic.npz") as z:
        reach = z["converged"].sum(axis=(1, 2))
    with np.load(tmp_path / "out" / "dic.npz") as z:
        c, d = z["converged"], z["displacement"]
        assert any("turned by" in line for line in json.loads(str(z["meta"]))["rig_notes"])
    print(c.sum(axis=(1, 2)), reach)
    # all the true rig measures, less the blank band the turn puts along the right image's edge
    assert (c.sum(axis=(1, 2)) >= 0.9 * reach).all()
    mean = d[1][c[1]].mean(axis=0)
    assert np.abs(mean - (0.6, -0.4, 1.2)).max() < 0.01            # mm, of a 1.4 mm translation
    assert main(["dic", *args, "--keep-rig", "-o", str(tmp_path / "kept")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--keep-rig" in err[0] and "does not fit" in err[0]


def test_a_model_rig_turns_in_its_model_without_a_blank_band():
    """An imported rig (parametric cameras) re-oriented: the right camera's new maps are its model's own
    projection of the turned rays (the model seeing p where it saw C + R^T (p - C), computed here from the
    file's model and the rotation, not through the turned model), blank only where that falls off the real
    image; the resampled route of a model-less rig would blank a band as wide as the turn moves the image."""
    from dataclasses import replace

    from calib.camera_models import CameraModel, image_of, prvms_of
    from stereodic.dic3d.refit import refit_rig, turn
    from stereodic.stereo.rig import RigCamera
    from stereodic.virtual.imm import IMM

    def camera(name, centre, yaw_deg):
        R = Rotation.from_euler("y", -yaw_deg, degrees=True).as_matrix()
        return CameraModel(1400, 1400, 330, 236, coefficients=[-0.12, 0.05, 0, 0, 0], R=R, t=-R @ centre,
                           width=640, height=480, name=name)

    cams = [camera("L", np.array([0.0, 0, 0]), 0.0), camera("R", np.array([120.0, 2, 0]), 14.0)]
    prvms = prvms_of(cams, where="two.yml", dataset="two")
    rig = build_rig(*prvms, where=("two.yml#L", "two.yml#R"), cameras=tuple(cams))
    R = turn(rig, 0.4, -0.25)
    fixed = refit_rig(rig, R)
    s, right = rig.sensor, rig.right
    p = s.grid()                                                # virtual pixel centres, rig frame
    seen = right.centre + (p - right.centre) @ R               # C + R^T (p - C), row-wise
    F = rig.world_from_rig
    uv, ok = image_of(cams[1], seen.reshape(-1, 3) @ F[:3, :3].T + F[:3, 3])
    uv, ok = uv.reshape(p.shape[:2] + (2,)), ok.reshape(p.shape[:2])
    ok &= (uv[..., 0] >= 0) & (uv[..., 0] <= 639) & (uv[..., 1] >= 0) & (uv[..., 1] <= 479)
    imm = fixed.right.imm
    assert (imm.valid == ok).mean() > 0.9999
    both = imm.valid & ok
    assert np.abs(np.stack([imm.map_x, imm.map_y], -1)[both] - uv[both]).max() < 1e-3
    d = fixed.right.direction[both]
    assert np.abs(d - (p - right.centre)[both] / np.linalg.norm((p - right.centre)[both], axis=-1)[:, None]
                  ).max() < 1e-9
    arrays = replace(rig, right=RigCamera(right.name, right.centre, right.imm, right.direction, right.im,
                                          dict(right.info)))                  # the model dropped
    resampled = refit_rig(arrays, R).right.imm.valid
    assert imm.valid.sum() - resampled.sum() > 0.01 * imm.valid.size     # the band it no longer has

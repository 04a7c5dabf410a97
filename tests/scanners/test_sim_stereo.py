"""The simulated stereo rig: poses, true projection, datasets, and registration of separately calibrated
cameras against the true transforms."""

import json

import numpy as np
import pytest

from calib.prvm_file import load_prvm
from scanners.sim.stereo import facing_straight, own_to_common, project_true, simulate_stereo, stereo_lenses
from stereodic.stereo.register import apply_registration, estimate_registration

SMALL = dict(width=160, height=128, pixel_mm=0.0053 * 8)


def test_pair_poses():
    left, right = stereo_lenses("brown", "noncentral", 160, 128, pixel_mm=SMALL["pixel_mm"], baseline_mm=180)
    assert np.linalg.norm(right.centre_mm - left.centre_mm) == pytest.approx(180)
    assert left.centre_mm[0] < right.centre_mm[0]
    assert left.family == "brown" and right.family == "noncentral"
    # both look at the display centre: their axes meet there
    for lens in (left, right):
        axis = lens.rotation[:, 2]
        p = np.array([959.5 * 0.2745, 539.5 * 0.2745, 0.0]) - lens.centre_mm
        assert np.linalg.norm(np.cross(axis, p / np.linalg.norm(p))) < 1e-9


@pytest.mark.parametrize("family", ["brown", "noncentral", "freeform"])
def test_project_true_inverts_the_lens(family):
    lens, _ = stereo_lenses(family, "brown", 160, 128, pixel_mm=SMALL["pixel_mm"])
    rng = np.random.default_rng(0)
    uv = np.column_stack([rng.uniform(0, 159, 300), rng.uniform(0, 127, 300)])
    o, d = lens.rays(uv[:, 0], uv[:, 1])
    x = o + rng.uniform(-80, 80, 300)[:, None] * d
    assert np.abs(project_true(lens, x) - uv).max() < 1e-6


def test_registration_recovers_the_true_transform():
    lens, _ = stereo_lenses("noncentral", "brown", 160, 128, pixel_mm=SMALL["pixel_mm"])
    own = facing_straight(lens)
    assert np.allclose(own.rotation[:, 2], [0, 0, 1])
    rot, t = own_to_common(own, lens)
    reg = estimate_registration(own.true_prvm(), lens.true_prvm())
    assert np.abs(reg.rotation - rot).max() < 1e-9 and np.abs(reg.translation_mm - t).max() < 1e-6
    moved = apply_registration(own.true_prvm(), reg, "common")
    truth = lens.true_prvm()
    assert np.abs(moved.origin - truth.origin).max() < 1e-6 and moved.meta["wcs"] == "common"


@pytest.mark.slow
def test_joint_dataset_calibrates_into_one_rig(tmp_path):
    from stereodic.cli import main
    from stereodic.stereo.rig import load_rig
    out = simulate_stereo(tmp_path / "st", left="brown", right="freeform", width=160, height=128,
                          lens_options={"pixel_mm": SMALL["pixel_mm"]},
                          supersample=8)
    for cam in ("cam0", "cam1"):
        assert main(["calibrate", str(out), "--camera", cam, "-o", str(tmp_path / f"{cam}.npz")]) == 0
    assert main(["rig", str(tmp_path / "cam0.npz"), str(tmp_path / "cam1.npz"), "-o", str(tmp_path / "rig.npz")]) == 0
    rig = load_rig(tmp_path / "rig.npz")
    truth = [load_prvm(out / f"truth_{c}.npz") for c in ("cam0", "cam1")]
    lenses = stereo_lenses("brown", "freeform", 160, 128, pixel_mm=SMALL["pixel_mm"])
    for cam, lens in zip((rig.left, rig.right), lenses):
        assert np.linalg.norm(cam.centre - lens.centre_mm) < 1.0          # mm, from calibrated rays
    assert truth[0].meta["wcs"] == truth[1].meta["wcs"]


@pytest.mark.slow
def test_separately_calibrated_cameras_are_registered(tmp_path):
    from stereodic.cli import main
    out = simulate_stereo(tmp_path / "st", left="noncentral", right="brown", width=160, height=128, separate=True,
                          lens_options={"pixel_mm": SMALL["pixel_mm"]}, supersample=8)
    files = {}
    for name, dataset, cam in (("L", "left", None), ("R", "right", None), ("LR", "register", "cam0"),
                               ("RR", "register", "cam1")):
        files[name] = str(tmp_path / f"{name}.npz")
        argv = ["calibrate", str(out / dataset), "-o", files[name]] + (["--camera", cam] if cam else [])
        assert main(argv) == 0
    assert main(["rig", files["L"], files["R"], "-o", str(tmp_path / "rig.npz")]) == 2     # not one WCS
    assert main(["rig", files["L"], files["R"], "--register", files["LR"], files["RR"], "-o",
                 str(tmp_path / "rig.npz")]) == 0
    truth = json.loads((out / "registration_truth.json").read_text())["cameras"]
    for own, common, cam in ((files["L"], files["LR"], "cam0"), (files["R"], files["RR"], "cam1")):
        reg = estimate_registration(load_prvm(own), load_prvm(common))
        angle = np.degrees(np.arccos(np.clip((np.trace(reg.rotation.T @ np.array(truth[cam]["rotation"])) - 1) / 2,
                                             -1, 1)))
        assert angle < 0.01                                                  # degrees
        assert np.linalg.norm(reg.translation_mm - truth[cam]["translation_mm"]) < 0.1   # mm

"""End to end: captures -> PRVM, against the truth (an independent synthetic generator and the simulator)."""

import json

import numpy as np
import pytest

from calib.capture import CoverGlass, load_capture
from calib.calibration import calibrate_camera
from calib.errors import InputError
from calib.evaluate import ErrorStats, ray_error_px
from calib.prvm_file import load_prvm
from calib.regularise import Smoother
from stereodic.cli import main
from synth_capture import make_capture

FLATS = [0, 32, 64, 96, 128, 160, 192, 224, 255]


def _err_mm(prvm, truth, z=20.0):
    e = prvm.at_z(z) - truth.at_z(z)
    return np.sqrt((e[prvm.valid] ** 2).sum(-1).mean())


def test_noise_free_rays_are_exact(tmp_path):
    manifest, truth = make_capture(tmp_path, gamma=1.0)
    cal = calibrate_camera(load_capture(manifest), smoother=None)
    assert cal.prvm.valid.all()
    assert _err_mm(cal.prvm, truth) < 0.003          # 8-bit code rounding only; 1 display px = 0.25 mm


def test_gamma_with_flats_is_compensated(tmp_path):
    """A 2.2 gamma without compensation errs by a quarter radian; with the flats it is removed."""
    manifest, truth = make_capture(tmp_path, gamma=2.2, flat_levels=FLATS, periods=(480, 96, 24))
    cal = calibrate_camera(load_capture(manifest), smoother=None)
    assert cal.intensity is not None and not cal.notes
    assert _err_mm(cal.prvm, truth) < 0.004
    # the same capture without flats is refused, not decoded with the gamma's error
    manifest2, _ = make_capture(tmp_path / "noflats", gamma=2.2, periods=(480, 96, 24))
    with pytest.raises(InputError, match="flat frames"):
        calibrate_camera(load_capture(manifest2), smoother=None)


def test_cover_glass_three_positions_four_steps_16bit(tmp_path):
    manifest, truth = make_capture(tmp_path, zs=(0.0, 25.0, 60.0), steps=4, bit_depth=16, noise=20.0,
                                   glass=CoverGlass(1.2, 1.5), periods=(480, 80, 16))
    cal = calibrate_camera(load_capture(manifest), smoother=None)
    assert _err_mm(cal.prvm, truth) < 0.004
    three = cal.prvm.extra["used_positions"] == 3
    assert three.mean() > 0.5 and np.isfinite(cal.prvm.residual_mm[three]).all()
    # ignoring the glass would leave an error of t * tan(a) * (1 - 1/n) ~ 0.06 mm at the edges
    cap = load_capture(manifest)
    cap.display = type(cap.display)(*cap.display.__dict__.values())
    object.__setattr__(cap.display, "cover_glass", None)
    assert _err_mm(calibrate_camera(cap, smoother=None).prvm, truth) > 5 * _err_mm(cal.prvm, truth)


def test_regularisation_lowers_noise_without_bias(tmp_path):
    manifest, truth = make_capture(tmp_path, w=128, h=96, noise=3.0, periods=(480, 60, 12))
    cap = load_capture(manifest)
    raw = calibrate_camera(cap, smoother=None)
    reg = calibrate_camera(cap, smoother=Smoother(10, 3, 2))
    assert _err_mm(reg.prvm, truth) < 0.4 * _err_mm(raw.prvm, truth)
    unc = reg.prvm.extra["uncertainty_mm"][..., 0]
    assert unc.shape == (96, 128) and np.all(unc[reg.prvm.valid] > 0)


@pytest.fixture(scope="module")
def sim_brown(tmp_path_factory):
    sim = pytest.importorskip("scanners.sim.calibration")
    out = tmp_path_factory.mktemp("sim") / "brown"
    sim.simulate_calibration(out, lens="brown", width=160, height=128)
    return out


def test_simulated_brown_lens_against_truth(sim_brown, tmp_path):
    assert main(["calibrate", str(sim_brown), "--report", str(tmp_path / "rep"), "-o", str(tmp_path / "cam.npz")]) == 0
    prvm = load_prvm(tmp_path / "cam.npz")
    truth = load_prvm(sim_brown / "truth.npz")
    assert prvm.valid.all() and prvm.meta["camera"] == "cam0"
    reg = ErrorStats.of(ray_error_px(prvm, truth))
    raw_cal = calibrate_camera(load_capture(sim_brown), smoother=None)
    raw = ErrorStats.of(ray_error_px(raw_cal.prvm, truth))
    # on a 160x128 image most pixels lie within a window of the border, so the bound is looser than
    # the bench's 1280x1024 figure
    assert reg.rms < 0.35 * raw.rms and reg.rms < 0.06
    # the decoded display points agree with the truth's to a fraction of a display pixel
    dcr = truth.extra["display_cr"]
    for i, p in enumerate(raw_cal.positions):
        e = p.coord.transpose(1, 2, 0) - dcr[i]
        assert np.sqrt(np.mean(e[p.valid] ** 2)) < 0.3
    for name in ("distortion.png", "uncertainty.png", "mask.png", "display_response.json"):
        assert (tmp_path / "rep" / name).is_file()
    assert main(["show", str(tmp_path / "cam.npz"), "--truth", str(sim_brown / "truth.npz"),
                 "-o", str(tmp_path / "show")]) == 0
    assert (tmp_path / "show" / "error.png").is_file()
    assert json.loads((tmp_path / "rep" / "display_response.json").read_text())["levels"]


def test_an_in_focus_display_grid_does_not_move_the_rays_through_the_weights(tmp_path):
    # a telecentric lens with the bench's pixel footprint (3 camera pixels per display pixel) resolves the
    # display's pixel grid at its in-focus middle position: a pixel's fringe modulation and its decoding
    # error both follow the grid (the rows are 85 % lit: the y fringes), so weighting each point by its
    # own modulation moved the rays by 1.75 um along y as a whole; the weights from the modulation
    # averaged over a window do not
    sim = pytest.importorskip("scanners.sim.calibration")
    out = tmp_path / "tele"
    capture = sim.simulate_calibration(out, lens="telecentric", width=160, height=128, z_positions=(0.0, 25.0, 50.0),
                                       periods=(30, 240, 1920), stage_error_um=0.0, lens_options={"pixel_mm": 0.0053})
    truth = load_prvm(out / "truth.npz")
    cal = calibrate_camera(capture, refine=False)
    err_um = 1000 * (cal.prvm.at_z(0.0) - truth.at_z(0.0))[cal.prvm.valid][:, :2]
    assert abs(err_um[:, 1].mean()) < 0.2
    assert np.sqrt(np.mean(err_um ** 2)) < 1.0

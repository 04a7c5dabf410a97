"""Simulated calibration datasets and the `stereodic simulate` command."""

import json

import numpy as np
import pytest

from calib.capture import load_capture
from calib.errors import InputError
from calib.prvm_file import load_prvm
from scanners.sim import calibration
from scanners.sim.calibration import simulate_calibration
from scanners.sim.lenses import LENS_FAMILIES
from stereodic.cli import main

SMALL = dict(width=160, height=128, periods=(20, 100), flat_levels=(0, 128, 255))


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    out = tmp_path_factory.mktemp("sim")
    cap = simulate_calibration(out, lens="noncentral", steps=4, z_positions=(0.0, 20.0, 40.0), bit_depth=12,
                               cover_glass=(0.7, 1.5), seed=3, **SMALL)
    return out, cap


def test_dataset_has_every_frame_and_a_valid_manifest(dataset):
    out, cap = dataset
    again = load_capture(out)                                     # what the calibration will read
    assert again.kind == "calibration" and again.cameras == {"cam0": (160, 128)}
    assert again.z_positions("cam0") == [0.0, 20.0, 40.0]        # nominal positions
    assert len(again.frames) == 3 * (3 + 2 * 2 * 4)
    fringes = again.select("cam0", z_mm=20.0, axis="y", period_px=100)
    assert sorted(f.pattern.shift_rad for f in fringes) == pytest.approx([-np.pi / 2, 0, np.pi / 2, np.pi])
    assert fringes[0].file == "z001/cam0_y_P100_s0.png"
    assert again.select("cam0", z_mm=0.0, type="flat", level=128)[0].file == "z000/cam0_flat_128.png"
    first = again.frames[0]
    assert first.pattern.type == "flat"                           # intensity calibration comes first
    manifest = json.loads((out / "capture.json").read_text())
    assert manifest["display"]["gamma"] == 2.2
    assert manifest["display"]["cover_glass"] == {"thickness_mm": 0.7, "refractive_index": 1.5}
    assert manifest["cameras"]["cam0"]["bit_depth"] == 12


def test_images_are_12_bit_with_the_brightest_fringe_near_full_scale(dataset):
    out, cap = dataset
    crest = max(cap.read(f).max() for f in cap.select("cam0", z_mm=0.0, type="fringe", period_px=20))
    img = cap.read(cap.frames[0])
    assert img.dtype == np.uint16 and cap.max_value("cam0", img) == 4095
    assert 0.84 * 4095 < crest < 0.93 * 4095


def test_truth_holds_the_true_rays_and_rig(dataset):
    out, cap = dataset
    truth = load_prvm(out / "truth.npz")
    assert truth.origin.shape == (128, 160, 3) and truth.valid.all() and truth.reference_z_mm == 0.0
    nominal, true = truth.extra["stage_nominal_z_mm"], truth.extra["stage_true_z_mm"]
    assert list(nominal) == [0.0, 20.0, 40.0]
    assert 0 < np.abs(true - nominal).max() < 0.02
    assert truth.extra["gain"].shape == (128, 160) and 0.005 < truth.extra["gain"].std() < 0.02
    assert truth.extra["vignetting"].max() <= 1.0
    assert 350 < truth.meta["working_distance_mm"] < 450
    assert 0.1 < truth.meta["pixel_footprint_mm"] < 0.3
    # The truth's display coordinates are where the true rays cross the pixel plane (up to the
    # cover glass's sub-pixel shift) at the true stage positions.
    cr = truth.extra["display_cr"]
    assert cr.shape == (3, 128, 160, 2)
    for i, z in enumerate(true):
        pts = truth.at_z(z)
        assert np.abs(pts[..., 0] / 0.2745 - cr[i, ..., 0]).max() < 0.5
        assert np.abs(pts[..., 1] / 0.2745 - cr[i, ..., 1]).max() < 0.5


def test_rendered_fringe_follows_the_display_coordinates_of_the_truth(dataset):
    # The camera sees the fringe's crest where the truth's display coordinate is a multiple of the
    # period: the brightest pixels of a shift-0 frame sit at phase ~0.
    out, cap = dataset
    truth = load_prvm(out / "truth.npz")
    frame = cap.select("cam0", z_mm=0.0, axis="x", period_px=20, shift_rad=0.0)[0]
    img = cap.read(frame).astype(float)
    phase = np.angle(np.exp(2j * np.pi * truth.extra["display_cr"][0, ..., 0] / 20))
    bright = img > np.percentile(img, 95)
    dark = img < np.percentile(img, 5)
    assert np.abs(phase[bright]).max() < 0.6 and np.abs(phase[dark]).min() > np.pi - 0.6


def test_chessboards_are_inside_the_field(tmp_path):
    cap = simulate_calibration(tmp_path, lens="brown", chessboard=True, noise=False, **SMALL)
    boards = cap.select("cam0", type="chessboard")
    assert len(boards) == 2 * 5
    truth = load_prvm(tmp_path / "truth.npz")
    cr = truth.extra["display_cr"]
    for f in boards:
        cols, rows = f.pattern.squares
        c0, r0 = f.pattern.origin_px
        size = f.pattern.square_px
        i = cap.z_positions("cam0").index(f.z_mm)
        assert cr[i, ..., 0].min() < c0 and c0 + cols * size < cr[i, ..., 0].max()
        assert cr[i, ..., 1].min() < r0 and r0 + rows * size < cr[i, ..., 1].max()
        img = cap.read(f)
        assert img.min() < 20 and img.max() > 150                 # dark squares and light ones seen


@pytest.mark.parametrize("family", ["brown", "telecentric", "scheimpflug"])
def test_small_sensor_chessboards_fit_each_position_and_are_found(tmp_path, family):
    """At 320x256 every board lies inside the camera's field (its true outline on the display, a
    trapezoid for the oblique Scheimpflug view, which also moves across the display with the stage) at
    its own stage position, and OpenCV finds all its inner corners."""
    import cv2

    from calib.opencv_baseline import chessboard_corners
    cap = simulate_calibration(tmp_path, lens=family, width=320, height=256, periods=(1920,), flat_levels=(),
                               chessboard=True, noise=False)
    cr = load_prvm(tmp_path / "truth.npz").extra["display_cr"]
    boards = cap.select("cam0", type="chessboard")
    assert len(boards) == 2 * 5
    for f in boards:
        c = cr[cap.z_positions("cam0").index(f.z_mm)]
        outline = np.concatenate([c[0], c[1:, -1], c[-1, -2::-1], c[-2:0:-1, 0]]).astype(np.float32)
        c0, r0 = f.pattern.origin_px
        w, h = np.array(f.pattern.squares) * f.pattern.square_px
        for corner in ((c0, r0), (c0 + w, r0), (c0, r0 + h), (c0 + w, r0 + h)):
            assert cv2.pointPolygonTest(outline, (float(corner[0]), float(corner[1])), True) > 0
        found = chessboard_corners(cap.read(f), tuple(f.pattern.squares))
        assert found is not None and len(found) == 8 * 6


@pytest.mark.parametrize("family", LENS_FAMILIES)
def test_every_lens_family_makes_a_dataset_with_one_position(tmp_path, family):
    cap = simulate_calibration(tmp_path, lens=family, z_positions=(10.0,), periods=(30,), flat_levels=(),
                               width=64, height=48)
    assert len(cap.frames) == 6 and cap.z_positions("cam0") == [10.0]


def test_an_interrupted_run_leaves_no_manifest(tmp_path, monkeypatch):
    simulate_calibration(tmp_path, **SMALL, noise=False)         # a complete dataset is there already
    calls = []

    def failing(path, image):
        calls.append(path)
        if len(calls) > 3:
            raise OSError("disk full")
        np.save(tmp_path / "junk.npy", image)

    monkeypatch.setattr(calibration, "write_gray", failing)
    with pytest.raises(OSError):
        simulate_calibration(tmp_path, **SMALL)
    with pytest.raises(InputError, match="manifest is missing"):
        load_capture(tmp_path)


@pytest.mark.parametrize("kwargs, where", [
    (dict(steps=2), "--steps"), (dict(periods=()), "--periods"), (dict(periods=(0, 60)), "--periods"),
    (dict(z_positions=()), "--positions-mm"), (dict(z_positions=(0, 0)), "--positions-mm"),
    (dict(bit_depth=9), "--bit-depth"), (dict(cover_glass=(1.0, 0.5)), "--cover-glass"),
    (dict(lens="fisheye"), "--lens"), (dict(lens_options={"target_mm": (-400, -400, 0)}), "does not see"),
    (dict(steps=(3, 4, 5)), "--steps"), (dict(overexposure=1.5), "flaws"),
])
def test_bad_arguments_are_input_errors(tmp_path, kwargs, where):
    with pytest.raises(InputError, match=where):
        simulate_calibration(tmp_path, **{**SMALL, **kwargs})


def test_a_real_benchs_flaws_are_in_the_images_and_the_truth(tmp_path):
    """Each flaw on: the display's (recorded pitch nominal, bow, angle), the sensor's (10 bits
    LSB-aligned in 16-bit files, hot pixels, ambient light, over-exposure), the stage's, a display not
    filling the view, unequal steps per period."""
    from scanners.sim.display import SimDisplay
    display = SimDisplay(bow_mm=0.1, pitch_error=1e-4, falloff=0.3, gamma_tilt=-0.1)
    cap = simulate_calibration(tmp_path, lens="brown", width=160, height=128, periods=(20, 100, 1920),
                               steps=(5, 3, 4), flat_levels=(0, 128, 255), bit_depth=10, display=display,
                               hot_pixels=0.01, ambient=0.03, ambient_variation=0.5, overexposure=0.03,
                               stage_tilt_deg=0.02, stage_lateral_um=5.0, unseen=0.15)
    truth = load_prvm(tmp_path / "truth.npz")
    assert cap.display.pitch_mm == (0.2745, 0.2745)                        # the manifest: nominal
    d = truth.meta["display"]
    assert d["bow_mm"] == 0.1 and d["pitch_error"] == 1e-4 and d["true_pitch_mm"][0] == pytest.approx(0.2745 * 1.0001)
    assert d["falloff"] == 0.3 and truth.meta["sensor"]["ambient"] == 0.03
    assert truth.meta["stage"]["tilt_deg"] == 0.02 and truth.extra["display_rotation"].shape == (2, 3, 3)
    # 10 bits LSB-aligned: 16-bit files, values up to 1023, the crest of the over-exposed pixels there
    frames = cap.select("cam0", z_mm=0.0, type="fringe", period_px=20)
    assert len(frames) == 2 * 5 and len(cap.select("cam0", z_mm=0.0, type="fringe", period_px=100)) == 2 * 3
    images = [cap.read(f) for f in frames]
    assert images[0].dtype == np.uint16 and max(int(i.max()) for i in images) == 1023
    hot = truth.extra["hot_pixels_e"] >= truth.meta["sensor"]["full_well_e"]
    dark = cap.read(cap.select("cam0", z_mm=0.0, type="flat", level=0)[0])
    assert hot.any() and (dark[hot] == 1023).all()
    # ambient light: the black flat's dark pixels sit above the sensor's dark offset
    assert np.median(dark) > 0.01 * 1023 + 0.02 * 1023
    # the display leaves the stated share of rows unseen at the last position (by the true rays)
    cr = truth.extra["display_cr"][-1]
    unseen_rows = np.mean(cr[:, 80, 1] > 1080 - 0.5)
    assert unseen_rows == pytest.approx(0.15, abs=0.03)
    clipped = np.mean([np.mean(img == 1023) for img in images])
    assert 0.003 < clipped < 0.05


def test_command_line(tmp_path, capsys):
    out = tmp_path / "ds"
    assert main(["simulate", "calibration", "--lens", "telecentric", "--width", "64", "--height", "48",
                 "--periods", "8,40", "--positions-mm", "0,2", "--no-noise", "--cover-glass", "0.5,1.5",
                 "--bit-depth", "16", "-o", str(out)]) == 0
    cap = load_capture(out)
    assert len(cap.frames) == 2 * (9 + 2 * 2 * 3) and cap.display.cover_glass.thickness_mm == 0.5
    assert main(["simulate", "calibration", "--steps", "2", "-o", str(tmp_path / "bad")]) == 2
    assert "--steps" in capsys.readouterr().err
    assert main(["simulate", "dic", "--width", "8", "-o", str(tmp_path / "dic")]) == 2
    assert "--width" in capsys.readouterr().err


@pytest.mark.slow
def test_default_dataset_is_complete(tmp_path):
    # Its generation time is a figure of `stereodic bench sim`, not of a test.
    cap = simulate_calibration(tmp_path)
    assert len(cap.frames) == 2 * (9 + 2 * 3 * 3) and cap.cameras["cam0"] == (1280, 1024)

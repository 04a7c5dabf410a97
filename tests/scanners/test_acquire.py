"""Acquisition on simulated devices: the plan's order, faults at every step, resume, and the CLI."""

import json

import numpy as np
import pytest

from calib.capture import load_capture
from calib.imageio import read_gray, write_gray
from calib.patterns import calibration_sequence
from scanners.acquire import Settings, calibration_plan, dic_plan, open_writer, run, scan_plan
from scanners.camera import SaturatedError, SimulatedCamera
from scanners.display import SimScreen
from scanners.errors import HardwareError
from scanners.stage_url import open_stage
from stereodic.cli import main

POSITIONS = (0.0, 50.0)
PERIODS = (120, 1920)
FLATS = (0, 128, 240)
PER_POSITION = len(FLATS) + 2 * len(PERIODS) * 3
STAGE = "emulated:zaber?speed=5000&timeout=0.5"
CLI = ["--display", "sim", "--camera", "sim:brown?size=96x80", "--positions-mm", "0,50", "--periods", "120,1920",
       "--flat-levels", "0,128,240", "--settle-ms", "0"]


def test_calibration_plan_order():
    shots = calibration_plan((64, 48), POSITIONS, PERIODS, 3, FLATS)
    assert len(shots) == 2 * PER_POSITION
    first = shots[:PER_POSITION]
    assert [s.stem for s in first[:3]] == ["flat_0", "flat_128", "flat_240"]     # intensity first
    assert [s.stem for s in first[3:9]] == ["x_P1920_s0", "x_P1920_s1", "x_P1920_s2",
                                            "x_P120_s0", "x_P120_s1", "x_P120_s2"]  # longest period first
    assert first[-1].stem == "y_P120_s2"
    assert {s.z_mm for s in first} == {0.0} and {s.z_mm for s in shots[PER_POSITION:]} == {50.0}
    assert {s.folder for s in shots[PER_POSITION:]} == {"z001"}
    # the images are calib.patterns' own
    seq = calibration_sequence(64, 48, periods=PERIODS, steps=3, axes=("x", "y"), low=20, high=240,
                               flat_levels=FLATS)
    assert all(np.array_equal(s.image, img) and s.pattern == p for s, (p, img) in zip(first, seq))


class FailingCamera(SimulatedCamera):
    """A simulated camera that is unplugged at its `fail_at`-th grab."""

    fail_at = None
    grabs = 0

    def grab(self):
        self.grabs += 1
        if self.grabs == self.fail_at:
            raise HardwareError(f"{self.name}: the camera returned no frame (unplugged?)")
        return super().grab()


class FailingScreen(SimScreen):
    fail_at = None
    shows = 0

    def _show(self, image):
        self.shows += 1
        if self.shows == self.fail_at:
            raise HardwareError("screen:0: lost the display")
        super()._show(image)


def acquire(out, fault=None, camera_fails_at=None, screen_fails_at=None, settings=Settings()):
    """One acquisition run with library calls, optionally with a fault; returns the frames taken."""
    stage = open_stage(STAGE)
    try:
        if fault:
            stage.emulator.inject(fault[0], at_move=fault[1], count=10**9 if fault[0] == "timeout" else 1)
        screen = FailingScreen()
        screen.fail_at = screen_fails_at
        cam = FailingCamera("cam0", screen, stage.emulator.true_position_mm, size=(96, 80), seed=3)
        cam.fail_at = camera_fails_at
        cam.set_exposure(240, 0.0)
        writer = open_writer(out, "calibration", [cam], screen.sim.record())
        return run(writer, calibration_plan(screen.size, POSITIONS, PERIODS, 3, FLATS), [cam], stage, screen,
                   settings)
    finally:
        stage.close()


def assert_same_dataset(a, b):
    ma, mb = (json.loads((d / "capture.json").read_text()) for d in (a, b))
    assert ma == mb
    for f in ma["frames"]:
        assert (a / f["file"]).read_bytes() == (b / f["file"]).read_bytes(), f["file"]


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    out = tmp_path_factory.mktemp("reference")
    assert acquire(out) == 2 * PER_POSITION
    return out


def test_reference_dataset_is_complete(reference):
    cap = load_capture(reference)
    assert len(cap.frames) == 2 * PER_POSITION
    assert cap.z_positions("cam0") == [0.0, 50.0]
    img = cap.read(cap.select("cam0", type="flat", level=240, z_mm=0.0)[0])
    dark = cap.read(cap.select("cam0", type="flat", level=0, z_mm=0.0)[0])
    assert img.mean() > 150 > 20 > dark.mean()      # it really sees the display


@pytest.mark.parametrize("fault", [
    dict(fault=("timeout", 1)),          # the stage stops answering at the second position
    dict(fault=("alarm", 1)),            # it stalls
    dict(fault=("drop", 1)),             # the cable is pulled
    dict(fault=("reject", 1)),           # it refuses the move
    dict(camera_fails_at=20),            # the camera goes away mid-position
    dict(screen_fails_at=5),             # the display fails
])
def test_fault_then_resume_equals_uninterrupted(tmp_path, reference, fault):
    with pytest.raises(HardwareError):
        acquire(tmp_path, **fault)
    # what is on disk is a valid dataset listing only complete frames
    part = load_capture(tmp_path, min_positions=0)
    assert 0 < len(part.frames) < 2 * PER_POSITION
    for f in part.frames:
        assert read_gray(part.path(f)).shape == (80, 96)
    taken = acquire(tmp_path)
    assert taken == 2 * PER_POSITION - len(part.frames)
    assert_same_dataset(reference, tmp_path)


def test_nothing_to_do_when_complete(tmp_path, reference):
    acquire(tmp_path)
    assert acquire(tmp_path) == 0


def test_saturated_fringe_is_refused(tmp_path):
    stage = open_stage(STAGE)
    try:
        screen = SimScreen()
        cam = SimulatedCamera("cam0", screen, stage.emulator.true_position_mm, size=(96, 80))
        cam.set_exposure(240, 0.0, fraction=2.0)           # twice too bright
        writer = open_writer(tmp_path, "calibration", [cam], screen.sim.record())
        with pytest.raises(SaturatedError, match="saturated; lower the exposure"):
            run(writer, calibration_plan(screen.size, POSITIONS, PERIODS, 3, FLATS), [cam], stage, screen)
    finally:
        stage.close()
    cap = load_capture(tmp_path, min_positions=0)
    saturated = [float(np.mean(cap.read(f) == 255)) for f in cap.frames]
    # the flats are kept even saturated (they measure the response); fringes are kept only if not
    assert [f.pattern.type for f in cap.frames[:3]] == ["flat"] * 3 and saturated[2] > 0.01
    assert 3 <= len(cap.frames) < PER_POSITION
    assert all(s <= 1e-4 for s in saturated[3:])


def test_cli_fault_is_one_line_and_the_same_command_resumes(tmp_path, capsys):
    ref, out = tmp_path / "ref", tmp_path / "out"
    assert main(["acquire", "calibration", "--stage", STAGE, *CLI, "-o", str(ref)]) == 0
    faulty = ["acquire", "calibration", "--stage", STAGE + "&fault=alarm@1", *CLI, "-o", str(out)]
    capsys.readouterr()
    assert main(faulty) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("stereodic: hardware fault: zaber stage") and "FS" in err[0]
    assert len(load_capture(out, min_positions=0).frames) == PER_POSITION
    # the same command resumes (the emulator is new, so the fault is gone only if we drop it: a real
    # bench would have been repaired) -> same command without the fault
    assert main(["acquire", "calibration", "--stage", STAGE, *CLI, "-o", str(out)]) == 0
    a = json.loads((ref / "capture.json").read_text())
    b = json.loads((out / "capture.json").read_text())
    assert a["frames"] == b["frames"]
    for f in a["frames"]:
        assert (ref / f["file"]).read_bytes() == (out / f["file"]).read_bytes()
    assert (ref / "truth.npz").is_file() and (out / "truth.npz").is_file()


def test_cli_bad_arguments(tmp_path, capsys):
    base = ["acquire", "calibration", "--stage", STAGE, "-o", str(tmp_path / "x")]
    assert main(base + CLI[:4] + ["--positions-mm", "0,0"]) == 2
    assert "distinct" in capsys.readouterr().err
    assert main(base + CLI + ["--steps", "2"]) == 2
    assert main(["acquire", "calibration", "--stage", "thorlabs:///dev/x", *CLI, "-o", str(tmp_path)]) == 2
    assert main(["acquire", "calibration", "--stage", STAGE, "--display", "file:" + str(tmp_path / "d")
                 + "?size=64x48", "--camera", "sim", "-o", str(tmp_path / "y")]) == 2
    assert "needs --display sim" in capsys.readouterr().err


def photos(folder, n, size=(40, 30), start=0):
    folder.mkdir(exist_ok=True)
    for i in range(n):
        write_gray(folder / f"IMG_{start + i:04d}.png", np.full((size[1], size[0]), 10 * (start + i), np.uint8))


def test_dic_with_folder_cameras(tmp_path):
    photos(tmp_path / "left", 3)
    photos(tmp_path / "right", 3)
    out = tmp_path / "dic"
    cmd = ["acquire", "dic", "--camera", f"folder:{tmp_path / 'left'}", "--camera",
           f"folder:{tmp_path / 'right'}?timeout=0.3", "--states", "3", "--interval-s", "0", "-o", str(out)]
    assert main(cmd) == 0
    cap = load_capture(out)
    assert cap.kind == "dic" and cap.states("cam0") == [0, 1, 2] and cap.states("cam1") == [0, 1, 2]
    assert [(f.camera, f.state, f.extra["source"]) for f in cap.frames] == [
        (c, s, f"IMG_{s:04d}.png") for s in range(3) for c in ("cam0", "cam1")]
    assert cap.read(cap.select("cam1", state=2)[0]).max() == 20


def test_dic_resumes_without_reusing_photos(tmp_path, capsys):
    photos(tmp_path / "cam", 2)
    out = tmp_path / "dic"
    cmd = ["acquire", "dic", "--camera", f"folder:{tmp_path / 'cam'}?timeout=0.2", "--states", "3", "--interval-s",
           "0", "-o", str(out)]
    assert main(cmd) == 1                                  # the third photo never came
    assert "no new photo" in capsys.readouterr().err
    assert len(load_capture(out).frames) == 2
    photos(tmp_path / "cam", 1, start=2)                   # the user takes it
    assert main(cmd) == 0
    cap = load_capture(out)
    assert [f.extra["source"] for f in cap.frames] == ["IMG_0000.png", "IMG_0001.png", "IMG_0002.png"]


def test_scan_plan_and_file_display(tmp_path):
    photos(tmp_path / "cam", 6)
    out, shown = tmp_path / "scan", tmp_path / "shown"
    cmd = ["acquire", "scan", "--display", f"file:{shown}?size=64x48", "--camera", f"folder:{tmp_path / 'cam'}",
           "--periods", "64", "--steps", "3", "--states", "2", "--interval-s", "0", "-o", str(out)]
    assert main(cmd) == 0
    cap = load_capture(out)
    assert cap.kind == "scan" and cap.extra["projector"] == {"width_px": 64, "height_px": 48}
    assert [f.file for f in cap.frames][:3] == ["s000/cam0_x_P64_s0.png", "s000/cam0_x_P64_s1.png",
                                                "s000/cam0_x_P64_s2.png"]
    assert cap.states("cam0") == [0, 1]
    seq = calibration_sequence(64, 48, periods=[64], steps=3, axes=("x",), low=20, high=240)
    files = sorted(shown.glob("*.png"))
    assert len(files) == 6
    for f, (_, img) in zip(files, seq + seq):
        assert np.array_equal(read_gray(f), img)


def test_dic_plan_shows_nothing():
    shots = dic_plan([0, 1])
    assert [(s.image, s.state, s.pattern.type) for s in shots] == [(None, 0, "none"), (None, 1, "none")]
    assert len(scan_plan((64, 48), [0], [64], 4, flats=[128])) == 1 + 4


@pytest.mark.slow
def test_acquired_dataset_calibrates_as_well_as_a_simulated_one(tmp_path):
    from calib.evaluate import ErrorStats, ray_error_px
    from calib.prvm_file import load_prvm
    acq, sim = tmp_path / "acq", tmp_path / "sim"
    assert main(["acquire", "calibration", "--stage", "emulated:grbl?speed=5000&feed=300000", "--display", "sim",
                 "--camera", "sim:brown?size=160x128", "--settle-ms", "0", "-o", str(acq)]) == 0
    assert main(["simulate", "calibration", "--width", "160", "--height", "128", "-o", str(sim)]) == 0
    rms = {}
    for d in (acq, sim):
        assert main(["calibrate", str(d), "-o", str(d / "cam.npz")]) == 0
        err = ray_error_px(load_prvm(d / "cam.npz"), load_prvm(d / "truth.npz"))
        stats = ErrorStats.of(err, margin=2)
        assert stats.valid > 0.99
        rms[d.name] = stats.rms
    assert rms["acq"] < 0.05                              # pixels, on the working plane
    assert rms["acq"] <= 1.25 * rms["sim"] + 0.005, rms

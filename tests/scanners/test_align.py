"""The alignment aid on the simulated bench, against the simulator's truth (scanners.sim.aim computes the
true readings from the lens's true rays and the display's true pose; nothing it computes is fitted):
camera tilts of 0-5 degrees and stage-axis tilts, a central lens with distortion (brown) and the
free-form lens, read through the true PRVM (of the lens in another pose: the PRVM's frame does not
matter) and through the true OpenCV pinhole; the pattern-alone estimate within the bounds the docs
state; the advice, followed, squares the camera and the screen; the command line end to end, and its
faults."""

import dataclasses
import functools
import json
import re

import cv2
import numpy as np
import pytest

from calib.alignment import PinholeRays, PrvmRays, Reading, StageAxis
from calib.imageio import write_gray, write_rgb
from calib.pinhole import PinholeCamera
from scanners.align import AlignRecord, AlignSession, AlignSettings, default_periods, readout, run
from scanners.align_advice import camera_advice, stage_advice
from scanners.align_picture import EXPECTED, OUTSIDE, WITHIN, fused_picture
from scanners.camera import SimulatedCamera
from scanners.display import SimScreen, open_screen
from scanners.errors import HardwareError
from scanners.sim.aim import aim, true_alignment
from scanners.sim.camera import SimCamera
from scanners.sim.display import SimDisplay
from scanners.sim.lenses import make_lens
from scanners.sim.optics import rotation
from scanners.sim.pose import DisplayPose
from scanners.sim.sensor import Sensor
from scanners.stage_url import open_stage
from stereodic.cli import main
from stereodic.virtual.camera import fit_optical_centre
from tests.scanners.xvfb import read_back, virtual_screen

SIZE = (320, 256)
PIXEL_UM = 21.2                      # the field of the default 1280x1024 camera at a quarter of its pixels
STAGE = "emulated:zaber?speed=5000&timeout=0.5"
TILTS = [(0.1, -0.15, 0.1), (-5.0, 3.5, -2.0), (4.5, 5.0, 1.5)]


def lens_of(family):
    return make_lens(family, width=SIZE[0], height=SIZE[1], seed=0, pixel_mm=PIXEL_UM / 1000)


@functools.lru_cache
def prvm_rays(family):
    """The true PRVM of the lens in its own (seeded) pose: another frame than the aimed camera's."""
    prvm = lens_of(family).true_prvm()
    return PrvmRays(prvm, fit_optical_centre(prvm)[0])


def pinhole_camera(family):
    p = lens_of(family).params
    k, tan = p["distortion"]["k"], p["distortion"]["p"]
    return PinholeCamera([[p["fx"], 0, p["cx"]], [0, p["fy"], p["cy"]], [0, 0, 1]],
                         [k[0], k[1], tan[0], tan[1], k[2]], np.eye(3), np.zeros(3), *SIZE)


def session(family, tilt, model, stage=None, **kw):
    screen = SimScreen()
    true_z = stage.emulator.true_position_mm if stage is not None else (lambda: 0.0)
    axis = stage.emulator.travel_axis if stage is not None else (0.0, 0.0, 1.0)
    cam = SimulatedCamera("cam0", screen, true_z, family, SIZE, 0, pixel_um=PIXEL_UM, aim=tilt, stage_axis=axis)
    cam.set_exposure(240, 0.0)
    return AlignSession(screen, cam, screen.pitch_mm, model,
                        settings=AlignSettings(default_periods(screen.size), hold_s=0.0), **kw), cam


def errors(m, cam):
    truth = true_alignment(cam.sim.lens, cam.screen.sim, cam.true_pose())
    got = m.reading.to_json()
    return {k: got[k] - truth[k] for k in ("tilt_x_deg", "tilt_y_deg", "roll_deg", "distance_mm")}, truth


@pytest.mark.parametrize("tilt", TILTS)
@pytest.mark.parametrize("family", ["brown", "freeform"])
def test_camera_readout_within_005_deg_through_the_prvm(family, tilt):
    s, cam = session(family, tilt, prvm_rays(family))
    s.calibrate_response()
    m = s.measure()
    err, truth = errors(m, cam)
    assert truth["tilt_x_deg"] == pytest.approx(tilt[0]) and truth["roll_deg"] == pytest.approx(tilt[2])
    assert max(abs(err[k]) for k in ("tilt_x_deg", "tilt_y_deg", "roll_deg")) < 0.05, err
    assert abs(err["distance_mm"]) < 0.1
    assert np.allclose(m.reading.line_of_sight_px, truth["line_of_sight_px"], atol=0.1)
    assert np.allclose(m.reading.foot_px, truth["foot_px"], atol=1.0)       # 0.05 deg at 400 mm is 1.3 px
    assert m.reading.square_within(0.2) == (max(abs(tilt[0]), abs(tilt[1])) <= 0.2)
    assert m.display_map.valid_fraction > 0.95 and m.fit.rms_px < 0.5


@pytest.mark.parametrize("tilt", [(0.1, -0.15, 0.1), (-5.0, 3.5, -2.0)])
def test_camera_readout_within_005_deg_through_the_opencv_pinhole(tilt):
    cam = pinhole_camera("brown")
    s, sim = session("brown", tilt, PinholeRays(cam.K, cam.dist, *SIZE))
    s.calibrate_response()
    err, _ = errors(s.measure(), sim)
    assert max(abs(err[k]) for k in ("tilt_x_deg", "tilt_y_deg", "roll_deg")) < 0.05, err


@pytest.mark.parametrize("family, bound_deg", [("brown", 0.6), pytest.param("freeform", 2.5, marks=pytest.mark.slow)])
def test_pattern_alone_with_the_stage(family, bound_deg):
    """Without intrinsics the stage's known travel fixes the focal length; the principal point stays
    assumed at the image centre and the lens undistorted (docs/real-bench.md states these bounds)."""
    with open_stage(STAGE + "&axis_deg=0.4,-0.3") as stage:
        s, cam = session(family, (2.5, -1.5, 0.8), None, stage)
        stage.move_to(0.0)
        s.calibrate_response()
        axis, _ = s.measure_stage(stage, (0.0, 50.0))
        stage.move_to(0.0)
        err, _ = errors(s.measure(0.0), cam)
    assert s.intrinsics.from_travel and s.intrinsics.focal_px == pytest.approx(cam.sim.lens.fx, rel=0.01)
    assert max(abs(err[k]) for k in ("tilt_x_deg", "tilt_y_deg", "roll_deg")) < bound_deg, err
    assert abs(err["distance_mm"]) < 1.0
    assert abs(axis.angle_x_deg - 0.4) < bound_deg and abs(axis.angle_y_deg + 0.3) < bound_deg


@pytest.mark.parametrize("family, axis_deg", [("brown", (0.3, -0.2)), ("freeform", (-1.2, 0.6)),
                                              ("freeform", (0.0, 0.0))])
def test_stage_axis_within_005_deg(family, axis_deg):
    with open_stage(STAGE + f"&axis_deg={axis_deg[0]},{axis_deg[1]}") as stage:
        s, _ = session(family, (1.5, -2.0, 0.5), prvm_rays(family), stage)
        stage.move_to(0.0)
        s.calibrate_response()
        axis, ms = s.measure_stage(stage, (0.0, 50.0))
    truth = np.array(stage.emulator.travel_axis)
    assert abs(axis.angle_x_deg - axis_deg[0]) < 0.05 and abs(axis.angle_y_deg - axis_deg[1]) < 0.05
    assert np.degrees(np.arccos(min(1.0, axis.axis @ truth))) < 0.05
    assert axis.travel_mm == pytest.approx(50.0 / truth[2], abs=0.2) and axis.rotation_deg < 0.02
    assert [m.z_mm for m in ms] == [0.0, 50.0]


def test_tracked_updates_follow_a_turning_camera():
    """Between full sets only the shortest period is shown, its fringe order taken from the last map;
    a turn too large for that (here 3 degrees, 76 display px at the screen, more than a quarter of the
    120 px period) is measured again in full, and every reading is the truth's."""
    s, cam = session("freeform", (1.0, -0.5, 0.2), prvm_rays("freeform"))
    s.calibrate_response()
    assert s.measure().frames == 12
    lens = cam.sim.lens
    for about, angle, frames in (("x", 0.15, 6), ("y", -0.1, 6), ("y", 3.0, 12), ("x", -0.2, 6)):
        lens = _turned(lens, about, angle)              # the person turns the camera about its centre
        cam.sim = SimCamera(lens, sensor=Sensor(bit_depth=8), supersample=3, seed=0)
        cam.set_exposure(240, 0.0)
        m = s.measure()
        err, _ = errors(m, cam)
        assert m.frames == frames, (about, angle)
        assert max(abs(err[k]) for k in ("tilt_x_deg", "tilt_y_deg", "roll_deg")) < 0.05, (about, angle, err)
    assert [s.measure().frames for _ in range(3)] == [6, 6, 12]       # and every 4th update in full


def test_a_stage_that_does_not_move_is_a_hardware_fault():
    with open_stage(STAGE + "&fault=slip@2") as stage:     # moves 0 and 1 go to 0, move 2 slips
        s, _ = session("brown", (1.0, 1.0, 0.0), prvm_rays("brown"), stage)
        stage.move_to(0.0)
        s.calibrate_response()
        with pytest.raises(HardwareError, match="sees the display where it was"):
            s.measure_stage(stage, (0.0, 50.0))


# ----------------------------------------------------------------------------------------- the words

def _turned(lens, about, angle_deg):
    """The lens turned about its projection centre by angle_deg about the WCS axis `about`."""
    return dataclasses.replace(lens, rotation=rotation(about, np.radians(angle_deg)) @ lens.rotation,
                               centre_mm=lens.centre_mm.copy())


def test_following_the_camera_advice_squares_it():
    """'tilt down' turns the line of sight towards the screen's bottom (+y: about x by -angle), 'turn
    left' towards its left (-x: about y by -angle), as a person behind the camera sees it."""
    display = SimDisplay()
    lens = aim(lens_of("brown"), 1.3, -0.9, 0.0)
    t = true_alignment(lens, display, DisplayPose())
    reading = Reading(t["tilt_x_deg"], t["tilt_y_deg"], t["roll_deg"], t["distance_mm"], np.zeros(2), np.zeros(2), 0)
    advice = camera_advice(reading, 0.2)
    assert advice == ["tilt the camera down 1.30 deg", "turn the camera right 0.90 deg"]
    fixed = _turned(_turned(lens, "x", -1.3), "y", 0.9)                      # down 1.3, right 0.9
    after = true_alignment(fixed, display, DisplayPose())
    assert abs(after["tilt_x_deg"]) < 0.03 and abs(after["tilt_y_deg"]) < 0.03
    rolled = Reading(0.0, 0.0, 0.5, 400.0, np.zeros(2), np.zeros(2), 0)
    assert camera_advice(rolled, 0.2) == ["roll the camera anticlockwise 0.50 deg (seen from behind)"]
    assert camera_advice(Reading(0.15, -0.1, 0.05, 400, np.zeros(2), np.zeros(2), 0), 0.2) == []


def test_following_the_stage_advice_puts_the_normal_on_the_axis():
    """The screen's right edge brought nearer the camera by the advised amount (a turn about its
    vertical axis) makes its normal the stage's direction of travel."""
    a = np.array([np.tan(np.radians(0.5)), np.tan(np.radians(-0.3)), 1.0])
    a /= np.linalg.norm(a)
    axis = StageAxis(a, 0.5, -0.3, a[:2] / a[2], 50.0, 50.0, 0.0)
    width, height = SimDisplay().size_mm
    advice = stage_advice(axis, (width, height), 0.2)
    assert advice[0].startswith("tilt the screen 0.50 deg: its right edge ")
    assert advice[1].startswith("tilt the screen 0.30 deg: its top edge ")
    right = float(advice[0].split("right edge ")[1].split(" mm")[0])
    top = float(advice[1].split("top edge ")[1].split(" mm")[0])
    # turn the screen: right edge (x = width) to z = -right, top edge (y = 0) to z = -top, relative
    x_axis = np.array([width, 0.0, -right])
    y_axis = np.array([0.0, height, top])                 # the bottom goes away as the top comes near
    normal = np.cross(x_axis, y_axis)
    normal /= np.linalg.norm(normal)
    assert np.degrees(np.arccos(normal @ a)) < 0.01
    level = StageAxis(np.array([0, 0, 1.0]), 0.1, -0.1, np.zeros(2), 50.0, 50.0, 0.0)
    assert stage_advice(level, (width, height), 0.2) == []


# ----------------------------------------------------------------------------------------- the picture

def near(pixels, colour, tol=40):
    """Which pixels are within `tol` of an RGB colour in every channel (lines are anti-aliased)."""
    return (np.abs(pixels.astype(int) - np.array(colour)) <= tol).all(axis=-1)


def test_the_picture_shows_both_crosshairs_in_the_tolerance_colour():
    pictures = {}
    for tilt in ((0.05, -0.08, 0.0), (1.5, -1.0, 0.3)):
        s, _ = session("brown", tilt, prvm_rays("brown"))
        s.calibrate_response()
        m = s.measure()
        lines = readout(m, s.settings, None, SimDisplay().size_mm, [])
        pictures[tilt[0] < 0.2] = (fused_picture(s.screen.size, m, s.pitch_mm, 0.2, lines), m)
    for within, (pic, m) in pictures.items():
        assert pic.shape == (1080, 1920, 3) and pic.dtype == np.uint8
        colour = np.array(WITHIN if within else OUTSIDE)
        other = np.array(OUTSIDE if within else WITHIN)
        assert (pic == colour).all(axis=-1).sum() > 2000 and (pic == other).all(axis=-1).sum() == 0
        fc, fr = np.rint(m.reading.foot_px).astype(int)
        assert near(pic[fr - 1:fr + 2], EXPECTED).any(axis=0).sum() > 1000   # the expected horizontal line
        assert near(pic[:, fc - 1:fc + 2], EXPECTED).any(axis=1).sum() > 500  # and its vertical line
        lc, lr = np.rint(m.reading.line_of_sight_px).astype(int)
        assert near(pic[lr - 12:lr + 13, lc - 12:lc + 13], colour).sum() > 20   # the captured centre


# ----------------------------------------------------------------------------------------- command line

CAMERA = f"sim:freeform?size={SIZE[0]}x{SIZE[1]}&pixel_um={PIXEL_UM}&tilt=3,-2&roll=1"


def test_command_line_end_to_end(tmp_path, capsys):
    lens_of("freeform").true_prvm().save(tmp_path / "cam0.npz")
    out = tmp_path / "align"
    assert main(["align", "--display", "sim", "--camera", CAMERA, "--stage", STAGE + "&axis_deg=0.25,0.15",
                 "--intrinsics", str(tmp_path / "cam0.npz"), "--frames", "2", "-o", str(out)]) == 0
    data = json.loads((out / "readings.json").read_text())
    assert data["format"] == "stereodic.align/1" and len(data["updates"]) == 2
    assert data["intrinsics"]["kind"] == "prvm" and data["camera"]["width"] == SIZE[0]
    truth = json.loads((out / "truth.json").read_text())
    lens = aim(lens_of("freeform"), 3, -2, 1)                 # the test's own truth of the same bench
    mine = true_alignment(lens, SimDisplay(), DisplayPose())
    for key in ("tilt_x_deg", "tilt_y_deg", "roll_deg", "distance_mm"):
        assert truth["camera"][key] == pytest.approx(mine[key], abs=1e-9)
    for u in data["updates"]:
        for key in ("tilt_x_deg", "tilt_y_deg", "roll_deg"):
            assert abs(u[key] - mine[key]) < 0.05, key
        assert not u["square"] and u["advice"][0] == "tilt the camera down 3.00 deg"
        assert (out / u["picture"]).is_file()
    st = data["stage"]
    assert abs(st["angle_x_deg"] - 0.25) < 0.05 and abs(st["angle_y_deg"] - 0.15) < 0.05
    assert truth["stage_axis"]["angle_x_deg"] == pytest.approx(0.25)
    assert (out / "stage.png").is_file() and st["advice"][0].startswith("tilt the screen 0.25 deg: its right edge")
    err = capsys.readouterr().err
    assert "stage axis 0.2" in err and "update 1: tilt x +" in err and "tilt the camera down 3.00 deg" in err


def one_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


def test_a_camera_that_does_not_see_the_pattern(tmp_path, capsys):
    rng = np.random.default_rng(0)
    for i in range(4):
        write_gray(tmp_path / "photos" / f"{i}.png", rng.integers(0, 12, (48, 64)).astype(np.uint8))
    out = tmp_path / "out"
    assert main(["align", "--display", f"file:{tmp_path}/shown?size=320x180", "--display-pitch-mm", "0.5", "--camera",
                 f"folder:{tmp_path}/photos?timeout=1", "--frames", "1", "-o", str(out)]) == 2
    assert "cam0 does not see the pattern: only 0.0% of its pixels brighten" in one_line(capsys)
    assert not (out / "readings.json").exists()


@pytest.mark.parametrize("fault, says", [("slip@2", "sees the display where it was"),
                                         ("alarm@2", "fault FS|stopped at 25.0000 mm")])
def test_a_stage_that_does_not_move(tmp_path, capsys, fault, says):
    out = tmp_path / "out"
    assert main(["align", "--display", "sim", "--camera", CAMERA, "--stage", f"{STAGE}&fault={fault}",
                 "--frames", "1", "-o", str(out)]) == 1
    line = one_line(capsys)
    assert line.startswith("stereodic: hardware fault: zaber stage") and re.search(says, line)
    assert not (out / "readings.json").exists()


@pytest.mark.parametrize("args, says", [
    (["--display", "sim", "--camera", CAMERA], "headless: give --frames N and -o DIR"),
    (["--display", "sim", "--camera", CAMERA, "--frames", "1", "-o", "OUT", "--tolerance-deg", "0"],
     "--tolerance-deg: must be positive"),
    (["--display", "sim", "--camera", CAMERA, "--frames", "1", "-o", "FULL"], "not an empty folder"),
    (["--display", "sim", "--camera", CAMERA, "--frames", "1", "-o", "OUT", "--intrinsics", "SMALL"],
     "describes a 64x48 camera, but cam0 delivers 320x256"),
    (["--display", "sim", "--camera", CAMERA + "&tilt=1", "--frames", "1", "-o", "OUT"],
     "tilt must be 2 comma-separated"),
    (["--display", "sim", "--camera", CAMERA, "--stage", STAGE + "&axis_deg=50,0", "--frames", "1", "-o", "OUT"],
     "axis_deg must be AX,AY"),
])
def test_bad_usage_is_one_line(tmp_path, capsys, args, says):
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "keep.txt").write_text("mine")
    make_lens("brown", width=64, height=48).true_prvm().save(tmp_path / "small.npz")
    names = {"OUT": str(tmp_path / "out"), "FULL": str(tmp_path / "full"), "SMALL": str(tmp_path / "small.npz")}
    assert main(["align"] + [names.get(a, a) for a in args]) == 2
    assert says in one_line(capsys)
    assert (tmp_path / "full" / "keep.txt").read_text() == "mine"


def test_the_record_is_complete_after_every_update(tmp_path):
    s, _ = session("brown", (0.5, 0.5, 0.0), prvm_rays("brown"))
    record = AlignRecord(tmp_path / "rec")
    record.header = {"camera": {"spec": "test"}}
    seen = []

    def report(line):
        seen.append(len(json.loads((tmp_path / "rec" / "readings.json").read_text())["updates"]))

    run(s, updates=2, record=record, report=report)
    assert seen == [1, 2]
    assert sorted(p.name for p in (tmp_path / "rec").iterdir()) == ["fused_0000.png", "fused_0001.png",
                                                                     "readings.json"]


# ----------------------------------------------------------------------------------------- on a real screen

class MirroredScreen(SimScreen):
    """The simulated LCD (which the simulated camera looks at) mirrored on a real full-screen window."""

    def __init__(self, window):
        super().__init__()
        self.window = window

    def _show(self, image):
        super()._show(image)
        self.window.show(image)

    def pressed(self):
        return self.window.pressed()


@pytest.mark.display
def test_the_live_aid_on_a_full_screen_stops_on_escape(tmp_path):
    """The fused picture reaches the full-screen window pixel for pixel (read back through the X
    server), and Esc pressed on it ends a session that had no update limit."""
    pytest.importorskip("Xlib")
    from Xlib import XK, X
    from Xlib import display as xdisplay
    from Xlib.ext import xtest
    with virtual_screen(1920, 1080) as name:
        window = open_screen("screen:0", settle_s=0.0)
        try:
            screen = MirroredScreen(window)
            cam = SimulatedCamera("cam0", screen, lambda: 0.0, "brown", SIZE, 0, pixel_um=PIXEL_UM,
                                  aim=(0.6, -0.3, 0.4))
            cam.set_exposure(240, 0.0)
            s = AlignSession(screen, cam, screen.pitch_mm, prvm_rays("brown"),
                             settings=AlignSettings(default_periods(screen.size), hold_s=5.0))
            record = AlignRecord(tmp_path / "rec")
            shots = []

            def press_escape(line):            # after the first update is on the screen
                if shots:
                    raise AssertionError("Esc did not stop the session")
                shots.append(read_back(name))
                x = xdisplay.Display(name)
                code = x.keysym_to_keycode(XK.string_to_keysym("Escape"))
                xtest.fake_input(x, X.KeyPress, code)
                xtest.fake_input(x, X.KeyRelease, code)
                x.sync()
                x.close()

            done = run(s, updates=0, record=record, report=press_escape, interactive=True)
        finally:
            window.close()
    assert len(done) == 1 and len(shots) == 1
    write_rgb(tmp_path / "screenshot.png", shots[0])
    sent = cv2.imread(str(tmp_path / "rec" / "fused_0000.png"))[:, :, ::-1]
    assert np.array_equal(shots[0], sent)
    assert near(shots[0], OUTSIDE).sum() > 2000 and near(shots[0], EXPECTED).sum() > 2000


@pytest.mark.slow
def test_through_a_calibrated_prvm(tmp_path):
    """The whole way on the simulated bench: acquire and calibrate the camera where it stands, aim it
    elsewhere, align it through the calibrated (not the true) PRVM."""
    camera = f"sim:brown?size={SIZE[0]}x{SIZE[1]}&pixel_um={PIXEL_UM}"
    assert main(["acquire", "calibration", "--stage", STAGE, "--display", "sim", "--camera", camera,
                 "--settle-ms", "0", "-o", str(tmp_path / "cal")]) == 0
    assert main(["calibrate", str(tmp_path / "cal"), "-o", str(tmp_path / "cam0.npz")]) == 0
    assert main(["align", "--display", "sim", "--camera", camera + "&tilt=-1.5,0.8&roll=-0.4", "--stage",
                 STAGE + "&axis_deg=-0.3,0.45", "--intrinsics", str(tmp_path / "cam0.npz"), "--frames", "1",
                 "-o", str(tmp_path / "align")]) == 0
    data = json.loads((tmp_path / "align" / "readings.json").read_text())
    truth = json.loads((tmp_path / "align" / "truth.json").read_text())
    for key in ("tilt_x_deg", "tilt_y_deg", "roll_deg"):
        assert abs(data["updates"][0][key] - truth["camera"][key]) < 0.05, key
    for key in ("angle_x_deg", "angle_y_deg"):
        assert abs(data["stage"][key] - truth["stage_axis"][key]) < 0.05, key

"""Every command, every class of bad input: exit status 2, exactly one line on stderr naming the file,
no traceback, and nothing left behind (no output, no temporary file, an existing output untouched).

The table `COMMANDS` has one row per command of `stereodic.cli` (every sub-parser: a command missing
from it fails `test_every_command_is_in_the_table`) giving a good command line whose path arguments are
slots: `In(dest, kind)` for a file the command reads, `Out(dest, kind)` for one it writes. Each slot is
replaced in turn by each bad input of its kind (`_bad_inputs`): a missing file, a directory where a file
belongs (or a file where a folder belongs), an empty file, a corrupt image (cut short, random bytes with
an image suffix), the wrong kind of .npz (a rig for a PRVM and the reverse, a DIC result for a rig, an
.npz without meta, a zip that is not an .npz), an image of another size than the rig, PRVM or reference
image it goes with, and an output that cannot be written (under a regular file; in a folder without write
permission, or /proc when the tests run as root). The inputs are small and built once per session.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import warnings
import zipfile
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pytest
import tifffile

from calib.imageio import read_gray, write_gray
from calib.prvm_file import PRVM
from stereodic.cli import build_parser, main


@dataclass(frozen=True)
class In:
    """A path the command reads: its argparse dest, what it holds (a key of `_bad_inputs`), the good
    input (a key of the `inputs` fixture) and, where its size must match another input, an input of
    another size (and, where the message names the other input, the name it gives: a rig of other
    cameras than the images')."""

    dest: str
    kind: str
    good: str
    wrong_size: str | None = None
    named: str | None = None


@dataclass(frozen=True)
class Out:
    """A path the command writes: its argparse dest, 'file' or 'dir', its name in the case folder, and
    whether a folder must be new or empty (the existing output is then an empty folder)."""

    dest: str
    kind: str
    name: str
    new: bool = False


SIM = ["--width", "16", "--height", "12"]
ALIGN = ["align", "--display", "sim", "--camera", "sim?size=32x24", "--frames", "1"]
ACQUIRE = ["--camera", "sim?size=32x24", "--average", "1"]
CAL, DIC, IMG = In("dataset", "calibration dataset", "cal"), In("dataset", "dic dataset", "dic"), "image"

# command -> its rows (a command line each; a command with several forms has several rows)
COMMANDS: dict[str, list[list]] = {
    "demo": [["demo", "-o", Out("output", "dir", "demo-out")]],
    "simulate calibration": [["simulate", "calibration", *SIM, "-o", Out("output", "dir", "cal")]],
    "simulate stereo": [["simulate", "stereo", *SIM, "-o", Out("output", "dir", "stereo")]],
    "simulate scan": [["simulate", "scan", *SIM, "-o", Out("output", "dir", "scan")]],
    "simulate dic": [["simulate", "dic", *SIM, "-o", Out("output", "dir", "dic")]],
    "simulate dic2d": [["simulate", "dic2d", "--width", "32", "--height", "32", "-o", Out("output", "dir", "dic2d")]],
    "patterns": [["patterns", "--display", "64x48", "--periods", "64,8", "--response",
                  In("response", "display response", "response"), "-o", Out("output", "dir", "patterns")]],
    "calibrate": [["calibrate", CAL, "-o", Out("output", "file", "cam.npz"), "--report",
                   Out("report", "dir", "report")]],
    "undistort": [["undistort", In("camera", "camera", "cam"), In("images", IMG, "cal_image", "a"),
                   "-o", Out("output", "dir", "undistorted"), "--save-virtual", Out("save_virtual", "file", "v.npz")]],
    "rig": [["rig", In("left", "PRVM", "left"), In("right", "PRVM", "right"), "--register",
             In("register", "PRVM", "left", "prvm_other_size"), In("register", "PRVM", "right", "prvm_other_size"), "-o",
             Out("output", "file", "rig.npz")]],
    "rectify": [["rectify", In("rig", "rig", "dic_rig", "scan_rig", "cam0.png"),
                 In("left", IMG, "dic_left", "small"), In("right", IMG, "dic_right", "small"), "-o",
                 Out("output", "dir", "rectified")]],
    "scan": [["scan", In("rig", "rig", "scan_rig", "dic_rig", "capture.json"), In("dataset", "scan dataset", "scan"),
              "-o", Out("output", "file", "cloud.ply"), "--mesh", Out("mesh", "file", "mesh.ply")]],
    "dic2d": [["dic2d", In("ref", IMG, "a"), In("defs", IMG, "b", "small"), "--mask", In("mask", IMG, "a", "small"),
               "--roi-polygon", In("roi_polygon", "polygon file", "polygon"), "-o", Out("output", "file", "r.csv"),
               "--npz", Out("npz", "file", "r.npz"), "--mat", Out("mat", "file", "r.mat"), "--plot",
               Out("plot", "dir", "maps")]],
    "dic": [["dic", In("rig", "rig", "dic_rig", "scan_rig", "capture.json"), DIC, "--mask",
             In("mask", IMG, "dic_left", "small"), "--roi-polygon", In("roi_polygon", "polygon file", "polygon"),
             "-o", Out("output", "dir", "run")],
            ["dic", In("rig", "rig", "dic_rig", "scan_rig", "cam0.png"), "--left", In("left", IMG, "dic_left", "small"),
             "--right", In("right", IMG, "dic_right", "small"), "-o", Out("output", "dir", "run")],
            ["dic", In("rig", "rig", "dic_rig", "scan_rig", "img_0000_0.png"), "--images",
             In("images", "image folder", "pairs"), "-o", Out("output", "dir", "run")]],
    "strain": [["strain", In("result", "DIC result", "result"), "-o", Out("output", "dir", "strain")]],
    "gauge": [["gauge", In("result", "DIC result", "result"), "--point", "30,24", "--gauges",
               In("gauges", "gauge file", "gauges"), "-o", Out("output", "dir", "gauges")],
              ["gauge", In("result", "DIC result", "result"), "--point", "30,24", "--load",
               In("load", "load file", "load"), "--join", "time", "--state-times",
               In("state_times", "timestamps file", "times"), "-o", Out("output", "dir", "gauges")]],
    "speckle": [["speckle", In("image", IMG, "a"), "--static", In("static", IMG, "b", "small"), "-o",
                 Out("output", "dir", "speckle")]],
    "import": [["import", In("calibration", "calibration", "opencv_yaml"), "-o", Out("output", "file", "rig.npz")]],
    "export": [["export", In("file", "camera or rig", "cam"), "--format", "opencv", "-o",
                Out("output", "file", "cam.yaml")],
               ["export", In("file", "camera or rig", "dic_rig"), "--format", "colmap", "-o",
                Out("output", "dir", "colmap")]],
    "bench": [],  # reads and writes no file (test_every_path_is_a_slot checks that it declares none)
    "acquire calibration": [["acquire", "calibration", "--stage", "emulated:zaber", "--display", "sim", *ACQUIRE,
                             "-o", Out("output", "dir", "capture")]],
    "acquire scan": [["acquire", "scan", "--display", "sim", *ACQUIRE, "-o", Out("output", "dir", "capture")]],
    "acquire dic": [["acquire", "dic", *ACQUIRE, "-o", Out("output", "dir", "capture")]],
    "align": [[*ALIGN, "--intrinsics", In("intrinsics", "camera", "cam", "prvm_other_size"), "-o",
               Out("output", "dir", "align", new=True)]],
    "show": [["show", In("prvm", "PRVM", "cam"), "--truth", In("truth", "PRVM", "cam", "prvm_other_size"), "-o",
              Out("output", "dir", "pictures")]],
    "view": [["view", In("paths", "workspace path", "result"), "--no-browser"]],   # a good one would serve
}


def _parsers(parser, path=()):
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _parsers(sub, path + (name,))
    if path and not any(isinstance(a, argparse._SubParsersAction) for a in parser._actions):
        yield " ".join(path), parser


# ------------------------------------------------------------------ the inputs, built once per session


def _speckle(width, height, seed):
    rng = np.random.default_rng(seed)
    img = cv2.GaussianBlur((rng.random((height, width)) * 255).astype(np.float32), (0, 0), 1.2)
    return cv2.normalize(img, None, 10, 245, cv2.NORM_MINMAX).astype(np.uint8)


def _prvm(width, height) -> PRVM:
    v, u = np.mgrid[0:height, 0:width].astype(float)
    origin = np.stack([u * 0.1, v * 0.1, np.zeros_like(u)], -1)
    direction = np.stack([(u - width / 2) * 1e-3, (v - height / 2) * 1e-3, np.ones_like(u)], -1)
    direction /= np.linalg.norm(direction, axis=-1, keepdims=True)
    return PRVM(origin, direction, np.ones((height, width), bool), meta={"camera": "cam0"})


def _run_ok(argv):
    assert main([str(a) for a in argv]) == 0, argv


def _opencv_stereo_yaml(path):
    K = np.array([[400.0, 0, 160], [0, 400.0, 120], [0, 0, 1]])
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for key, value in (("M1", K), ("D1", np.zeros((1, 5))), ("M2", K), ("D2", np.zeros((1, 5))), ("R", np.eye(3)),
                       ("T", np.array([[-100.0], [0], [0]]))):
        fs.write(key, value)
    fs.write("image_width", 320)
    fs.write("image_height", 240)
    fs.release()


@pytest.fixture(scope="session")
def inputs(tmp_path_factory) -> dict[str, Path]:
    """Good inputs (a key per `In.good`) and the bad ones, in one read-only folder."""
    root = tmp_path_factory.mktemp("bad_input")
    paths = {}
    speckle = _speckle(70, 54, 1)
    for name, img in {"a": speckle[:48, :64], "b": speckle[2:50, 1:65], "small": _speckle(40, 30, 3)}.items():
        write_gray(root / f"{name}.png", np.ascontiguousarray(img))
        paths[name] = root / f"{name}.png"
    _run_ok(["simulate", "calibration", "--width", 32, "--height", 24, "--no-noise", "-o", root / "cal"])
    _run_ok(["simulate", "dic", "--width", 64, "--height", 48, "--supersample", 1, "-o", root / "dic"])
    _run_ok(["simulate", "scan", "--objects", "plane", "--width", 32, "--height", 24, "--supersample", 1,
             "--periods", "1280,160", "-o", root / "scan"])
    paths.update(cal=root / "cal", dic=root / "dic", scan=root / "scan", dic_rig=root / "dic" / "rig.npz",
                 scan_rig=root / "scan" / "rig.npz", dic_left=root / "dic" / "s000" / "cam0.png",
                 dic_right=root / "dic" / "s000" / "cam1.png", cal_image=next((root / "cal").glob("z*/*.png")))
    assert read_gray(paths["dic_left"]).shape == (48, 64)
    paths["cam"] = root / "cal" / "truth.npz"
    paths["left"], paths["right"] = root / "scan" / "truth_cam0.npz", root / "scan" / "truth_cam1.npz"
    _prvm(24, 16).save(root / "other_size.npz")
    paths["prvm_other_size"] = root / "other_size.npz"
    pairs = root / "pairs"
    pairs.mkdir()
    for k in range(2):
        for cam in (0, 1):
            shutil.copy(root / "dic" / f"s{k:03d}" / f"cam{cam}.png", pairs / f"img_{k:04d}_{cam}.png")
    paths["pairs"] = pairs
    _run_ok(["dic2d", paths["a"], paths["b"], "--subset", 11, "--step", 8, "-o", root / "result.csv",
             "--npz", root / "result.npz"])
    paths["result"] = root / "result.npz"
    (root / "gauges.json").write_text(json.dumps({"format": "stereodic.gauges/1", "points": [{"at": [40, 20]}]}))
    (root / "load.csv").write_text("time,force\n0,0\n10,100\n")
    (root / "times.csv").write_text("time\n1.5\n2.5\n")
    paths.update(gauges=root / "gauges.json", load=root / "load.csv", times=root / "times.csv")
    _run_ok(["calibrate", paths["cal"], "-o", root / "calibrated.npz", "--report", root / "report"])
    paths["response"] = root / "report" / "display_response.json"
    assert paths["response"].is_file()
    _opencv_stereo_yaml(root / "stereo.yml")
    paths["opencv_yaml"] = root / "stereo.yml"
    polygon = {"outer": [[2, 2], [61, 2], [61, 45], [2, 45]], "holes": [[[30, 20], [34, 20], [34, 24]]]}
    (root / "polygon.json").write_text(json.dumps(polygon))     # inside the 64x48 images
    paths["polygon"] = root / "polygon.json"

    bad = root / "bad"
    bad.mkdir()
    (bad / "frames").mkdir()
    for suffix in (".png", ".tif", ".npz", ".json", ".yml", ".csv"):
        (bad / f"empty{suffix}").write_bytes(b"")
        (bad / f"random{suffix}").write_bytes(np.random.default_rng(5).bytes(3000))
    png = paths["a"].read_bytes()
    (bad / "truncated.png").write_bytes(png[:len(png) // 2])
    write_gray(bad / "full.tif", _speckle(64, 48, 4))      # OpenCV's TIFF: its directory after the data
    tif = (bad / "full.tif").read_bytes()
    (bad / "truncated.tif").write_bytes(tif[:len(tif) // 2])
    tifffile.imwrite(bad / "full16.tif", _speckle(64, 48, 4).astype(np.uint16) * 257)   # directory first
    tif = (bad / "full16.tif").read_bytes()
    (bad / "truncated16.tif").write_bytes(tif[:len(tif) // 2])
    np.savez(bad / "no_meta.npz", origin=np.zeros((2, 2, 3)))
    with zipfile.ZipFile(bad / "not_numpy.npz", "w") as z:
        z.writestr("notes.txt", "a zip, but not of numpy arrays")
    (bad / "other.json").write_text(json.dumps({"format": "stereodic.capture/1", "kind": "dic"}))
    (bad / "outside.json").write_text(json.dumps([[2, 2], [90, 2], [90, 40]]))    # beyond the 64x48 images
    for name, dataset in (("cal", paths["cal"]), ("dic", paths["dic"]), ("scan", paths["scan"]),
                          ("pairs", pairs)):
        for flaw in ("truncated", "other_size"):
            copy = bad / f"{name}_{flaw}"
            shutil.copytree(dataset, copy)
            image = sorted(copy.rglob("*.png"))[-1]     # the last state's last image
            if flaw == "truncated":
                image.write_bytes(image.read_bytes()[:200])
            else:
                h, w = read_gray(image).shape
                write_gray(image, _speckle(w + 8, h + 4, 6))
            paths[f"{name}_{flaw}"], paths[f"{name}_{flaw}_image"] = copy, image
    (bad / "empty_dataset").mkdir()
    (bad / "empty_manifest").mkdir()
    (bad / "empty_manifest" / "capture.json").write_bytes(b"")
    paths["bad"] = bad
    for p in root.rglob("*"):
        if p.is_file():
            p.chmod(0o444)
    return paths


# ------------------------------------------------------------------ the bad inputs of each kind


def _bad_inputs(slot: In, paths) -> list[tuple[str, str, Path, str]]:
    """(class, label, path, the name the message must contain) of every bad input for `slot`."""
    bad = paths["bad"]
    missing = ("missing", "missing", bad / "nothing_here.npz", "nothing_here")
    cases = [missing]
    if slot.kind in ("calibration dataset", "dic dataset", "scan dataset", "image folder"):
        name = {"calibration dataset": "cal", "dic dataset": "dic", "scan dataset": "scan",
                "image folder": "pairs"}[slot.kind]
        cases += [("directory", "a file where a folder belongs" if name == "pairs" else "a folder without capture.json",
                   bad / ("random.json" if name == "pairs" else "empty_dataset"),
                   "random.json" if name == "pairs" else "empty_dataset")]
        if name != "pairs":
            cases += [("empty file", "empty capture.json", bad / "empty_manifest", "capture.json"),
                      ("corrupt", "random bytes as the manifest", bad / "random.json", "random.json"),
                      ("wrong kind", "a dataset of another kind",
                       paths["dic" if name != "dic" else "cal"], "capture.json")]
        else:
            cases += [("empty file", "a folder without image pairs", bad / "empty_dataset", "empty_dataset")]
        cases += [("corrupt", "an image cut short", paths[f"{name}_truncated"], paths[f"{name}_truncated_image"].name),
                  ("wrong size", "an image of another size", paths[f"{name}_other_size"],
                   paths[f"{name}_other_size_image"].name)]
        return cases
    cases += [("directory", "a directory", bad / "frames", "frames")]
    if slot.kind == IMG:
        cases += [("empty file", "empty", bad / "empty.png", "empty.png"),
                  ("corrupt", "a PNG cut short", bad / "truncated.png", "truncated.png"),
                  ("corrupt", "a TIFF cut short", bad / "truncated.tif", "truncated.tif"),
                  ("corrupt", "a 16-bit TIFF cut short after its directory", bad / "truncated16.tif",
                   "truncated16.tif"),
                  ("corrupt", "random bytes", bad / "random.png", "random.png")]
        if slot.wrong_size:
            cases += [("wrong size", "another size", paths[slot.wrong_size], paths[slot.wrong_size].name)]
        return cases
    if slot.kind == "polygon file":
        return cases + [("empty file", "empty", bad / "empty.json", "empty.json"),
                        ("corrupt", "random bytes", bad / "random.json", "random.json"),
                        ("wrong size", "a polygon outside the image", bad / "outside.json", "outside.json")]
    if slot.kind == "workspace path":     # any result, dataset, PRVM, rig or PLY is good: no wrong kind
        return cases + [("empty file", "empty", bad / "empty.npz", "empty.npz"),
                        ("corrupt", "random bytes", bad / "random.npz", "random.npz"),
                        ("wrong kind", "an .npz without meta", bad / "no_meta.npz", "no_meta.npz"),
                        ("wrong kind", "a zip that is not an .npz", bad / "not_numpy.npz", "not_numpy.npz"),
                        ("wrong kind", "a JSON file", bad / "other.json", "other.json")]
    if slot.kind in ("gauge file", "load file", "timestamps file"):
        suffix = ".json" if slot.kind == "gauge file" else ".csv"
        cases += [("empty file", "empty", bad / f"empty{suffix}", f"empty{suffix}"),
                  ("corrupt", "random bytes", bad / f"random{suffix}", f"random{suffix}"),
                  ("wrong kind", "another JSON file", bad / "other.json", "other.json")]
        return cases
    if slot.kind in ("display response", "calibration"):
        suffix = ".json" if slot.kind == "display response" else ".yml"
        cases += [("empty file", "empty", bad / f"empty{suffix}", f"empty{suffix}"),
                  ("corrupt", "random bytes", bad / f"random{suffix}", f"random{suffix}"),
                  ("wrong kind", "a PRVM file", paths["cam"], paths["cam"].name)]
        if slot.kind == "display response":
            cases += [("wrong kind", "another JSON file", bad / "other.json", "other.json")]
        return cases
    # .npz files: a PRVM, a camera (a PRVM or a virtual camera), a camera or rig, a rig, a DIC result
    cases += [("empty file", "empty", bad / "empty.npz", "empty.npz"),
              ("corrupt", "random bytes", bad / "random.npz", "random.npz"),
              ("wrong kind", "an .npz without meta", bad / "no_meta.npz", "no_meta.npz"),
              ("wrong kind", "a zip that is not an .npz", bad / "not_numpy.npz", "not_numpy.npz")]
    others = {"PRVM": ("dic_rig", "result"), "camera": ("dic_rig", "result"), "camera or rig": ("result",),
              "rig": ("cam", "result"), "DIC result": ("cam", "dic_rig")}[slot.kind]
    cases += [("wrong kind", f"a {'rig' if o == 'dic_rig' else 'DIC result' if o == 'result' else 'PRVM'}",
               paths[o], paths[o].name) for o in others]
    if slot.wrong_size:
        cases += [("wrong size", "another size", paths[slot.wrong_size], slot.named or paths[slot.wrong_size].name)]
    return cases


def _bad_outputs(slot: Out, case: Path) -> list[tuple[str, str, Path, str]]:
    """(class, label, path, name in the message) of every output that cannot be written; creates what
    blocks it in the case folder `case`."""
    (case / "notes.txt").write_text("my notes\n")
    cases = [("unwritable", "under a regular file", case / "notes.txt" / slot.name, "notes.txt")]
    if slot.kind == "file":
        (case / "taken").mkdir()
        cases += [("unwritable", "a directory where a file belongs", case / "taken", "taken")]
    else:
        cases += [("unwritable", "a file where a folder belongs", case / "notes.txt", "notes.txt")]
    return cases


# ------------------------------------------------------------------ the cases


def _cases():
    for command, rows in COMMANDS.items():
        for r, row in enumerate(rows):
            for i, item in enumerate(row):
                if isinstance(item, (In, Out)):
                    yield pytest.param(command, r, i, id=f"{command}[{r}]-{item.dest}{i}")


def _argv(row, case: Path, paths, replace: int | None = None, value: Path | None = None) -> list[str]:
    out = []
    for i, item in enumerate(row):
        if i == replace:
            out.append(str(value))
        elif isinstance(item, In):
            out.append(str(paths[item.good]))
        elif isinstance(item, Out):
            out.append(str(case / "out" / item.name))
        else:
            out.append(item)
    return out


def _snapshot(root: Path) -> dict:
    """Every file and folder under root: (kind, size, content hash)."""
    shot = {}
    for p in sorted(root.rglob("*")):
        if p.is_dir():
            shot[p.relative_to(root)] = "dir"
        else:
            shot[p.relative_to(root)] = (p.stat().st_size, hashlib.sha1(p.read_bytes()).hexdigest())
    return shot


def _refused(argv, capfd, name: str, label: str):
    """Run the command; assert it was refused in one line (stderr at the file descriptor: OpenCV's and
    libtiff's own messages count) naming `name`, with no Python warning."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            status = main(argv)
        except SystemExit as exc:  # argparse's own errors: not expected here
            status = exc.code
    out, err = capfd.readouterr()
    lines = err.strip().splitlines()
    where = f"{label}: {' '.join(argv)}\nstdout: {out}\nstderr: {err}"
    assert status == 2, where
    assert len(lines) == 1 and "Traceback" not in err, where
    assert name in lines[0], where
    assert lines[0].startswith("stereodic: "), where
    assert not caught, f"{where}\nwarnings: {[str(w.message) for w in caught]}"


def _make_outputs(row, case: Path) -> None:
    """Existing outputs, which a refused command must leave untouched."""
    for item in row:
        if isinstance(item, Out):
            path = case / "out" / item.name
            if item.kind == "file":
                path.parent.mkdir(parents=True, exist_ok=True)
                path.write_text("an earlier result\n")
            else:
                path.mkdir(parents=True, exist_ok=True)
                if not item.new:
                    (path / "earlier.txt").write_text("an earlier result\n")


@pytest.mark.parametrize("command,row,index", list(_cases()))
def test_bad_input(command, row, index, inputs, tmp_path, capfd, request):
    line = COMMANDS[command][row]
    slot = line[index]
    inputs_before = {k: (p.stat().st_size, p.stat().st_mtime_ns) for k, p in _inputs_files(inputs).items()}
    if isinstance(slot, In):
        variants = [(c, label, path, name, existing) for c, label, path, name in _bad_inputs(slot, inputs)
                    for existing in (False, True)]
    else:
        variants = [(c, label, path, name, False) for c, label, path, name in _bad_outputs(slot, tmp_path)]
    for k, (klass, label, path, name, existing) in enumerate(variants):
        case = tmp_path / f"case{k}"
        case.mkdir()
        if existing:
            _make_outputs(line, case)
        before = _snapshot(tmp_path)
        _refused(_argv(line, case, inputs, index, path), capfd, name,
                 f"{command}: {slot.dest} {klass} ({label}){', outputs existing' if existing else ''}")
        assert _snapshot(tmp_path) == before, f"{command} {slot.dest} {label}: something was written or changed"
    after = {k: (p.stat().st_size, p.stat().st_mtime_ns) for k, p in _inputs_files(inputs).items()}
    assert after == inputs_before, "an input was changed or a file written beside the inputs"


def _output_slots():
    for case in _cases():
        command, row, index = case.values
        if isinstance(COMMANDS[command][row][index], Out):
            yield case


@pytest.mark.parametrize("command,row,index", list(_output_slots()))
def test_output_in_a_folder_where_nothing_can_be_created(command, row, index, inputs, tmp_path, capfd):
    """A folder without write permission; as root, where permissions do not stop writes, /proc (where no
    one can create a file): refused before any work, whoever runs it."""
    line = COMMANDS[command][row]
    if os.geteuid() == 0:
        target = Path("/proc") / f"stereodic-{line[index].name}"
        _refused(_argv(line, tmp_path, inputs, index, target), capfd, target.name,
                 f"{command}: {line[index].dest} in /proc")
        assert not target.exists()
        return
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o555)
    try:
        _refused(_argv(line, tmp_path, inputs, index, locked / line[index].name), capfd, "locked",
                 f"{command}: {line[index].dest} in a folder without write permission")
        assert not any(locked.iterdir())
    finally:
        locked.chmod(0o755)


def _inputs_files(paths) -> dict[Path, Path]:
    root = paths["bad"].parent
    return {p.relative_to(root): p for p in root.rglob("*")}


# ------------------------------------------------------------------ the table covers everything


def test_every_command_is_in_the_table():
    commands = {name for name, _ in _parsers(build_parser())}
    assert commands == set(COMMANDS), (f"add a row to tests/stereodic/test_commands_bad_input.py's COMMANDS for "
                                       f"{sorted(commands - set(COMMANDS))}; remove {sorted(set(COMMANDS) - commands)}")


PATH_WORDS = ("DIR", "FILE", ".npz", ".csv", ".ply", ".yaml", "PNG", "IMG", "IMAGE", "PATTERN", "DATASET",
              "CALIBRATION", "RESULT")


def test_every_path_is_a_slot():
    """Each path a command declares (add_input / add_output) is a slot of its rows, and each argument
    that names a file by its metavar is declared."""
    for command, parser in _parsers(build_parser()):
        declared = {p.dest for p in parser.get_default("_paths") or []}
        slots = {item.dest for row in COMMANDS[command] for item in row if isinstance(item, (In, Out))}
        assert declared == slots, f"{command}: declared {sorted(declared)}, in the table {sorted(slots)}"
        for action in parser._actions:
            metavar = action.metavar if isinstance(action.metavar, tuple) else (action.metavar or "",)
            if any(w in m for m in metavar for w in PATH_WORDS):
                assert action.dest in declared, (f"{command}: {action.dest} ({action.metavar}) names a file: "
                                                 f"declare it with add_input/add_output")

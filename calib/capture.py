"""Capture datasets: the `stereodic.capture/1` format of DESIGN.md (`capture.json` beside the images).

`load_capture` reads and validates a manifest and returns a `Capture` whose images are read lazily, one
frame at a time (`Capture.read`), so a 5 MP, 40-frame dataset never needs all its images in memory.
`CaptureWriter` writes a dataset frame by frame, keeping a valid manifest on disk after every frame (an
interrupted acquisition loses nothing and can be resumed).

Every problem is an `InputError` naming the file (the manifest, or the image) and what is wrong.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from calib.atomic import write_json
from calib.errors import InputError
from calib.imageio import check_size, read_gray, write_gray
from calib.jsonfile import read_json

FORMAT = "stereodic.capture/1"
KINDS = ("calibration", "scan", "dic")
MANIFEST = "capture.json"
BAYER_PATTERNS = ("RGGB", "BGGR", "GRBG", "GBRG")
# the fewest display poses of a stage-free capture: three planes at unknown poses fix a generic
# (non-central) ray field (Sturm and Ramalingam 2004); each pixel's line then has 2 spare equations
MIN_POSES = 3

# Pattern types and the keys each one requires. "fringe": a phase-shifting fringe of DESIGN.md;
# "flat": a uniform grey level (intensity calibration); "chessboard": squares of `square_px` display
# pixels, `squares` = [columns, rows], top-left corner of the board at display pixel `origin_px`
# (used for the OpenCV comparison); "none": no pattern shown (ambient, DIC speckle under plain light);
# "gray": bit `bit` (0 = least significant) of the binary-reflected Gray code of the column (axis "x") or
# row, white where 1, optional "inverse": true for its complement (calib.graycode).
PATTERN_KEYS = {
    "fringe": ("axis", "period_px", "shift_rad"),
    "gray": ("axis", "bit"),
    "flat": ("level",),
    "chessboard": ("squares", "square_px"),
    "none": (),
}


@dataclass(frozen=True)
class CoverGlass:
    """A glass layer in front of the display's pixel plane, towards the camera."""

    thickness_mm: float
    refractive_index: float


@dataclass(frozen=True)
class Display:
    """The calibration display (or a scan projector's panel): size in pixels and pixel pitch in mm."""

    width_px: int
    height_px: int
    pitch_mm: tuple[float, float]
    gamma: float | None = None
    cover_glass: CoverGlass | None = None

    def to_json(self) -> dict:
        d: dict[str, Any] = {"width_px": self.width_px, "height_px": self.height_px,
                             "pitch_mm": list(self.pitch_mm)}
        if self.gamma is not None:
            d["gamma"] = self.gamma
        if self.cover_glass is not None:
            d["cover_glass"] = {"thickness_mm": self.cover_glass.thickness_mm,
                                "refractive_index": self.cover_glass.refractive_index}
        return d


@dataclass(frozen=True)
class Pattern:
    """What the display (or projector) showed. `params` holds the type's keys as in the manifest.

    Fringe: value(c) = low + (high - low) / 2 * (1 + cos(2*pi*c/period_px - shift_rad)), c the display
    column (axis "x") or row (axis "y").
    """

    type: str
    params: dict = field(default_factory=dict)

    def __getattr__(self, name):  # pattern.period_px, pattern.axis, ... as in the manifest
        try:
            return self.__dict__["params"][name]
        except KeyError:
            raise AttributeError(name) from None

    @property
    def low(self) -> float:
        return float(self.params.get("low", 0))

    @property
    def high(self) -> float:
        return float(self.params.get("high", 255))

    def key(self) -> str:
        """A canonical string for comparing patterns."""
        return json.dumps({"type": self.type, **self.params}, sort_keys=True)

    def to_json(self) -> dict:
        return {"type": self.type, **self.params}


@dataclass(frozen=True)
class Frame:
    """One image of the dataset. `file` is relative to the dataset folder."""

    camera: str
    file: str
    pattern: Pattern
    z_mm: float | None = None
    state: int | None = None
    exposure_ms: float | None = None
    repeat: int | None = None
    extra: dict = field(default_factory=dict)
    pose: int | None = None

    def to_json(self) -> dict:
        d: dict[str, Any] = {"camera": self.camera, "file": self.file}
        if self.z_mm is not None:
            d["z_mm"] = self.z_mm
        if self.pose is not None:
            d["pose"] = self.pose
        if self.state is not None:
            d["state"] = self.state
        d["pattern"] = self.pattern.to_json()
        if self.exposure_ms is not None:
            d["exposure_ms"] = self.exposure_ms
        if self.repeat is not None:
            d["repeat"] = self.repeat
        d.update(self.extra)
        return d

    def identity(self) -> tuple:
        """What makes two frames the same capture (a duplicate if it appears twice)."""
        return (self.camera, self.z_mm, self.pose, self.state, self.pattern.key(), self.repeat or 0, self.exposure_ms)


@dataclass
class Capture:
    """A loaded dataset. Images are read on demand with `read`."""

    root: Path
    kind: str
    cameras: dict[str, tuple[int, int]]          # name -> (width, height)
    frames: list[Frame]
    display: Display | None = None
    stage_axis: tuple[float, float, float] = (0.0, 0.0, 1.0)
    extra: dict = field(default_factory=dict)     # other top-level keys (projector, notes, ...), kept
    bit_depth: dict[str, int] = field(default_factory=dict)  # camera -> bits per pixel, where declared
    bayer: dict[str, str] = field(default_factory=dict)      # camera -> raw mosaic layout, where declared

    @property
    def posed(self) -> bool:
        """Whether this is a stage-free capture (frames carry `pose`, not `z_mm`)."""
        return any(f.pose is not None for f in self.frames)

    @property
    def manifest_path(self) -> Path:
        return self.root / MANIFEST

    def path(self, frame: Frame) -> Path:
        return self.root / frame.file

    def read(self, frame: Frame) -> np.ndarray:
        """The frame's image as a 2-D uint8/uint16 array, checked against the camera's size and declared
        bit depth (a value above 2**bit_depth - 1, e.g. 12-bit data written MSB-aligned, is an InputError:
        its full scale would be misread)."""
        img = read_gray(self.path(frame))
        w, h = self.cameras[frame.camera]
        if img.shape != (h, w):
            raise InputError(self.path(frame), f"image is {img.shape[1]}x{img.shape[0]}, camera "
                                               f"{frame.camera!r} is {w}x{h}")
        bits = self.bit_depth.get(frame.camera)
        if bits is not None:
            stored = 8 * img.dtype.itemsize
            if bits > stored:
                raise InputError(self.path(frame), f"camera {frame.camera!r} declares bit_depth {bits}, but the "
                                                   f"file holds {stored}-bit values")
            top = int(img.max()) if bits < stored else 0
            if top > 2 ** bits - 1:
                raise InputError(self.path(frame), f"values up to {top} exceed camera {frame.camera!r}'s declared "
                                                   f"bit_depth {bits} (full scale {2 ** bits - 1}): MSB-aligned "
                                                   f"data? declare bit_depth {stored}, or store the values "
                                                   f"LSB-aligned")
        return img

    def max_value(self, camera: str, image: np.ndarray) -> int:
        """The sensor's full-scale value: 2**bit_depth - 1 if declared, else the dtype's maximum."""
        if camera in self.bit_depth:
            return 2 ** self.bit_depth[camera] - 1
        return int(np.iinfo(image.dtype).max)

    def select(self, camera: str | None = None, **where) -> list[Frame]:
        """Frames of `camera` whose attributes (z_mm, state) or pattern parameters (type, axis,
        period_px, ...) equal the given values."""
        out = []
        for f in self.frames:
            if camera is not None and f.camera != camera:
                continue
            ok = True
            for k, v in where.items():
                have = getattr(f, k) if k in ("z_mm", "pose", "state", "repeat", "exposure_ms") else (
                    f.pattern.type if k == "type" else f.pattern.params.get(k))
                if have != v:
                    ok = False
                    break
            if ok:
                out.append(f)
        return out

    def z_positions(self, camera: str) -> list[float]:
        """The distinct stage positions (mm) at which `camera` has frames, sorted."""
        return sorted({f.z_mm for f in self.frames if f.camera == camera and f.z_mm is not None})

    def poses(self, camera: str) -> list[int]:
        """The distinct display poses at which `camera` has frames (a stage-free capture), sorted."""
        return sorted({f.pose for f in self.frames if f.camera == camera and f.pose is not None})

    def positions(self, camera: str) -> list:
        """Where the display stood for `camera`'s frames: the poses (ints) of a stage-free capture, else
        the stage positions (mm)."""
        return self.poses(camera) if self.posed else self.z_positions(camera)

    def at(self, position) -> dict:
        """The `select` keyword of one position: {"pose": N} or {"z_mm": z}."""
        return {"pose": position} if self.posed else {"z_mm": position}

    def label(self, position) -> str:
        """One position in words, for messages: "pose 3" or "z=50 mm"."""
        return f"pose {position}" if self.posed else f"z={position:g} mm"

    def states(self, camera: str) -> list[int]:
        """The distinct states (load steps) of `camera`, sorted."""
        return sorted({f.state for f in self.frames if f.camera == camera and f.state is not None})

    def display_to_wcs(self, c: np.ndarray, r: np.ndarray, z_mm: float) -> np.ndarray:
        """WCS point (mm, shape (..., 3)) of display pixel coordinates (c, r) at stage position z_mm.

        Display pixel (c, r) lies at (c*pitch_x, r*pitch_y, 0) + z_mm * (ax/az, ay/az, 1) where
        (ax, ay, az) is the stage axis.
        """
        if self.display is None:
            raise InputError(self.manifest_path, "dataset has no display")
        ax, ay, az = self.stage_axis
        px, py = self.display.pitch_mm
        c = np.asarray(c, dtype=np.float64)
        r = np.asarray(r, dtype=np.float64)
        return np.stack(np.broadcast_arrays(c * px + z_mm * ax / az, r * py + z_mm * ay / az,
                                            np.full(np.broadcast(c, r).shape, float(z_mm))), axis=-1)

    def to_json(self) -> dict:
        d: dict[str, Any] = {"format": FORMAT, "kind": self.kind}
        if self.display is not None:
            d["display"] = self.display.to_json()
        if tuple(self.stage_axis) != (0.0, 0.0, 1.0):
            d["stage"] = {"axis": list(self.stage_axis)}
        d["cameras"] = {n: {"width": w, "height": h,
                            **({"bit_depth": self.bit_depth[n]} if n in self.bit_depth else {}),
                            **({"bayer": self.bayer[n]} if n in self.bayer else {})}
                        for n, (w, h) in self.cameras.items()}
        d.update(self.extra)
        d["frames"] = [f.to_json() for f in self.frames]
        return d

    def save(self) -> None:
        """Write the manifest atomically."""
        write_json(self.manifest_path, self.to_json())


# --------------------------------------------------------------------------------------------- reading

def _num(where: Path, ctx: str, v, positive=False, integer=False) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise InputError(where, f"{ctx} must be a number, got {v!r}")
    if integer and int(v) != v:
        raise InputError(where, f"{ctx} must be a whole number, got {v!r}")
    if positive and v <= 0:
        raise InputError(where, f"{ctx} must be positive, got {v!r}")
    return int(v) if integer else float(v)


def _parse_display(where: Path, d: Any, ctx: str = "display") -> Display:
    if not isinstance(d, dict):
        raise InputError(where, f"'{ctx}' must be an object")
    for k in ("width_px", "height_px", "pitch_mm"):
        if k not in d:
            raise InputError(where, f"'{ctx}' lacks '{k}'")
    pitch = d["pitch_mm"]
    if isinstance(pitch, (int, float)):
        pitch = [pitch, pitch]
    if not isinstance(pitch, list) or len(pitch) != 2:
        raise InputError(where, f"'{ctx}.pitch_mm' must be [x, y] in mm")
    glass = None
    if d.get("cover_glass") is not None:
        g = d["cover_glass"]
        if not isinstance(g, dict) or "thickness_mm" not in g or "refractive_index" not in g:
            raise InputError(where, f"'{ctx}.cover_glass' needs thickness_mm and refractive_index")
        glass = CoverGlass(_num(where, f"{ctx}.cover_glass.thickness_mm", g["thickness_mm"]),
                           _num(where, f"{ctx}.cover_glass.refractive_index", g["refractive_index"],
                                positive=True))
        if glass.thickness_mm < 0 or glass.refractive_index < 1:
            raise InputError(where, f"'{ctx}.cover_glass' needs thickness >= 0 and index >= 1")
    gamma = d.get("gamma")
    return Display(
        _num(where, f"{ctx}.width_px", d["width_px"], positive=True, integer=True),
        _num(where, f"{ctx}.height_px", d["height_px"], positive=True, integer=True),
        (_num(where, f"{ctx}.pitch_mm[0]", pitch[0], positive=True),
         _num(where, f"{ctx}.pitch_mm[1]", pitch[1], positive=True)),
        None if gamma is None else _num(where, f"{ctx}.gamma", gamma, positive=True),
        glass,
    )


def _parse_pattern(where: Path, i: int, p: Any) -> Pattern:
    ctx = f"frame {i}"
    if not isinstance(p, dict) or "type" not in p:
        raise InputError(where, f"{ctx}: 'pattern' must be an object with a 'type'")
    t = p["type"]
    if t not in PATTERN_KEYS:
        raise InputError(where, f"{ctx}: unknown pattern type {t!r} (known: {', '.join(PATTERN_KEYS)})")
    for k in PATTERN_KEYS[t]:
        if k not in p:
            raise InputError(where, f"{ctx}: {t} pattern lacks '{k}'")
    params = {k: v for k, v in p.items() if k != "type"}
    if t == "fringe":
        if params["axis"] not in ("x", "y"):
            raise InputError(where, f"{ctx}: fringe axis must be 'x' or 'y', got {params['axis']!r}")
        _num(where, f"{ctx}: period_px", params["period_px"], positive=True)
        _num(where, f"{ctx}: shift_rad", params["shift_rad"])
        low, high = params.get("low", 0), params.get("high", 255)
        _num(where, f"{ctx}: low", low)
        _num(where, f"{ctx}: high", high)
        if not low < high:
            raise InputError(where, f"{ctx}: fringe needs low < high, got {low} and {high}")
    elif t == "flat":
        _num(where, f"{ctx}: level", params["level"])
    elif t == "gray":
        if params["axis"] not in ("x", "y"):
            raise InputError(where, f"{ctx}: gray axis must be 'x' or 'y', got {params['axis']!r}")
        if not (isinstance(params["bit"], int) and 0 <= params["bit"] < 32):
            raise InputError(where, f"{ctx}: gray 'bit' must be a whole number 0..31, got {params['bit']!r}")
        if not isinstance(params.get("inverse", False), bool):
            raise InputError(where, f"{ctx}: gray 'inverse' must be true or false, got {params['inverse']!r}")
    elif t == "chessboard":
        sq = params["squares"]
        if not (isinstance(sq, list) and len(sq) == 2 and all(isinstance(s, int) and s >= 2 for s in sq)):
            raise InputError(where, f"{ctx}: chessboard 'squares' must be [columns, rows], each >= 2")
        _num(where, f"{ctx}: square_px", params["square_px"], positive=True)
    return Pattern(t, params)


_FRAME_KEYS = {"camera", "file", "pattern", "z_mm", "pose", "state", "exposure_ms", "repeat"}


def _parse_frame(where: Path, i: int, f: Any, cameras: dict, kind: str) -> Frame:
    if not isinstance(f, dict):
        raise InputError(where, f"frame {i} must be an object")
    for k in ("camera", "file"):
        if k not in f:
            raise InputError(where, f"frame {i} lacks '{k}'")
    if f["camera"] not in cameras:
        raise InputError(where, f"frame {i}: camera {f['camera']!r} is not in 'cameras'")
    if kind == "calibration" and "z_mm" not in f and "pose" not in f:
        raise InputError(where, f"frame {i} ({f['file']}): calibration frames need 'z_mm' (a stage position) "
                                "or 'pose' (a stage-free capture)")
    if "z_mm" in f and "pose" in f:
        raise InputError(where, f"frame {i} ({f['file']}): has both 'z_mm' and 'pose'; a frame is either "
                                "at a stage position or at a display pose")
    if kind in ("scan", "dic") and "state" not in f:
        raise InputError(where, f"frame {i} ({f['file']}): {kind} frames need 'state'")
    pattern = _parse_pattern(where, i, f.get("pattern", {"type": "none"}))
    return Frame(
        camera=f["camera"], file=str(f["file"]), pattern=pattern,
        z_mm=None if f.get("z_mm") is None else _num(where, f"frame {i}: z_mm", f["z_mm"]),
        pose=None if f.get("pose") is None else _pose(where, i, f["pose"]),
        state=None if f.get("state") is None else _num(where, f"frame {i}: state", f["state"], integer=True),
        exposure_ms=None if f.get("exposure_ms") is None else _num(where, f"frame {i}: exposure_ms",
                                                                    f["exposure_ms"], positive=True),
        repeat=None if f.get("repeat") is None else _num(where, f"frame {i}: repeat", f["repeat"],
                                                         integer=True),
        extra={k: v for k, v in f.items() if k not in _FRAME_KEYS},
    )


def _pose(where: Path, i: int, v) -> int:
    pose = _num(where, f"frame {i}: pose", v, integer=True)
    if pose < 0:
        raise InputError(where, f"frame {i}: pose must be a whole number >= 0, got {v!r}")
    return pose


def _check_poses(where: Path, frames: list[Frame]) -> None:
    """A capture has `z_mm` on every calibration frame or `pose` on every one; every pose of a camera
    shows the same fringe sets (axis and period, 3 or more distinct shifts each)."""
    posed = [f for f in frames if f.pose is not None]
    if not posed:
        return
    staged = [f for f in frames if f.z_mm is not None]
    if staged:
        raise InputError(where, f"mixes stage positions and display poses: {staged[0].file} has 'z_mm', "
                                f"{posed[0].file} has 'pose'; a capture has one or the other on every frame")
    for camera in sorted({f.camera for f in frames}):
        sets: dict[int, dict[tuple, set]] = {}
        for f in posed:
            if f.camera == camera:
                by_set = sets.setdefault(f.pose, {})
                if f.pattern.type == "fringe":
                    key = (f.pattern.axis, float(f.pattern.period_px))
                    by_set.setdefault(key, set()).add(round(float(f.pattern.shift_rad), 9))
        every = set().union(*(s.keys() for s in sets.values()))
        for pose in sorted(sets):
            for axis, period in sorted(every):
                shifts = sets[pose].get((axis, period), set())
                if len(shifts) < 3:
                    have = f"only {len(shifts)} distinct shift(s)" if shifts else "none of its frames"
                    raise InputError(where, f"camera {camera!r}, pose {pose}: the {axis} fringe set of period "
                                            f"{period:g} px is incomplete ({have}; other poses have it)")


def load_capture(path: str | os.PathLike, *, check_images: bool = True,
                 min_positions: int | None = None) -> Capture:
    """Read and validate a stereodic.capture/1 dataset.

    Parameters
    ----------
    path : path
        The dataset's folder or its ``capture.json``.
    check_images : bool
        Also check that every image exists, is readable and has its camera's size (reads the file
        headers only).
    min_positions : int, optional
        The fewest distinct stage positions each camera must have; None: 2 for a calibration dataset (a
        ray needs two points), 0 otherwise.

    Returns
    -------
    capture : Capture
        The manifest (cameras, display, stage, frames); images are read lazily (`Capture.read`).
        InputError naming the manifest or the image, and the problem, if it is not valid.
    """
    path = Path(path)
    manifest = path / MANIFEST if path.is_dir() else path
    d = read_json(manifest, "dataset manifest")
    if d.get("format") != FORMAT:
        raise InputError(manifest, f"format is {d.get('format')!r}, expected {FORMAT!r}")
    kind = d.get("kind")
    if kind not in KINDS:
        raise InputError(manifest, f"kind is {kind!r}, expected one of {', '.join(KINDS)}")
    display = None
    if "display" in d:
        display = _parse_display(manifest, d["display"])
    elif kind == "calibration":
        raise InputError(manifest, "a calibration dataset needs 'display'")
    axis = (0.0, 0.0, 1.0)
    stage = d.get("stage") or {}
    if "axis" in stage:
        a = stage["axis"]
        if not (isinstance(a, list) and len(a) == 3):
            raise InputError(manifest, "'stage.axis' must be a 3-vector")
        a = np.array([_num(manifest, "stage.axis", v) for v in a])
        if a[2] <= 0:
            raise InputError(manifest, "'stage.axis' must point away from the camera (z > 0)")
        axis = tuple(float(v) for v in a / np.linalg.norm(a))
    cams = d.get("cameras")
    if not isinstance(cams, dict) or not cams:
        raise InputError(manifest, "'cameras' must name at least one camera")
    cameras, bits, bayer = {}, {}, {}
    for name, c in cams.items():
        if not isinstance(c, dict) or "width" not in c or "height" not in c:
            raise InputError(manifest, f"camera {name!r} needs width and height")
        cameras[name] = (_num(manifest, f"camera {name}: width", c["width"], positive=True, integer=True),
                         _num(manifest, f"camera {name}: height", c["height"], positive=True, integer=True))
        if "bit_depth" in c:
            bits[name] = _num(manifest, f"camera {name}: bit_depth", c["bit_depth"], positive=True, integer=True)
            if not 1 <= bits[name] <= 16:
                raise InputError(manifest, f"camera {name}: bit_depth must be 1..16, got {bits[name]}")
        if c.get("bayer") is not None:
            if c["bayer"] not in BAYER_PATTERNS:
                raise InputError(manifest, f"camera {name}: bayer must be one of {', '.join(BAYER_PATTERNS)}, "
                                           f"got {c['bayer']!r}")
            bayer[name] = c["bayer"]
    raw_frames = d.get("frames")
    if not isinstance(raw_frames, list) or not raw_frames:
        raise InputError(manifest, "'frames' must be a non-empty list")
    frames = [_parse_frame(manifest, i, f, cameras, kind) for i, f in enumerate(raw_frames)]
    _check_poses(manifest, frames)

    seen_files: dict[str, int] = {}
    seen_ids: dict[tuple, int] = {}
    for i, f in enumerate(frames):
        if f.file in seen_files:
            raise InputError(manifest, f"duplicate frame: file {f.file} appears in frames "
                                       f"{seen_files[f.file]} and {i}")
        seen_files[f.file] = i
        if f.identity() in seen_ids:
            raise InputError(manifest, f"duplicate frame: frames {seen_ids[f.identity()]} and {i} are the same "
                                       f"capture ({f.camera}, {'pose' if f.pose is not None else 'z'}="
                                       f"{f.pose if f.pose is not None else f.z_mm}, state={f.state}, "
                                       f"{f.pattern.key()}); give each a distinct 'repeat'")
        seen_ids[f.identity()] = i

    cap = Capture(manifest.parent, kind, cameras, frames, display, axis,
                  {k: v for k, v in d.items()
                   if k not in ("format", "kind", "display", "stage", "cameras", "frames")}, bits, bayer)
    if min_positions is None:
        min_positions = (MIN_POSES if cap.posed else 2) if kind == "calibration" else 0
    for name in cameras:
        if not cap.select(name):
            raise InputError(manifest, f"camera {name!r} has no frames")
        have = len(cap.positions(name))
        if min_positions and have < min_positions:
            what = "display pose(s)" if cap.posed else "stage position(s)"
            raise InputError(manifest, f"camera {name!r} has frames at {have} {what}; at least {min_positions} "
                                       f"are needed" + (" (a stage-free calibration fixes the poses and rays "
                                                        "together)" if cap.posed else ""))
    if check_images:
        for f in frames:
            check_size(cap.path(f), cameras[f.camera], f"camera {f.camera!r}")
    return cap


# --------------------------------------------------------------------------------------------- writing

class CaptureWriter:
    """Write a dataset frame by frame; the manifest on disk is valid after every `add`.

    Opening a folder that already holds a manifest of the same kind resumes it: `has(frame)` tells which
    frames are already there, so an interrupted acquisition continues where it stopped.
    """

    def __init__(self, root: str | os.PathLike, kind: str, cameras: dict[str, tuple[int, int]],
                 display: Display | None = None, stage_axis=(0.0, 0.0, 1.0), extra: dict | None = None,
                 bit_depth: dict[str, int] | None = None, bayer: dict[str, str] | None = None):
        root = Path(root)
        if kind not in KINDS:
            raise ValueError(f"kind must be one of {KINDS}")
        self.capture = Capture(root, kind, dict(cameras), [], display, tuple(stage_axis), dict(extra or {}),
                               dict(bit_depth or {}), dict(bayer or {}))
        if (root / MANIFEST).is_file():
            old = load_capture(root, check_images=False, min_positions=0)
            if old.kind != kind or old.cameras != self.capture.cameras:
                raise InputError(old.manifest_path, "an existing dataset of another kind or other cameras is "
                                                    "in the way; choose another output folder")
            self.capture.frames = [f for f in old.frames if old.path(f).is_file()]
        self._ids = {f.identity() for f in self.capture.frames}

    def has(self, frame: Frame) -> bool:
        """True if an identical frame (camera, z, state, pattern, repeat) is already written."""
        return frame.identity() in self._ids

    def add(self, frame: Frame, image: np.ndarray) -> None:
        """Write the frame's image, then the manifest that lists it (both atomically)."""
        if frame.camera not in self.capture.cameras:
            raise ValueError(f"unknown camera {frame.camera!r}")
        w, h = self.capture.cameras[frame.camera]
        if image.shape != (h, w):
            raise ValueError(f"image shape {image.shape} does not match camera {frame.camera} ({w}x{h})")
        if self.has(frame):
            raise ValueError(f"frame already written: {frame.file}")
        write_gray(self.capture.root / frame.file, image)
        self.capture.frames.append(frame)
        self._ids.add(frame.identity())
        self.capture.save()

    def add_many(self, items: Iterable[tuple[Frame, np.ndarray]]) -> None:
        for frame, image in items:
            self.add(frame, image)


def fringe_frame(camera: str, file: str, z_mm: float | None, axis: str, period_px: float, shift_rad: float,
                 low: float = 20, high: float = 240, **kw) -> Frame:
    """A fringe frame record (convenience for writers)."""
    return Frame(camera, file, Pattern("fringe", {"axis": axis, "period_px": period_px,
                                                  "shift_rad": float(shift_rad), "low": low, "high": high}),
                 z_mm=z_mm, **kw)


__all__ = ["FORMAT", "KINDS", "MANIFEST", "BAYER_PATTERNS", "MIN_POSES", "CoverGlass", "Display", "Pattern", "Frame", "Capture",
           "CaptureWriter", "load_capture", "fringe_frame"]

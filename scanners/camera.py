"""Cameras for acquisition: one interface (`Camera.grab`), averaging and the saturation check (`capture`).

- `OpenCVCamera` (`--camera cv:INDEX?exposure_ms=..&gain=..&bit_depth=..`): a `cv2.VideoCapture` device
  (USB/UVC, V4L2, DirectShow, AVFoundation). Exposure and gain are set where the driver allows and read
  back; a setting the driver ignores is reported, not silently assumed. Frames buffered before the
  pattern changed are discarded (`discard`), colour frames become monochrome (the seed: colour as
  monochrome).
- `FolderCamera` (`--camera folder:DIR?size=WxH&timeout=S&bit_depth=..`): photos taken by hand (a
  phone, a DSLR on a tripod: the seed's reduced PRVM and hand-held cases). Each `grab` takes the next
  photo (by file name) not used yet, waiting for it to appear (the user is asked to take it). Pixels
  stay as the sensor stored them (EXIF rotation is not applied: a PRVM belongs to the sensor).
- `SimulatedCamera` (`--camera sim[:LENS]?size=WxH&seed=N&pixel_um=P&tilt=TX,TY&roll=R`):
  `scanners.sim.camera.SimCamera` looking at the `SimScreen` on the emulated stage, rendered at the
  stage's TRUE position along its true travel direction (`stage_axis`). `pixel_um` sets the pixel pitch
  (default 5.3 um: a small sensor has a narrow field; pixel_um=21.2 at 320x256 sees the field of the
  1280x1024 default); `tilt` and `roll` (degrees) aim it so that its true alignment readings
  (`scanners.sim.aim`) are those (either given: the other defaults to 0; neither: the lens keeps its
  seeded pose). Its noise is seeded by what it sees (image shown, position, grab number), so a resumed
  acquisition gives the same images.

Bit depth (`Camera.bit_depth`, recorded as `cameras.NAME.bit_depth` in capture.json): the significant
bits of the pixel values, LSB-aligned. 8-bit frames are 8 bits. A 16-bit frame may hold 10, 12 or 14
significant bits: an OpenCV backend that reports it (XIMEA, `CAP_PROP_XI_OUTPUT_DATA_BIT_DEPTH`) is
asked; otherwise the user declares it with `bit_depth=N` in the camera's spec (a 12-bit camera whose
driver delivers 16-bit words: `cv:0?bit_depth=12`), and without either it is the frame's 16 bits. A
declared depth is checked against the first frame: values beyond 2^N - 1 (data MSB-aligned, or the
wrong N) are refused. The full scale 2^N - 1 is then where saturation is counted, here and in the
calibration.
"""

from __future__ import annotations

import os
import sys
import time
import zlib
from abc import ABC, abstractmethod
from pathlib import Path
from typing import Callable
from urllib.parse import parse_qsl, urlsplit

import numpy as np

from calib.errors import InputError
from calib.imageio import read_gray
from scanners.errors import HardwareError

PHOTO_SUFFIXES = (".png", ".tif", ".tiff", ".jpg", ".jpeg")


class SaturatedError(HardwareError):
    """A capture with too many pixels at full scale (tip 3.4: lower the exposure or the gain)."""


class Camera(ABC):
    """A camera: `name` in the dataset, `size` = (width, height), `bit_depth` of its pixel values (None:
    not known, the frames' own depth)."""

    name: str
    size: tuple[int, int]
    bit_depth: int | None = 8
    exposure_ms: float | None = None
    source: str | None = None  # where the last frame came from, if it came from a file

    @abstractmethod
    def grab(self) -> np.ndarray:
        """One new frame taken after this call: 2-D uint8 or uint16, (height, width)."""

    def close(self) -> None:
        """Release the device."""

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def capture(camera: Camera, average: int = 1, max_saturated: float | None = 1e-4) -> np.ndarray:
    """The mean of `average` frames (rounded, the camera's dtype). Raises SaturatedError if in any frame
    more than `max_saturated` of the pixels (a fraction) are at full scale (None: no check)."""
    if average < 1:
        raise ValueError("average must be >= 1")
    acc = None
    for _ in range(average):
        img = camera.grab()
        full = 2 ** camera.bit_depth - 1 if camera.bit_depth else int(np.iinfo(img.dtype).max)
        w, h = camera.size
        if img.shape != (h, w):
            raise HardwareError(f"{camera.name}: frame is {img.shape[1]}x{img.shape[0]}, expected {w}x{h}")
        if max_saturated is not None:
            frac = float(np.count_nonzero(img >= full)) / img.size
            if frac > max_saturated:
                raise SaturatedError(f"{camera.name}: {100 * frac:.2f}% of the pixels are saturated; lower "
                                     f"the exposure or the gain (or the pattern's high level)")
        acc = img.astype(np.float64) if acc is None else acc + img
    if average == 1:
        return img
    return np.rint(acc / average).astype(img.dtype)


# ------------------------------------------------------------------------------------------ OpenCV

def frame_bit_depth(first: np.ndarray, name: str, declared: int | None = None,
                    reported: int | None = None) -> int:
    """A camera's bit depth (module docstring) from its first frame, the user's `declared` depth and the
    driver's `reported` one (ignored unless 1..16): declared, else reported, else the frame's dtype.
    InputError (naming --camera) if the declared depth does not fit the frames."""
    stored = 8 * first.dtype.itemsize
    if declared is not None:
        if not 1 <= declared <= stored:
            raise InputError("--camera", f"{name}: bit_depth={declared} does not fit its {stored}-bit frames")
        top = int(first.max())
        if top > 2 ** declared - 1:
            raise InputError("--camera", f"{name}: a frame value of {top} exceeds bit_depth={declared} "
                                         f"(full scale {2 ** declared - 1}): MSB-aligned data, or another depth")
        return declared
    if reported is not None and 1 <= reported <= stored:
        return int(reported)
    return stored


class OpenCVCamera(Camera):
    """A `cv2.VideoCapture` device. exposure_ms/gain: None leaves the driver's setting (and automatic
    exposure) alone. discard: frames thrown away before each grab (driver buffers hold stale frames).
    bit_depth: the significant bits the user declares (`frame_bit_depth`)."""

    def __init__(self, index: int, name: str, exposure_ms: float | None = None, gain: float | None = None,
                 discard: int = 2, width: int | None = None, height: int | None = None,
                 bit_depth: int | None = None):
        import cv2
        self._cv2 = cv2
        self.name, self.discard = name, discard
        self._cap = cv2.VideoCapture(index)
        if not self._cap.isOpened():
            raise HardwareError(f"{name}: cannot open camera cv:{index}")
        self._cap.set(cv2.CAP_PROP_BUFFERSIZE, 1)
        if width and height:
            self._cap.set(cv2.CAP_PROP_FRAME_WIDTH, width)
            self._cap.set(cv2.CAP_PROP_FRAME_HEIGHT, height)
        if exposure_ms is not None:
            self._cap.set(cv2.CAP_PROP_AUTO_EXPOSURE, 1)  # V4L2: 1 = manual
            backend = self._cap.getBackendName()
            # V4L2 counts exposure in 100 us; DirectShow and MSMF in log2(seconds)
            value = exposure_ms * 10 if backend == "V4L2" else float(np.log2(exposure_ms / 1000))
            if not self._cap.set(cv2.CAP_PROP_EXPOSURE, value):
                print(f"stereodic: {name}: the {backend} driver ignored the exposure setting", file=sys.stderr)
            else:
                self.exposure_ms = exposure_ms
        if gain is not None and not self._cap.set(cv2.CAP_PROP_GAIN, gain):
            print(f"stereodic: {name}: the driver ignored the gain setting", file=sys.stderr)
        first = self._read()
        self.size = (first.shape[1], first.shape[0])
        reported = int(self._cap.get(cv2.CAP_PROP_XI_OUTPUT_DATA_BIT_DEPTH) or 0)
        self.bit_depth = frame_bit_depth(first, name, bit_depth, reported)

    def _read(self) -> np.ndarray:
        ok, frame = self._cap.read()
        if not ok or frame is None:
            raise HardwareError(f"{self.name}: the camera returned no frame (unplugged?)")
        if frame.ndim == 3:
            frame = self._cv2.cvtColor(frame, self._cv2.COLOR_BGR2GRAY)
        return frame

    def grab(self) -> np.ndarray:
        for _ in range(self.discard):
            self._cap.grab()
        return self._read()

    def close(self) -> None:
        self._cap.release()


# ------------------------------------------------------------------------------------------ folder

class FolderCamera(Camera):
    """Photos arriving in `folder`, used in file-name order, each once. `size` = (width, height), or
    None to take it from the first photo already there."""

    def __init__(self, folder: str | os.PathLike, name: str, size: tuple[int, int] | None = None,
                 timeout_s: float = 600.0, poll_s: float = 0.2, bit_depth: int | None = None):
        self.folder, self.name = Path(folder), name
        self.timeout_s, self.poll_s = timeout_s, poll_s
        self.used: set[str] = set()
        self.bit_depth = bit_depth                    # None until a photo or the user tells
        photos = self._photos()
        if size is None and not photos:
            raise InputError(self.folder, "no photo here yet to take the size from; give it: "
                                          "folder:DIR?size=WIDTHxHEIGHT")
        if photos:
            img = read_gray(self.folder / photos[0])
            size = size or (img.shape[1], img.shape[0])
            self.bit_depth = frame_bit_depth(img, name, bit_depth)
        self.size = size

    def _photos(self) -> list[str]:
        if not self.folder.is_dir():
            return []
        return sorted(p.name for p in self.folder.iterdir() if p.suffix.lower() in PHOTO_SUFFIXES)

    def grab(self) -> np.ndarray:
        deadline = time.monotonic() + self.timeout_s
        asked = False
        while True:
            fresh = [p for p in self._photos() if p not in self.used]
            if fresh:
                break
            if not asked:
                print(f"Take a photo with {self.name} now (it should appear in {self.folder}).", file=sys.stderr)
                asked = True
            if time.monotonic() > deadline:
                raise HardwareError(f"{self.name}: no new photo in {self.folder} within {self.timeout_s:g} s")
            time.sleep(self.poll_s)
        name = fresh[0]
        time.sleep(self.poll_s if asked else 0)  # a photo that just appeared may still be being written
        try:
            img = read_gray(self.folder / name)
        except InputError as exc:
            raise HardwareError(f"{self.name}: {exc}") from None
        self.used.add(name)
        self.source = name
        return img


# ------------------------------------------------------------------------------------------ simulated

class SimulatedCamera(Camera):
    """A simulated camera rendering a SimScreen at the true position `true_z_mm()` (mm) of its stage."""

    def __init__(self, name: str, screen, true_z_mm: Callable[[], float], lens: str = "brown",
                 size: tuple[int, int] = (160, 128), seed: int = 0, noise: bool = True, supersample: int = 3, *,
                 pixel_um: float | None = None, aim: tuple[float, float, float] | None = None,
                 stage_axis=(0.0, 0.0, 1.0)):
        from scanners.sim.aim import aim as aim_lens
        from scanners.sim.camera import SimCamera
        from scanners.sim.lenses import make_lens
        from scanners.sim.sensor import Sensor
        self.name, self.size, self.seed, self.noise = name, size, seed, noise
        self.screen, self.true_z_mm, self.stage_axis = screen, true_z_mm, tuple(stage_axis)
        optics = make_lens(lens, width=size[0], height=size[1], seed=seed,
                           **({} if pixel_um is None else {"pixel_mm": pixel_um / 1000}))
        if aim is not None:
            optics = aim_lens(optics, *aim, display=screen.sim)
        self.sim = SimCamera(optics, sensor=Sensor(bit_depth=8), supersample=supersample, seed=seed)
        self.bit_depth = self.sim.sensor.bit_depth
        self._seen: tuple[int, int] = (-1, 0)  # (screen serial, grabs of that image)

    def set_exposure(self, level: int, z_mm: float, fraction: float = 0.87) -> None:
        """Expose so that the brightest pixel seeing a flat screen at `level` reaches `fraction` of full
        scale at stage position z_mm."""
        self.sim.set_exposure(self.screen.sim, level, self.true_pose(z_mm), fraction=fraction)

    def true_pose(self, z_mm: float | None = None):
        """The display's TRUE pose (`scanners.sim.pose.DisplayPose`) at stage position z_mm (default: where
        the stage truly is now)."""
        from scanners.sim.pose import DisplayPose
        return DisplayPose.staged(self.true_z_mm() if z_mm is None else z_mm, axis=self.stage_axis)

    def grab(self) -> np.ndarray:
        if self.screen.image is None:
            raise HardwareError(f"{self.name}: the simulated screen shows nothing yet")
        serial, k = self._seen
        k = k + 1 if serial == self.screen.serial else 0
        self._seen = (self.screen.serial, k)
        z = self.true_z_mm()
        rng = np.random.default_rng([self.seed, zlib.crc32(self.screen.image.tobytes()),
                                     round(z * 1e6) & 0xFFFFFFFF, k])
        return self.sim.render(self.screen.image, self.screen.sim, self.true_pose(z), noise=self.noise, rng=rng)


# ------------------------------------------------------------------------------------------ specs

def _size_option(options: dict, spec: str) -> tuple[int, int] | None:
    if "size" not in options:
        return None
    try:
        w, h = (int(v) for v in options["size"].lower().split("x"))
        if w > 0 and h > 0:
            return w, h
    except ValueError:
        pass
    raise InputError("--camera", f"{spec!r}: size must be WIDTHxHEIGHT")


def _float_option(options: dict, key: str, spec: str) -> float | None:
    if key not in options:
        return None
    try:
        return float(options[key])
    except ValueError:
        raise InputError("--camera", f"{spec!r}: {key} must be a number") from None


def _floats_option(options: dict, key: str, spec: str, count: int) -> tuple[float, ...] | None:
    if key not in options:
        return None
    try:
        values = tuple(float(v) for v in options[key].split(","))
    except ValueError:
        values = ()
    if len(values) != count or not all(np.isfinite(values)):
        raise InputError("--camera", f"{spec!r}: {key} must be {count} comma-separated number(s)")
    return values


def open_camera(spec: str, name: str, screen=None, true_z_mm: Callable[[], float] | None = None,
                stage_axis=(0.0, 0.0, 1.0)) -> Camera:
    """A camera from a `--camera` value: `cv:INDEX`, `folder:DIR` or `sim[:LENS]`, with ?key=value
    options (see the module docstring). A simulated camera needs the SimScreen, the stage's true
    position and its true travel direction (`stage_axis`, a unit vector in the WCS)."""
    parts = urlsplit(spec)
    kind = parts.scheme or spec.split("?")[0]
    options = dict(parse_qsl(parts.query))
    target = parts.netloc + parts.path if parts.scheme else ""
    allowed = {"cv": {"exposure_ms", "gain", "size", "discard", "bit_depth"}, "folder": {"size", "timeout", "bit_depth"},
               "sim": {"size", "seed", "noise", "pixel_um", "tilt", "roll"}}
    if kind not in allowed:
        raise InputError("--camera", f"unknown camera {spec!r} (cv:INDEX, folder:DIR or sim[:LENS])")
    unknown = set(options) - allowed[kind]
    if unknown:
        raise InputError("--camera", f"{spec!r}: unknown option(s) {', '.join(sorted(unknown))}")
    size = _size_option(options, spec)
    bits = _float_option(options, "bit_depth", spec)
    if bits is not None and (bits != int(bits) or not 1 <= bits <= 16):
        raise InputError("--camera", f"{spec!r}: bit_depth must be a whole number 1..16")
    bits = None if bits is None else int(bits)
    if kind == "cv":
        if not target.isdigit():
            raise InputError("--camera", f"{spec!r}: expected cv:INDEX, e.g. cv:0")
        w, h = size or (None, None)
        return OpenCVCamera(int(target), name, _float_option(options, "exposure_ms", spec),
                            _float_option(options, "gain", spec), int(_float_option(options, "discard", spec) or 2),
                            w, h, bits)
    if kind == "folder":
        if not target:
            raise InputError("--camera", f"{spec!r}: expected folder:DIR")
        timeout = _float_option(options, "timeout", spec)
        return FolderCamera(target, name, size, 600.0 if timeout is None else timeout, bit_depth=bits)
    from scanners.display import SimScreen
    if not isinstance(screen, SimScreen) or true_z_mm is None:
        raise InputError("--camera", "a simulated camera needs --display sim and a stage (emulated:zaber or "
                                     "emulated:grbl)")
    seed = _float_option(options, "seed", spec)
    pixel_um = _float_option(options, "pixel_um", spec)
    if pixel_um is not None and not pixel_um > 0:
        raise InputError("--camera", f"{spec!r}: pixel_um must be positive")
    tilt, roll = _floats_option(options, "tilt", spec, 2), _floats_option(options, "roll", spec, 1)
    aim = None if tilt is None and roll is None else (*(tilt or (0.0, 0.0)), (roll or (0.0,))[0])
    if aim is not None and max(abs(a) for a in aim) > 30:
        raise InputError("--camera", f"{spec!r}: tilt and roll must be within +-30 degrees")
    return SimulatedCamera(name, screen, true_z_mm, target or "brown", size or (160, 128),
                           int(seed or 0), options.get("noise", "1") not in ("0", "no", "false"),
                           pixel_um=pixel_um, aim=aim, stage_axis=stage_axis)


__all__ = ["Camera", "SaturatedError", "capture", "frame_bit_depth", "OpenCVCamera", "FolderCamera", "SimulatedCamera",
           "open_camera"]

"""Acquisition: drive stage, screen and cameras through a plan of shots and write a capture dataset.

A plan is a list of `Shot`s, each one thing shown (or nothing) at one stage position or state, taken by
every camera. `run` goes through it in order: move the stage when the position changes, ask for the next
state (load step, object pose) when the state changes, show the pattern, then for each camera capture
(averaging, refusing saturated fringe frames) and append the frame to the dataset with
`calib.capture.CaptureWriter`, which rewrites a valid manifest after every frame. Frames already in the
output folder are skipped without moving or showing anything, so after any fault (a `HardwareError`
from the stage, the screen or a camera, or Ctrl-C) the same command resumes where it stopped, and the
finished dataset equals one taken without interruption.

Plans:
- `calibration_plan`: at each stage position the flat frames first (intensity calibration before the
  geometry, seed tip 3.6), then the phase-shifting fringes of `calib.patterns.calibration_sequence`.
  Files `z000/cam0_flat_128.png`, `z000/cam0_x_P60_s0.png` (s = index of the phase step), as the
  simulator names them.
- `scan_plan`: projector fringes (and flats) per state: `s000/cam0_x_P60_s0.png`.
- `dic_plan`: one frame per camera per state, nothing shown: `s000/cam0.png`.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from calib.capture import CaptureWriter, Display, Frame, Pattern
from calib.patterns import calibration_sequence, step_shifts
from calib.progress import progress
from scanners.camera import Camera, FolderCamera, capture
from scanners.display import Screen
from scanners.errors import HardwareError
from scanners.stage import Stage

DEFAULT_FLATS = (0, 32, 64, 96, 128, 160, 192, 224, 255)


@dataclass(frozen=True)
class Shot:
    """One exposure of every camera: the pattern shown (`image`: uint8 at the screen's size, None to
    show nothing), the stage position `z_mm` (None: no stage), the `state` (None: none) and the file
    `folder/<camera>_<stem>.png` each camera's frame goes to."""

    pattern: Pattern
    image: np.ndarray | None
    folder: str
    stem: str
    z_mm: float | None = None
    state: int | None = None

    def frame(self, camera: Camera) -> Frame:
        stem = camera.name if not self.stem else f"{camera.name}_{self.stem}"
        return Frame(camera.name, f"{self.folder}/{stem}.png", self.pattern, z_mm=self.z_mm, state=self.state,
                     exposure_ms=camera.exposure_ms)


@dataclass(frozen=True)
class Settings:
    """average: frames averaged per image (tip 3.3); max_saturated: largest fraction of full-scale pixels
    accepted in a fringe frame (tip 3.4; flats, which measure the response, are not checked)."""

    average: int = 1
    max_saturated: float = 1e-4


def _stem(pattern: Pattern, steps: int) -> str:
    if pattern.type == "flat":
        return f"flat_{pattern.level}"
    k = int(np.argmin(np.abs(step_shifts(steps) - pattern.shift_rad)))
    return f"{pattern.axis}_P{pattern.period_px:g}_s{k}"


def pattern_shots(size: tuple[int, int], periods: Sequence[float], steps: int, flats: Sequence[int],
                  axes: Sequence[str], low: int, high: int, folder: str, z_mm: float | None = None,
                  state: int | None = None) -> list[Shot]:
    """Flats, then fringes (each axis, each period longest first, each phase step) at one position or
    state, for a screen of `size` = (width, height)."""
    seq = calibration_sequence(size[0], size[1], periods=periods, steps=steps, axes=tuple(axes), low=low,
                               high=high, flat_levels=tuple(flats))
    return [Shot(p, img, folder, _stem(p, steps), z_mm, state) for p, img in seq]


def calibration_plan(size: tuple[int, int], positions: Sequence[float], periods: Sequence[float], steps: int = 3,
                     flats: Sequence[int] = DEFAULT_FLATS, low: int = 20, high: int = 240) -> list[Shot]:
    """Every shot of a calibration: at each stage position (mm) flats, then x and y fringes."""
    shots = []
    for i, z in enumerate(positions):
        shots += pattern_shots(size, periods, steps, flats, ("x", "y"), low, high, f"z{i:03d}", z_mm=float(z))
    return shots


def scan_plan(size: tuple[int, int], states: Sequence[int], periods: Sequence[float], steps: int = 3,
              flats: Sequence[int] = (), axes: Sequence[str] = ("x",), low: int = 20,
              high: int = 240) -> list[Shot]:
    """Every shot of a structured-light scan: for each state (object pose) the projector's patterns."""
    shots = []
    for s in states:
        shots += pattern_shots(size, periods, steps, flats, axes, low, high, f"s{s:03d}", state=s)
    return shots


def dic_plan(states: Sequence[int]) -> list[Shot]:
    """One frame per camera and state (load step), nothing shown."""
    return [Shot(Pattern("none"), None, f"s{s:03d}", "", state=s) for s in states]


def open_writer(out_dir, kind: str, cameras: Sequence[Camera], display: Display | None = None,
                extra: dict | None = None) -> CaptureWriter:
    """A CaptureWriter for these cameras (resuming `out_dir` if it holds this dataset already)."""
    return CaptureWriter(out_dir, kind, {c.name: c.size for c in cameras}, display, extra=extra,
                         bit_depth={c.name: c.bit_depth for c in cameras if c.bit_depth is not None})


def ask_on_terminal(state: int) -> None:
    """Wait for the user to set up `state` (on stderr, Enter on stdin)."""
    print(f"Set up state {state} (load step / object pose), then press Enter.", file=sys.stderr)
    try:
        input()
    except EOFError:
        raise HardwareError(f"state {state}: no answer on standard input") from None


def run(writer: CaptureWriter, shots: Sequence[Shot], cameras: Sequence[Camera], stage: Stage | None = None,
        screen: Screen | None = None, settings: Settings = Settings(),
        next_state: Callable[[int], None] = ask_on_terminal) -> int:
    """Capture every frame of `shots` not already in `writer`; returns how many were captured.

    Raises what the devices raise (HardwareError, SaturatedError) with every frame taken so far on
    disk and listed in the manifest."""
    for cam in cameras:  # a folder camera must not reuse photos already in the dataset
        if isinstance(cam, FolderCamera):
            cam.used |= {f.extra["source"] for f in writer.capture.frames
                         if f.camera == cam.name and "source" in f.extra}
    z_now = state_now = shown = None
    taken = 0
    for shot in progress(shots, "acquiring", total=len(shots)):
        todo = [c for c in cameras if not writer.has(shot.frame(c))]
        if not todo:
            continue
        if shot.z_mm is not None and shot.z_mm != z_now:
            stage.move_to(shot.z_mm)
            z_now = shot.z_mm
        if shot.state is not None and shot.state != state_now:
            next_state(shot.state)
            state_now = shot.state
        if shot.image is not None and shown is not shot.image:
            screen.show(shot.image)
            shown = shot.image
        for cam in todo:
            limit = None if shot.pattern.type in ("flat", "none") else settings.max_saturated
            image = capture(cam, settings.average, limit)
            frame = shot.frame(cam)
            extra = {}
            if settings.average > 1:
                extra["average"] = settings.average
            if cam.source is not None:
                extra["source"] = cam.source
            if extra:
                frame = Frame(**{**frame.__dict__, "extra": extra})
            writer.add(frame, image)
            taken += 1
    return taken


__all__ = ["Shot", "Settings", "DEFAULT_FLATS", "pattern_shots", "calibration_plan", "scan_plan", "dic_plan",
           "open_writer", "ask_on_terminal", "run"]

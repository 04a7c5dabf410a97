"""The alignment aid's live loop (`stereodic align`): bring a camera square to the display, and the stage
axis onto the display's normal, with a live readout on the display itself.

A session (`AlignSession`) first shows a few flat grey levels and measures the display's response from
them (`calib.live_decode.flat_correction`: the intensity calibration of tip 3.6, which removes the
phase error of the display's gamma). Each update (`measure`) then shows a quick fringe set (both axes,
by default two periods, the longest spanning the display and one 16 times shorter, 3 steps each: 12
frames), decodes it on the fly (`calib.live_decode.decode_display`), fits the display's pose through
the camera's rays (`calib.alignment`) and reads the camera's tilt, roll and distance. Between full sets
(every `full_every`-th update) an update shows only the shortest period (6 frames) and takes the fringe
order from the last map (`calib.live_decode.track_display`); when the camera moved too far for that
(fewer pixels agree, or they agree less well), the update is taken again in full. The rays are a
PRVM's or a pinhole calibration's when given, else the pattern-alone estimate
(`calib.alignment.PatternIntrinsics`). `measure_stage` measures at two stage positions and turns the
two poses into the stage axis; a display that did not move as far as the stage says (less than half)
is a hardware fault.

`run` drives a session: the stage check (if there is a stage), then updates, each followed by the fused
picture (`scanners.align_picture`) on the display for `hold_s`, until `updates` are done or Esc / q is
pressed on the screen (s measures the stage again). `AlignRecord` keeps what is measured: every fused
picture (`fused_0000.png`, ...) and `readings.json` (format "stereodic.align/1"), each written whole
(atomically) after every update, so a stop at any moment leaves complete files.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from calib import __version__
from calib.alignment import (PatternIntrinsics, PinholeRays, PoseFit, PrvmRays, Reading, StageAxis,
                             fit_display_pose, read_alignment, stage_axis)
from calib.atomic import write_json
from calib.errors import InputError
from calib.imageio import write_rgb
from calib.live_decode import DisplayMap, decode_display, flat_correction, track_display
from calib.patterns import flat_image, fringe_image, step_shifts
from calib.reduced import fit_homography
from scanners.align_advice import camera_advice, stage_advice, stage_direction
from scanners.align_picture import OUTSIDE, TEXT, WITHIN, fused_picture, message_picture
from scanners.camera import Camera, capture
from scanners.display import Screen
from scanners.errors import HardwareError
from scanners.stage import Stage

FORMAT = "stereodic.align/1"
# a camera sees the pattern when at least this fraction of its pixels (and MIN_PIXELS) decode it
MIN_FRACTION = 0.05
MIN_PIXELS = 500
# a tracked update is taken again in full when fewer pixels than this fraction of the last map's decode
# it, or their median disagreement with that map exceeds MAX_TRACK_MISMATCH (periods)
MIN_TRACKED = 0.8
MAX_TRACK_MISMATCH = 0.1
# the display must move at least this fraction of the stage's commanded travel (and the display points
# seen by the camera this fraction of what that travel moves them)
MIN_TRAVEL_FRACTION = 0.5


class PatternNotSeen(InputError):
    """The camera does not see the pattern (pointed elsewhere, covered, out of focus, badly exposed)."""


def default_periods(display_size: tuple[int, int]) -> tuple[float, float]:
    """The longest period spans the display; the other is 16 times shorter (safe to unwrap with the
    display response corrected: the periods disagree by ~0.03 period RMS on the simulated bench)."""
    longest = float(max(display_size))
    return longest, longest / 16


@dataclass(frozen=True)
class AlignSettings:
    """periods: fringe periods (display pixels; the longest must span the display); steps: phase steps;
    low, high: fringe levels; flats: grey levels of the response measurement (3 or more);
    tolerance_deg: the squareness tolerance; average: frames averaged per image; hold_s: how long the
    fused picture stays on the display after each update; full_every: every how many updates the full
    fringe set is shown (1: always; in between only the shortest period, tracked)."""

    periods: tuple[float, ...]
    steps: int = 3
    low: int = 20
    high: int = 240
    flats: tuple[int, ...] = (20, 130, 240)
    tolerance_deg: float = 0.2
    average: int = 1
    hold_s: float = 0.5
    full_every: int = 4

    def to_json(self) -> dict:
        return {"periods": list(self.periods), "steps": self.steps, "low": self.low, "high": self.high,
                "flats": list(self.flats), "tolerance_deg": self.tolerance_deg, "average": self.average,
                "full_every": self.full_every}


@dataclass
class Measurement:
    """One update: what each pixel saw (`display_map`), the homography display pixels -> image pixels,
    the camera model used, the display's pose in its frame, the reading; z_mm: the stage position (None
    without a stage); seconds: how long the update took; frames: how many fringe frames it showed."""

    display_map: DisplayMap
    homography: np.ndarray
    model: PrvmRays | PinholeRays
    fit: PoseFit
    reading: Reading
    z_mm: float | None
    seconds: float
    frames: int


class AlignSession:
    """A camera looking at a screen of pixel pitch `pitch_mm` (mm, (x, y)). model: the camera's rays
    (`PrvmRays` or `PinholeRays`), or None to estimate them from the pattern (`focal_px`: a known focal
    length in pixels for that estimate)."""

    def __init__(self, screen: Screen, camera: Camera, pitch_mm, model=None, *, settings: AlignSettings,
                 focal_px: float | None = None):
        if model is not None and (model.width, model.height) != tuple(camera.size):
            raise InputError("--intrinsics", f"describes a {model.width}x{model.height} camera, but "
                                             f"{camera.name} delivers {camera.size[0]}x{camera.size[1]} frames")
        if max(settings.periods) < max(screen.size):
            raise InputError("--periods", f"the longest period ({max(settings.periods):g} px) must span the "
                                          f"display ({screen.size[0]}x{screen.size[1]})")
        self.screen, self.camera, self.model, self.settings = screen, camera, model, settings
        self.pitch_mm = (float(pitch_mm[0]), float(pitch_mm[1]))
        self.intrinsics = PatternIntrinsics(*camera.size, focal_px=focal_px) if model is None else None
        self.shifts = step_shifts(settings.steps)
        w, h = screen.size
        self.patterns = {(axis, float(p)): [fringe_image(w, h, axis=axis, period_px=p, shift_rad=d,
                                                         low=settings.low, high=settings.high)
                                            for d in self.shifts]
                         for axis in ("x", "y") for p in sorted(settings.periods, reverse=True)}
        self.shortest = {key: images for key, images in self.patterns.items() if key[1] == min(settings.periods)}
        self.full_scale = 2 ** camera.bit_depth - 1
        self.correction = None
        self.last_map: DisplayMap | None = None       # the map the next tracked update is unwrapped with
        self.tracked_since_full = 0

    def _grab(self, image: np.ndarray) -> np.ndarray:
        self.screen.show(image)
        return capture(self.camera, self.settings.average, None)

    def _not_seen(self, why: str) -> PatternNotSeen:
        return PatternNotSeen("--camera", f"{self.camera.name} does not see the pattern: {why} (point it at the "
                                          "screen, focus it, and check its exposure)")

    def calibrate_response(self) -> None:
        """Measure the display's response from flat frames. PatternNotSeen if the camera sees no screen:
        fewer than MIN_FRACTION of its pixels brighten by a tenth of full scale from the darkest grey level
        to the brightest."""
        w, h = self.screen.size
        images = [self._grab(flat_image(w, h, level)) for level in self.settings.flats]
        order = np.argsort(self.settings.flats)
        lit = float(np.mean(images[order[-1]].astype(np.float32) - images[order[0]] > 0.1 * self.full_scale))
        if lit < MIN_FRACTION:
            raise self._not_seen(f"only {lit:.1%} of its pixels brighten from grey {min(self.settings.flats)} to "
                                 f"{max(self.settings.flats)}")
        try:
            self.correction = flat_correction(self.settings.flats, images, self.full_scale, self.settings.low,
                                              self.settings.high, self.shifts)
        except ValueError as exc:
            raise self._not_seen(f"the flat grey levels show no response ({exc})") from None

    def measure(self, z_mm: float | None = None, model=None, *, full: bool = False) -> Measurement:
        """Show the fringe set (the full one when `full`, at the first update, every `full_every`-th and
        when tracking fails; else the shortest period, tracked), capture it and `process` it."""
        start = time.monotonic()
        track = (not full and self.last_map is not None and len(self.patterns) > len(self.shortest)
                 and self.tracked_since_full + 1 < self.settings.full_every)
        shown = self.shortest if track else self.patterns
        frames = {key: [self._grab(img) for img in images] for key, images in shown.items()}
        if track:
            last = self.last_map
            try:
                m = self.process(frames, z_mm, model, start, previous=last)
            except PatternNotSeen:
                m = None
            if (m is None or m.display_map.valid.sum() < MIN_TRACKED * last.valid.sum()
                    or max(s[0] for s in m.display_map.mismatch_sigma.values()) > MAX_TRACK_MISMATCH):
                return self.measure(z_mm, model, full=True)          # moved too far: the full set
            self.tracked_since_full += 1
        else:
            m = self.process(frames, z_mm, model, start)
            self.tracked_since_full = 0
        self.last_map = m.display_map
        return m

    def process(self, frames: dict, z_mm: float | None = None, model=None, start: float | None = None,
                previous: DisplayMap | None = None) -> Measurement:
        """Decode a captured fringe set ({(axis, period): [frames]}) and read the camera's alignment.
        model: the rays to use (default: the session's, or the pattern-alone estimate updated with this
        view); start: when the update began (time.monotonic()); previous: the map to take the fringe
        order from (then `frames` holds one period per axis). PatternNotSeen when too few pixels decode
        the pattern."""
        start = time.monotonic() if start is None else start
        try:
            if previous is None:
                dm = decode_display(frames, self.shifts, self.screen.size, self.full_scale,
                                    correction=self.correction)
            else:
                dm = track_display(frames, self.shifts, previous, self.full_scale, correction=self.correction)
        except ValueError as exc:
            raise self._not_seen(f"its fringes do not decode consistently ({exc})") from None
        need = max(MIN_PIXELS, MIN_FRACTION * dm.valid.size)
        if dm.valid.sum() < need:
            raise self._not_seen(f"only {dm.valid_fraction:.1%} of its pixels decode it")
        step = max(1, int(np.sqrt(dm.valid.sum() / 5000)))       # a few thousand points fix a homography
        hom = np.diag([step, step, 1.0]) @ fit_homography(dm.coord[:, ::step, ::step], dm.valid[::step, ::step])
        if model is None:
            model = self.model if self.model is not None else self.intrinsics.update(hom, self.pitch_mm)
        try:
            fit = fit_display_pose(model, dm.coord, dm.valid, self.pitch_mm)
            reading = read_alignment(model, fit, self.pitch_mm)
        except ValueError as exc:
            raise self._not_seen(str(exc)) from None
        return Measurement(dm, hom, model, fit, reading, z_mm, time.monotonic() - start,
                           sum(len(f) for f in frames.values()))

    def refit(self, m: Measurement, model) -> Measurement:
        """The same decoded view read through other rays."""
        fit = fit_display_pose(model, m.display_map.coord, m.display_map.valid, self.pitch_mm)
        return Measurement(m.display_map, m.homography, model, fit, read_alignment(model, fit, self.pitch_mm),
                           m.z_mm, m.seconds, m.frames)

    def measure_stage(self, stage: Stage, positions) -> tuple[StageAxis, list[Measurement]]:
        """The stage axis from measurements at the two `positions` (mm), both with the same camera model.
        Without intrinsics the known travel fixes the focal length (`PatternIntrinsics.scale_focal`).
        HardwareError when the display points the camera's pixels see moved less than MIN_TRAVEL_FRACTION
        of what the travel would move them (median over the pixels), or, with known intrinsics, when the
        display moved less than MIN_TRAVEL_FRACTION of the commanded travel."""
        stage.move_to(positions[0])
        first = self.measure(positions[0], full=True)
        stage.move_to(positions[1])
        second = self.measure(positions[1], model=first.model, full=True)
        self.last_map = None                          # the camera is read next at another position
        travel = positions[1] - positions[0]
        both = first.display_map.valid & second.display_map.valid
        a, b = first.display_map.coord[:, both], second.display_map.coord[:, both]
        moved = float(np.median(np.linalg.norm(b - a, axis=0))) if a.size else 0.0
        # moving the display by `travel` along its normal changes its scale by travel / distance
        radius = np.median(np.linalg.norm(a - first.reading.line_of_sight_px[:, None], axis=0)) if a.size else 0.0
        expected = abs(travel) / first.reading.distance_mm * radius
        fault = f"{stage.name}: it reports moving {abs(travel):g} mm, but "
        if moved < MIN_TRAVEL_FRACTION * expected:
            raise HardwareError(fault + f"the camera sees the display where it was (moved {moved:.2f} display px, "
                                        f"{expected:.0f} expected): a slipping coupling, a loose carriage, or "
                                        "another stage?")
        axis = stage_axis(first.fit, second.fit, travel)
        if self.intrinsics is not None and not self.intrinsics.fixed:
            for _ in range(3):
                model = self.intrinsics.scale_focal(axis.commanded_mm / axis.travel_mm)
                first, second = self.refit(first, model), self.refit(second, model)
                axis = stage_axis(first.fit, second.fit, travel)
        elif axis.travel_mm < MIN_TRAVEL_FRACTION * axis.commanded_mm:
            raise HardwareError(fault + f"the display moved {axis.travel_mm:.2f} mm relative to the camera: a "
                                        "slipping coupling, a loose carriage, or another stage?")
        return axis, [first, second]

    def model_note(self, described: str = "") -> str:
        """One line on the rays used (`described`: e.g. the intrinsics file)."""
        if self.intrinsics is None:
            return f"rays: {described or {'prvm': 'a PRVM', 'pinhole': 'an OpenCV pinhole'}[self.model.kind]}"
        i = self.intrinsics
        if i.fixed:
            return f"rays: pattern alone, focal length {i.focal_px:.0f} px (given)"
        if i.from_travel:
            return f"rays: pattern alone, focal length {i.focal_px:.0f} px from the stage travel"
        if i.focal_measured:
            return f"rays: pattern alone, focal length {i.focal_px:.0f} px from a {i.obliquity_deg:.1f} deg view"
        return ("rays: pattern alone, focal length not measured yet (tilt the camera 3+ deg once, or give "
                "--focal-px): tilts are rough")


def readout(m: Measurement, settings: AlignSettings, stage: StageAxis | None, display_mm, notes: list[str]
            ) -> list[tuple[str, tuple]]:
    """The fused picture's text: (line, colour) pairs."""
    rd, tol = m.reading, settings.tolerance_deg
    lines = [(f"camera tilt x {rd.tilt_x_deg:+.3f} deg, y {rd.tilt_y_deg:+.3f} deg, roll {rd.roll_deg:+.3f} deg, "
              f"distance {rd.distance_mm:.1f} mm", TEXT)]
    advice = camera_advice(rd, tol)
    if rd.square_within(tol):
        lines.append((f"square to the screen within {tol:g} deg", WITHIN))
    lines += [(a, OUTSIDE) for a in advice]
    if stage is not None:
        lines.append((f"stage axis {stage_direction(stage)} (drift {1000 * stage.drift[0]:+.1f}, "
                      f"{1000 * stage.drift[1]:+.1f} um per mm)", TEXT))
        tilt = stage_advice(stage, display_mm, tol)
        lines += [(a, OUTSIDE) for a in tilt] or [(f"stage axis along the screen normal within {tol:g} deg",
                                                   WITHIN)]
    return lines + [(n, TEXT) for n in notes]


class AlignRecord:
    """The session's outputs in `folder` (which must be new or empty; checked here, before any work):
    fused pictures and readings.json. `header`: the session's description (camera, display, intrinsics,
    settings), set once the devices are open."""

    def __init__(self, folder):
        self.folder = Path(folder)
        if self.folder.exists() and (not self.folder.is_dir() or any(self.folder.iterdir())):
            raise InputError(self.folder, "exists and is not an empty folder; give a new one")
        self.header: dict = {}
        self.data: dict = {"stage": None, "updates": []}

    def picture(self, name: str, picture: np.ndarray) -> str:
        write_rgb(self.folder / name, picture)
        return name

    def stage(self, axis: StageAxis, measurements: list[Measurement], advice: list[str], picture) -> None:
        self.data["stage"] = {**axis.to_json(), "advice": advice, "picture": self.picture("stage.png", picture),
                              "positions": [{"z_mm": m.z_mm, **m.reading.to_json()} for m in measurements]}
        self.write()

    def update(self, entry: dict, picture: np.ndarray) -> None:
        entry["picture"] = self.picture(f"fused_{len(self.data['updates']):04d}.png", picture)
        self.data["updates"].append(entry)
        self.write()

    def write(self) -> None:
        write_json(self.folder / "readings.json", {"format": FORMAT, "software": f"stereodic {__version__}",
                                                   **self.header, **self.data})


def _entry(m: Measurement, session: AlignSession) -> dict:
    rd, tol = m.reading, session.settings.tolerance_deg
    entry = {"z_mm": m.z_mm, **rd.to_json(), "square": rd.square_within(tol), "advice": camera_advice(rd, tol),
             "valid_fraction": m.display_map.valid_fraction, "frames": m.frames, "seconds": m.seconds}
    if session.intrinsics is not None:
        entry["focal_px"] = session.intrinsics.focal_px
        entry["focal_measured"] = session.intrinsics.focal_measured
    return entry


def run(session: AlignSession, *, updates: int = 0, stage: Stage | None = None, positions=(0.0, 50.0),
        record: AlignRecord | None = None, described: str = "", report: Callable[[str], None] = print,
        interactive: bool = False) -> list[Measurement]:
    """The session: response, stage check (with a stage), then `updates` updates (0: until Esc or q on
    the screen). Returns the updates' measurements. Raises PatternNotSeen (the camera does not see the
    pattern at the first update) and what the devices raise (HardwareError)."""
    screen, settings = session.screen, session.settings
    display_mm = (screen.size[0] * session.pitch_mm[0], screen.size[1] * session.pitch_mm[1])
    notes = [] if not interactive else ["Esc: stop" + ("   s: measure the stage again" if stage else "")]
    if stage is not None:
        stage.move_to(positions[0])
    session.calibrate_response()
    axis = None

    def check_stage():
        nonlocal axis
        axis, ms = session.measure_stage(stage, positions)
        stage.move_to(positions[0])
        picture = fused_picture(screen.size, ms[1], session.pitch_mm, settings.tolerance_deg,
                                readout(ms[1], settings, axis, display_mm, [session.model_note(described)]))
        advice = stage_advice(axis, display_mm, settings.tolerance_deg)
        if record is not None:
            record.stage(axis, ms, advice, picture)
        report(f"stage axis {stage_direction(axis)} (travel {axis.travel_mm:.2f} of {axis.commanded_mm:g} mm): "
               + ("; ".join(advice) or f"aligned within {settings.tolerance_deg:g} deg"))

    if stage is not None:
        check_stage()
    done: list[Measurement] = []
    while updates == 0 or len(done) < updates:
        try:
            m = session.measure(positions[0] if stage is not None else None)
        except PatternNotSeen as exc:
            if not done:
                raise
            screen.show(message_picture(screen.size, [(f"pattern lost: {exc.problem}", OUTSIDE)]))
            report(f"update {len(done)}: pattern lost ({exc.problem})")
            time.sleep(settings.hold_s)
            continue
        done.append(m)
        picture = fused_picture(screen.size, m, session.pitch_mm, settings.tolerance_deg,
                                readout(m, settings, axis, display_mm, [session.model_note(described)] + notes))
        screen.show(picture)
        entry = _entry(m, session)
        if record is not None:
            record.update(entry, picture)
        rd = m.reading
        report(f"update {len(done) - 1}: tilt x {rd.tilt_x_deg:+.3f} y {rd.tilt_y_deg:+.3f} deg, roll "
               f"{rd.roll_deg:+.3f} deg, distance {rd.distance_mm:.1f} mm: "
               + ("square" if entry["square"] else "; ".join(entry["advice"])))
        deadline = time.monotonic() + settings.hold_s
        keys: list[str] = []
        while True:
            keys += screen.pressed()
            if time.monotonic() >= deadline or keys:
                break
            time.sleep(0.02)
        if {"escape", "q", "quit"} & set(keys):
            break
        if "s" in keys and stage is not None:
            check_stage()
    return done


__all__ = ["FORMAT", "PatternNotSeen", "default_periods", "AlignSettings", "Measurement", "AlignSession",
           "readout", "AlignRecord", "run"]

"""A display held by hand (the seed's tip 2.3): random, realistic display poses in front of the camera,
held still for each fringe set, with the truth in the frame the calibration reports (DESIGN.md: the
display's frame at pose 0).

Poses (`handheld_poses`): the display faces the camera, its centre `distance_mm` (drawn uniformly) in
front of the camera along the optical axis, shifted sideways by up to a tenth of the field there, tilted
about an axis across the line of sight by up to `max_tilt_deg` (the tilt axes of successive poses go
round the circle, so that the planes' normals span all directions), and turned about its normal by up to
`roll_deg`. As people hold a monitor (`as_held`, issue 29): pose 0 at a set distance (`first_mm`),
tilts from `min_tilt_deg` up, about the display's x or y axis in turn (`tilt_about="xy"`), the lens
focused at pose 0 behind a cover glass. A pose is drawn again until the display covers `min_cover` of the camera's field (pose 0,
which also carries the flats: all of it) and no pixel sees it at more than `MAX_INCIDENCE_DEG` from its
normal.

A disturbed pose (`HandHeld.disturbed`) models a display that moved while its fringes were shown: its
second half of fringe frames is rendered with the display moved by a small rigid motion about its
centre (`disturbance_mm` along a random direction, `disturbance_deg` about a random axis).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.errors import InputError
from calib.prvm_file import PRVM
from scanners.sim.display import SimDisplay
from scanners.sim.lenses import Lens
from scanners.sim.optics import rotation
from scanners.sim.pose import DisplayPose, about_point

# no camera pixel sees the display at more than this angle from its normal (grazing views blur the
# fringes along the tilt into the display's neighbouring pixels; a person holding the display would not)
MAX_INCIDENCE_DEG = 60.0
# the sensor is checked on a grid of every COVER_STEP-th pixel
COVER_STEP = 16
MAX_DRAWS = 200
# the display's focus, distance and cover glass as people hold a monitor for a stage-free calibration
# (issue 29): pose 0 at 420 mm, the others 45 mm nearer to 25 mm farther, tipped 4-15 degrees about its
# x or y axis; the lens focused at 420 mm; a 0.5 mm cover glass of index 1.52; 90 % pixel fill
HELD_FOCUS_MM = 420.0
HELD_GLASS = (0.5, 1.52)
HELD_FILL = (0.9, 0.9)


@dataclass(frozen=True)
class HandHeld:
    """How the display is held: `poses` poses (>= 3), distances (mm, along the camera's axis to the
    display's centre), the largest tilt and roll (degrees), the least covered share of the field;
    `first_mm`: pose 0's distance (None: drawn like the others'); `min_tilt_deg`: the least tilt
    (None: 0.3 of the largest); `tilt_about`: "round" (the tilt axes go round the circle) or "xy" (about
    the display's x or y axis in turn, as a person tips a monitor); `disturbed`: the index of a pose
    whose display moves halfway through its fringe frames (None: none), by `disturbance_mm` and
    `disturbance_deg`; given: the poses themselves, in the simulator's frame
    (the cameras of a rig see the same display; default: drawn by `handheld_poses`)."""

    poses: int = 8
    distance_mm: tuple[float, float] = (300.0, 600.0)
    max_tilt_deg: float = 35.0
    roll_deg: float = 15.0
    min_cover: float = 0.85
    disturbed: int | None = None
    disturbance_mm: float = 0.2
    disturbance_deg: float = 0.1
    given: tuple[DisplayPose, ...] | None = None
    first_mm: float | None = None
    min_tilt_deg: float | None = None
    tilt_about: str = "round"

    def __post_init__(self):
        if int(self.poses) != self.poses or self.poses < 3:
            raise InputError("--handheld", f"a stage-free capture needs at least 3 poses, got {self.poses}")
        lo, hi = self.distance_mm
        if not 0 < lo <= hi:
            raise InputError("--hold-distance-mm", f"need 0 < near <= far (mm), got {self.distance_mm}")
        if not 0 <= self.max_tilt_deg < 70 or not 0 <= self.roll_deg <= 180:
            raise InputError("--max-tilt-deg", f"tilt must be in [0, 70) and roll in [0, 180] degrees, got "
                                           f"{self.max_tilt_deg} and {self.roll_deg}")
        if not 0 < self.min_cover <= 1:
            raise InputError("handheld", f"min_cover must be in (0, 1], got {self.min_cover}")
        if self.first_mm is not None and not self.first_mm > 0:
            raise InputError("--distance", f"pose 0's distance must be positive (mm), got {self.first_mm}")
        if self.min_tilt_deg is not None and not 0 <= self.min_tilt_deg <= self.max_tilt_deg:
            raise InputError("--max-tilt", f"the least tilt must be in [0, {self.max_tilt_deg}] degrees, got "
                                           f"{self.min_tilt_deg}")
        if self.tilt_about not in ("round", "xy"):
            raise InputError("handheld", f"tilt_about must be 'round' or 'xy', got {self.tilt_about!r}")
        if self.disturbed is not None and not 0 <= self.disturbed < self.poses:
            raise InputError("--disturb", f"pose {self.disturbed} is not one of the {self.poses} poses")


def as_held(*, poses: int = 7, **lens_options) -> dict:
    """`scanners.sim.calibration.simulate_calibration`'s arguments for a display held as people hold a
    monitor (`HELD_FOCUS_MM`, `HELD_GLASS`, `HELD_FILL`; the hand-held poses above it); lens_options: the
    lens's further overrides (`scanners.sim.lenses.make_lens`)."""
    held = HandHeld(poses=poses, distance_mm=(HELD_FOCUS_MM - 45.0, HELD_FOCUS_MM + 25.0), first_mm=HELD_FOCUS_MM,
                    min_tilt_deg=4.0, max_tilt_deg=15.0, roll_deg=2.0, tilt_about="xy")
    return {"handheld": held, "cover_glass": HELD_GLASS, "display": SimDisplay(fill_factor=HELD_FILL),
            "lens_options": {"focus_mm": HELD_FOCUS_MM, **lens_options}}


def coverage(lens: Lens, display: SimDisplay, pose: DisplayPose) -> tuple[float, float]:
    """(share of the camera's field that sees the display, largest incidence angle (degrees) of a ray on
    the display there), on a grid of every COVER_STEP-th pixel."""
    u, v = np.meshgrid(np.arange(0, lens.width, COVER_STEP, dtype=float),
                       np.arange(0, lens.height, COVER_STEP, dtype=float))
    o, d = lens.rays(u, v)
    c, r = display.hit(o, d, pose)
    inside = (c >= 0.5) & (c <= display.width_px - 1.5) & (r >= 0.5) & (r <= display.height_px - 1.5)
    cos_in = d @ pose.normal
    if not inside.any():
        return 0.0, 90.0
    return float(inside.mean()), float(np.degrees(np.arccos(np.clip(cos_in[inside].min(), -1, 1))))


def handheld_poses(lenses: Lens | list[Lens], display: SimDisplay, held: HandHeld, seed: int) -> list[DisplayPose]:
    """`held.poses` display poses in the simulator's frame (module docstring), seeded; `held.given` if
    set. With several lenses (a rig), the display faces their mean axis from their mean centre and must
    cover each camera's field."""
    if held.given is not None:
        if len(held.given) != held.poses:
            raise InputError("handheld", f"{len(held.given)} poses given for {held.poses}")
        return list(held.given)
    lenses = [lenses] if isinstance(lenses, Lens) else list(lenses)
    lens = lenses[0]
    rng = np.random.default_rng([seed, 11])
    axis = np.mean([ln.rotation[:, 2] for ln in lenses], axis=0)
    axis /= np.linalg.norm(axis)
    origin = np.mean([ln.centre_mm for ln in lenses], axis=0)
    # the camera's axes, turned onto the mean axis (a display facing the rig)
    facing = _turn(lens.rotation[:, 2], axis) @ lens.rotation
    centre_px = np.array([(display.width_px - 1) / 2 * display.pitch_mm[0],
                          (display.height_px - 1) / 2 * display.pitch_mm[1], 0.0])
    phase = rng.uniform(0, 2 * np.pi)
    poses = []
    for i in range(held.poses):
        need = 1.0 if i == 0 else held.min_cover
        for _ in range(MAX_DRAWS):
            dist = held.first_mm if i == 0 and held.first_mm is not None else rng.uniform(*held.distance_mm)
            shift = rng.uniform(-0.1, 0.1, 2) * _field_mm(lens, dist)
            target = origin + dist * axis + facing[:, :2] @ shift
            if held.tilt_about == "xy":          # about x or y in turn, either way
                spin = np.pi / 2 * (i % 2) + np.pi * rng.integers(2)
            else:
                spin = phase + 2 * np.pi * i / held.poses + rng.normal(0, 0.3)
            least = 0.3 * held.max_tilt_deg if held.min_tilt_deg is None else held.min_tilt_deg
            tilt = np.radians(rng.uniform(least, held.max_tilt_deg))
            tilt_axis = facing @ np.array([np.cos(spin), np.sin(spin), 0.0])
            rot = _axis_angle(tilt_axis, tilt) @ facing @ rotation(
                "z", np.radians(rng.uniform(-held.roll_deg, held.roll_deg)))
            pose = DisplayPose(rot, target - rot @ centre_px)
            seen = [coverage(ln, display, pose) for ln in lenses]
            cover, incidence = min(c for c, _ in seen), max(a for _, a in seen)
            if cover >= need and incidence <= MAX_INCIDENCE_DEG:
                poses.append(pose)
                break
        else:
            raise InputError("--handheld", f"no pose {i} in {MAX_DRAWS} draws lets the display cover "
                                           f"{need:.0%} of the camera's field: bring the distances closer "
                                           f"or lower the tilt")
    return poses


def disturbed_pose(pose: DisplayPose, display: SimDisplay, held: HandHeld, seed: int) -> DisplayPose:
    """The pose `pose` after the display moved (`HandHeld.disturbance_mm`, `disturbance_deg`, random
    directions, seeded) about its centre."""
    rng = np.random.default_rng([seed, 12])
    move = rng.normal(size=3)
    turn = rng.normal(size=3)
    centre = np.array([display.size_mm[0] / 2, display.size_mm[1] / 2, 0.0])
    motion = about_point(_axis_angle(turn / np.linalg.norm(turn), np.radians(held.disturbance_deg)), centre,
                         held.disturbance_mm * move / np.linalg.norm(move))
    return DisplayPose(pose.R @ motion.R, pose.R @ motion.t + pose.t)


def to_pose0_frame(truth: PRVM, pose0: DisplayPose) -> PRVM:
    """The true rays `truth` (simulator frame) expressed in the display's frame at `pose0` (the WCS of a
    stage-free calibration), origins on its plane z = 0; InputError if a ray does not reach that plane
    from the front."""
    try:
        return truth.transformed(pose0.R.T, -pose0.R.T @ pose0.t)
    except ValueError:
        raise InputError("--handheld", "some pixels' rays meet the display of pose 0 from behind") from None


def relative_poses(poses: list[DisplayPose]) -> tuple[np.ndarray, np.ndarray]:
    """(M, 3, 3) rotations and (M, 3) translations of each pose in the display's frame at pose 0
    (X_pose0 = R X_display + t; the first is the identity)."""
    r0, t0 = poses[0].R, poses[0].t
    rot = np.array([r0.T @ p.R for p in poses])
    return rot, np.array([r0.T @ (p.t - t0) for p in poses])


def _field_mm(lens: Lens, distance_mm: float) -> np.ndarray:
    """(2,) width and height (mm) of the camera's field on the plane across its axis at `distance_mm`."""
    u = np.array([0.0, lens.width - 1.0, (lens.width - 1) / 2, (lens.width - 1) / 2])
    v = np.array([(lens.height - 1) / 2, (lens.height - 1) / 2, 0.0, lens.height - 1.0])
    o, d = lens.rays(u, v)
    axis = lens.rotation[:, 2]
    t = (lens.centre_mm @ axis + distance_mm - o @ axis) / (d @ axis)
    p = o + t[:, None] * d
    return np.array([np.linalg.norm(p[1] - p[0]), np.linalg.norm(p[3] - p[2])])


def _turn(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation taking unit vector a onto unit vector b."""
    c = np.cross(a, b)
    s = np.linalg.norm(c)
    if s < 1e-12:
        return np.eye(3)
    return _axis_angle(c / s, float(np.arctan2(s, a @ b)))


def _axis_angle(axis: np.ndarray, angle: float) -> np.ndarray:
    """3x3 rotation by `angle` (radians) about the unit vector `axis` (Rodrigues)."""
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k

"""The simulated camera's alignment to the display: aiming a lens at known tilts, and the true readings.

The readings follow `calib.alignment`'s conventions, computed here from the lens's TRUE rays and the
display's TRUE pose (nothing is fitted): the line of sight is the ray of the image centre
((W-1)/2, (H-1)/2), with direction a in the display's frame; tilt_x = atan2(-a_y, a_z) (positive: the
camera looks up the screen), tilt_y = atan2(a_x, a_z) (positive: it looks right); roll is the direction
on the display's pixel plane of the image's central row, from the point seen by ((W-1)/4, (H-1)/2) to
the one seen by (3(W-1)/4, (H-1)/2); distance is from the projection centre to the display plane.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from scanners.sim.display import SimDisplay
from scanners.sim.lenses import Lens
from scanners.sim.pose import DisplayPose


def _chord_pixels(lens: Lens) -> tuple[np.ndarray, np.ndarray]:
    w, h = lens.width - 1, lens.height - 1
    return np.array([w / 2, w / 4, 3 * w / 4]), np.full(3, h / 2)


def _axis_angle(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rotation matrix by `angle` (radians) about the unit vector `axis` (Rodrigues)."""
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def true_alignment(lens: Lens, display: SimDisplay, pose: DisplayPose) -> dict:
    """The true readings of `lens` against `display` at `pose`: tilt_x_deg, tilt_y_deg, roll_deg,
    distance_mm, and line_of_sight_px / foot_px (display pixels where the line of sight meets the
    display, and the foot of the perpendicular from the lens's projection centre `centre_mm`)."""
    o, d = lens.rays(*_chord_pixels(lens))
    c, r = display.hit(o, d, pose)
    a = pose.to_display(o, d)[1][0]
    centre = pose.to_display(lens.centre_mm)
    pitch = np.asarray(display.pitch_mm)
    return {"tilt_x_deg": float(np.degrees(np.arctan2(-a[1], a[2]))),
            "tilt_y_deg": float(np.degrees(np.arctan2(a[0], a[2]))),
            "roll_deg": float(np.degrees(np.arctan2((r[2] - r[1]) * pitch[1], (c[2] - c[1]) * pitch[0]))),
            "distance_mm": float(-centre[2]), "line_of_sight_px": [float(c[0]), float(r[0])],
            "foot_px": [float(x) for x in centre[:2] / pitch]}


def aim(lens: Lens, tilt_x_deg: float, tilt_y_deg: float, roll_deg: float, *, display: SimDisplay | None = None,
        pose: DisplayPose = DisplayPose()) -> Lens:
    """A copy of `lens` turned so that its true readings against `display` at `pose` (default: the
    default display at stage position 0) are the given tilts and roll (degrees), its line of sight
    meeting the display where it did before and its projection centre at the same distance."""
    display = display or SimDisplay()
    cu, cv = _chord_pixels(lens)
    od, dd = pose.to_display(*lens.rays(cu[0], cv[0]))
    target = pose.to_wcs(od - od[2] / dd[2] * dd)                     # where the line of sight meets it
    distance = true_alignment(lens, display, pose)["distance_mm"]
    oc, dc = lens._camera_rays(np.array(cu[0]), np.array(cv[0]))        # camera frame
    tx, ty = np.radians(tilt_x_deg), np.radians(tilt_y_deg)
    a = pose.R @ np.array([np.tan(ty), -np.tan(tx), 1.0])
    a /= np.linalg.norm(a)
    axis = np.cross(dc, a)
    base = _axis_angle(axis / np.linalg.norm(axis), np.arccos(np.clip(dc @ a, -1, 1))) \
        if np.linalg.norm(axis) > 1e-15 else np.eye(3)
    phi = 0.0
    for _ in range(20):
        rot = _axis_angle(a, phi) @ base
        aimed = dataclasses.replace(lens, rotation=rot, centre_mm=lens.centre_mm.copy(), params=dict(lens.params))
        # the projection centre on the line back from the target, at the same distance from the display
        aimed.centre_mm = target - rot @ oc - a * distance / (a @ pose.normal)
        err = roll_deg - true_alignment(aimed, display, pose)["roll_deg"]
        if abs(err) < 1e-9:
            break
        phi += np.radians(err)
    return aimed


__all__ = ["true_alignment", "aim"]

"""The alignment aid's readings in words for the person at the bench: which way to turn what.

Directions are as seen by someone standing behind the camera and facing the screen (the screen's
"right edge" is then on their right, the side of its increasing columns). The camera's readings follow
`calib.alignment`: tilt_x > 0 means it looks up, tilt_y > 0 that it looks right, roll > 0 that it is
turned clockwise. For the stage, the screen's normal must be brought onto the stage's direction of
travel: when the display drifts to the right as the stage moves it away (angle_x > 0), the screen's
right edge must come nearer to the camera, by its width times tan(angle_x).
"""

from __future__ import annotations

import numpy as np

from calib.alignment import Reading, StageAxis


def camera_advice(reading: Reading, tolerance_deg: float) -> list[str]:
    """What to turn on the camera, one line per axis outside `tolerance_deg` (degrees); [] when square
    and level."""
    out = []
    tx, ty, roll = reading.tilt_x_deg, reading.tilt_y_deg, reading.roll_deg
    if abs(tx) > tolerance_deg:
        out.append(f"tilt the camera {'down' if tx > 0 else 'up'} {abs(tx):.2f} deg")
    if abs(ty) > tolerance_deg:
        out.append(f"turn the camera {'left' if ty > 0 else 'right'} {abs(ty):.2f} deg")
    if abs(roll) > tolerance_deg:
        out.append(f"roll the camera {'anticlockwise' if roll > 0 else 'clockwise'} {abs(roll):.2f} deg "
                   "(seen from behind)")
    return out


def stage_direction(axis: StageAxis) -> str:
    """Where the stage's travel points off the screen's normal, in words."""
    x, y = axis.angle_x_deg, axis.angle_y_deg
    return (f"{abs(x):.3f} deg {'right' if x >= 0 else 'left'} and {abs(y):.3f} deg {'down' if y >= 0 else 'up'} "
            "of the screen normal")


def stage_advice(axis: StageAxis, display_mm: tuple[float, float], tolerance_deg: float) -> list[str]:
    """How to tilt the screen (display_mm: its width and height in mm) so that its normal follows the
    stage's travel, one line per axis outside `tolerance_deg`; [] when aligned."""
    out = []
    for angle, size, edge, other, across in ((axis.angle_x_deg, display_mm[0], "right", "left", "width"),
                                             (axis.angle_y_deg, display_mm[1], "bottom", "top", "height")):
        if abs(angle) <= tolerance_deg:
            continue
        near, far = (edge, other) if angle > 0 else (other, edge)
        shift = size * np.tan(np.radians(abs(angle)))
        out.append(f"tilt the screen {abs(angle):.2f} deg: its {near} edge {shift:.2f} mm nearer the camera than "
                   f"its {far} edge ({100 * np.tan(np.radians(abs(angle))):.3f} mm per 100 mm of {across}: "
                   f"turn the screws at its {near} edge that way)")
    return out


__all__ = ["camera_advice", "stage_direction", "stage_advice"]

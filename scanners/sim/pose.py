"""Where the simulated display stands: a rigid pose of its pixel plane in the WCS.

The display's own frame (mm): x along its columns, y along its rows, z along its normal away from the
camera; display pixel (c, r) has its centre at (c * pitch_x, r * pitch_y, 0) (DESIGN.md's WCS at stage
position 0 is this frame), and a cover glass lies in -thickness <= z <= 0. A `DisplayPose` maps that
frame into the WCS: X_wcs = rotation @ X_display + translation. A stage position z_mm along the stage
axis (ax, ay, az) is the pure translation z_mm * (ax/az, ay/az, 1) (`DisplayPose.staged`); a stage with
tilt and lateral errors, or a display held by hand, has a general pose.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

IDENTITY = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))


@dataclass(frozen=True)
class DisplayPose:
    """A rigid transform display frame -> WCS (hashable: rotation and translation are tuples).

    rotation: 3x3 rotation matrix (rows); translation: (3,) mm, the WCS position of display pixel (0, 0).
    """

    rotation: tuple = IDENTITY
    translation: tuple = (0.0, 0.0, 0.0)

    def __post_init__(self):
        r = np.asarray(self.rotation, float).reshape(3, 3)
        if not np.allclose(r @ r.T, np.eye(3), atol=1e-9) or np.linalg.det(r) <= 0:
            raise ValueError(f"display rotation must be a proper rotation matrix, got {r.tolist()}")
        object.__setattr__(self, "rotation", tuple(tuple(float(x) for x in row) for row in r))
        object.__setattr__(self, "translation", tuple(float(x) for x in np.asarray(self.translation, float)))

    @classmethod
    def staged(cls, z_mm: float, *, axis=(0.0, 0.0, 1.0)) -> DisplayPose:
        """The display moved by an ideal stage.

        Parameters
        ----------
        z_mm : float
            The stage position: the display's z coordinate, WCS mm.
        axis : (3,) float
            The stage's direction of travel, WCS (any length, z component not 0).

        Returns
        -------
        pose : DisplayPose
            No rotation; the display's origin at z_mm along `axis`.
        """
        ax, ay, az = (float(a) for a in axis)
        return cls(IDENTITY, (z_mm * ax / az, z_mm * ay / az, float(z_mm)))

    @property
    def R(self) -> np.ndarray:
        return np.array(self.rotation)

    @property
    def t(self) -> np.ndarray:
        return np.array(self.translation)

    @property
    def normal(self) -> np.ndarray:
        """(3,) the display's normal in the WCS (its z axis, away from the camera)."""
        return self.R[:, 2]

    def to_wcs(self, points: np.ndarray) -> np.ndarray:
        """WCS points (..., 3) of display-frame points (..., 3), mm."""
        return np.asarray(points, float) @ self.R.T + self.t

    def to_display(self, points: np.ndarray, directions: np.ndarray | None = None):
        """Display-frame points (..., 3) of WCS points; with `directions`, also those rotated (a pair)."""
        p = (np.asarray(points, float) - self.t) @ self.R
        return p if directions is None else (p, np.asarray(directions, float) @ self.R)

    def is_staged(self) -> bool:
        """Whether the pose is a pure translation (an ideal stage)."""
        return self.rotation == IDENTITY


def about_point(rotation: np.ndarray, pivot_display_mm, translation) -> DisplayPose:
    """The pose that rotates the display by `rotation` about its own point `pivot_display_mm` ((3,) in the
    display frame) and then puts that point at WCS `translation` + pivot (so a small tilt about the
    display's centre leaves the centre where the translation alone would put it)."""
    pivot = np.asarray(pivot_display_mm, float)
    return DisplayPose(rotation, np.asarray(translation, float) + pivot - rotation @ pivot)

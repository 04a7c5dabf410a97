"""The simulated linear stage: nominal positions and the true display poses, with small positioning errors
along the axis, tilt (pitch and yaw of the carriage) and lateral run-out."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from scanners.sim.optics import rotation
from scanners.sim.pose import DisplayPose, about_point


@dataclass
class SimStage:
    """A stage moving the display along `axis` (unit vector in the WCS, DESIGN.md `stage.axis`).

    nominal_mm: the positions commanded (and stated in the manifest), as z coordinates (mm). At each
    position the true display differs from the nominal one by independent Gaussian errors (seeded): the
    travel along the axis by `error_um` micrometres RMS (a ground-screw stage with an encoder), a tilt
    about the display's x and y axes by `tilt_deg` degrees RMS each (the carriage's pitch and yaw, about
    the display point `pivot_mm`, (x, y) in the display frame, by default its pixel (0, 0)), and a shift
    across the axis (x and y) by `lateral_um` micrometres RMS each (straightness). `true_mm` holds the
    true travel (as z coordinates) and `poses` the true `DisplayPose`s, in the order of `nominal_mm`.
    """

    nominal_mm: tuple[float, ...]
    error_um: float = 3.0
    axis: tuple[float, float, float] = (0.0, 0.0, 1.0)
    seed: int = 0
    tilt_deg: float = 0.0
    lateral_um: float = 0.0
    pivot_mm: tuple[float, float] = (0.0, 0.0)
    true_mm: tuple[float, ...] = field(init=False)
    tilts_deg: np.ndarray = field(init=False)        # (M, 2) true tilt about the display's x, y axes
    lateral_mm: np.ndarray = field(init=False)       # (M, 2) true lateral shift along WCS x, y
    poses: tuple[DisplayPose, ...] = field(init=False)

    def __post_init__(self):
        a = np.asarray(self.axis, float)
        if a.shape != (3,) or a[2] <= 0:
            raise ValueError(f"stage axis must be a 3-vector with positive z, got {self.axis}")
        if self.error_um < 0 or self.tilt_deg < 0 or self.lateral_um < 0:
            raise ValueError("stage errors must be >= 0")
        self.axis = tuple(float(x) for x in a / np.linalg.norm(a))
        m = len(self.nominal_mm)
        errors = np.random.default_rng([self.seed, 7]).normal(0.0, self.error_um * 1e-3, m)
        self.true_mm = tuple(float(n + e) for n, e in zip(self.nominal_mm, errors))
        self.tilts_deg = np.random.default_rng([self.seed, 8]).normal(0.0, self.tilt_deg, (m, 2))
        self.lateral_mm = np.random.default_rng([self.seed, 9]).normal(0.0, self.lateral_um * 1e-3, (m, 2))
        poses = []
        for z, (tx, ty), (lx, ly) in zip(self.true_mm, np.radians(self.tilts_deg), self.lateral_mm):
            staged = DisplayPose.staged(z, axis=self.axis)
            if tx == 0 and ty == 0 and lx == 0 and ly == 0:
                poses.append(staged)
                continue
            pivot = (*self.pivot_mm, 0.0)
            poses.append(about_point(rotation("y", ty) @ rotation("x", tx), pivot,
                                     staged.t + np.array([lx, ly, 0.0])))
        self.poses = tuple(poses)

    def true_pose(self, nominal_mm: float) -> DisplayPose:
        """The true display pose when the stage is commanded to `nominal_mm`."""
        return self.poses[list(self.nominal_mm).index(nominal_mm)]

"""The simulated linear stage: nominal positions and the true ones, with small positioning errors."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class SimStage:
    """A stage moving the display along `axis` (unit vector in the WCS, DESIGN.md `stage.axis`).

    nominal_mm: the positions commanded (and stated in the manifest), as z coordinates (mm); the true
    positions differ by independent Gaussian errors of `error_um` micrometres (seeded), as from a
    ground-screw stage with an encoder. `true_mm` holds them, in the order of `nominal_mm`.
    """

    nominal_mm: tuple[float, ...]
    error_um: float = 3.0
    axis: tuple[float, float, float] = (0.0, 0.0, 1.0)
    seed: int = 0
    true_mm: tuple[float, ...] = field(init=False)

    def __post_init__(self):
        a = np.asarray(self.axis, float)
        if a.shape != (3,) or a[2] <= 0:
            raise ValueError(f"stage axis must be a 3-vector with positive z, got {self.axis}")
        self.axis = tuple(float(x) for x in a / np.linalg.norm(a))
        errors = np.random.default_rng([self.seed, 7]).normal(0.0, self.error_um * 1e-3, len(self.nominal_mm))
        self.true_mm = tuple(float(n + e) for n, e in zip(self.nominal_mm, errors))

    def true_position(self, nominal_mm: float) -> float:
        """The true z (mm) of the display when the stage is commanded to `nominal_mm`."""
        return self.true_mm[list(self.nominal_mm).index(nominal_mm)]

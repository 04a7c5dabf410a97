"""The simulated image sensor: electrons to digital numbers, with shot noise, read noise, full well,
dark offset, quantisation and saturation."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Sensor:
    """bit_depth: 8, 10, 12 or 16 (a 12-bit image is stored in uint16 with values 0..4095); the ADC's
    full scale equals `full_well_e` electrons; read_noise_e: Gaussian read noise (electrons RMS);
    dark_offset: the black level added by the ADC, as a fraction of full scale; prnu: RMS per-pixel
    gain non-uniformity (fraction)."""

    bit_depth: int = 8
    full_well_e: float = 10_000.0
    read_noise_e: float = 5.0
    dark_offset: float = 0.01
    prnu: float = 0.01

    def __post_init__(self):
        if self.bit_depth not in (8, 10, 12, 14, 16):
            raise ValueError(f"bit depth must be 8, 10, 12, 14 or 16, got {self.bit_depth}")

    @property
    def max_dn(self) -> int:
        return 2 ** self.bit_depth - 1

    @property
    def dtype(self):
        return np.uint8 if self.bit_depth == 8 else np.uint16

    def digitise(self, electrons: np.ndarray, rng: np.random.Generator | None) -> np.ndarray:
        """Digital image of expected photo-electrons per pixel (float array); noise-free if rng is None
        (the expected signal, rounded), else with Poisson shot noise and Gaussian read noise."""
        e = np.clip(electrons, 0.0, None)
        if rng is not None:
            e = rng.poisson(e).astype(np.float64)
        e = np.minimum(e, self.full_well_e)
        if rng is not None:
            e = e + rng.normal(0.0, self.read_noise_e, e.shape)
        dn = e * (self.max_dn / self.full_well_e) + self.dark_offset * self.max_dn
        return np.clip(np.rint(dn), 0, self.max_dn).astype(self.dtype)

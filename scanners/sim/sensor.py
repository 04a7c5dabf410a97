"""The simulated image sensor: electrons to digital numbers, with shot noise, read noise, full well,
dark offset, quantisation and saturation; optionally hot pixels."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Sensor:
    """bit_depth: 8, 10, 12 or 16 (a 12-bit image is stored in uint16 with values 0..4095); the ADC's
    full scale equals `full_well_e` electrons; read_noise_e: Gaussian read noise (electrons RMS);
    dark_offset: the black level added by the ADC, as a fraction of full scale; prnu: RMS per-pixel
    gain non-uniformity (fraction); hot_pixels: the fraction of pixels with a dark signal of their own
    (`hot_signal_e`)."""

    bit_depth: int = 8
    full_well_e: float = 10_000.0
    read_noise_e: float = 5.0
    dark_offset: float = 0.01
    prnu: float = 0.01
    hot_pixels: float = 0.0

    def __post_init__(self):
        if self.bit_depth not in (8, 10, 12, 14, 16):
            raise ValueError(f"bit depth must be 8, 10, 12, 14 or 16, got {self.bit_depth}")
        if not 0 <= self.hot_pixels < 1:
            raise ValueError(f"hot_pixels must be a fraction in [0, 1), got {self.hot_pixels}")

    def hot_signal_e(self, shape: tuple[int, int], rng: np.random.Generator) -> np.ndarray | None:
        """(H, W) float32 dark electrons per frame of the hot pixels (0 elsewhere), drawn from `rng`: a
        `hot_pixels` fraction of the pixels, each with a dark signal uniform between 5 % and 150 % of
        the full well (a third of them stuck at full scale); None without hot pixels."""
        if not self.hot_pixels:
            return None
        hot = rng.random(shape) < self.hot_pixels
        out = np.zeros(shape, np.float32)
        out[hot] = rng.uniform(0.05, 1.5, int(hot.sum())) * self.full_well_e
        return out

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

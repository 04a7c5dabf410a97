"""A simulated colour camera with a raw Bayer mosaic: each photosite under a red, green or blue filter.

What differs from the monochrome camera:
- each colour's photosites see the display's white with their own sensitivity (`BayerSensor.gain`,
  relative to green) and their own response curve: the liquid crystal's transmission against its
  drive depends on the wavelength, so the display's white follows a different gamma through each
  filter (`BayerSensor.gamma`);
- the lens bends each colour its own way (lateral chromatic aberration, `LateralColour`): a photosite's
  ray is the lens's ray of a point radially displaced on the sensor by `magnification - 1` of its
  distance from the sensor centre, so the red, green and blue photosites' true rays differ. Each
  colour's image is rendered whole, with that colour's rays at every sub-sample, blurred, and then
  read at that colour's photosites (the blur spreads the red image over its neighbours too, never the
  green one into a red photosite).

The display itself is a monochrome panel (each sub-pixel stripe emits the white; on a colour panel each
colour would see only its own sub-pixels, a third of a pixel apart, docs/calibration.md).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from calib.capture import BAYER_PATTERNS
from calib.errors import InputError
from scanners.sim.camera import SimCamera
from scanners.sim.defocus import blur_and_integrate
from scanners.sim.display import SimDisplay
from scanners.sim.pose import DisplayPose

COLOURS = "RGB"


@dataclass(frozen=True)
class LateralColour:
    """Lateral chromatic aberration: each colour's rays are the lens's rays at sensor points scaled
    about `centre` (u, v pixels) by that colour's `magnification` (R, G, B); `pattern`: the mosaic."""

    pattern: str
    magnification: tuple[float, float, float]
    centre: tuple[float, float]
    only: int | None = None            # every point with this colour's rays (index into "RGB")

    def sensor_point(self, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Where the lens is asked for the rays of sensor points (u, v): each point scaled by the
        magnification of the colour of the photosite it lies in (or of colour `only`)."""
        if self.only is not None:
            m = self.magnification[self.only]
        else:
            m = np.asarray(self.magnification, float)[colour_index(self.pattern, np.floor(v + 0.5).astype(int),
                                                                   np.floor(u + 0.5).astype(int))]
        cu, cv = self.centre
        return cu + (u - cu) * m, cv + (v - cv) * m


def colour_index(pattern: str, row: np.ndarray, col: np.ndarray) -> np.ndarray:
    """Index into "RGB" of the filter over photosites (row, col) of a Bayer `pattern`."""
    table = np.array([COLOURS.index(c) for c in pattern]).reshape(2, 2)
    return table[np.mod(row, 2), np.mod(col, 2)]


@dataclass(frozen=True)
class BayerSensor:
    """A raw Bayer mosaic: `pattern` (one of calib.capture.BAYER_PATTERNS); per colour (R, G, B): `gain`
    (sensitivity to the display's white, relative), `gamma` (the display's white's response curve
    through that filter), `lateral_colour` (magnification - 1 of that colour's image, lateral chromatic
    aberration)."""

    pattern: str = "RGGB"
    gain: tuple[float, float, float] = (0.55, 1.0, 0.7)
    gamma: tuple[float, float, float] = (2.1, 2.2, 2.35)
    lateral_colour: tuple[float, float, float] = (6e-4, 0.0, -8e-4)

    def __post_init__(self):
        if self.pattern not in BAYER_PATTERNS:
            raise InputError("--bayer", f"must be one of {', '.join(BAYER_PATTERNS)}, got {self.pattern!r}")
        if min(self.gain) <= 0 or min(self.gamma) <= 0:
            raise InputError("bayer", "gains and gammas must be positive")

    def colour(self, width: int, height: int) -> LateralColour:
        return LateralColour(self.pattern, tuple(1.0 + c for c in self.lateral_colour),
                             ((width - 1) / 2, (height - 1) / 2))


class BayerCamera(SimCamera):
    """A SimCamera whose sensor is a Bayer mosaic (`BayerSensor`); its lens should carry the sensor's
    `LateralColour` (`Lens.colour`)."""

    def __init__(self, lens, *, bayer: BayerSensor, **kwargs):
        super().__init__(lens, **kwargs)
        self.bayer = bayer
        h, w = self.shape
        v, u = np.mgrid[0:h, 0:w]
        self.colour = colour_index(bayer.pattern, v, u)
        # one camera per colour, for its views (every sub-sample traced with that colour's rays)
        self._colours = [SimCamera(dataclasses.replace(lens, colour=dataclasses.replace(lens.colour, only=i)),
                                   **kwargs) for i in range(3)]

    def irradiance(self, display_image: np.ndarray, display: SimDisplay, pose: DisplayPose) -> np.ndarray:
        """Each photosite's irradiance through its own filter: its colour's image of the display's white
        (that colour's rays and response curve), blurred and integrated, times its sensitivity."""
        out = np.empty(self.shape, np.float32)
        for i in range(3):
            v = self._colours[i].view(display, pose)
            seen = dataclasses.replace(display, gamma=self.bayer.gamma[i])
            radiance = seen.luminance_at(display_image, v.c, v.r, v.window, v.sin2)
            full = v.crop(blur_and_integrate(radiance, self.supersample, v.blur_px, self.sigma_px))
            mask = self.colour == i
            out[mask] = full[mask] * np.float32(self.bayer.gain[i])
        return out

"""A real bench's flaws, for a simulated calibration: each can be turned on alone, and `REAL_BENCH` turns
them all on at the sizes a careful user's bench has (docs/simulator.md, "A real bench's flaws").

`Flaws` gathers them as `simulate_calibration` takes them: the display's (`SimDisplay`: bow, pitch
error, viewing-angle falloff and gamma), the sensor's (bit depth, hot pixels, ambient light,
over-exposure), the stage's (tilt, lateral run-out) and the view's (a display that does not fill it).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from scanners.sim.display import SimDisplay


@dataclass(frozen=True)
class Flaws:
    """bow_mm, pitch_error, falloff, gamma_tilt: `SimDisplay`'s; bit_depth: the sensor's (None: the
    dataset's default); hot_pixels, ambient, ambient_variation, overexposure, unseen, stage_tilt_deg,
    stage_lateral_um: `simulate_calibration`'s (0: off)."""

    bow_mm: float = 0.0
    pitch_error: float = 0.0
    falloff: float = 0.0
    gamma_tilt: float = 0.0
    bit_depth: int | None = None
    hot_pixels: float = 0.0
    ambient: float = 0.0
    ambient_variation: float = 0.0
    overexposure: float = 0.0
    unseen: float = 0.0
    stage_tilt_deg: float = 0.0
    stage_lateral_um: float = 0.0

    def kwargs(self, display: SimDisplay | None = None) -> dict:
        """`simulate_calibration` keyword arguments with these flaws (on `display`, default SimDisplay())."""
        shown = dataclasses.replace(display or SimDisplay(), bow_mm=self.bow_mm, pitch_error=self.pitch_error,
                                    falloff=self.falloff, gamma_tilt=self.gamma_tilt)
        out = dict(display=shown, hot_pixels=self.hot_pixels, ambient=self.ambient,
                   ambient_variation=self.ambient_variation, overexposure=self.overexposure, unseen=self.unseen,
                   stage_tilt_deg=self.stage_tilt_deg, stage_lateral_um=self.stage_lateral_um)
        if self.bit_depth is not None:
            out["bit_depth"] = self.bit_depth
        return out

    def active(self) -> dict:
        """The flaws that are on, as {name: value}."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)
                if getattr(self, f.name) not in (0, 0.0, None)}


# A careful user's bench: a monitor 0.1 mm from flat with a pitch 1e-4 off its data sheet, an IPS panel
# seen up to ~20 degrees off its normal (luminance -18 %, gamma -5 % at 30 degrees), room light
# reflected by the screen (2 % of white, +-30 % across the view), a stage pitching and yawing by
# 0.005 degrees (90 urad) with 3 um of run-out per position, a 12-bit camera with 1e-4 hot pixels and
# 1 % of its pixels over-exposed, the display missing 10 % of the image rows at the far position
REAL_BENCH = Flaws(bow_mm=0.1, pitch_error=1e-4, falloff=0.7, gamma_tilt=-0.2, bit_depth=12, hot_pixels=1e-4,
                   ambient=0.02, ambient_variation=0.3, overexposure=0.01, unseen=0.1, stage_tilt_deg=0.005,
                   stage_lateral_um=3.0)


def each_flaw(flaws: Flaws = REAL_BENCH) -> list[tuple[str, Flaws]]:
    """One Flaws per flaw that `flaws` has on, with that flaw alone (the ambient light's variation and the
    stage's two errors going with their flaw), named for it."""
    groups = {"display bow": ("bow_mm",), "pitch error": ("pitch_error",),
              "viewing angle": ("falloff", "gamma_tilt"), "bit depth": ("bit_depth",),
              "hot pixels": ("hot_pixels",), "ambient light": ("ambient", "ambient_variation"),
              "over-exposure": ("overexposure",), "display not filling the view": ("unseen",),
              "stage tilt and run-out": ("stage_tilt_deg", "stage_lateral_um")}
    on = flaws.active()
    return [(name, Flaws(**{k: getattr(flaws, k) for k in keys})) for name, keys in groups.items()
            if any(k in on for k in keys)]

"""The simulated camera: renders what a lens + sensor record of the simulated display.

Rendering a frame (`SimCamera.render`):
 1. each pixel is sampled at S x S sub-pixel points (area integration); the TRUE ray of every sub-sample
    (`Lens.rays`) is traced through the display's cover glass to its pixel plane -> display coordinates
    (computed once per display and display pose and cached: rays do not change between patterns);
 2. the display's luminance is averaged over each sub-sample's footprint on the pixel grid (8-bit value
    -> gamma -> black level -> lit sub-pixel stripes and black gaps; the bezel outside the pixel area;
    an angle-dependent display's falloff and gamma at each sub-sample's viewing angle);
 3. the image-plane radiance is blurred by the thin-lens defocus circle and diffraction, and integrated
    over each pixel (`defocus`), so the display's edge mixes display and bezel; the radiance is rendered
    `View.margin` pixels beyond the sensor's edges (as far as the blur reaches), so that a border
    pixel's blur mixes in what the lens images there, as on a real sensor (not a mirror image);
 4. plus the room light (`ambient`: a veiling offset, constant or slowly varying across the image),
    times relative illumination (vignetting), per-pixel gain (PRNU) and exposure -> electrons, plus the
    hot pixels' dark signal -> shot noise, full well, read noise, dark offset, quantisation,
    saturation (`sensor`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.errors import InputError
from scanners.sim.defocus import blur_and_integrate
from scanners.sim.display import SimDisplay
from scanners.sim.lenses import Lens
from scanners.sim.pose import DisplayPose
from scanners.sim.sensor import Sensor

ROWS_PER_CHUNK = 64


@dataclass(frozen=True)
class View:
    """Where a camera's sub-samples land on the display's pixel plane at one display pose.

    c, r: ((H+2m)*S, (W+2m)*S) float32 display coordinates of the sub-samples (row-major sub-pixel grid)
    of the sensor and a margin of m = `margin` pixels around it (the blur's reach); window: (wc, wr) a
    sub-sample's footprint in display pixels; blur_px: (H+2m, W+2m) defocus blur-circle diameters
    (pixels); display_cr: (H, W, 2) float64 mean display coordinates (c, r) of each pixel's
    sub-samples; points_mm: (H, W, 3) the WCS points on the pixel surface at those coordinates;
    sin2: (H*S, W*S) float32 sin^2 of each sub-sample's viewing angle (None unless the display is
    angle-dependent); seen: (H, W) bool, the pixels whose sub-samples' mean lies on the pixel area.
    """

    c: np.ndarray
    r: np.ndarray
    window: tuple[float, float]
    blur_px: np.ndarray
    display_cr: np.ndarray
    points_mm: np.ndarray
    sin2: np.ndarray | None
    seen: np.ndarray
    margin: int = 0

    def crop(self, image: np.ndarray) -> np.ndarray:
        """The sensor's part (H, W) of an image (H+2m, W+2m) of the view's grid."""
        m = self.margin
        return image[m:image.shape[0] - m, m:image.shape[1] - m] if m else image


class SimCamera:
    """A simulated camera: a lens (its true rays) and a sensor, supersampling S x S per pixel.

    Parameters
    ----------
    lens : Lens
        The true rays (`scanners.sim.lenses.make_lens`), WCS mm; the image size.
    sensor : Sensor, optional
        Bit depth, full well, noise, PRNU, hot pixels; None: `Sensor()`.
    supersample : int
        S, sub-samples per pixel side (1..16; InputError otherwise).
    exposure_e : float
        Expected photo-electrons of a pixel with unit gain and unit relative illumination looking at unit
        mean display luminance (`set_exposure` chooses it).
    seed : int
        Draws the PRNU gain map, the hot pixels, the ambient light's gradient and the noise.
    diffraction : bool
        Include the Airy blur of `wavelength_mm`.
    wavelength_mm : float
        The light's wavelength, mm.
    ambient : float
        Room light reaching the sensor through the lens (a veiling offset, in the display's relative
        luminance: 0.02 = 2 % of a white display).
    ambient_variation : float
        Its linear variation across the image, +- this fraction, along a seeded direction.
    """

    def __init__(self, lens: Lens, *, sensor: Sensor | None = None, supersample: int = 3,
                 exposure_e: float = 10_000.0, seed: int = 0, diffraction: bool = True,
                 wavelength_mm: float = 550e-6, ambient: float = 0.0, ambient_variation: float = 0.0):
        if int(supersample) != supersample or not 1 <= supersample <= 16:
            raise InputError("--supersample", f"must be a whole number 1..16, got {supersample}")
        if not (ambient >= 0 and 0 <= ambient_variation <= 1):
            raise InputError("--ambient", f"needs ambient >= 0 and a variation in 0..1, got {ambient}, "
                                          f"{ambient_variation}")
        self.lens = lens
        self.sensor = sensor or Sensor()
        self.supersample = int(supersample)
        self.exposure_e = float(exposure_e)
        self.sigma_px = lens.diffraction_sigma_px(wavelength_mm) if diffraction else 0.0
        self.gain = (1.0 + self.sensor.prnu * np.random.default_rng([seed, 1]).standard_normal(
            (lens.height, lens.width))).astype(np.float32)
        self.rng = np.random.default_rng([seed, 2])
        self.vignetting = lens.relative_illumination(*lens.pixel_grid()).astype(np.float32)
        self.hot_e = self.sensor.hot_signal_e(self.shape, np.random.default_rng([seed, 3]))
        self.ambient = None
        if ambient > 0:
            angle = np.random.default_rng([seed, 4]).uniform(0, 2 * np.pi)
            u, v = lens.pixel_grid()
            ramp = ((u / max(lens.width - 1, 1) - 0.5) * np.cos(angle) + (v / max(lens.height - 1, 1) - 0.5)
                    * np.sin(angle)) * 2 / (abs(np.cos(angle)) + abs(np.sin(angle)))       # -1 .. 1
            self.ambient = (ambient * (1 + ambient_variation * ramp)).astype(np.float32)
        self._views: dict[tuple, View] = {}

    @property
    def shape(self) -> tuple[int, int]:
        return self.lens.height, self.lens.width

    def view(self, display: SimDisplay, pose: DisplayPose) -> View:
        """The (cached) View of `display` at its TRUE `pose`; InputError if the camera does not see the
        display there at all or the supersampling is too coarse for its pixel grid. A display that
        covers only part of the field is rendered as a real bench shows it: the bezel beyond it."""
        key = (display, pose)
        if key not in self._views:
            if len(self._views) >= 2:               # keep memory bounded: ~100 MB per 1.3 MP view
                self._views.pop(next(iter(self._views)))
            self._views[key] = self._compute_view(display, pose)
        return self._views[key]

    def _margin(self, display: SimDisplay, pose: DisplayPose) -> int:
        """Pixels beyond the sensor's edges that the blur reaches at `pose`: the blur circle's radius at
        the border pixels plus 3 sigma of the diffraction, and one pixel more (the blur varies
        little over that distance)."""
        h, w = self.shape
        u = np.concatenate([np.arange(w), np.arange(w), np.zeros(h), np.full(h, w - 1.0)]).astype(np.float64)
        v = np.concatenate([np.zeros(w), np.full(w, h - 1.0), np.arange(h), np.arange(h)]).astype(np.float64)
        o, d = self.lens.rays(u, v)
        c, r = display.hit(o, d, pose)
        px, py = display.true_pitch_mm
        pts = pose.to_wcs(np.stack([c * px, r * py, np.zeros_like(c)], axis=-1))
        blur = float(np.nanmax(self.lens.blur_diameter_px(u, v, pts), initial=0.0))
        return int(np.ceil(blur / 2 + 3 * self.sigma_px)) + 1

    def _compute_view(self, display: SimDisplay, pose: DisplayPose) -> View:
        s, (h, w) = self.supersample, self.shape
        m = self._margin(display, pose)
        hm, wm = h + 2 * m, w + 2 * m
        sub = (np.arange(s) + 0.5) / s - 0.5
        us = (np.arange(-m, w + m)[:, None] + sub[None, :]).ravel()
        c = np.empty((hm * s, wm * s), np.float32)
        r = np.empty((hm * s, wm * s), np.float32)
        sin2 = np.empty((hm * s, wm * s), np.float32) if display.angular else None
        for v0 in range(0, hm, ROWS_PER_CHUNK):
            vs = (np.arange(v0 - m, min(hm, v0 + ROWS_PER_CHUNK) - m)[:, None] + sub[None, :]).ravel()
            o, d = self.lens.rays(*np.meshgrid(us, vs))
            cc, rr = display.hit(o, d, pose)
            c[v0 * s:v0 * s + len(vs)] = cc
            r[v0 * s:v0 * s + len(vs)] = rr
            if sin2 is not None:
                sin2[v0 * s:v0 * s + len(vs)] = display.sin2_view(d, pose)
        cm = c.reshape(hm, s, wm, s).mean(axis=(1, 3), dtype=np.float64)
        rm = r.reshape(hm, s, wm, s).mean(axis=(1, 3), dtype=np.float64)
        seen = (cm >= -0.5) & (cm <= display.width_px - 0.5) & (rm >= -0.5) & (rm <= display.height_px - 0.5)
        sensor = (slice(m, m + h), slice(m, m + w))
        if not seen[sensor].any():
            raise InputError("simulated rig", f"the camera does not see the display "
                             f"({display.width_px}x{display.height_px} px) at {_where(pose)}: its field spans "
                             f"columns {c.min():.0f}..{c.max():.0f} and rows {r.min():.0f}..{r.max():.0f}; "
                             f"move the camera or the stage positions")
        window = (float(np.median(np.abs(np.diff(c, axis=1)))), float(np.median(np.abs(np.diff(r, axis=0)))))
        if max(window) > 1.0:
            need = int(np.ceil(s * max(window)))
            raise InputError("--supersample", f"a sub-sample covers {max(window):.2f} display pixels at "
                                              f"{_where(pose)}; use supersample >= {need}")
        px, py = display.true_pitch_mm
        x, y = cm * px, rm * py
        z = display.bow(x, y)[0] if display.bow_mm else np.zeros_like(cm)
        pts = pose.to_wcs(np.stack([x, y, z], axis=-1))
        u, v = np.meshgrid(np.arange(-m, w + m, dtype=np.float64), np.arange(-m, h + m, dtype=np.float64))
        blur = self.lens.blur_diameter_px(u, v, pts).astype(np.float32)
        return View(c, r, window, blur, np.stack([cm, rm], axis=-1)[sensor], pts[sensor], sin2, seen[sensor], m)

    def irradiance(self, display_image: np.ndarray, display: SimDisplay, pose: DisplayPose) -> np.ndarray:
        """(H, W) float32 blurred, pixel-integrated display luminance seen by each pixel (relative
        units: 1 = a fully lit display area at value 255), before vignetting and gain."""
        v = self.view(display, pose)
        radiance = display.luminance_at(display_image, v.c, v.r, v.window, v.sin2)
        return v.crop(blur_and_integrate(radiance, self.supersample, v.blur_px, self.sigma_px))

    def electrons(self, display_image: np.ndarray, display: SimDisplay, pose: DisplayPose) -> np.ndarray:
        """(H, W) expected photo-electrons (and hot pixels' dark electrons) of each pixel: the display's
        irradiance plus the ambient light, times vignetting, gain and exposure."""
        irr = self.irradiance(display_image, display, pose)
        if self.ambient is not None:
            irr = irr + self.ambient
        e = irr * (self.vignetting * self.gain * np.float32(self.exposure_e))
        return e if self.hot_e is None else e + self.hot_e

    def render(self, display_image: np.ndarray, display: SimDisplay, pose: DisplayPose, *, noise: bool = True,
               rng: np.random.Generator | None = None) -> np.ndarray:
        """The camera's image of a display showing an image.

        Parameters
        ----------
        display_image : (height_px, width_px) uint8
            What the display shows.
        display : SimDisplay
            The display.
        pose : DisplayPose
            Its TRUE pose, WCS mm.
        noise : bool
            Shot and read noise; False: the expected image, rounded.
        rng : numpy.random.Generator, optional
            The noise generator for this frame; None: the camera's own stream.

        Returns
        -------
        image : (H, W) uint8, or uint16 above 8 bits
            The camera image.
        """
        e = self.electrons(display_image, display, pose)
        return self.sensor.digitise(e, (self.rng if rng is None else rng) if noise else None)

    def set_exposure(self, display: SimDisplay, level: int, pose: DisplayPose, *, fraction: float = 0.87,
                     clipped: float = 0.0) -> float:
        """Choose the exposure for a flat display.

        Parameters
        ----------
        display : SimDisplay
            The display.
        level : int
            The flat's code value.
        pose : DisplayPose
            The display's TRUE pose, WCS mm.
        fraction : float
            The brightest pixel seeing the flat reaches this fraction of full scale (dark offset
            included).
        clipped : float
            > 0: over-expose instead: this fraction of the pixels seeing the display exceeds full scale
            there (hot pixels aside).

        Returns
        -------
        exposure_e : float
            The chosen exposure (also set on the camera), photo-electrons (class docstring).
        """
        flat = np.full((display.height_px, display.width_px), level, np.uint8)
        irr = self.irradiance(flat, display, pose)
        if self.ambient is not None:
            irr = irr + self.ambient
        signal = irr * self.vignetting * self.gain
        if clipped > 0:
            seen = signal[self.view(display, pose).seen]
            target = (1 - self.sensor.dark_offset) * self.sensor.full_well_e
            self.exposure_e = float(target / np.quantile(seen, 1 - clipped))
        else:
            target = (fraction - self.sensor.dark_offset) * self.sensor.full_well_e
            self.exposure_e = float(target / signal.max())
        return self.exposure_e


def _where(pose: DisplayPose) -> str:
    """The pose in words, for messages: a stage position, or a general pose."""
    if pose.is_staged():
        return f"stage position z = {pose.translation[2]:g} mm"
    return f"display pose at ({', '.join(f'{x:.1f}' for x in pose.translation)}) mm"

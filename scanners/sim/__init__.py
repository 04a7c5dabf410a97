"""The simulated calibration rig: an LCD display on a linear stage in front of a camera.

It stands in for the hardware in tests, benchmarks and the demo. Every image is rendered from the
camera's TRUE rays (`lenses`), through the display's cover glass onto its pixel grid (`display`, `optics`),
with the sensor's integration, blur and noise (`camera`, `sensor`, `defocus`); the datasets it writes
(`calibration`) carry their ground truth. It shares no code with the calibration it checks.

Modules: `optics` (Snell refraction, planes), `lenses` (the five lens families), `display` (the LCD),
`screens` (the 8-bit images the display shows), `stage` (positions with errors), `sensor` (photons to
digital numbers), `defocus` (the blur), `camera` (rendering), `calibration` (calibration datasets).
"""

# The lens families of `lenses`, here so that the command line can offer them without loading the renderer.
LENS_FAMILIES = ("brown", "freeform", "noncentral", "telecentric", "scheimpflug")

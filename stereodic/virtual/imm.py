"""The Inverse Mapping Matrix (IMM): which real pixels make each virtual pixel, and applying it.

For each virtual pixel the IMM holds the real image position (u, v) (float, column/row, integers at real
pixel centres) whose ray crosses the virtual sensor plane at that virtual pixel's centre. Stored as two
float32 maps, `map_x` (u) and `map_y` (v): exactly `cv2.remap`'s map form. The seed's "4 real pixels and
4 coefficients per virtual pixel" are implied by it: the real pixels (i, j), (i+1, j), (i, j+1),
(i+1, j+1) with i = floor(u), j = floor(v), and the bilinear weights (1-a)(1-b), a(1-b), (1-a)b, ab with
a = u - i, b = v - j, which are the weights `cv2.remap(INTER_LINEAR)` uses (`IMM.taps` spells them out).

Building: the real pixels are projected onto the virtual plane (the Projected Real Pixels); within the
quadrilateral of 4 projected real pixels containing a virtual pixel, the bilinear map real (u, v) ->
plane (x, y) is inverted by Newton's method on its 2x2 Jacobian (a numba kernel, one virtual pixel at a
time, moving to the neighbouring quadrilateral when the step leaves the current one), starting from a
coarse inverse (the same Newton on a grid every 8 virtual pixels, itself started from a homography). Virtual pixels that fall outside the valid real field are blank (map value -1).

Applying: `cv2.remap` with the float32 maps (default) or OpenCV's fixed-point maps (CV_16SC2, 1/32
pixel). With OpenCV >= 5, float maps give exact bilinear interpolation and are not slower; the
fixed-point maps round every position to 1/32 pixel (see docs/virtual-camera.md for the numbers).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from calib.errors import InputError
from calib.prvm_file import PRVM
from stereodic.virtual.camera import VirtualSensor, project_to_plane

BLANK = -1.0  # map value of a blank virtual pixel: outside the image, so cv2.remap gives the border (0)


@dataclass
class IMM:
    """Inverse Mapping Matrix of one virtual sensor.

    map_x, map_y: (Hv, Wv) float32, the real image column u and row v sampled by each virtual pixel
    (BLANK where the virtual pixel is blank). valid: (Hv, Wv) bool, not blank. real_size: (width, height)
    of the real image it applies to.
    """

    map_x: np.ndarray
    map_y: np.ndarray
    valid: np.ndarray
    real_size: tuple[int, int]
    _fixed: tuple | None = field(default=None, repr=False, compare=False)

    @property
    def shape(self) -> tuple[int, int]:
        """(height, width) of the virtual image."""
        return self.valid.shape

    def fixed_point(self) -> tuple[np.ndarray, np.ndarray]:
        """The maps as OpenCV fixed point (CV_16SC2 integer positions + CV_16UC1 1/32-pixel fractions),
        computed once."""
        if self._fixed is None:
            self._fixed = cv2.convertMaps(self.map_x, self.map_y, cv2.CV_16SC2)
        return self._fixed

    def real_position(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """(..., 2) float64 real image positions (u, v) sampled by virtual positions (x, y) (arrays of one
        shape, sub-pixel): the maps interpolated bilinearly, as cv2.remap does between virtual pixel
        centres. NaN outside the virtual image or where one of the 4 neighbouring virtual pixels is
        blank."""
        h, w = self.shape
        x, y = np.broadcast_arrays(np.asarray(x, np.float64), np.asarray(y, np.float64))
        inside = np.isfinite(x) & np.isfinite(y) & (x >= 0) & (x <= w - 1) & (y >= 0) & (y <= h - 1)
        i = np.clip(np.floor(np.where(inside, x, 0)), 0, w - 2).astype(np.intp)
        j = np.clip(np.floor(np.where(inside, y, 0)), 0, h - 2).astype(np.intp)
        a, b = x - i, y - j
        taps = ((j, i), (j, i + 1), (j + 1, i), (j + 1, i + 1))
        ok = inside & np.logical_and.reduce([self.valid[t] for t in taps])
        out = []
        for m in (self.map_x, self.map_y):
            p00, p10, p01, p11 = (m[t].astype(np.float64) for t in taps)
            out.append(np.where(ok, p00 + a * (p10 - p00) + b * (p01 - p00) + a * b * (p11 - p10 - p01 + p00),
                                np.nan))
        return np.stack(out, axis=-1)

    def taps(self) -> tuple[np.ndarray, np.ndarray]:
        """The seed's form: (index (Hv, Wv, 4) int64 into the row-major flattened real image,
        weights (Hv, Wv, 4) float64) such that virtual = sum(weights * real.ravel()[index], axis=-1).
        Blank virtual pixels get index 0 and weights 0."""
        w, h = self.real_size
        u = np.where(self.valid, self.map_x.astype(np.float64), 0)
        v = np.where(self.valid, self.map_y.astype(np.float64), 0)
        i = np.clip(np.floor(u), 0, w - 2).astype(np.int64)
        j = np.clip(np.floor(v), 0, h - 2).astype(np.int64)
        a, b = u - i, v - j
        k = j * w + i
        index = np.stack([k, k + 1, k + w, k + w + 1], axis=-1)
        weights = np.stack([(1 - a) * (1 - b), a * (1 - b), (1 - a) * b, a * b], axis=-1)
        return index, weights * self.valid[..., None]


def build_imm(prvm: PRVM, sensor: VirtualSensor, *, tol_px: float = 1e-6, iterations: int = 12) -> IMM:
    """The IMM of a virtual sensor for a real camera (module docstring).

    Parameters
    ----------
    prvm : PRVM
        The real camera's (H, W) rays, WCS mm.
    sensor : VirtualSensor
        The virtual sensor plane (Hv, Wv pixels), WCS mm.
    tol_px : float
        Convergence tolerance of the inversion: the residual on the plane, virtual pixels.
    iterations : int
        Newton iterations per virtual pixel.

    Returns
    -------
    imm : IMM
        ``map_x``, ``map_y`` (Hv, Wv) float32: the real column u and row v (pixels, integers at pixel
        centres) each virtual pixel samples, -1 where blank; ``valid`` (Hv, Wv) bool: the inversion
        converged to a position inside [0, W-1] x [0, H-1] whose 4 neighbouring real pixels are valid.
    """
    q = np.ascontiguousarray(project_to_plane(prvm, sensor))  # (H, W, 2) virtual coords of real pixels
    coarse = _coarse_inverse(q, sensor.width, sensor.height, tol_px)
    hv, wv = sensor.height, sensor.width
    map_x = np.full((hv, wv), BLANK, np.float32)
    map_y = np.full((hv, wv), BLANK, np.float32)
    valid = np.zeros((hv, wv), np.bool_)
    from stereodic.virtual.imm_kernels import invert_rows
    invert_rows(q, coarse, 1.0 / _STEP, 1.0, iterations, tol_px, map_x, map_y, valid)
    return IMM(map_x, map_y, valid, (prvm.width, prvm.height))


_STEP = 8  # virtual pixels between the nodes of the coarse inverse


def _coarse_inverse(q: np.ndarray, wv: int, hv: int, tol_px: float, max_points: int = 10_000) -> np.ndarray:
    """(Hc, Wc, 2) float64 real (u, v) at the virtual nodes (k * _STEP, l * _STEP) covering the virtual
    image: a homography fitted to a sub-grid of projected real pixels gives the start, Newton (many
    steps) the node; nodes outside the real field take the nearest node's value (they only start the
    full-resolution Newton)."""
    h, w = q.shape[:2]
    step = max(1, int(np.ceil(np.sqrt(h * w / max_points))))
    sub = q[::step, ::step]
    vv, uu = np.mgrid[0:h:step, 0:w:step]
    good = np.isfinite(sub).all(axis=-1)
    if good.sum() < 4:
        raise InputError(None, "the PRVM has fewer than 4 valid pixels")
    hom, _ = cv2.findHomography(sub[good], np.stack([uu[good], vv[good]], axis=-1).astype(np.float64), 0)
    nu, nv = max(2, -(-(wv - 1) // _STEP) + 1), max(2, -(-(hv - 1) // _STEP) + 1)
    gv, gu = np.mgrid[0:nv, 0:nu] * float(_STEP)
    start = cv2.perspectiveTransform(np.stack([gu, gv], axis=-1).reshape(-1, 1, 2), hom).reshape(nv, nu, 2)
    mx, my = np.full((nv, nu), BLANK, np.float32), np.full((nv, nu), BLANK, np.float32)
    ok = np.zeros((nv, nu), np.bool_)
    coarse = np.ascontiguousarray(start, np.float64)
    from stereodic.virtual.imm_kernels import invert_rows
    invert_rows(q, coarse, 1.0, float(_STEP), 100, tol_px, mx, my, ok)
    if not ok.any():
        raise InputError(None, "the virtual sensor does not overlap the real field")
    coarse = np.stack([mx, my], axis=-1).astype(np.float64)
    if not ok.all():
        from scipy.ndimage import distance_transform_edt  # here: building an IMM only (0.2 s of import)
        near = distance_transform_edt(~ok, return_distances=False, return_indices=True)
        coarse = coarse[near[0], near[1]]
    return np.ascontiguousarray(coarse)


def apply_imm(image: np.ndarray, imm: IMM, *, fixed_point: bool = False) -> np.ndarray:
    """The virtual image of a real image: bilinear samples at the IMM's positions (`cv2.remap`).

    Parameters
    ----------
    image : (H, W) or (H, W, C) array
        The real image, any dtype cv2.remap takes; (H, W) must be the IMM's real size.
    imm : IMM
        The Inverse Mapping Matrix (`build_imm`).
    fixed_point : bool
        Use OpenCV's fixed-point maps (positions rounded to 1/32 pixel) instead of the float maps.

    Returns
    -------
    virtual : (Hv, Wv) or (Hv, Wv, C) array
        The same dtype; blank virtual pixels 0. InputError if the image is not of the IMM's real size.
    """
    if image.shape[:2] != (imm.real_size[1], imm.real_size[0]):
        raise InputError(None, f"image is {image.shape[1]}x{image.shape[0]} but the camera is "
                               f"{imm.real_size[0]}x{imm.real_size[1]}")
    maps = imm.fixed_point() if fixed_point else (imm.map_x, imm.map_y)
    return cv2.remap(image, maps[0], maps[1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)

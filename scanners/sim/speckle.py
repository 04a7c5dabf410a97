"""Synthetic speckle images with exactly known displacement, for testing and benchmarking DIC.

The pattern is a Boolean-like model of blurred dots: random dot centres (a Poisson process), each a
Gaussian spot of random size; overlapping spots merge through a saturating union, so the image is
background + contrast * (1 - exp(-S)), S the sum of the spots. A deformed image moves every dot by the
given displacement field and deforms its shape by the local deformation gradient. Pixels integrate the
light over their area: analytically (error functions) while the dots stay round (pure translations),
otherwise by evaluating the analytic spots on a fine sub-pixel grid. No image interpolation is used,
so the truth does not depend on any interpolator under test.
Frame: pixel (x = column, y = row), integer coordinates are pixel centres; the content moves from x to
x + u(x) (u in pixels).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np
from numba import njit

Displacement = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]


@dataclass
class Speckle:
    """Dots of one pattern: centres (N, 2) as (x, y) pixels in the reference image, Gaussian radii (N,)
    (standard deviation, pixels), strength (N,) (optical density at the spot's centre)."""

    centres: np.ndarray
    radii: np.ndarray
    strength: np.ndarray
    width: int
    height: int
    background: float = 40.0
    contrast: float = 180.0


def make_speckle(width: int, height: int, dot_radius: float = 1.6, coverage: float = 0.5,
                 seed: int = 0) -> Speckle:
    """Random pattern over a (width, height) image (plus a margin, so that content may move in).

    dot_radius: mean Gaussian radius of a dot (pixels; a dot looks about 4x that wide);
    coverage: expected fraction of the area inside dots."""
    rng = np.random.default_rng(seed)
    margin = 8 * dot_radius + 16
    area = (width + 2 * margin) * (height + 2 * margin)
    mean_area = math.pi * (2.0 * dot_radius) ** 2
    n = rng.poisson(-math.log(1.0 - coverage) * area / mean_area)
    centres = np.column_stack([rng.uniform(-margin, width + margin, n),
                               rng.uniform(-margin, height + margin, n)])
    radii = dot_radius * rng.uniform(0.7, 1.3, n)
    strength = rng.uniform(1.5, 3.0, n)
    return Speckle(centres, radii, strength, width, height)


@njit(cache=True)
def _splat_round(S, cx, cy, r, a):
    """Add pixel-area integrals of round Gaussian spots to S (analytic, with erf)."""
    h, w = S.shape
    for k in range(cx.size):
        ext = 5.0 * r[k] + 1.0
        x0 = max(0, int(math.floor(cx[k] - ext)))
        x1 = min(w - 1, int(math.ceil(cx[k] + ext)))
        y0 = max(0, int(math.floor(cy[k] - ext)))
        y1 = min(h - 1, int(math.ceil(cy[k] + ext)))
        if x1 < x0 or y1 < y0:
            continue
        s = 1.0 / (math.sqrt(2.0) * r[k])
        # integral over a pixel of exp(-d^2/2r^2), normalised so that the peak density is a[k]
        norm = a[k] * 2.0 * math.pi * r[k] * r[k]
        ex = np.empty(x1 - x0 + 1)
        for i in range(x0, x1 + 1):
            ex[i - x0] = 0.5 * (math.erf((i + 0.5 - cx[k]) * s) - math.erf((i - 0.5 - cx[k]) * s))
        for j in range(y0, y1 + 1):
            ey = 0.5 * (math.erf((j + 0.5 - cy[k]) * s) - math.erf((j - 0.5 - cy[k]) * s)) * norm
            for i in range(x0, x1 + 1):
                S[j, i] += ey * ex[i - x0]


@njit(cache=True)
def _splat_general(S, cx, cy, icov, ext, a, ss):
    """Add spots exp(-d^T icov d / 2) averaged over an ss x ss sub-pixel grid of each pixel."""
    h, w = S.shape
    for k in range(cx.size):
        x0 = max(0, int(math.floor(cx[k] - ext[k])))
        x1 = min(w - 1, int(math.ceil(cx[k] + ext[k])))
        y0 = max(0, int(math.floor(cy[k] - ext[k])))
        y1 = min(h - 1, int(math.ceil(cy[k] + ext[k])))
        p, q, r = icov[k, 0], icov[k, 1], icov[k, 2]
        for j in range(y0, y1 + 1):
            for i in range(x0, x1 + 1):
                acc = 0.0
                for sj in range(ss):
                    dy = j - 0.5 + (sj + 0.5) / ss - cy[k]
                    for si in range(ss):
                        dx = i - 0.5 + (si + 0.5) / ss - cx[k]
                        acc += math.exp(-0.5 * (p * dx * dx + 2.0 * q * dx * dy + r * dy * dy))
                S[j, i] += a[k] * acc / (ss * ss)


def render(speckle: Speckle, displacement: Displacement | tuple[float, float] | None = None,
           noise_sigma: float = 0.0, bits: int | None = 8, supersample: int = 8,
           contrast: float | None = None, background: float | None = None,
           seed: int | None = None) -> np.ndarray:
    """Image of the pattern moved by `displacement`: None (reference), a translation (tx, ty) in
    pixels, or a function (x, y) -> (u, v) of reference positions (arrays, pixels).

    noise_sigma: Gaussian noise (grey levels) added before quantisation; bits: 8 or 16 (uint image,
    clipped) or None (float64, unclipped). contrast/background override the pattern's, e.g. to render a
    deformed image with other lighting."""
    cx, cy = speckle.centres[:, 0].copy(), speckle.centres[:, 1].copy()
    S = np.zeros((speckle.height, speckle.width))
    if displacement is None or isinstance(displacement, tuple):
        tx, ty = displacement if displacement is not None else (0.0, 0.0)
        _splat_round(S, cx + tx, cy + ty, speckle.radii, speckle.strength)
    else:
        e = 1e-3
        u, v = displacement(cx, cy)
        uxp, vxp = displacement(cx + e, cy)
        uxm, vxm = displacement(cx - e, cy)
        uyp, vyp = displacement(cx, cy + e)
        uym, vym = displacement(cx, cy - e)
        F = np.empty((cx.size, 2, 2))
        F[:, 0, 0] = 1 + (uxp - uxm) / (2 * e)
        F[:, 0, 1] = (uyp - uym) / (2 * e)
        F[:, 1, 0] = (vxp - vxm) / (2 * e)
        F[:, 1, 1] = 1 + (vyp - vym) / (2 * e)
        cov = F @ F.transpose(0, 2, 1) * (speckle.radii ** 2)[:, None, None]
        icov = np.linalg.inv(cov)
        ext = 5.0 * np.sqrt(np.linalg.eigvalsh(cov)[:, 1]) + 1.0
        _splat_general(S, cx + u, cy + v, np.column_stack([icov[:, 0, 0], icov[:, 0, 1], icov[:, 1, 1]]),
                       ext, speckle.strength, supersample)
    c = speckle.contrast if contrast is None else contrast
    b = speckle.background if background is None else background
    img = b + c * (1.0 - np.exp(-S))
    if noise_sigma > 0:
        img = img + np.random.default_rng(seed).normal(0.0, noise_sigma, img.shape)
    if bits is None:
        return img
    top = 2 ** bits - 1
    return np.clip(np.rint(img), 0, top).astype(np.uint8 if bits == 8 else np.uint16)


def affine_displacement(shift: tuple[float, float] = (0.0, 0.0), *, strain: float = 0.0, poisson: float = 0.0,
                        rotation_deg: float = 0.0, centre: tuple[float, float] = (0.0, 0.0)) -> Displacement:
    """The displacement field (x, y) -> (u, v), pixels, of a uniaxial stretch along x (engineering strain
    `strain`, with the lateral contraction -poisson * strain along y), then a rotation by `rotation_deg`
    (counter-clockwise on the screen's x right, y down axes: positive turns x towards y), both about
    `centre` (x, y pixels), then the translation `shift` (x, y pixels). Exact: the map is affine."""
    a = math.radians(rotation_deg)
    c, s = math.cos(a), math.sin(a)
    sx, sy = 1.0 + strain, 1.0 - poisson * strain
    x0, y0 = centre

    def field(x, y):
        dx, dy = (x - x0) * sx, (y - y0) * sy
        return x0 + c * dx - s * dy + shift[0] - x, y0 + s * dx + c * dy + shift[1] - y
    return field


@njit(cache=True)
def _density_at(x, y, cx, cy, r, a, order, start, x0, y0, cell, nx, ny, out):
    """Optical density S at points (x, y): the sum of the Gaussian spots of the cells around each point
    (dots sorted by cell: `order`, cell k's dots are order[start[k]:start[k + 1]])."""
    for i in range(x.size):
        ci = int(math.floor((x[i] - x0) / cell))
        cj = int(math.floor((y[i] - y0) / cell))
        s = 0.0
        for j in range(max(cj - 1, 0), min(cj + 2, ny)):
            for q in range(max(ci - 1, 0), min(ci + 2, nx)):
                k = j * nx + q
                for m in range(start[k], start[k + 1]):
                    d = order[m]
                    dx = x[i] - cx[d]
                    dy = y[i] - cy[d]
                    s += a[d] * math.exp(-0.5 * (dx * dx + dy * dy) / (r[d] * r[d]))
        out[i] = s


class SpeckleSampler:
    """The pattern's value at arbitrary points of its plane (no pixel integration): background +
    contrast * (1 - exp(-S)), S the sum of the dots' spots (the same model as `render`). Positions in
    the pattern's units (pixels of `make_speckle`; a specimen may use them as scaled material
    coordinates). Dots further than 5 radii are left out (their spot is below 4e-6 of its peak)."""

    def __init__(self, speckle: Speckle):
        self.speckle = speckle
        c = speckle.centres
        self.cell = 5.0 * float(speckle.radii.max()) if len(c) else 1.0
        self.x0, self.y0 = (c.min(0) if len(c) else np.zeros(2)) - self.cell
        span = (c.max(0) if len(c) else np.zeros(2)) + self.cell - (self.x0, self.y0)
        self.nx, self.ny = (int(v // self.cell) + 1 for v in span)
        cells = (np.floor((c[:, 1] - self.y0) / self.cell).astype(np.int64) * self.nx
                 + np.floor((c[:, 0] - self.x0) / self.cell).astype(np.int64))
        self.order = np.argsort(cells, kind="stable")
        self.start = np.searchsorted(cells[self.order], np.arange(self.nx * self.ny + 1))

    def __call__(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Values (float64, grey levels, the shape of x) at positions (x, y)."""
        x, y = np.broadcast_arrays(np.asarray(x, np.float64), np.asarray(y, np.float64))
        sp = self.speckle
        S = np.empty(x.size)
        _density_at(np.ascontiguousarray(x).ravel(), np.ascontiguousarray(y).ravel(), sp.centres[:, 0].copy(),
                    sp.centres[:, 1].copy(), sp.radii, sp.strength, self.order, self.start, self.x0, self.y0,
                    self.cell, self.nx, self.ny, S)
        return (sp.background + sp.contrast * (1.0 - np.exp(-S))).reshape(x.shape)

"""Straight-line truth for virtual cameras: a grid of lines on a known plane, seen through true rays, and
how straight the lines come out in a virtual image.

Rendering uses only the rays of a camera (e.g. a simulated lens's true rays): each real pixel is the
value of a smooth line profile where its ray crosses the plane z = z_mm (a band-limited scene sampled at
the pixel centre, so no aliasing). Straightness fits a straight line to the sub-pixel centres of every
line in the virtual image and reports the RMS perpendicular deviation in virtual pixels.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

Rays = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]


def render_lines(rays: Rays, width: int, height: int, z_mm: float, spacing_mm: float, sigma_mm: float,
                 axis: str, low: float = 40.0, high: float = 220.0) -> np.ndarray:
    """(height, width) float32 image of lines on the plane z = z_mm (WCS mm): lines x = k * spacing_mm
    (axis "x", roughly vertical in the image) or y = k * spacing_mm (axis "y"), Gaussian profile of
    standard deviation sigma_mm, values from `low` (background) to `high` (line centre)."""
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    o, d = rays(u, v)
    p = o + ((z_mm - o[..., 2]) / d[..., 2])[..., None] * d
    c = p[..., 0 if axis == "x" else 1]
    off = c - spacing_mm * np.round(c / spacing_mm)
    return (low + (high - low) * np.exp(-0.5 * (off / sigma_mm) ** 2)).astype(np.float32)


def line_centres(image: np.ndarray, valid: np.ndarray, axis: str, sigma_px: float, min_points: int = 20
                 ) -> list[np.ndarray]:
    """Sub-pixel centres of the lines of a virtual image: for axis "x" (roughly vertical lines) one
    (N, 2) array of (u, v) per line, found along each row; axis "y" along each column, (u, v) too.

    Centre = centroid of the background-subtracted profile over +-3 sigma_px around the peak, repeated
    with the window re-centred on the centroid (interpolated linearly at the window ends, so that the
    window does not lock to the pixel grid). Profiles touching blank pixels are skipped.
    """
    img = image if axis == "x" else image.T
    ok = valid if axis == "x" else valid.T
    half = 3.0 * sigma_px
    bg = np.percentile(img[ok], 5)
    found: list[tuple[float, float]] = []
    for row in range(img.shape[0]):
        prof = img[row].astype(np.float64) - bg
        good = ok[row]
        peaks = np.nonzero((prof[1:-1] > prof[:-2]) & (prof[1:-1] >= prof[2:]) & good[1:-1] & good[:-2]
                           & good[2:] & (prof[1:-1] > 0.5 * prof[good].max()))[0] + 1
        for pk in peaks:
            c = float(pk)
            for _ in range(3):
                lo, hi = c - half, c + half
                if lo < 0 or hi > len(prof) - 1 or not good[int(np.floor(lo)):int(np.ceil(hi)) + 1].all():
                    c = np.nan
                    break
                x = np.arange(np.ceil(lo), np.floor(hi) + 1)
                xs = np.r_[lo, x, hi]
                ys = np.interp(xs, np.arange(len(prof)), prof)
                c = np.trapezoid(xs * ys, xs) / np.trapezoid(ys, xs)
            if np.isfinite(c):
                found.append((c, row))
    pts = np.array(found) if found else np.zeros((0, 2))
    if axis == "y":
        pts = pts[:, ::-1]
    return _group(pts, axis, sigma_px, min_points)


def _group(pts: np.ndarray, axis: str, sigma_px: float, min_points: int) -> list[np.ndarray]:
    """Chain centres into lines: consecutive rows (columns) whose centres are within 2 sigma."""
    k = 0 if axis == "x" else 1  # the coordinate across the line
    lines: list[list[np.ndarray]] = []
    for p in pts[np.argsort(pts[:, 1 - k], kind="stable")]:
        for line in lines:
            last = line[-1]
            if abs(p[1 - k] - last[1 - k]) <= 1.5 and abs(p[k] - last[k]) <= 2 * sigma_px:
                line.append(p)
                break
        else:
            lines.append([p])
    return [np.array(line) for line in lines if len(line) >= min_points]


def straightness_rms(lines: list[np.ndarray]) -> float:
    """RMS perpendicular distance (pixels) of line centres from the straight line fitted to each line
    (total least squares), over all lines."""
    res = []
    for pts in lines:
        c = pts - pts.mean(axis=0)
        normal = np.linalg.svd(c, full_matrices=False)[2][1]
        res.append(c @ normal)
    return float(np.sqrt(np.mean(np.concatenate(res) ** 2)))

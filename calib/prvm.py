"""Per-pixel rays from decoded display points: the least-squares line through each pixel's points at the
stage positions, the cover-glass refraction, and the conversion to the PRVM arrays (DESIGN.md).

All geometry is WCS mm, float64. A line is kept as x(z) = x0 + s * (z - z_ref) for x and y: `start`
(H, W, 2) the point on the plane z = z_ref, `slope` (H, W, 2) dx/dz and dy/dz. The display planes are
z = const, so every point's error is lateral and this parametrisation's least squares is the right one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.capture import CoverGlass


@dataclass
class Lines:
    """One line per pixel. start: (H, W, 2) x, y on z = z_ref (mm); slope: (H, W, 2); valid: (H, W) bool;
    residual_mm: (H, W) float32 RMS distance of the points from the line, NaN with fewer than 3 points;
    used: (H, W) number of stage positions that contributed."""

    start: np.ndarray
    slope: np.ndarray
    valid: np.ndarray
    residual_mm: np.ndarray
    used: np.ndarray
    z_ref: float = 0.0

    def at(self, z_mm: float) -> np.ndarray:
        """(H, W, 2) x, y of each line on the plane z = z_mm."""
        return self.start + (z_mm - self.z_ref) * self.slope

    def direction(self) -> np.ndarray:
        """(H, W, 3) unit directions, z > 0."""
        d = np.concatenate([self.slope, np.ones(self.slope.shape[:2] + (1,))], axis=2)
        return d / np.linalg.norm(d, axis=2, keepdims=True)

    def origin(self) -> np.ndarray:
        """(H, W, 3) points on z = z_ref."""
        return np.concatenate([self.start, np.full(self.start.shape[:2] + (1,), self.z_ref)], axis=2)

    @classmethod
    def through(cls, z_a: float, xy_a: np.ndarray, z_b: float, xy_b: np.ndarray, valid: np.ndarray,
                residual_mm: np.ndarray, used: np.ndarray, z_ref: float = 0.0) -> "Lines":
        """The lines through points (H, W, 2) on two planes z_a != z_b."""
        slope = (xy_b - xy_a) / (z_b - z_a)
        return cls(xy_a + (z_ref - z_a) * slope, slope, valid, residual_mm, used, z_ref)


def fit_lines(z_mm: np.ndarray, points: np.ndarray, weights: np.ndarray, z_ref: float = 0.0) -> Lines:
    """Weighted least-squares line through each pixel's points.

    z_mm: (M,) plane of each stage position; points: (M, H, W, 2) x, y (mm) on those planes;
    weights: (M, H, W) >= 0 (0 leaves a point out; e.g. inverse variances). A pixel is valid when it has
    points on at least two distinct planes.
    """
    z = np.asarray(z_mm, np.float64) - z_ref
    finite = np.isfinite(points).all(axis=3)
    w = np.where(finite, weights, 0.0).astype(np.float64)
    p = points if finite.all() else np.where(finite[..., None], points, 0.0)
    zz = z[:, None, None]
    s, sz, szz = w.sum(0), (w * zz).sum(0), (w * zz * zz).sum(0)
    det = s * szz - sz * sz
    used = (w > 0).sum(0)
    valid = (used >= 2) & (det > 1e-12 * np.maximum(s * szz, 1e-300))
    det = np.where(valid, det, 1.0)
    sx, szx = np.zeros(p.shape[1:]), np.zeros(p.shape[1:])
    for m in range(len(z)):
        wp = w[m][..., None] * p[m]
        sx += wp
        szx += z[m] * wp
    slope = (s[..., None] * szx - sz[..., None] * sx) / det[..., None]
    start = (sx - slope * sz[..., None]) / np.where(valid, s, 1.0)[..., None]
    start[~valid] = np.nan
    slope[~valid] = np.nan
    lines = Lines(start, slope, valid, np.full(valid.shape, np.nan, np.float32), used, z_ref)
    if len(z) > 2:
        d = lines.direction()
        ss, n = np.zeros(valid.shape), np.zeros(valid.shape)
        for m in range(len(z)):
            e = p[m] - lines.at(z_mm[m])
            along = (e * d[..., :2]).sum(axis=2)
            dist2 = (e * e).sum(axis=2) - along * along
            use = w[m] > 0
            ss += np.where(use, dist2, 0.0)
            n += use
        with np.errstate(invalid="ignore"):
            lines.residual_mm = np.where(valid & (n > 2), np.sqrt(ss / np.maximum(n, 1)), np.nan).astype(np.float32)
    return lines


def glass_offset(slope: np.ndarray, glass: CoverGlass) -> np.ndarray:
    """(H, W, 2) mm to add to a decoded display point seen through the cover glass to get the point where
    the ray in air meets the pixel plane.

    The glass (thickness t, index n) lies in front of the pixel plane. A ray in air at angle a to the
    display normal travels the last t millimetres in the glass at angle a' (sin a = n sin a'), so it lands
    t * (tan a - tan a') short of where the straight air ray would; slope = (dx/dz, dy/dz) of the air ray.
    """
    t2 = (slope * slope).sum(axis=-1, keepdims=True)          # tan^2 a
    sin2 = t2 / (1 + t2)
    cos_a = np.sqrt(1 - sin2)
    cos_g = np.sqrt(1 - sin2 / glass.refractive_index ** 2)
    # tan a - tan a' = tan a * (1 - cos a / (n cos a'))
    return glass.thickness_mm * slope * (1 - cos_a / (glass.refractive_index * cos_g))

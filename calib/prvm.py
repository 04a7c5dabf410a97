"""Per-pixel rays from decoded display points: the least-squares line through each pixel's points at the
stage positions, the cover-glass refraction, and the conversion to the PRVM arrays (DESIGN.md).

All geometry is WCS mm, float64. A line is kept as x(z) = x0 + s * (z - z_ref) for x and y: `start`
(H, W, 2) the point on the plane z = z_ref, `slope` (H, W, 2) dx/dz and dy/dz. The display planes are
z = const, so every point's error is lateral and this parametrisation's least squares is the right one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from calib.capture import CoverGlass

# refits of the lines with the cover glass's refraction computed from the previous fit's directions
GLASS_ITERATIONS = 4


@dataclass
class Lines:
    """One line per pixel. start: (H, W, 2) x, y on z = z_ref (mm); slope: (H, W, 2); valid: (H, W) bool;
    residual_mm: (H, W) float32 RMS distance of the points from the line, NaN with fewer than 3 points;
    used: (H, W) int16 number of stage positions that contributed."""

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
        d = np.empty(self.slope.shape[:2] + (3,))
        d[..., 2] = 1.0 / np.sqrt(1.0 + self.slope[..., 0] ** 2 + self.slope[..., 1] ** 2)
        np.multiply(self.slope, d[..., 2:], out=d[..., :2])
        return d

    def origin(self) -> np.ndarray:
        """(H, W, 3) points on z = z_ref."""
        o = np.empty(self.start.shape[:2] + (3,))
        o[..., :2] = self.start
        o[..., 2] = self.z_ref
        return o

    @classmethod
    def through(cls, z_a: float, xy_a: np.ndarray, z_b: float, xy_b: np.ndarray, valid: np.ndarray,
                residual_mm: np.ndarray, used: np.ndarray, z_ref: float = 0.0) -> "Lines":
        """The lines through points (H, W, 2) on two planes z_a != z_b."""
        slope = (xy_b - xy_a) / (z_b - z_a)
        return cls(xy_a + (z_ref - z_a) * slope, slope, valid, residual_mm, used, z_ref)


def fit_lines(z_mm: np.ndarray, points: np.ndarray, weights: np.ndarray, z_ref: float = 0.0) -> Lines:
    """Weighted least-squares line through each pixel's points.

    z_mm: (M,) plane of each stage position, or (M, H, W) each point's own z (display planes in general
    poses); points: (M, H, W, 2) x, y (mm) on those planes; weights: (M, H, W) >= 0 (0 leaves a point
    out, as does a non-finite point; e.g. inverse variances). A pixel is valid when it has points at
    two or more distinct z.
    """
    m, h, w = np.shape(weights)
    z = np.asarray(z_mm, np.float64) - z_ref
    z = np.broadcast_to(z.reshape(m, 1) if z.ndim == 1 else z.reshape(m, h * w), (m, h * w))
    pts = np.ascontiguousarray(points, np.float64).reshape(m, h * w, 2)
    wts = np.ascontiguousarray(weights).reshape(m, h * w)
    start, slope = np.empty((h, w, 2)), np.empty((h, w, 2))
    valid = np.empty((h, w), bool)
    used = np.empty((h, w), np.int16)
    residual = np.empty((h, w), np.float32)
    _fit_lines(z, pts, wts, start.reshape(-1, 2), slope.reshape(-1, 2), valid.reshape(-1), used.reshape(-1),
               residual.reshape(-1))
    return Lines(start, slope, valid, residual, used, z_ref)


@numba.njit(cache=True, parallel=True)
def _fit_lines(z, points, weights, start, slope, valid, used, residual):  # pragma: no cover - compiled
    """Per pixel i: the weighted line x = start + slope * z through points[:, i] at z[:, i] (float64);
    residual = RMS distance of the used points from the line (NaN unless 3 or more were used)."""
    m = z.shape[0]
    for i in numba.prange(weights.shape[1]):
        s = sz = szz = sx0 = sx1 = szx0 = szx1 = 0.0
        n = 0
        for k in range(m):
            wk = np.float64(weights[k, i])
            x0, x1 = points[k, i, 0], points[k, i, 1]
            if not (wk > 0) or not (np.isfinite(x0) and np.isfinite(x1)):
                continue
            n += 1
            s += wk
            sz += wk * z[k, i]
            szz += wk * z[k, i] * z[k, i]
            sx0 += wk * x0
            sx1 += wk * x1
            szx0 += wk * z[k, i] * x0
            szx1 += wk * z[k, i] * x1
        det = s * szz - sz * sz
        ok = n >= 2 and det > 1e-12 * max(s * szz, 1e-300)
        used[i] = n
        valid[i] = ok
        residual[i] = np.nan
        if not ok:
            start[i, 0] = start[i, 1] = slope[i, 0] = slope[i, 1] = np.nan
            continue
        a0 = (s * szx0 - sz * sx0) / det
        a1 = (s * szx1 - sz * sx1) / det
        b0 = (sx0 - a0 * sz) / s
        b1 = (sx1 - a1 * sz) / s
        slope[i, 0], slope[i, 1], start[i, 0], start[i, 1] = a0, a1, b0, b1
        if n > 2:
            norm2 = 1.0 + a0 * a0 + a1 * a1
            ss = 0.0
            for k in range(m):
                wk = np.float64(weights[k, i])
                x0, x1 = points[k, i, 0], points[k, i, 1]
                if not (wk > 0) or not (np.isfinite(x0) and np.isfinite(x1)):
                    continue
                e0 = x0 - (b0 + a0 * z[k, i])
                e1 = x1 - (b1 + a1 * z[k, i])
                along = (e0 * a0 + e1 * a1)
                ss += e0 * e0 + e1 * e1 - along * along / norm2
            residual[i] = np.sqrt(max(ss, 0.0) / n)


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


@dataclass
class PosedLines:
    """Result of `fit_posed_lines`: the lines (in the output frame), and per pose the RMS distance (mm)
    of its points from them (across the fitting frame's z) and how many points it gave."""

    lines: Lines
    rms_mm: np.ndarray
    points: np.ndarray


def fit_posed_lines(coords: list[np.ndarray], weights: list[np.ndarray], rotation: np.ndarray,
                    translation: np.ndarray, pitch_mm, *, glass: CoverGlass | None = None,
                    to_output: tuple[np.ndarray, np.ndarray] | None = None, z_ref: float = 0.0,
                    rows: int = 128) -> PosedLines:
    """The least-squares line per pixel through its display points at displays in general poses.

    coords: per pose (2, H, W) display coordinates (c, r) (display pixels); weights: per pose (H, W)
    (0 leaves a point out); rotation (M, 3, 3), translation (M, 3): each pose's display frame in the
    fitting frame, X = R (c pitch_x, r pitch_y, 0) + t (mm), whose z should run roughly along the rays
    (the lines are x, y as functions of z there, `fit_lines`); glass: the displays' cover glass (the
    points are corrected with each line's direction in each display's own frame, `glass_offset`);
    to_output: (A, b) mapping the fitting frame to the output frame, X_out = A X + b (default: the
    same); z_ref: the plane z = z_ref of the output frame on which the lines start. Works on `rows`
    image rows at a time (a few arrays of M x rows x W points).
    """
    m = len(coords)
    h, w = weights[0].shape
    pitch = np.asarray(pitch_mm, float)
    a, b = (np.eye(3), np.zeros(3)) if to_output is None else (np.asarray(to_output[0]), np.asarray(to_output[1]))
    out = Lines(np.empty((h, w, 2)), np.empty((h, w, 2)), np.empty((h, w), bool), np.empty((h, w), np.float32),
                np.empty((h, w), np.int16), z_ref)
    ss, count = np.zeros(m), np.zeros(m)
    for r0 in range(0, h, rows):
        sl = slice(r0, min(h, r0 + rows))
        q = np.stack([np.stack([c[0, sl] * pitch[0], c[1, sl] * pitch[1]], axis=-1) for c in coords])
        wt = np.stack([wk[sl] for wk in weights])
        shift = np.zeros_like(q)
        for it in range(1 + (GLASS_ITERATIONS if glass is not None and glass.thickness_mm > 0 else 0)):
            x = np.einsum("kij,kabj->kabi", rotation[:, :, :2], q + shift) + translation[:, None, None, :]
            part = fit_lines(x[..., 2], x[..., :2], wt, 0.0)
            if it < GLASS_ITERATIONS and glass is not None and glass.thickness_mm > 0:
                d = np.concatenate([np.nan_to_num(part.slope), np.ones(part.slope.shape[:2] + (1,))], axis=-1)
                for k in range(m):
                    dk = d @ rotation[k]                     # the direction in display k's frame
                    shift[k] = glass_offset(dk[..., :2] / dk[..., 2:], glass)
        e = x[..., :2] - part.start[None] - x[..., 2:] * part.slope[None]
        used = (wt > 0) & part.valid[None] & np.isfinite(e).all(axis=-1)
        ss += np.where(used, (e * e).sum(axis=-1), 0.0).sum(axis=(1, 2))
        count += used.sum(axis=(1, 2))
        # the lines in the output frame, starting on its plane z = z_ref
        p = np.concatenate([part.start, np.zeros(part.start.shape[:2] + (1,))], axis=-1) @ a.T + b
        d = np.concatenate([part.slope, np.ones(part.slope.shape[:2] + (1,))], axis=-1) @ a.T
        with np.errstate(invalid="ignore", divide="ignore"):
            slope = d[..., :2] / d[..., 2:]
            out.start[sl] = p[..., :2] + (z_ref - p[..., 2:]) * slope
        out.slope[sl] = slope
        out.valid[sl] = part.valid & (d[..., 2] > 0)
        out.residual_mm[sl] = part.residual_mm
        out.used[sl] = part.used
    out.start[~out.valid] = np.nan
    out.slope[~out.valid] = np.nan
    return PosedLines(out, np.sqrt(ss / np.maximum(count, 1)), count)

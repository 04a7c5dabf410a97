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

    def moved(self, rotation: np.ndarray, translation: np.ndarray, z_ref: float = 0.0) -> "Lines":
        """The same lines in another frame, X_new = rotation @ X + translation (mm), starting on its plane
        z = z_ref; a line that does not run towards +z there is no longer valid (NaN)."""
        a, b = np.asarray(rotation, float), np.asarray(translation, float)
        p = np.concatenate([self.start, np.full(self.start.shape[:-1] + (1,), self.z_ref)], axis=-1) @ a.T + b
        d = np.concatenate([self.slope, np.ones(self.slope.shape[:-1] + (1,))], axis=-1) @ a.T
        with np.errstate(invalid="ignore", divide="ignore"):
            slope = d[..., :2] / d[..., 2:]
            start = p[..., :2] + (z_ref - p[..., 2:]) * slope
        valid = self.valid & (d[..., 2] > 0)
        start[~valid] = np.nan
        slope[~valid] = np.nan
        return Lines(start, slope, valid, self.residual_mm, self.used, z_ref)

    @classmethod
    def through(cls, z_a: float, xy_a: np.ndarray, z_b: float, xy_b: np.ndarray, valid: np.ndarray,
                residual_mm: np.ndarray, used: np.ndarray, z_ref: float = 0.0) -> "Lines":
        """The lines through points (H, W, 2) on two planes z_a != z_b."""
        slope = (xy_b - xy_a) / (z_b - z_a)
        return cls(xy_a + (z_ref - z_a) * slope, slope, valid, residual_mm, used, z_ref)


def fit_lines(z_mm: np.ndarray, points: np.ndarray, weights: np.ndarray, z_ref: float = 0.0) -> Lines:
    """Weighted least-squares line through each pixel's points.

    z_mm: (M,) plane of each stage position; points: (M, H, W, 2) x, y (mm) on those planes;
    weights: (M, H, W) >= 0 (0 leaves a point out, as does a non-finite point; e.g. inverse variances).
    A pixel is valid when it has points on at least two distinct planes.
    """
    m, h, w = np.shape(weights)
    pts = np.ascontiguousarray(points, np.float64).reshape(m, h * w, 2)
    wts = np.ascontiguousarray(weights).reshape(m, h * w)
    start, slope = np.empty((h, w, 2)), np.empty((h, w, 2))
    valid = np.empty((h, w), bool)
    used = np.empty((h, w), np.int16)
    residual = np.empty((h, w), np.float32)
    # the planes as displays in poses X = I (x, y, 0) + (0, 0, z)
    rotation = np.broadcast_to(np.eye(3), (m, 3, 3)).copy()
    translation = np.zeros((m, 3))
    translation[:, 2] = np.asarray(z_mm, np.float64) - z_ref
    _fit_posed(pts, wts, rotation, translation, start.reshape(-1, 2), slope.reshape(-1, 2), valid.reshape(-1),
               used.reshape(-1), residual.reshape(-1), np.empty((0, m)))
    return Lines(start, slope, valid, residual, used, z_ref)


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


def posed_glass_offset(slope: np.ndarray, rotation: np.ndarray, glass: CoverGlass) -> np.ndarray:
    """(M, ..., 2) mm to add to the decoded display points of lines with slopes `slope` (..., 2) (dx/dz,
    dy/dz in a frame; NaN: taken as along z) seen on displays whose rotations in that frame are
    `rotation` (M, 3, 3): `glass_offset` of each line's direction in each display's own frame."""
    d = np.concatenate([np.nan_to_num(slope), np.ones(slope.shape[:-1] + (1,))], axis=-1)
    out = np.empty((len(rotation),) + slope.shape)
    for k, r in enumerate(rotation):
        dk = d @ r                                   # the direction in display k's frame (R^T d)
        out[k] = glass_offset(dk[..., :2] / dk[..., 2:], glass)
    return out


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
    glassy = glass is not None and glass.thickness_mm > 0
    for r0 in range(0, h, rows):
        sl = slice(r0, min(h, r0 + rows))
        q = np.stack([np.stack([c[0, sl] * pitch[0], c[1, sl] * pitch[1]], axis=-1) for c in coords])
        wt = np.ascontiguousarray(np.stack([wk[sl] for wk in weights]), np.float32)
        n = q.shape[1] * w
        shift = np.zeros_like(q)
        part = Lines(np.empty((n, 2)), np.empty((n, 2)), np.empty(n, bool), np.empty(n, np.float32),
                     np.empty(n, np.int16))
        sq = np.empty((n, m))
        for it in range(1 + (GLASS_ITERATIONS if glassy else 0)):
            _fit_posed(np.ascontiguousarray((q + shift).reshape(m, n, 2)), wt.reshape(m, n), rotation, translation,
                       part.start, part.slope, part.valid, part.used, part.residual_mm, sq)
            if it < GLASS_ITERATIONS and glassy:
                shift = posed_glass_offset(part.slope, rotation, glass).reshape(shift.shape)
        ss += np.nansum(sq, axis=0)
        count += (np.isfinite(sq) & (wt.reshape(m, n).T > 0)).sum(axis=0)
        part = Lines(*(a_.reshape(q.shape[1], w, *a_.shape[1:]) for a_ in
                       (part.start, part.slope, part.valid, part.residual_mm, part.used))).moved(a, b, z_ref)
        out.start[sl], out.slope[sl], out.valid[sl] = part.start, part.slope, part.valid
        out.residual_mm[sl] = part.residual_mm
        out.used[sl] = part.used
    return PosedLines(out, np.sqrt(ss / np.maximum(count, 1)), count)


@numba.njit(cache=True, inline="always")
def _point(q, weights, rotation, translation, k, i):  # pragma: no cover - compiled
    """(weight, x, y, z) of point k of pixel i: R_k (q[k, i], 0) + t_k; weight 0 where left out."""
    wk = np.float64(weights[k, i])
    if not (wk > 0) or not (np.isfinite(q[k, i, 0]) and np.isfinite(q[k, i, 1])):
        return 0.0, 0.0, 0.0, 0.0
    x0 = rotation[k, 0, 0] * q[k, i, 0] + rotation[k, 0, 1] * q[k, i, 1] + translation[k, 0]
    x1 = rotation[k, 1, 0] * q[k, i, 0] + rotation[k, 1, 1] * q[k, i, 1] + translation[k, 1]
    return wk, x0, x1, rotation[k, 2, 0] * q[k, i, 0] + rotation[k, 2, 1] * q[k, i, 1] + translation[k, 2]


@numba.njit(cache=True, parallel=True)
def _fit_posed(q, weights, rotation, translation, start, slope, valid, used, residual, sq):  # pragma: no cover
    """Per pixel i: its points X_k = R_k (q[k, i], 0) + t_k (float64) and the weighted line
    x, y = start + slope * z through them; residual = RMS distance of the used points from the line
    (NaN unless 3 or more were used); sq[i, k] (if sq has rows): the squared distance of point k from
    the line (NaN where the point is not used or the line not valid)."""
    m = q.shape[0]
    keep = sq.shape[0] > 0
    for i in numba.prange(q.shape[1]):
        s = sz = szz = sx0 = sx1 = szx0 = szx1 = 0.0
        n = 0
        for k in range(m):
            wk, x0, x1, zk = _point(q, weights, rotation, translation, k, i)
            if not wk > 0:
                continue
            n += 1
            s += wk
            sz += wk * zk
            szz += wk * zk * zk
            sx0 += wk * x0
            sx1 += wk * x1
            szx0 += wk * zk * x0
            szx1 += wk * zk * x1
        det = s * szz - sz * sz
        ok = n >= 2 and det > 1e-12 * max(s * szz, 1e-300)
        used[i] = n
        valid[i] = ok
        residual[i] = np.nan
        if keep:
            for k in range(m):
                sq[i, k] = np.nan
        if not ok:
            start[i, 0] = start[i, 1] = slope[i, 0] = slope[i, 1] = np.nan
            continue
        a0 = (s * szx0 - sz * sx0) / det
        a1 = (s * szx1 - sz * sx1) / det
        b0 = (sx0 - a0 * sz) / s
        b1 = (sx1 - a1 * sz) / s
        slope[i, 0], slope[i, 1], start[i, 0], start[i, 1] = a0, a1, b0, b1
        norm2 = 1.0 + a0 * a0 + a1 * a1
        ss = 0.0
        for k in range(m):
            wk, x0, x1, zk = _point(q, weights, rotation, translation, k, i)
            if not wk > 0:
                continue
            e0 = x0 - (b0 + a0 * zk)
            e1 = x1 - (b1 + a1 * zk)
            along = e0 * a0 + e1 * a1
            d2 = max(e0 * e0 + e1 * e1 - along * along / norm2, 0.0)
            if keep:
                sq[i, k] = d2
            ss += d2
        if n > 2:
            residual[i] = np.sqrt(ss / n)

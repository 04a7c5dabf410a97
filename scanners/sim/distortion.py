"""Lens distortion on normalised image coordinates, forward and inverse (numba kernels).

Normalised coordinates are (x, y) = (X/Z, Y/Z) of a direction in the camera frame (x right, y down,
z forward) -- or, for a telecentric lens, object-plane coordinates divided by a reference length. The
forward map (ideal -> distorted) is Brown-Conrady as in OpenCV (radial k1, k2, k3; tangential p1, p2)
plus a sum of Gaussian displacement bumps (a local distortion no polynomial model can follow) and a
radial ripple (the fine periodic figure error a turned or moulded asphere can leave, of amplitude a and
wavelength L, finer than any of the bumps):

    r2 = x^2 + y^2,  R = 1 + k1 r2 + k2 r2^2 + k3 r2^3,  q = a sin(2 pi r / L) / r
    xd = x R + 2 p1 x y + p2 (r2 + 2 x^2) + sum_b ax_b g_b + x q,   g_b = exp(-|(x, y) - c_b|^2 / (2 s_b^2))
    yd = y R + p1 (r2 + 2 y^2) + 2 p2 x y + sum_b ay_b g_b + y q

The inverse is solved per point by Newton's method with the analytic Jacobian to 1e-15.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numba
import numpy as np


@dataclass(frozen=True)
class Distortion:
    """k: (k1, k2, k3) radial; p: (p1, p2) tangential; bumps: (n, 5) rows (cx, cy, sigma, ax, ay); ripple:
    (a, L) the radial ripple's amplitude and wavelength (a = 0: none); all in normalised units (a bump
    of amplitude (ax, ay) and width sigma centred at (cx, cy)). A ripple must keep the map monotonic:
    2 pi a / L < 1."""

    k: tuple[float, float, float] = (0.0, 0.0, 0.0)
    p: tuple[float, float] = (0.0, 0.0)
    bumps: np.ndarray = field(default_factory=lambda: np.zeros((0, 5)))
    ripple: tuple[float, float] = (0.0, 1.0)

    def __post_init__(self):
        a, length = self.ripple
        if not (length > 0 and 2 * np.pi * abs(a) < length):
            raise ValueError(f"a ripple needs a wavelength > 0 and 2 pi amplitude < wavelength, got {self.ripple}")

    def _args(self):
        return (np.asarray(self.k, np.float64), np.asarray(self.p, np.float64),
                np.ascontiguousarray(self.bumps, np.float64).reshape(-1, 5),
                np.asarray(self.ripple, np.float64))

    def apply(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Distorted (xd, yd) of ideal normalised coordinates (x, y) (float64 arrays, any shape)."""
        x, y = np.broadcast_arrays(np.asarray(x, np.float64), np.asarray(y, np.float64))
        xd, yd = np.empty(x.size), np.empty(x.size)
        _apply_all(x.ravel(), y.ravel(), *self._args(), xd, yd)
        return xd.reshape(x.shape), yd.reshape(x.shape)

    def invert(self, xd: np.ndarray, yd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Ideal (x, y) whose distorted coordinates are (xd, yd); RuntimeError if Newton fails."""
        xd, yd = np.broadcast_arrays(np.asarray(xd, np.float64), np.asarray(yd, np.float64))
        x, y = np.empty(xd.size), np.empty(xd.size)
        ok = _invert_all(np.ascontiguousarray(xd).ravel(), np.ascontiguousarray(yd).ravel(),
                         *self._args(), x, y)
        if not ok:
            raise RuntimeError("distortion could not be inverted (is it monotonic over the field?)")
        return x.reshape(xd.shape), y.reshape(xd.shape)

    def to_json(self) -> dict:
        return {"k": list(self.k), "p": list(self.p), "bumps": np.asarray(self.bumps).tolist(),
                "ripple": list(self.ripple)}


@numba.njit(cache=True, fastmath=False)
def _forward(x, y, k, p, bumps, ripple):
    r2 = x * x + y * y
    rad = 1.0 + r2 * (k[0] + r2 * (k[1] + r2 * k[2]))
    drad = k[0] + r2 * (2.0 * k[1] + 3.0 * k[2] * r2)          # dR/d(r2)
    xd = x * rad + 2.0 * p[0] * x * y + p[1] * (r2 + 2.0 * x * x)
    yd = y * rad + p[0] * (r2 + 2.0 * y * y) + 2.0 * p[1] * x * y
    j11 = rad + 2.0 * x * x * drad + 2.0 * p[0] * y + 6.0 * p[1] * x
    j12 = 2.0 * x * y * drad + 2.0 * p[0] * x + 2.0 * p[1] * y
    j21 = 2.0 * x * y * drad + 2.0 * p[0] * x + 2.0 * p[1] * y
    j22 = rad + 2.0 * y * y * drad + 6.0 * p[0] * y + 2.0 * p[1] * x
    for b in range(bumps.shape[0]):
        dx = x - bumps[b, 0]
        dy = y - bumps[b, 1]
        s2 = bumps[b, 2] * bumps[b, 2]
        q = (dx * dx + dy * dy) / s2
        if q < 80.0:                                   # exp(-40) ~ 4e-18: beyond double precision
            g = np.exp(-0.5 * q)
            gx = -g * dx / s2
            gy = -g * dy / s2
            xd += bumps[b, 3] * g
            yd += bumps[b, 4] * g
            j11 += bumps[b, 3] * gx
            j12 += bumps[b, 3] * gy
            j21 += bumps[b, 4] * gx
            j22 += bumps[b, 4] * gy
    a = ripple[0]
    if a != 0.0:
        w = 2.0 * np.pi / ripple[1]
        r = np.sqrt(r2)
        t = w * r
        if t > 1e-4:
            q = a * np.sin(t) / r
            dq = a * (w * np.cos(t) * r - np.sin(t)) / (r * r)      # dq/dr
            dqr = dq / r                                             # (dq/dr) / r
        else:                                   # sin(t)/r = w (1 - t^2/6): q' / r -> -a w^3 / 3
            q = a * w * (1.0 - t * t / 6.0)
            dqr = -a * w * w * w / 3.0
        xd += x * q
        yd += y * q
        j11 += q + x * x * dqr
        j12 += x * y * dqr
        j21 += x * y * dqr
        j22 += q + y * y * dqr
    return xd, yd, j11, j12, j21, j22


@numba.njit(cache=True, parallel=True)
def _apply_all(x, y, k, p, bumps, ripple, xd, yd):
    for i in numba.prange(x.size):
        a, b, _, _, _, _ = _forward(x[i], y[i], k, p, bumps, ripple)
        xd[i] = a
        yd[i] = b


@numba.njit(cache=True, parallel=True)
def _invert_all(xd, yd, k, p, bumps, ripple, x, y):
    ok = np.ones(xd.size, np.bool_)
    for i in numba.prange(xd.size):
        xi, yi = xd[i], yd[i]
        done = False
        for _ in range(60):
            fx, fy, j11, j12, j21, j22 = _forward(xi, yi, k, p, bumps, ripple)
            ex, ey = fx - xd[i], fy - yd[i]
            det = j11 * j22 - j12 * j21
            sx = (j22 * ex - j12 * ey) / det
            sy = (j11 * ey - j21 * ex) / det
            xi -= sx
            yi -= sy
            if abs(sx) + abs(sy) < 1e-15 * (1.0 + abs(xi) + abs(yi)):
                done = True
                break
        x[i] = xi
        y[i] = yi
        ok[i] = done and np.isfinite(xi) and np.isfinite(yi)
    return ok.all()

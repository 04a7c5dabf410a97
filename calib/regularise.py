"""Spatial regularisation of the ray field (the seed's tip 1.5: "Gaussian filtering, NURBS").

Neighbouring pixels' rays differ smoothly, while the phase noise of each pixel is independent. Each ray
is represented by its points on two planes (x, y at the nearest and farthest stage positions) and each of
these four fields is fitted locally by a polynomial: a separable Savitzky-Golay filter of degree `order`
over a (2m+1) x (2m+1) window. A local polynomial reproduces any field of that degree exactly, so real
distortion (down to features a few windows wide) is not flattened the way a plain blur would; the noise
variance drops by the filter's centre weight.

Masked pixels are handled by removing a global low-order polynomial first, filling the holes of the small
remainder with its nearest valid value and smoothing the remainder; at the image border the window becomes
one-sided and twice as long (`Smoother.edge_order`, `edge_span`).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy import ndimage
from scipy.signal import savgol_coeffs

# global polynomial removed before local smoothing (its degree in u and v together)
BASE_DEGREE = 3


@dataclass(frozen=True)
class Smoother:
    """half_window m (pixels) and polynomial order of the local fit; edge_order, edge_span: the order
    and the length (in windows) of the one-sided fit used for the m pixels nearest the image border (a
    longer window offsets the noise of an off-centre polynomial evaluation)."""

    half_window: int = 20
    order: int = 3
    edge_order: int = 3
    edge_span: int = 2

    @property
    def window(self) -> int:
        return 2 * self.half_window + 1

    def variance_factor(self) -> float:
        """Noise variance after / before for an interior pixel (the 2-D centre weight)."""
        c = savgol_coeffs(self.window, self.order)[self.half_window]
        return float(c * c)

    def filter_axis(self, a: np.ndarray, axis: int) -> np.ndarray:
        """Local polynomial smoothing of a 2-D array along one axis (float64)."""
        m, n = self.half_window, self.window
        a = np.ascontiguousarray(a if axis == 0 else np.asarray(a).T, np.float64)
        k = savgol_coeffs(n, self.order, use="dot").reshape(-1, 1)
        out = cv2.filter2D(a, -1, k, borderType=cv2.BORDER_REPLICATE)
        ne = min(self.edge_span * n, len(a))     # one-sided windows at both ends, longer to
        for i in range(m):                       # offset the off-centre evaluation's noise
            c = savgol_coeffs(ne, self.edge_order, pos=i, use="dot")
            out[i] = c @ a[:ne]
            out[-1 - i] = c[::-1] @ a[-ne:]
        return out if axis == 0 else out.T


def _base(field: np.ndarray, valid: np.ndarray, degree: int = BASE_DEGREE) -> np.ndarray:
    """Least-squares polynomial of total degree `degree` in the normalised pixel coordinates."""
    h, w = field.shape
    step = max(1, int(np.sqrt(valid.sum() / 20000)))
    vv, uu = np.mgrid[0:h:step, 0:w:step]
    sel = valid[::step, ::step] & np.isfinite(field[::step, ::step])
    terms = [(i, j) for i in range(degree + 1) for j in range(degree + 1 - i)]

    def design(u, v):
        un, vn = 2 * u / max(w - 1, 1) - 1, 2 * v / max(h - 1, 1) - 1
        return np.stack([un ** i * vn ** j for i, j in terms], axis=-1)

    coef, *_ = np.linalg.lstsq(design(uu[sel], vv[sel]), field[::step, ::step][sel], rcond=None)
    un = 2 * np.arange(w) / max(w - 1, 1) - 1
    vn = 2 * np.arange(h) / max(h - 1, 1) - 1
    out = np.zeros((h, w))
    for j in range(degree + 1):                 # sum over j of vn^j * (sum over i of c_ij un^i)
        row = sum(c * un ** i for c, (i, jj) in zip(coef, terms) if jj == j)
        out += np.outer(vn ** j, row)
    return out


def smooth_fields(fields: np.ndarray, valid: np.ndarray, smoother: Smoother) -> tuple[np.ndarray, np.ndarray]:
    """Smooth (K, H, W) fields over the valid pixels.

    Returns (smoothed fields (K, H, W) float64, NaN outside `valid`; local noise (K, H, W) float32: the
    estimated 1-sigma noise of the unsmoothed fields, from the local RMS of raw minus smoothed).
    """
    k, h, w = fields.shape
    if min(h, w) <= smoother.window:
        raise ValueError(f"image ({w}x{h}) is too small for a {smoother.window}-pixel smoothing window")
    fill_idx = None
    if not valid.all():
        fill_idx = ndimage.distance_transform_edt(~valid, return_distances=False, return_indices=True)
    out = np.empty((k, h, w))
    noise = np.empty((k, h, w), np.float32)
    vf = valid.astype(np.float32)
    box = (smoother.window, smoother.window)
    count = cv2.blur(vf, box, borderType=cv2.BORDER_REPLICATE)
    centre_1d = savgol_coeffs(smoother.window, smoother.order)[smoother.half_window]
    keep = 1 - centre_1d ** 2                 # E[(raw - smooth)^2] = sigma^2 (1 - centre weight)
    for i in range(k):
        base = _base(fields[i], valid)
        rem = np.where(valid, fields[i] - base, 0.0)
        if fill_idx is not None:
            rem = rem[fill_idx[0], fill_idx[1]]
        sm = smoother.filter_axis(smoother.filter_axis(rem, 0), 1)
        out[i] = np.where(valid, sm + base, np.nan)
        e2 = np.where(valid, (rem - sm) ** 2, 0.0).astype(np.float32)
        mean_e2 = cv2.blur(e2, box, borderType=cv2.BORDER_REPLICATE) / np.maximum(count, 1e-6)
        noise[i] = np.where(valid, np.sqrt(np.maximum(mean_e2, 0) / keep), np.nan)
    return out, noise

"""B-spline image interpolation with precomputed coefficients (cubic or quintic).

`BSplineImage.from_image` runs the B-spline prefilter once per image (optionally after a small Gaussian
low-pass, which lowers the interpolation bias of sub-pixel DIC); the numba kernels below then evaluate
the interpolant and its gradient at any position. Frame: pixel (column x, row y), integer coordinates are
pixel centres; values are in the image's grey levels. Outside the image the signal is mirrored.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
from numba import njit, prange
from scipy import ndimage

# fast-math flags without 'nnan'/'ninf', so that NaN and infinity checks stay meaningful
FAST = {"nsz", "arcp", "contract", "afn", "reassoc"}
PAD = 4  # coefficient border (pixels) so that every tap of a point inside the image is in the array


@dataclass
class BSplineImage:
    """B-spline coefficients of one image, padded by `PAD` pixels on each side.

    coef: (height + 2*PAD, width + 2*PAD) float32 (ample for grey levels; sums run in float64);
    order: 3 (bicubic) or 5 (biquintic)."""

    coef: np.ndarray
    order: int
    width: int
    height: int
    _pixels: np.ndarray | None = field(default=None, repr=False, compare=False)

    @classmethod
    def from_image(cls, image: np.ndarray, order: int = 3, prefilter_sigma: float = 0.0) -> "BSplineImage":
        """Coefficients of `image` (2-D, any real dtype); `prefilter_sigma` (pixels) > 0 first applies a
        Gaussian low-pass of that standard deviation."""
        if order not in (3, 5):
            raise ValueError(f"B-spline order must be 3 or 5, got {order}")
        img = np.asarray(image, dtype=np.float64)
        if prefilter_sigma > 0:
            img = gaussian_lowpass(img, prefilter_sigma)
        coef = ndimage.spline_filter(img, order=order, mode="mirror", output=np.float32)  # float64 inside
        return cls(np.pad(coef, PAD, mode="reflect"), order, img.shape[1], img.shape[0])

    def pixel_gradients(self) -> np.ndarray:
        """(3, height, width) float32: the interpolant's value, d/dx and d/dy at every pixel centre
        (computed on first use, then kept)."""
        if self._pixels is None:
            self._pixels = _pixel_gradients(self.coef, self.order, self.width, self.height)
        return self._pixels

    def sample(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Interpolated values at positions (x, y) (any equal shapes, pixels); NaN outside the image."""
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        out = _sample_many(self.coef, self.order, x.ravel(), y.ravel(), self.width, self.height)
        return out.reshape(x.shape)

    def gradient(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Gradient (d/dx, d/dy) of the interpolant at (x, y), grey levels per pixel; NaN outside."""
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        gx, gy = _gradient_many(self.coef, self.order, x.ravel(), y.ravel(), self.width, self.height)
        return gx.reshape(x.shape), gy.reshape(x.shape)


def gaussian_lowpass(img: np.ndarray, sigma: float) -> np.ndarray:
    """Gaussian low-pass (standard deviation `sigma` pixels, kernel to 3 sigma, mirrored borders) of a
    float64 image; the same as scipy.ndimage.gaussian_filter(img, sigma, mode='mirror', truncate=3),
    multi-threaded."""
    radius = int(3.0 * sigma + 0.5)
    x = np.arange(-radius, radius + 1, dtype=np.float64)
    k = np.exp(-0.5 * (x / sigma) ** 2)
    k /= k.sum()
    return cv2.sepFilter2D(img, cv2.CV_64F, k, k, borderType=cv2.BORDER_REFLECT_101)


@njit(cache=True, inline="always")
def _beta5(a):
    """Quintic B-spline at |a| (a >= 0)."""
    if a < 1.0:
        a2 = a * a
        return (66.0 - 60.0 * a2 + 30.0 * a2 * a2 - 10.0 * a2 * a2 * a) / 120.0
    if a < 2.0:
        a2 = a * a
        return (51.0 + 75.0 * a - 210.0 * a2 + 150.0 * a2 * a - 45.0 * a2 * a2 + 5.0 * a2 * a2 * a) / 120.0
    if a < 3.0:
        b = 3.0 - a
        return b * b * b * b * b / 120.0
    return 0.0


@njit(cache=True, inline="always")
def _dbeta5(a):
    """Derivative of the quintic B-spline with respect to |a| (a >= 0)."""
    if a < 1.0:
        a2 = a * a
        return (-120.0 * a + 120.0 * a2 * a - 50.0 * a2 * a2) / 120.0
    if a < 2.0:
        a2 = a * a
        return (75.0 - 420.0 * a + 450.0 * a2 - 180.0 * a2 * a + 25.0 * a2 * a2) / 120.0
    if a < 3.0:
        b = 3.0 - a
        return -5.0 * b * b * b * b / 120.0
    return 0.0


@njit(cache=True, inline="always")
def weights(order, t):
    """The 6 tap weights for fraction t in [0, 1); taps at floor + (-2..3). Cubic: the outer two are 0."""
    if order == 3:
        s = 1.0 - t
        t2 = t * t
        t3 = t2 * t
        return (0.0, s * s * s / 6.0, (3.0 * t3 - 6.0 * t2 + 4.0) / 6.0,
                (-3.0 * t3 + 3.0 * t2 + 3.0 * t + 1.0) / 6.0, t3 / 6.0, 0.0)
    return (_beta5(t + 2.0), _beta5(t + 1.0), _beta5(t), _beta5(1.0 - t), _beta5(2.0 - t), _beta5(3.0 - t))


@njit(cache=True, inline="always")
def dweights(order, t):
    """Derivatives with respect to t of `weights(order, t)`."""
    if order == 3:
        s = 1.0 - t
        return (0.0, -0.5 * s * s, 1.5 * t * t - 2.0 * t, -1.5 * t * t + t + 0.5, 0.5 * t * t, 0.0)
    return (_dbeta5(t + 2.0), _dbeta5(t + 1.0), _dbeta5(t), -_dbeta5(1.0 - t), -_dbeta5(2.0 - t),
            -_dbeta5(3.0 - t))


@njit(cache=True, fastmath=FAST, inline="always")
def sample_cubic(coef, x, y):
    """Bicubic B-spline value at (x, y) (image pixels, must be inside the padded array)."""
    xp = x + PAD
    yp = y + PAD
    ix = int(xp)
    iy = int(yp)
    tx = xp - ix
    ty = yp - iy
    sx = 1.0 - tx
    tx2 = tx * tx
    tx3 = tx2 * tx
    wx0 = sx * sx * sx
    wx1 = 3.0 * tx3 - 6.0 * tx2 + 4.0
    wx3 = tx3
    wx2 = 6.0 - wx0 - wx1 - wx3
    sy = 1.0 - ty
    ty2 = ty * ty
    ty3 = ty2 * ty
    wy0 = sy * sy * sy
    wy1 = 3.0 * ty3 - 6.0 * ty2 + 4.0
    wy3 = ty3
    wy2 = 6.0 - wy0 - wy1 - wy3
    a = ix - 1
    b = iy - 1
    v0 = wx0 * coef[b, a] + wx1 * coef[b, a + 1] + wx2 * coef[b, a + 2] + wx3 * coef[b, a + 3]
    v1 = wx0 * coef[b + 1, a] + wx1 * coef[b + 1, a + 1] + wx2 * coef[b + 1, a + 2] + wx3 * coef[b + 1, a + 3]
    v2 = wx0 * coef[b + 2, a] + wx1 * coef[b + 2, a + 1] + wx2 * coef[b + 2, a + 2] + wx3 * coef[b + 2, a + 3]
    v3 = wx0 * coef[b + 3, a] + wx1 * coef[b + 3, a + 1] + wx2 * coef[b + 3, a + 2] + wx3 * coef[b + 3, a + 3]
    return (wy0 * v0 + wy1 * v1 + wy2 * v2 + wy3 * v3) * (1.0 / 36.0)


@njit(cache=True, fastmath=FAST, inline="always")
def sample_any(coef, order, x, y):
    """B-spline value of order 3 or 5 at (x, y)."""
    if order == 3:
        return sample_cubic(coef, x, y)
    xp = x + PAD
    yp = y + PAD
    ix = int(xp)
    iy = int(yp)
    wx = weights(order, xp - ix)
    wy = weights(order, yp - iy)
    v = 0.0
    for j in range(6):
        row = coef[iy - 2 + j]
        s = 0.0
        for i in range(6):
            s += wx[i] * row[ix - 2 + i]
        v += wy[j] * s
    return v


@njit(cache=True, fastmath=FAST, inline="always")
def sample_with_gradient(coef, order, x, y):
    """(value, d/dx, d/dy) of the B-spline of order 3 or 5 at (x, y)."""
    xp = x + PAD
    yp = y + PAD
    ix = int(xp)
    iy = int(yp)
    wx = weights(order, xp - ix)
    wy = weights(order, yp - iy)
    dx = dweights(order, xp - ix)
    dy = dweights(order, yp - iy)
    v = 0.0
    gx = 0.0
    gy = 0.0
    for j in range(6):
        row = coef[iy - 2 + j]
        s = 0.0
        sd = 0.0
        for i in range(6):
            c = row[ix - 2 + i]
            s += wx[i] * c
            sd += dx[i] * c
        v += wy[j] * s
        gx += wy[j] * sd
        gy += dy[j] * s
    return v, gx, gy


@njit(cache=True, parallel=True)
def _sample_many(coef, order, x, y, width, height):
    out = np.empty(x.size)
    for k in prange(x.size):
        if 0.0 <= x[k] <= width - 1 and 0.0 <= y[k] <= height - 1:
            out[k] = sample_any(coef, order, x[k], y[k])
        else:
            out[k] = np.nan
    return out


@njit(cache=True, parallel=True)
def _gradient_many(coef, order, x, y, width, height):
    gx = np.empty(x.size)
    gy = np.empty(x.size)
    for k in prange(x.size):
        if 0.0 <= x[k] <= width - 1 and 0.0 <= y[k] <= height - 1:
            _, gx[k], gy[k] = sample_with_gradient(coef, order, x[k], y[k])
        else:
            gx[k] = np.nan
            gy[k] = np.nan
    return gx, gy


@njit(cache=True, parallel=True)
def _pixel_gradients(coef, order, width, height):
    out = np.empty((3, height, width), np.float32)
    for y in prange(height):
        for x in range(width):
            v, gx, gy = sample_with_gradient(coef, order, float(x), float(y))
            out[0, y, x] = v
            out[1, y, x] = gx
            out[2, y, x] = gy
    return out

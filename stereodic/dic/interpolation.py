"""B-spline image interpolation with precomputed coefficients (cubic or quintic).

`BSplineImage.from_image` computes the B-spline coefficients once per image (optionally after a small
Gaussian low-pass, which lowers the interpolation bias of sub-pixel DIC); the compiled kernels
(stereodic/dic/src/bspline.c, Unser's recursive prefilter with mirrored borders) then evaluate the
interpolant and its gradient at any position. Frame: pixel (column x, row y), integer coordinates are
pixel centres; values are in the image's grey levels. Outside the image the signal is mirrored.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from stereodic.dic import _kernels
from stereodic.dic.kept import kept

PAD = _kernels.PAD  # coefficient border (pixels) so that every tap of a point inside the image is in the array


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
    def from_image(cls, image: np.ndarray, *, order: int = 3, prefilter_sigma: float = 0.0) -> "BSplineImage":
        """The B-spline interpolant of an image.

        Parameters
        ----------
        image : (H, W) array
            Any real dtype.
        order : {3, 5}
            Bicubic or biquintic.
        prefilter_sigma : float
            > 0: first a Gaussian low-pass of that standard deviation, pixels.

        Returns
        -------
        bspline : BSplineImage
            ``coef`` (H + 2 PAD, W + 2 PAD) float32 coefficients, the order and the image size. That of a
            read-only image is kept while the image lives and given again for it (`stereodic.dic.kept`: a
            run's rectified reference pair is interpolated by the rig check, its region and the run).
        """
        if order not in (3, 5):
            raise ValueError(f"B-spline order must be 3 or 5, got {order}")
        if isinstance(image, np.ndarray) and not image.flags.writeable:
            return kept(("bspline", id(image), order, float(prefilter_sigma)), (image,),
                        lambda: cls._computed(image, order, prefilter_sigma))
        return cls._computed(image, order, prefilter_sigma)

    @classmethod
    def _computed(cls, image: np.ndarray, order: int, prefilter_sigma: float) -> "BSplineImage":
        """`from_image` computed."""
        img = np.ascontiguousarray(image, dtype=np.float64)
        if prefilter_sigma > 0:
            img = gaussian_lowpass(img, prefilter_sigma)
        coef = np.empty((img.shape[0] + 2 * PAD, img.shape[1] + 2 * PAD), np.float32)
        _kernels.spline_coefficients(img, order, coef)  # float64 inside, float32 between the two axes
        return cls(coef, order, img.shape[1], img.shape[0])

    def pixel_gradients(self) -> np.ndarray:
        """(3, height, width) float32: the interpolant's value, d/dx and d/dy at every pixel centre
        (computed on first use, then kept)."""
        if self._pixels is None:
            self._pixels = np.empty((3, self.height, self.width), np.float32)
            _kernels.pixel_gradients(self.coef, self.order, self.width, self.height, self._pixels)
        return self._pixels

    def sample(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Interpolated values at positions (x, y) (any equal shapes, pixels); NaN outside the image."""
        x, y = np.broadcast_arrays(np.asarray(x, np.float64), np.asarray(y, np.float64))
        out = np.empty(x.shape)
        _kernels.sample(self.coef, self.order, self.width, self.height, np.ascontiguousarray(x).ravel(),
                        np.ascontiguousarray(y).ravel(), out.ravel())
        return out

    def gradient(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Gradient (d/dx, d/dy) of the interpolant at (x, y), grey levels per pixel; NaN outside."""
        x, y = np.broadcast_arrays(np.asarray(x, np.float64), np.asarray(y, np.float64))
        gx, gy = np.empty(x.shape), np.empty(x.shape)
        _kernels.gradient(self.coef, self.order, self.width, self.height, np.ascontiguousarray(x).ravel(),
                          np.ascontiguousarray(y).ravel(), gx.ravel(), gy.ravel())
        return gx, gy


def gaussian_lowpass(img: np.ndarray, sigma: float) -> np.ndarray:
    """Gaussian low-pass (standard deviation `sigma` pixels, kernel to 3 sigma, mirrored borders) of a
    float64 image; the same as scipy.ndimage.gaussian_filter(img, sigma, mode='mirror', truncate=3),
    multi-threaded."""
    radius = int(3.0 * sigma + 0.5)
    x = np.arange(-radius, radius + 1, dtype=np.float64)
    k = np.exp(-0.5 * (x / sigma) ** 2)
    k /= k.sum()
    return cv2.sepFilter2D(img, cv2.CV_64F, k, k, borderType=cv2.BORDER_REFLECT_101)

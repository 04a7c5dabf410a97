"""The grid of points where DIC measures: every `step` pixels inside a region of interest and a mask,
keeping whole subsets inside the image. Positions are integer pixels (x = column, y = row)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Grid:
    """Point (row i, column j) sits at (xs[j], ys[i]); `active[i, j]` says it is measured."""

    xs: np.ndarray  # (nx,) float64, pixels
    ys: np.ndarray  # (ny,) float64, pixels
    active: np.ndarray  # (ny, nx) bool

    @property
    def shape(self) -> tuple[int, int]:
        return self.active.shape

    def points(self) -> tuple[np.ndarray, np.ndarray]:
        """Flat (x, y) of every grid node, row-major (length ny * nx)."""
        X, Y = np.meshgrid(self.xs, self.ys)
        return X.ravel().copy(), Y.ravel().copy()


def make_grid(width: int, height: int, *, subset: int, step: int,
              roi: tuple[int, int, int, int] | None = None, mask: np.ndarray | None = None) -> Grid:
    """The points where DIC measures, `step` pixels apart, whose subsets lie inside the image.

    Parameters
    ----------
    width, height : int
        The image size, pixels.
    subset : int
        The subset side, pixels: points within subset // 2 of the border are left out.
    step : int
        The grid spacing, pixels.
    roi : (x0, y0, x1, y1) int, optional
        Inclusive pixel bounds of the region of interest; None: the whole image.
    mask : (height, width) bool, optional
        Keep only the points whose centre pixel is True (the others are inactive).

    Returns
    -------
    grid : Grid
        ``xs`` (nx,) and ``ys`` (ny,) float64 integer pixel positions (x = column, y = row) and
        ``active`` (ny, nx) bool.
    """
    half = subset // 2
    x0, y0, x1, y1 = roi if roi is not None else (0, 0, width - 1, height - 1)
    x0, y0 = max(x0, half), max(y0, half)
    x1, y1 = min(x1, width - 1 - half), min(y1, height - 1 - half)
    xs = np.arange(x0, x1 + 1, step, dtype=np.float64)
    ys = np.arange(y0, y1 + 1, step, dtype=np.float64)
    active = np.ones((ys.size, xs.size), bool)
    if mask is not None:
        active &= mask[np.ix_(ys.astype(int), xs.astype(int))]
    return Grid(xs, ys, active)

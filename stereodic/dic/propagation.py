"""Reliability-guided propagation of initial guesses over a grid of points, solved in parallel batches.

Points sit on a (ny, nx) grid (index k = row * nx + col) at any positions (xs[k], ys[k]) in the
reference image. From the points already solved well (seeds, or guesses from a previous image), the
pending 4-neighbours enter a priority queue keyed by the ZNCC of the neighbour that queued them. The
256 most reliable candidates are taken at a time; each starts from the warp of its best solved neighbour
(highest ZNCC), moved to its own position, and the batch is solved in parallel. This follows the order
of reliability-guided DIC (Pan, Appl. Opt. 48, 2009: the best-correlated region grows first, so
doubtful points are reached last and from their best neighbour) while keeping both cores busy. Points
that fail (low ZNCC, no texture, divergence) are flagged and do not propagate.

On large grids the propagation first runs on a coarse lattice (every `stride`-th row and column);
`guesses_from_lattice` then gives every other point a blend of its lattice corners' warps, so that all
of them are solved in one parallel sweep (few synchronisations); only the points that fail there go
through fine propagation again.

The kernels are compiled (stereodic/dic/src/propagation.c):
`propagate(ref, refpix, dfm, order, width, height, xs, ys, nx, stride, half, P, fit, max_iter, tol,
min_zncc, zncc, iters, status, done)` solves every pending point reachable from the solved good ones
(done[k] = 1 and status OK), moving `stride` grid points at a time; done (int8 per point: 0 pending, 1
solved or not a point), P, zncc, iters and status are updated (arguments as `icgn.solve_points`);
returns the number of points solved.
"""

from __future__ import annotations

import numpy as np

from stereodic.dic import _kernels
from stereodic.dic._kernels import propagate

__all__ = ["guesses_from_lattice", "propagate"]


def guesses_from_lattice(xs: np.ndarray, ys: np.ndarray, nx: int, stride: int, P: np.ndarray, zncc: np.ndarray,
                         status: np.ndarray, done: np.ndarray) -> np.ndarray:
    """Initial warps P for the pending points from the solved lattice (rows and columns multiple of
    `stride`): the bilinear blend, over the good corners of the point's lattice cell, of their warps
    moved to the point's position. Returns the indices (int64) of the points that got a guess (still
    pending)."""
    out = np.empty(xs.size, np.int64)
    return out[:_kernels.guesses_from_lattice(xs, ys, nx, stride, P, zncc, status, done, out)]

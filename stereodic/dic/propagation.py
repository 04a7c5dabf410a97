"""Reliability-guided propagation of initial guesses over a grid of points, solved in parallel batches.

Points sit on a (ny, nx) grid (index k = row * nx + col) at any positions (xs[k], ys[k]) in the
reference image. From the points already solved well (seeds, or guesses from a previous image), the
pending 4-neighbours enter a priority queue keyed by the ZNCC of the neighbour that queued them. The
`batch` most reliable candidates are taken at a time; each starts from the warp of its best solved
neighbour (highest ZNCC), moved to its own position, and the batch is solved in parallel. This follows
the order of reliability-guided DIC (the best-correlated region grows first, so doubtful points are
reached last and from their best neighbour) while keeping both cores busy. Points that fail (low ZNCC,
no texture, divergence) are flagged and do not propagate.

On large grids the propagation first runs on a coarse lattice (every `stride`-th row and column);
`guesses_from_lattice` then gives every other point a blend of its lattice corners' warps, so that all
of them are solved in one parallel sweep (few synchronisations); only the points that fail there go
through fine propagation again.
"""

from __future__ import annotations

import heapq

import numpy as np
from numba import njit, prange

from stereodic.dic.icgn import OK, shift_warp, solve_point

BATCH = 256  # points solved in parallel per step: enough for the threads, small against the front


@njit(cache=True, parallel=True)
def _solve_batch(ref, refpix, dfm, order, width, height, xs, ys, half, P, fit, max_iter, tol, min_zncc,
                 zncc, iters, status, batch):
    for t in prange(batch.size):
        k = batch[t]
        z, it, st = solve_point(ref, refpix, dfm, order, width, height, xs[k], ys[k], half, P[k], fit,
                                max_iter, tol, min_zncc)
        zncc[k] = z
        iters[k] = it
        status[k] = st


@njit(cache=True)
def _push_neighbours(heap, k, nx, ny, stride, done, key):
    r = k // nx
    c = k - r * nx
    for d in range(4):
        rr = r + stride * ((d == 0) - (d == 1))
        cc = c + stride * ((d == 2) - (d == 3))
        if 0 <= rr < ny and 0 <= cc < nx:
            q = rr * nx + cc
            if done[q] == 0:
                heapq.heappush(heap, (-key, q))


@njit(cache=True)
def propagate(ref, refpix, dfm, order, width, height, xs, ys, nx, stride, half, P, fit, max_iter, tol,
              min_zncc, zncc, iters, status, done):
    """Solve every pending point reachable from the solved good ones (done[k] = 1 and status OK),
    moving `stride` grid points at a time (stride > 1: a coarse lattice first, see guesses_from_lattice).

    done: int8 per point, 0 pending, 1 solved or not a point (updated). P, zncc, iters, status are
    updated for every point solved here. Returns the number of points solved."""
    npts = xs.size
    ny = npts // nx
    heap = [(0.0, np.int64(0))]
    heap.pop()
    for k in range(npts):
        if done[k] == 1 and status[k] == OK:
            _push_neighbours(heap, k, nx, ny, stride, done, zncc[k])
    batch = np.empty(BATCH, np.int64)
    solved = 0
    while len(heap) > 0:
        nb = 0
        while len(heap) > 0 and nb < BATCH:
            _, q = heapq.heappop(heap)
            if done[q] == 0:
                done[q] = 2  # taken
                batch[nb] = q
                nb += 1
        for t in range(nb):
            q = batch[t]
            r = q // nx
            c = q - r * nx
            best = -1
            bestz = -2.0
            for d in range(4):
                rr = r + stride * ((d == 0) - (d == 1))
                cc = c + stride * ((d == 2) - (d == 3))
                if 0 <= rr < ny and 0 <= cc < nx:
                    s = rr * nx + cc
                    if done[s] == 1 and status[s] == OK and zncc[s] > bestz:
                        bestz = zncc[s]
                        best = s
            shift_warp(P[best], xs[q] - xs[best], ys[q] - ys[best], P[q])
        _solve_batch(ref, refpix, dfm, order, width, height, xs, ys, half, P, fit, max_iter, tol, min_zncc,
                     zncc, iters, status, batch[:nb])
        for t in range(nb):
            q = batch[t]
            done[q] = 1
            if status[q] == OK:
                _push_neighbours(heap, q, nx, ny, stride, done, zncc[q])
        solved += nb
    return solved


@njit(cache=True)
def guesses_from_lattice(xs, ys, nx, stride, P, zncc, status, done):
    """Initial warps for the pending points from the solved lattice (rows and columns multiple of
    `stride`): the bilinear blend, over the good corners of the point's lattice cell, of their warps
    moved to the point's position. Returns the indices of the points that got a guess (still pending)."""
    npts = xs.size
    ny = npts // nx
    n = P.shape[1]
    out = np.empty(npts, np.int64)
    moved = np.empty(n)
    count = 0
    for q in range(npts):
        if done[q] != 0:
            continue
        r = q // nx
        c = q - r * nx
        r0 = (r // stride) * stride
        c0 = (c // stride) * stride
        wsum = 0.0
        for rr in (r0, r0 + stride):
            for cc in (c0, c0 + stride):
                if rr < ny and cc < nx:
                    s = rr * nx + cc
                    if done[s] == 1 and status[s] == OK:
                        w = (1.0 - abs(rr - r) / stride) * (1.0 - abs(cc - c) / stride) + 1e-6
                        shift_warp(P[s], xs[q] - xs[s], ys[q] - ys[s], moved)
                        if wsum == 0.0:
                            P[q, :] = 0.0
                        for a in range(n):
                            P[q, a] += w * moved[a]
                        wsum += w
        if wsum > 0.0:
            for a in range(n):
                P[q, a] /= wsum
            out[count] = q
            count += 1
    return out[:count]

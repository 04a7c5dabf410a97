/* Solving many points, and reliability-guided propagation over a grid (see propagation.c). */
#ifndef STEREODIC_PROPAGATION_H
#define STEREODIC_PROPAGATION_H

#include <stdint.h>

#include "icgn.h"

/* The results of a set of points: warps P (N, nparams), zncc, iterations and status (N each). */
typedef struct {
    const double *xs, *ys;
    double *P, *zncc;
    int32_t *iters;
    int8_t *status;
} Points;

/* Solve points idx[0..count) (all points 0..count-1 if idx is NULL) in parallel from the warps in P.
 * Returns 0, or -1 if out of memory. */
int solve_many(const Problem *pb, Points *pts, const int64_t *idx, long count);

/* Reference status of points 0..count-1 into status. Returns 0, or -1 if out of memory. */
int status_many(const Problem *pb, const double *xs, const double *ys, long count, int8_t *status);

/* Propagation over an (npts / nx) x nx grid, `stride` grid points at a time; done: 0 pending, 1 solved
 * or not a point. Returns the number of points solved, or -1 if out of memory. */
long propagate(const Problem *pb, Points *pts, long npts, long nx, long stride, int8_t *done);

/* Initial warps for the pending points from the solved lattice (rows and columns multiple of `stride`):
 * the bilinear blend, over the good corners of the point's lattice cell, of their warps moved to the
 * point's position. Their indices go to out; returns their number. */
long guesses_from_lattice(const Points *pts, int nparams, long npts, long nx, long stride, const int8_t *done,
                          int64_t *out);

#endif

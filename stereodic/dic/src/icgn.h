/* IC-GN registration of square subsets (see icgn.c for the method and the warp parameters). */
#ifndef STEREODIC_ICGN_H
#define STEREODIC_ICGN_H

#include "bspline.h"

enum { OK = 0, NO_TEXTURE = 1, OUTSIDE = 2, DIVERGED = 3, LOW_ZNCC = 4 };

/* What one registration needs besides the point: both images, the reference's pixel values and
 * gradients ((3, height, width) float32, for points on pixel centres), the subset and the stopping rule. */
typedef struct {
    Spline ref, dfm;
    const float *refpix;
    int half, nparams, max_iter;
    double tol, min_zncc;
    const double *fit;   /* (6, 9) quadratic composition fit (icgn.quadratic_fit_matrix) */
} Problem;

/* Per-thread scratch space of one registration. */
typedef struct {
    double *J, *fc, *H, *JS, *JF, *SJg, *rhs, *dp;
} Work;

int work_alloc(Work *w, int half, int nparams);
void work_free(Work *w);

/* The warp p of a point re-expressed for a point offset by (ox, oy) pixels, into out. */
void shift_warp(const double *p, int n, double ox, double oy, double *out);

/* Register the subset centred on (x0, y0); p: the initial warp, refined in place. Returns the status;
 * *zncc and *iters are set. */
int solve_point(const Problem *pb, Work *w, double x0, double y0, double *p, double *zncc, int *iters);

/* Whether the reference subset at (x0, y0) can be registered at all: OK, NO_TEXTURE or OUTSIDE. */
int reference_status(const Problem *pb, Work *w, double x0, double y0);

#endif

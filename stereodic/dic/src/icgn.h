/* IC-GN registration of square subsets (see icgn.c for the method and the warp parameters). */
#ifndef STEREODIC_ICGN_H
#define STEREODIC_ICGN_H

#include <stdint.h>

#include "bspline.h"

enum { OK = 0, NO_TEXTURE = 1, OUTSIDE = 2, DIVERGED = 3, LOW_ZNCC = 4 };

/* What one registration needs besides the point: both images, the reference's pixel values and
 * gradients ((3, height, width) float32, for points on pixel centres), the subset and the stopping rule;
 * optionally the reference side of the subsets computed beforehand (`reference_data`): cache (M,
 * reference_width(nparams)) float64, the row of point k being rows[k] (k itself if rows is NULL). */
typedef struct {
    Spline ref, dfm;
    const float *refpix;
    int half, nparams, max_iter;
    double tol, min_zncc;
    const double *fit;   /* (6, 9) quadratic composition fit (icgn.quadratic_fit_matrix) */
    const double *cache;
    const int64_t *rows;
} Problem;

/* Per-thread scratch space of one registration. J: for affine warps and bicubic interpolation, three
 * planes gx, gy, f of the subset's pixels (row-major, `plane` values apart, each followed by zeros);
 * else one row of `lanes` values per subset pixel: the n steepest-descent values, f, 1, zeros. f, from
 * J + value, `lanes` apart, is the reference value (zero-mean once prepared). SJg: sum J g (n), sum
 * fc g, sum g. */
typedef struct {
    double *J, *H, *JS, *JF, *SJg, *rhs, *dp;
    int lanes;
    long plane, value;
} Work;

int work_alloc(Work *w, const Problem *pb);
void work_free(Work *w);

/* The warp p of a point re-expressed for a point offset by (ox, oy) pixels, into out. */
void shift_warp(const double *p, int n, double ox, double oy, double *out);

/* Values per point of the reference side of a subset (`reference_data`): status, x0, y0, the mean
 * reference value, the norm of the zero-mean values, JS (n), JF (n), the Hessian's Cholesky factor (n x
 * n, lower triangle). */
enum { REF_STATUS, REF_X, REF_Y, REF_MEAN, REF_NORM, REF_HEAD };
static inline long reference_width(int nparams)
{
    return REF_HEAD + 2L * nparams + (long)nparams * nparams;
}

/* The reference side of the subset centred on (x0, y0) into row (reference_width values); returns its
 * status (OK, NO_TEXTURE or OUTSIDE). */
int reference_data(const Problem *pb, Work *w, double x0, double y0, double *row);

/* Register the subset centred on (x0, y0); p: the initial warp, refined in place; cached: its row of
 * reference data (the same numbers as computing them here), or NULL. Returns the status; *zncc and *iters
 * are set. */
int solve_point(const Problem *pb, Work *w, double x0, double y0, const double *cached, double *p, double *zncc,
                int *iters);

/* Whether the reference subset at (x0, y0) can be registered at all: OK, NO_TEXTURE or OUTSIDE. */
int reference_status(const Problem *pb, Work *w, double x0, double y0);

#endif

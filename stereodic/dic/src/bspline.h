/* B-spline interpolation of an image from its padded coefficients (see bspline.c).
 *
 * Frame: pixel (column x, row y), integer coordinates are pixel centres. A coefficient array covers the
 * image plus PAD pixels on every side, row-major, `stride` = width + 2 * PAD values per row; every tap of
 * a position within half a pixel of the image lies inside it. */
#ifndef STEREODIC_BSPLINE_H
#define STEREODIC_BSPLINE_H

#include <string.h>

#define PAD 4

typedef struct {
    const float *c;   /* (height + 2 PAD) x stride coefficients */
    long stride;
    int width, height, order;   /* image size in pixels; order 3 (bicubic) or 5 (biquintic) */
} Spline;

/* Vectors of 4 lanes (GCC/Clang vector extensions: the target's SIMD instructions, or scalar code). */
typedef double v4d __attribute__((vector_size(32)));
typedef float v4f __attribute__((vector_size(16)));

static inline v4d load4f(const float *p)   /* 4 float32 from p (any alignment) as doubles */
{
    v4f f;
    memcpy(&f, p, sizeof f);
    return __builtin_convertvector(f, v4d);
}

static inline v4d load4d(const double *p)   /* 4 doubles from p (any alignment) */
{
    v4d v;
    memcpy(&v, p, sizeof v);
    return v;
}

/* Vectors of 8 lanes, the same way. */
typedef double v8d __attribute__((vector_size(64)));
typedef float v8f __attribute__((vector_size(32)));
typedef long v8l __attribute__((vector_size(64)));

static inline v8d load8f(const float *p)   /* 8 float32 from p (any alignment) as doubles */
{
    v8f f;
    memcpy(&f, p, sizeof f);
    return __builtin_convertvector(f, v8d);
}

static inline v8d load8d(const double *p)   /* 8 doubles from p (any alignment) */
{
    v8d v;
    memcpy(&v, p, sizeof v);
    return v;
}

static inline double sum8(v8d v)   /* the sum of the 8 lanes */
{
    return ((v[0] + v[1]) + (v[2] + v[3])) + ((v[4] + v[5]) + (v[6] + v[7]));
}

/* 36 times the bicubic value at (x, y) (the weights' common factor 1/36 left to the caller): the 4 x 4
 * taps as four rows of 4 lanes. The weights (times 6) of the taps at floor - 1 .. floor + 2 for the
 * fraction t: (1 - t)^3, 3t^3 - 6t^2 + 4, -3t^3 + 3t^2 + 3t + 1, t^3. */
static inline double sample_cubic36(const float *c, long stride, double x, double y)
{
    const double xp = x + PAD, yp = y + PAD;
    const long ix = (long)xp, iy = (long)yp;
    const double tx = xp - ix, ty = yp - iy;
    const v4d b0 = {1.0, 4.0, 1.0, 0.0}, b1 = {-3.0, 0.0, 3.0, 0.0}, b2 = {3.0, -6.0, 3.0, 0.0},
              b3 = {-1.0, 3.0, -3.0, 1.0};
    const v4d wx = ((b3 * tx + b2) * tx + b1) * tx + b0;
    const v4d wy = ((b3 * ty + b2) * ty + b1) * ty + b0;
    const float *r = c + (iy - 1) * stride + (ix - 1);
    const v4d acc = (wy[0] * load4f(r) + wy[1] * load4f(r + stride) + wy[2] * load4f(r + 2 * stride)
                     + wy[3] * load4f(r + 3 * stride)) * wx;
    return (acc[0] + acc[1]) + (acc[2] + acc[3]);
}

/* The lanes of `a` where `m` is all ones (-1), of `b` elsewhere (m 0): a bitwise select, exact. */
static inline v8d select8(v8l m, v8d a, v8d b)
{
    return (v8d)(((v8l)a & m) | ((v8l)b & ~m));
}

/* sample_cubic36 of eight samples at once, lanes = samples: (x0 + a * (d + q), y0 + b * (d + q)) for
 * q = 0..7 (the positions along a row of an affine subset). Where the samples' taps share the same 4
 * rows and start on 8 consecutive columns (nearly every group when the subset is not stretched, sheared
 * or rotated much) each tap is one load of 8 columns; where the lanes' first tap row or column drifts by
 * one across the group (a subset stretched or turned by up to 1/7: a stereo match's foreshortening, a
 * large strain), 5 x 5 such loads cover every lane's taps and each lane selects its own. Returns 0,
 * without writing out, when the drift is larger. With AVX-512 a lane per sample; on narrower SIMD the
 * compiler splits the vectors. */
static inline int sample_cubic36_row8(const float *c, long stride, double x0, double y0, double a, double b, double d,
                                      v8d *out)
{
    const v8d q = {0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0};
    const v8l ql = {0, 1, 2, 3, 4, 5, 6, 7};
    const v8d xp = x0 + a * (d + q) + PAD, yp = y0 + b * (d + q) + PAD;
    const long ix = (long)xp[0], iy = (long)yp[0];
    /* each lane's first tap column and row relative to lane 0's: 0, or one on (either way) across the group */
    const v8l sx = __builtin_convertvector(xp, v8l) - ql - ix, sy = __builtin_convertvector(yp, v8l) - iy;
    const long xlo = sx[7] < 0 ? sx[7] : 0, ylo = sy[7] < 0 ? sy[7] : 0;   /* the lower of the two, if any */
    const v8l on_x = sx - xlo, on_y = sy - ylo;
    long any = 0, far = 0;
    for (int k = 0; k < 8; ++k) {
        any |= sx[k] | sy[k];
        far |= (on_x[k] | on_y[k]) & ~1L;     /* a lane not at the first's or one on from it */
    }
    if (far)
        return 0;
    const v8d tx = xp - (double)ix - q - __builtin_convertvector(sx, v8d), ty = yp - (double)iy - __builtin_convertvector(sy, v8d);
    /* the weight of each tap, per lane (the rows of sample_cubic36's b0..b3) */
    const v8d wx0 = ((-tx + 3.0) * tx - 3.0) * tx + 1.0, wx1 = ((3.0 * tx - 6.0) * tx) * tx + 4.0;
    const v8d wx2 = ((-3.0 * tx + 3.0) * tx + 3.0) * tx + 1.0, wx3 = tx * tx * tx;
    const v8d wy0 = ((-ty + 3.0) * ty - 3.0) * ty + 1.0, wy1 = ((3.0 * ty - 6.0) * ty) * ty + 4.0;
    const v8d wy2 = ((-3.0 * ty + 3.0) * ty + 3.0) * ty + 1.0, wy3 = ty * ty * ty;
    if (!any) {
        const float *r = c + (iy - 1) * stride + (ix - 1);
        v8d col[4];
        for (int k = 0; k < 4; ++k)
            col[k] = wy0 * load8f(r + k) + wy1 * load8f(r + stride + k) + wy2 * load8f(r + 2 * stride + k)
                     + wy3 * load8f(r + 3 * stride + k);
        *out = (wx0 * col[0] + wx1 * col[1]) + (wx2 * col[2] + wx3 * col[3]);
        return 1;
    }
    /* a lane whose taps start a column (row) later than the group's first takes the load one further */
    const v8l later_x = -on_x, later_y = -on_y;
    const float *r = c + (iy + ylo - 1) * stride + (ix + xlo - 1);
    v8d row[5];
    for (int k = 0; k < 5; ++k, r += stride) {
        const v8d t0 = load8f(r), t1 = load8f(r + 1), t2 = load8f(r + 2), t3 = load8f(r + 3), t4 = load8f(r + 4);
        row[k] = (wx0 * select8(later_x, t1, t0) + wx1 * select8(later_x, t2, t1))
                 + (wx2 * select8(later_x, t3, t2) + wx3 * select8(later_x, t4, t3));
    }
    *out = (wy0 * select8(later_y, row[1], row[0]) + wy1 * select8(later_y, row[2], row[1]))
           + (wy2 * select8(later_y, row[3], row[2]) + wy3 * select8(later_y, row[4], row[3]));
    return 1;
}

/* Bicubic value at (x, y). */
static inline double sample_cubic(const float *c, long stride, double x, double y)
{
    return sample_cubic36(c, stride, x, y) * (1.0 / 36.0);
}

/* Value of the B-spline of order 3 or 5 at (x, y). */
double sample_any(const Spline *s, double x, double y);

/* Value and gradient (d/dx, d/dy) at (x, y). */
void sample_with_gradient(const Spline *s, double x, double y, double *v, double *gx, double *gy);

/* Coefficients of a (height x width) float64 image, mirrored at its borders, into `out`
 * ((height + 2 PAD) x (width + 2 PAD) float32, borders reflected). Returns 0, or -1 if out of memory. */
int spline_coefficients(const double *img, int height, int width, int order, float *out);

/* (3, height, width) float32: value, d/dx, d/dy at every pixel centre. */
void pixel_gradients(const Spline *s, float *out);

#endif

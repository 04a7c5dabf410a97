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

/* sample_cubic36 of eight samples at once, lanes = samples: (x0 + a * (d + q), y0 + b * (d + q)) for
 * q = 0..7 (the positions along a row of an affine subset), if their taps share the same 4 rows and
 * start on 8 consecutive columns (true of nearly every group when the subset is not stretched or
 * rotated much); returns 0 otherwise, without writing out. With AVX-512 a lane per sample; on narrower
 * SIMD the compiler splits the vectors. */
static inline int sample_cubic36_row8(const float *c, long stride, double x0, double y0, double a, double b, double d,
                                      v8d *out)
{
    const v8d q = {0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0};
    const v8l ql = {0, 1, 2, 3, 4, 5, 6, 7};
    const v8d xp = x0 + a * (d + q) + PAD, yp = y0 + b * (d + q) + PAD;
    const long ix = (long)xp[0], iy = (long)yp[0];
    const v8l off = (__builtin_convertvector(xp, v8l) - ql - ix) | (__builtin_convertvector(yp, v8l) - iy);
    long any = 0;
    for (int k = 0; k < 8; ++k)
        any |= off[k];
    if (any)
        return 0;
    const v8d tx = xp - (double)ix - q, ty = yp - (double)iy;
    /* the weight of each tap, per lane (the rows of sample_cubic36's b0..b3) */
    const v8d wx0 = ((-tx + 3.0) * tx - 3.0) * tx + 1.0, wx1 = ((3.0 * tx - 6.0) * tx) * tx + 4.0;
    const v8d wx2 = ((-3.0 * tx + 3.0) * tx + 3.0) * tx + 1.0, wx3 = tx * tx * tx;
    const v8d wy0 = ((-ty + 3.0) * ty - 3.0) * ty + 1.0, wy1 = ((3.0 * ty - 6.0) * ty) * ty + 4.0;
    const v8d wy2 = ((-3.0 * ty + 3.0) * ty + 3.0) * ty + 1.0, wy3 = ty * ty * ty;
    const float *r = c + (iy - 1) * stride + (ix - 1);
    v8d col[4];
    for (int k = 0; k < 4; ++k)
        col[k] = wy0 * load8f(r + k) + wy1 * load8f(r + stride + k) + wy2 * load8f(r + 2 * stride + k)
                 + wy3 * load8f(r + 3 * stride + k);
    *out = (wx0 * col[0] + wx1 * col[1]) + (wx2 * col[2] + wx3 * col[3]);
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

/* B-spline interpolation of an image from its padded coefficients (see bspline.c).
 *
 * Frame: pixel (column x, row y), integer coordinates are pixel centres. A coefficient array covers the
 * image plus PAD pixels on every side, row-major, `stride` = width + 2 * PAD values per row; every tap of
 * a position within half a pixel of the image lies inside it. */
#ifndef STEREODIC_BSPLINE_H
#define STEREODIC_BSPLINE_H

#define PAD 4

typedef struct {
    const float *c;   /* (height + 2 PAD) x stride coefficients */
    long stride;
    int width, height, order;   /* image size in pixels; order 3 (bicubic) or 5 (biquintic) */
} Spline;

/* Bicubic value at (x, y). */
static inline double sample_cubic(const float *c, long stride, double x, double y)
{
    const double xp = x + PAD, yp = y + PAD;
    const long ix = (long)xp, iy = (long)yp;
    const double tx = xp - ix, ty = yp - iy;
    const double sx = 1.0 - tx, tx2 = tx * tx, tx3 = tx2 * tx;
    const double wx0 = sx * sx * sx, wx1 = 3.0 * tx3 - 6.0 * tx2 + 4.0, wx3 = tx3;
    const double wx2 = 6.0 - wx0 - wx1 - wx3;
    const double sy = 1.0 - ty, ty2 = ty * ty, ty3 = ty2 * ty;
    const double wy0 = sy * sy * sy, wy1 = 3.0 * ty3 - 6.0 * ty2 + 4.0, wy3 = ty3;
    const double wy2 = 6.0 - wy0 - wy1 - wy3;
    const float *r = c + (iy - 1) * stride + (ix - 1);
    const double v0 = wx0 * r[0] + wx1 * r[1] + wx2 * r[2] + wx3 * r[3];
    r += stride;
    const double v1 = wx0 * r[0] + wx1 * r[1] + wx2 * r[2] + wx3 * r[3];
    r += stride;
    const double v2 = wx0 * r[0] + wx1 * r[1] + wx2 * r[2] + wx3 * r[3];
    r += stride;
    const double v3 = wx0 * r[0] + wx1 * r[1] + wx2 * r[2] + wx3 * r[3];
    return (wy0 * v0 + wy1 * v1 + wy2 * v2 + wy3 * v3) * (1.0 / 36.0);
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

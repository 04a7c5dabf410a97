/* B-spline image interpolation, cubic or quintic (Unser, Aldroubi & Eden, "B-spline signal processing",
 * IEEE Trans. Signal Processing 41, 1993): the coefficients come from a recursive (causal + anti-causal)
 * filter per line with whole-sample mirror boundaries, as scipy.ndimage.spline_filter(mode="mirror")
 * computes them; the interpolant then passes through every pixel value. */
#include <math.h>
#include <stdlib.h>

#include "bspline.h"

static double beta5(double a)   /* quintic B-spline at |a| */
{
    if (a < 1.0) {
        const double a2 = a * a;
        return (66.0 - 60.0 * a2 + 30.0 * a2 * a2 - 10.0 * a2 * a2 * a) / 120.0;
    }
    if (a < 2.0) {
        const double a2 = a * a;
        return (51.0 + 75.0 * a - 210.0 * a2 + 150.0 * a2 * a - 45.0 * a2 * a2 + 5.0 * a2 * a2 * a) / 120.0;
    }
    if (a < 3.0) {
        const double b = 3.0 - a;
        return b * b * b * b * b / 120.0;
    }
    return 0.0;
}

static double dbeta5(double a)  /* its derivative with respect to |a| */
{
    if (a < 1.0) {
        const double a2 = a * a;
        return (-120.0 * a + 120.0 * a2 * a - 50.0 * a2 * a2) / 120.0;
    }
    if (a < 2.0) {
        const double a2 = a * a;
        return (75.0 - 420.0 * a + 450.0 * a2 - 180.0 * a2 * a + 25.0 * a2 * a2) / 120.0;
    }
    if (a < 3.0) {
        const double b = 3.0 - a;
        return -5.0 * b * b * b * b / 120.0;
    }
    return 0.0;
}

/* The 6 tap weights (taps at floor + (-2..3)) and their derivatives for fraction t in [0, 1). */
static inline void weights(int order, double t, double w[6], double d[6])
{
    if (order == 3) {
        const double s = 1.0 - t, t2 = t * t, t3 = t2 * t;
        w[0] = 0.0; w[1] = s * s * s / 6.0; w[2] = (3.0 * t3 - 6.0 * t2 + 4.0) / 6.0;
        w[3] = (-3.0 * t3 + 3.0 * t2 + 3.0 * t + 1.0) / 6.0; w[4] = t3 / 6.0; w[5] = 0.0;
        if (d) {
            d[0] = 0.0; d[1] = -0.5 * s * s; d[2] = 1.5 * t2 - 2.0 * t; d[3] = -1.5 * t2 + t + 0.5;
            d[4] = 0.5 * t2; d[5] = 0.0;
        }
        return;
    }
    w[0] = beta5(t + 2.0); w[1] = beta5(t + 1.0); w[2] = beta5(t);
    w[3] = beta5(1.0 - t); w[4] = beta5(2.0 - t); w[5] = beta5(3.0 - t);
    if (d) {
        d[0] = dbeta5(t + 2.0); d[1] = dbeta5(t + 1.0); d[2] = dbeta5(t);
        d[3] = -dbeta5(1.0 - t); d[4] = -dbeta5(2.0 - t); d[5] = -dbeta5(3.0 - t);
    }
}

double sample_any(const Spline *s, double x, double y)
{
    if (s->order == 3)
        return sample_cubic(s->c, s->stride, x, y);
    const double xp = x + PAD, yp = y + PAD;
    const long ix = (long)xp, iy = (long)yp;
    double wx[6], wy[6];
    weights(s->order, xp - ix, wx, NULL);
    weights(s->order, yp - iy, wy, NULL);
    double v = 0.0;
    for (int j = 0; j < 6; ++j) {
        const float *row = s->c + (iy - 2 + j) * s->stride + (ix - 2);
        double acc = 0.0;
        for (int i = 0; i < 6; ++i)
            acc += wx[i] * row[i];
        v += wy[j] * acc;
    }
    return v;
}

void sample_with_gradient(const Spline *s, double x, double y, double *v, double *gx, double *gy)
{
    const double xp = x + PAD, yp = y + PAD;
    const long ix = (long)xp, iy = (long)yp;
    double wx[6], wy[6], dx[6], dy[6];
    weights(s->order, xp - ix, wx, dx);
    weights(s->order, yp - iy, wy, dy);
    double sv = 0.0, sx = 0.0, sy = 0.0;
    for (int j = 0; j < 6; ++j) {
        const float *row = s->c + (iy - 2 + j) * s->stride + (ix - 2);
        double acc = 0.0, accd = 0.0;
        for (int i = 0; i < 6; ++i) {
            acc += wx[i] * row[i];
            accd += dx[i] * row[i];
        }
        sv += wy[j] * acc;
        sx += wy[j] * accd;
        sy += dy[j] * acc;
    }
    *v = sv;
    *gx = sx;
    *gy = sy;
}

/* The recursive filter of one line of n samples (in place), whole-sample mirror boundaries. */
static void filter_line(double *c, long n, const double *poles, int npoles)
{
    if (n < 2)
        return;
    double gain = 1.0;
    for (int k = 0; k < npoles; ++k)
        gain *= (1.0 - poles[k]) * (1.0 - 1.0 / poles[k]);
    for (long i = 0; i < n; ++i)
        c[i] *= gain;
    for (int k = 0; k < npoles; ++k) {
        const double z = poles[k];
        /* causal initial value: the mirrored signal's infinite sum, folded onto the n samples */
        const double zn1 = pow(z, (double)(n - 1));
        double z2 = zn1 * zn1 / z;   /* z^(2n-3), walks down while zi walks up */
        double zi = z, sum = c[0] + zn1 * c[n - 1];
        for (long i = 1; i < n - 1; ++i) {
            sum += (zi + z2) * c[i];
            zi *= z;
            z2 /= z;
        }
        c[0] = sum / (1.0 - zn1 * zn1);
        for (long i = 1; i < n; ++i)
            c[i] += z * c[i - 1];
        c[n - 1] = (z / (z * z - 1.0)) * (c[n - 1] + z * c[n - 2]);
        for (long i = n - 2; i >= 0; --i)
            c[i] = z * (c[i + 1] - c[i]);
    }
}

static long reflect(long i, long n)   /* numpy's 'reflect' padding: the edge sample is not repeated */
{
    if (n == 1)
        return 0;
    const long period = 2 * (n - 1);
    i %= period;
    if (i < 0)
        i += period;
    return i < n ? i : period - i;
}

int spline_coefficients(const double *img, int height, int width, int order, float *out)
{
    double poles[2];
    int npoles;
    if (order == 3) {
        poles[0] = sqrt(3.0) - 2.0;
        npoles = 1;
    } else {
        poles[0] = sqrt(67.5 - sqrt(4436.25)) + sqrt(26.25) - 6.5;
        poles[1] = sqrt(67.5 + sqrt(4436.25)) - sqrt(26.25) - 6.5;
        npoles = 2;
    }
    const long W = width, H = height, stride = W + 2 * PAD;
    /* columns first, rounded to float32 between the passes (as scipy does with a float32 output) */
    float *tmp = malloc(sizeof(float) * (size_t)(W * H));
    if (!tmp)
        return -1;
    int failed = 0;
    #pragma omp parallel
    {
        double *line = malloc(sizeof(double) * (size_t)(W > H ? W : H));
        if (!line) {
            #pragma omp atomic write
            failed = 1;
        }
        #pragma omp for schedule(static)
        for (long x = 0; x < W; ++x) {
            if (!line)
                continue;
            for (long y = 0; y < H; ++y)
                line[y] = img[y * W + x];
            filter_line(line, H, poles, npoles);
            for (long y = 0; y < H; ++y)
                tmp[y * W + x] = (float)line[y];
        }
        #pragma omp for schedule(static)
        for (long y = 0; y < H; ++y) {
            if (!line)
                continue;
            for (long x = 0; x < W; ++x)
                line[x] = tmp[y * W + x];
            filter_line(line, W, poles, npoles);
            float *row = out + (y + PAD) * stride + PAD;
            for (long x = 0; x < W; ++x)
                row[x] = (float)line[x];
            for (long k = 1; k <= PAD; ++k) {
                row[-k] = row[reflect(-k, W)];
                row[W - 1 + k] = row[reflect(W - 1 + k, W)];
            }
        }
        free(line);
    }
    free(tmp);
    if (failed)
        return -1;
    for (long k = 1; k <= PAD; ++k) {   /* whole padded rows, so the corners are reflected twice */
        const long top = PAD - k, bottom = PAD + H - 1 + k;
        const float *src_top = out + (PAD + reflect(-k, H)) * stride;
        const float *src_bottom = out + (PAD + reflect(H - 1 + k, H)) * stride;
        for (long x = 0; x < stride; ++x) {
            out[top * stride + x] = src_top[x];
            out[bottom * stride + x] = src_bottom[x];
        }
    }
    return 0;
}

void pixel_gradients(const Spline *s, float *out)
{
    const long W = s->width, H = s->height, plane = W * H;
    #pragma omp parallel for schedule(static)
    for (long y = 0; y < H; ++y) {
        for (long x = 0; x < W; ++x) {
            double v, gx, gy;
            sample_with_gradient(s, (double)x, (double)y, &v, &gx, &gy);
            out[y * W + x] = (float)v;
            out[plane + y * W + x] = (float)gx;
            out[2 * plane + y * W + x] = (float)gy;
        }
    }
}

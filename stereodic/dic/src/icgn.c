/* Inverse-compositional Gauss-Newton (IC-GN) sub-pixel registration of square subsets with the
 * zero-normalised SSD criterion (Pan, Li & Tong, "Fast, robust and accurate digital image correlation
 * calculation without redundant computations", Exp. Mech. 53, 2013; the quadratic shape function after
 * Gao et al., Opt. Lasers Eng. 65, 2015).
 *
 * Warp parameters of one point, relative to its reference position (x0, y0), local offsets (dx, dy):
 *   affine (6):     p = (u, ux, uy, v, vx, vy)
 *   quadratic (12): p = (u, ux, uy, uxx, uxy, uyy, v, vx, vy, vxx, vxy, vyy)
 *   x' = x0 + dx + sum_i p[i] phi_i(dx, dy),  y' = y0 + dy + sum_i p[nb + i] phi_i(dx, dy)
 *   with phi = (1, dx, dy) or (1, dx, dy, dx^2/2, dx dy, dy^2/2), nb = number of phi; pixels.
 * The reference side of a subset (values, steepest-descent images, Hessian) is computed once per
 * registration, or once per run where it is kept (`reference_data`: the reference image and the points
 * are the same in every state of a sequence); each iteration samples the deformed image only. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "icgn.h"

/* The fast path: affine warps, bicubic interpolation. */
static inline int fast_path(const Problem *pb)
{
    return pb->nparams == 6 && pb->ref.order == 3;
}

int work_alloc(Work *w, const Problem *pb)
{
    const size_t side = 2 * (size_t)pb->half + 1, m = side * side, n = (size_t)pb->nparams;
    const size_t sums = (n + 2 + 3) / 4 * 4, plane = m + 8;
    const int fast = fast_path(pb);
    const size_t rows = fast ? 3 * plane : m * sums;
    w->J = calloc(rows + n * n + 4 * n + sums, sizeof(double));   /* zeros: the planes' padding */
    if (!w->J)
        return -1;
    w->lanes = fast ? 1 : (int)sums;
    w->plane = fast ? (long)plane : 0;
    w->value = fast ? 2 * (long)plane : (long)n;
    w->H = w->J + rows;
    w->JS = w->H + n * n;
    w->JF = w->JS + n;
    w->SJg = w->JF + n;
    w->rhs = w->SJg + sums;
    w->dp = w->rhs + n;
    return 0;
}

void work_free(Work *w)
{
    free(w->J);
    w->J = NULL;
}

/* Displacement component whose coefficients start at p[0], at local offset (dx, dy). */
static inline double displacement(const double *p, int nb, double dx, double dy)
{
    double d = p[0] + p[1] * dx + p[2] * dy;
    if (nb == 6)
        d += 0.5 * p[3] * dx * dx + p[4] * dx * dy + 0.5 * p[5] * dy * dy;
    return d;
}

void shift_warp(const double *p, int n, double ox, double oy, double *out)
{
    const int nb = n / 2;
    for (int c = 0; c < 2; ++c) {
        const double *q = p + c * nb;
        double *o = out + c * nb;
        const double d = displacement(q, nb, ox, oy);
        if (nb == 3) {
            o[0] = d;
            o[1] = q[1];
            o[2] = q[2];
        } else {
            const double d1 = q[1] + q[3] * ox + q[4] * oy, d2 = q[2] + q[4] * ox + q[5] * oy;
            o[0] = d;
            o[1] = d1;
            o[2] = d2;
            o[3] = q[3];
            o[4] = q[4];
            o[5] = q[5];
        }
    }
}

/* Cholesky factor of the n x n matrix H in its lower triangle; 0 if H is not clearly positive definite. */
static int cholesky(double *H, int n)
{
    double dmax = 0.0;
    for (int i = 0; i < n; ++i)
        dmax = fmax(dmax, H[i * n + i]);
    if (dmax <= 0.0)
        return 0;
    for (int j = 0; j < n; ++j) {
        double s = H[j * n + j];
        for (int k = 0; k < j; ++k)
            s -= H[j * n + k] * H[j * n + k];
        if (s <= 1e-12 * dmax)
            return 0;
        const double d = sqrt(s);
        H[j * n + j] = d;
        for (int i = j + 1; i < n; ++i) {
            double t = H[i * n + j];
            for (int k = 0; k < j; ++k)
                t -= H[i * n + k] * H[j * n + k];
            H[i * n + j] = t / d;
        }
    }
    return 1;
}

static void cholesky_solve(const double *L, const double *b, int n, double *out)
{
    for (int i = 0; i < n; ++i) {
        double s = b[i];
        for (int k = 0; k < i; ++k)
            s -= L[i * n + k] * out[k];
        out[i] = s / L[i * n + i];
    }
    for (int i = n - 1; i >= 0; --i) {
        double s = out[i];
        for (int k = i + 1; k < n; ++k)
            s -= L[k * n + i] * out[k];
        out[i] = s / L[i * n + i];
    }
}

/* p <- p o d^-1 for affine warps (local frame). */
static void compose_affine(double *p, const double *d)
{
    const double a = 1.0 + d[1], b = d[2], c = d[4], e = 1.0 + d[5];
    const double det = a * e - b * c;
    const double ia = e / det, ib = -b / det, ic = -c / det, ie = a / det;
    const double tx = -(ia * d[0] + ib * d[3]), ty = -(ic * d[0] + ie * d[3]);
    const double pa = 1.0 + p[1], pb = p[2], pc = p[4], pe = 1.0 + p[5];
    const double u = pa * tx + pb * ty + p[0], v = pc * tx + pe * ty + p[3];
    const double na = pa * ia + pb * ic, nb = pa * ib + pb * ie, nc = pc * ia + pe * ic, ne = pc * ib + pe * ie;
    p[0] = u;
    p[1] = na - 1.0;
    p[2] = nb;
    p[3] = v;
    p[4] = nc;
    p[5] = ne - 1.0;
}

/* p <- p o d^-1 for quadratic warps, fitted (least squares, matrix `fit`) at the 3 x 3 points
 * (-half, 0, half)^2 of the subset. */
static void compose_quadratic(double *p, const double *d, const double *fit, int half)
{
    double du[9], dv[9];
    const double s[3] = {-half, 0.0, half};
    int k = 0;
    for (int a = 0; a < 3; ++a) {
        const double sy = s[a];
        for (int b = 0; b < 3; ++b) {
            const double sx = s[b];
            /* invert z + w_d(z) = s by Newton */
            double zx = sx - displacement(d, 6, sx, sy), zy = sy - displacement(d + 6, 6, sx, sy);
            for (int it = 0; it < 4; ++it) {
                const double rx = zx + displacement(d, 6, zx, zy) - sx;
                const double ry = zy + displacement(d + 6, 6, zx, zy) - sy;
                const double j11 = 1.0 + d[1] + d[3] * zx + d[4] * zy, j12 = d[2] + d[4] * zx + d[5] * zy;
                const double j21 = d[7] + d[9] * zx + d[10] * zy, j22 = 1.0 + d[8] + d[10] * zx + d[11] * zy;
                const double det = j11 * j22 - j12 * j21;
                zx -= (j22 * rx - j12 * ry) / det;
                zy -= (-j21 * rx + j11 * ry) / det;
            }
            du[k] = zx + displacement(p, 6, zx, zy) - sx;
            dv[k] = zy + displacement(p + 6, 6, zx, zy) - sy;
            ++k;
        }
    }
    for (int i = 0; i < 6; ++i) {
        double su = 0.0, sv = 0.0;
        for (int j = 0; j < 9; ++j) {
            su += fit[i * 9 + j] * du[j];
            sv += fit[i * 9 + j] * dv[j];
        }
        p[i] = su;
        p[6 + i] = sv;
    }
}

/* Lower triangle of H = J^T J, JS = sum J and JF = sum J fc over the m rows of J (`lanes` values per
 * row, fc in lane n). */
static void sums_generic(const double *J, int lanes, int m, int n, double *H, double *JS, double *JF)
{
    for (int a = 0; a < n * n; ++a)
        H[a] = 0.0;
    for (int a = 0; a < n; ++a)
        JS[a] = JF[a] = 0.0;
    for (int k = 0; k < m; ++k) {
        const double *Jk = J + (long)k * lanes;
        const double c = Jk[n];
        for (int a = 0; a < n; ++a) {
            const double ja = Jk[a];
            JS[a] += ja;
            JF[a] += ja * c;
            for (int b = 0; b <= a; ++b)
                H[a * n + b] += ja * Jk[b];
        }
    }
}

/* sums_generic for the fast path's planes gx, gy, fc (`plane` values apart) of a subset of half-width
 * `half`. The 6 steepest-descent values are (gx, gx dx, gx dy, gy, gy dx, gy dy); every sum is a sum over
 * the rows (dy) of a row's sum of a product of gx, gy, fc and dx, times 1, dy or dy^2. So each row's 17
 * such sums (`R_*`) are taken eight pixels at a time (lanes past the row's end masked out), and folded
 * into the totals with their weights once per row. */
enum { R_X, R_XD, R_Y, R_YD, R_XF, R_XDF, R_YF, R_YDF, R_XX, R_XXD, R_XXDD, R_XY, R_XYD, R_XYDD, R_YY, R_YYD,
       R_YYDD, R_COUNT };

static void sums_affine(const double *J, long plane, int half, double *H, double *JS, double *JF)
{
    const int side = 2 * half + 1;
    const double *GX = J, *GY = J + plane, *F = J + 2 * plane;
    const v8d lane = {0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0};
    v8d t0[R_COUNT], t1[R_COUNT], t2[R_COUNT];     /* sums over the rows of a row's sum times 1, dy, dy^2 */
    for (int k = 0; k < R_COUNT; ++k)
        t0[k] = t1[k] = t2[k] = (v8d){0.0};
    for (int j = 0; j < side; ++j) {
        const double dy = j - half;
        const double *gxr = GX + (long)j * side, *gyr = GY + (long)j * side, *fr = F + (long)j * side;
        v8d r[R_COUNT];
        for (int k = 0; k < R_COUNT; ++k)
            r[k] = (v8d){0.0};
        for (int i = 0; i < side; i += 8) {
            const v8d mask = __builtin_convertvector(-(lane < (double)(side - i)), v8d);   /* 1 within the row */
            const v8d dx = lane + (double)(i - half);
            const v8d gx = load8d(gxr + i) * mask, gy = load8d(gyr + i) * mask, f = load8d(fr + i);
            const v8d a = gx * dx, b = gy * dx;
            r[R_X] += gx;
            r[R_XD] += a;
            r[R_Y] += gy;
            r[R_YD] += b;
            r[R_XF] += gx * f;
            r[R_XDF] += a * f;
            r[R_YF] += gy * f;
            r[R_YDF] += b * f;
            r[R_XX] += gx * gx;
            r[R_XXD] += gx * a;
            r[R_XXDD] += a * a;
            r[R_XY] += gx * gy;
            r[R_XYD] += gx * b;
            r[R_XYDD] += a * b;
            r[R_YY] += gy * gy;
            r[R_YYD] += gy * b;
            r[R_YYDD] += b * b;
        }
        for (int k = 0; k < R_COUNT; ++k) {
            t0[k] += r[k];
            t1[k] += r[k] * dy;
            t2[k] += r[k] * (dy * dy);
        }
    }
    double s0[R_COUNT], s1[R_COUNT], s2[R_COUNT];
    for (int k = 0; k < R_COUNT; ++k) {
        s0[k] = sum8(t0[k]);
        s1[k] = sum8(t1[k]);
        s2[k] = sum8(t2[k]);
    }
    /* J = (gx, gx dx, gx dy, gy, gy dx, gy dy) */
    const double lower[21] = {
        s0[R_XX],
        s0[R_XXD], s0[R_XXDD],
        s1[R_XX], s1[R_XXD], s2[R_XX],
        s0[R_XY], s0[R_XYD], s1[R_XY], s0[R_YY],
        s0[R_XYD], s0[R_XYDD], s1[R_XYD], s0[R_YYD], s0[R_YYDD],
        s1[R_XY], s1[R_XYD], s2[R_XY], s1[R_YY], s1[R_YYD], s2[R_YY]};
    for (int a = 0, q = 0; a < 6; ++a)
        for (int b = 0; b <= a; ++b)
            H[a * 6 + b] = lower[q++];
    JS[0] = s0[R_X]; JS[1] = s0[R_XD]; JS[2] = s1[R_X]; JS[3] = s0[R_Y]; JS[4] = s0[R_YD]; JS[5] = s1[R_Y];
    JF[0] = s0[R_XF]; JF[1] = s0[R_XDF]; JF[2] = s1[R_XF]; JF[3] = s0[R_YF]; JF[4] = s0[R_YDF]; JF[5] = s1[R_YF];
}

/* The rows of the reference subset at (x0, y0) in w->J, one per pixel: on the fast path (gx, gy, f, 1),
 * otherwise the n steepest-descent values, f, 1, zeros. OUTSIDE if the subset leaves the image, else OK. */
static int subset_rows(const Problem *pb, Work *w, double x0, double y0)
{
    const int n = pb->nparams, nb = n / 2, half = pb->half, side = 2 * half + 1, lanes = w->lanes;
    const int width = pb->ref.width, height = pb->ref.height, fast = fast_path(pb);
    if (!(0.0 <= x0 - half && x0 + half <= width - 1 && 0.0 <= y0 - half && y0 + half <= height - 1))
        return OUTSIDE;
    const int on_pixel = x0 == floor(x0) && y0 == floor(y0);
    const long ix0 = (long)x0, iy0 = (long)y0, plane = (long)width * height;
    if (fast && on_pixel) {      /* the common case: the planes' rows copied from the pixels' own values */
        for (int j = 0; j < side; ++j) {
            const float *at = pb->refpix + (iy0 + j - half) * width + ix0 - half;
            double *gx = w->J + (long)j * side, *gy = gx + w->plane, *f = gx + 2 * w->plane;
            for (int i = 0; i < side; ++i) {
                f[i] = at[i];
                gx[i] = at[plane + i];
                gy[i] = at[2 * plane + i];
            }
        }
        return OK;
    }
    double *Jk = w->J;
    for (int j = 0; j < side; ++j) {
        const double dy = j - half;
        for (int i = 0; i < side; ++i, Jk += lanes) {
            const double dx = i - half;
            double f, gx, gy;
            if (on_pixel) {
                const long at = (iy0 + j - half) * width + ix0 + i - half;
                f = pb->refpix[at];
                gx = pb->refpix[plane + at];
                gy = pb->refpix[2 * plane + at];
            } else {
                sample_with_gradient(&pb->ref, x0 + dx, y0 + dy, &f, &gx, &gy);
            }
            if (fast) {
                const long k = (long)j * side + i;
                w->J[k] = gx;
                w->J[w->plane + k] = gy;
                w->J[2 * w->plane + k] = f;
                continue;
            }
            Jk[0] = gx;
            Jk[1] = gx * dx;
            Jk[2] = gx * dy;
            Jk[nb] = gy;
            Jk[nb + 1] = gy * dx;
            Jk[nb + 2] = gy * dy;
            if (nb == 6) {
                Jk[3] = 0.5 * gx * dx * dx;
                Jk[4] = gx * dx * dy;
                Jk[5] = 0.5 * gx * dy * dy;
                Jk[9] = 0.5 * gy * dx * dx;
                Jk[10] = gy * dx * dy;
                Jk[11] = 0.5 * gy * dy * dy;
            }
            Jk[n] = f;
            Jk[n + 1] = 1.0;
            for (int a = n + 2; a < lanes; ++a)
                Jk[a] = 0.0;
        }
    }
    return OK;
}

/* The m values `step` apart from v: their sum (`total`), their sum of squares (`squares`), each less
 * `mean` (`subtract`). Step 1 (the fast path's contiguous plane) has its own loop, which the compiler
 * runs in vectors; a step known only at run time would keep it scalar. */
static inline double total(const double *v, long step, int m)
{
    double s = 0.0;
    if (step == 1)
        for (int k = 0; k < m; ++k)
            s += v[k];
    else
        for (int k = 0; k < m; ++k)
            s += v[(long)k * step];
    return s;
}

static inline double squares(const double *v, long step, int m)
{
    double s = 0.0;
    if (step == 1)
        for (int k = 0; k < m; ++k)
            s += v[k] * v[k];
    else
        for (int k = 0; k < m; ++k)
            s += v[(long)k * step] * v[(long)k * step];
    return s;
}

static inline void subtract(double *v, long step, int m, double mean)
{
    if (step == 1)
        for (int k = 0; k < m; ++k)
            v[k] -= mean;
    else
        for (int k = 0; k < m; ++k)
            v[(long)k * step] -= mean;
}

/* Reference side of one subset: its rows (subset_rows) with zero-mean values, the Hessian's Cholesky
 * factor H (n, n), JS = sum J, JF = sum J fc. Returns the status; *fmean = the mean value, *norm = |fc|. */
static int reference_side(const Problem *pb, Work *w, double x0, double y0, double *fmean_, double *norm)
{
    const int n = pb->nparams, lanes = w->lanes, m = (2 * pb->half + 1) * (2 * pb->half + 1);
    const int st = subset_rows(pb, w, x0, y0);
    if (st != OK)
        return st;
    double *J = w->J, *values = J + w->value;
    const double fmean = total(values, lanes, m) / m;
    subtract(values, lanes, m, fmean);
    const double ss = squares(values, lanes, m);
    if (ss <= 1e-10 * m)
        return NO_TEXTURE;
    double *H = w->H, *JS = w->JS, *JF = w->JF;
    if (fast_path(pb))
        sums_affine(J, w->plane, pb->half, H, JS, JF);
    else
        sums_generic(J, lanes, m, n, H, JS, JF);
    if (!cholesky(H, n))
        return NO_TEXTURE;
    *fmean_ = fmean;
    *norm = sqrt(ss);
    return OK;
}

/* reference_side from a row of reference_data: the rows rebuilt, the sums and the factor copied. */
static int cached_side(const Problem *pb, Work *w, double x0, double y0, const double *row, double *norm)
{
    const int n = pb->nparams, lanes = w->lanes, m = (2 * pb->half + 1) * (2 * pb->half + 1);
    const int st = (int)row[REF_STATUS];
    if (st != OK || subset_rows(pb, w, x0, y0) != OK)
        return st;
    const double fmean = row[REF_MEAN];
    double *values = w->J + w->value;
    subtract(values, lanes, m, fmean);
    memcpy(w->JS, row + REF_HEAD, sizeof(double) * (size_t)n);
    memcpy(w->JF, row + REF_HEAD + n, sizeof(double) * (size_t)n);
    memcpy(w->H, row + REF_HEAD + 2 * n, sizeof(double) * (size_t)(n * n));
    *norm = row[REF_NORM];
    return OK;
}

int reference_data(const Problem *pb, Work *w, double x0, double y0, double *row)
{
    const int n = pb->nparams;
    double fmean = NAN, norm = NAN;
    const int st = reference_side(pb, w, x0, y0, &fmean, &norm);
    row[REF_STATUS] = st;
    row[REF_X] = x0;
    row[REF_Y] = y0;
    row[REF_MEAN] = fmean;
    row[REF_NORM] = norm;
    for (int a = 0; a < n; ++a) {
        row[REF_HEAD + a] = st == OK ? w->JS[a] : NAN;
        row[REF_HEAD + n + a] = st == OK ? w->JF[a] : NAN;
    }
    for (int a = 0; a < n * n; ++a)
        row[REF_HEAD + 2 * n + a] = st == OK ? w->H[a] : NAN;
    return st;
}

int reference_status(const Problem *pb, Work *w, double x0, double y0)
{
    double fmean, norm;
    return reference_side(pb, w, x0, y0, &fmean, &norm);
}

/* One pass over the warped subset in the deformed image: sums of g, g^2, fc g and SJg = sum J g (the
 * lanes of the rows: SJg[n] = sum fc g, SJg[n + 1] = sum g). Returns 0 if the warped subset leaves the
 * image. Any shape function, any order. */
static int pass_generic(const Problem *pb, Work *w, const double *p, double x0, double y0, double *sgg_)
{
    const int n = pb->nparams, nb = n / 2, half = pb->half, side = 2 * half + 1, lanes = w->lanes;
    const double width = pb->dfm.width, height = pb->dfm.height;
    v4d acc[4] = {{0.0}};
    double sgg = 0.0;
    const double *Jk = w->J;
    for (int j = 0; j < side; ++j) {
        const double dy = j - half;
        for (int i = 0; i < side; ++i, Jk += lanes) {
            const double dx = i - half;
            const double xw = x0 + dx + displacement(p, nb, dx, dy);
            const double yw = y0 + dy + displacement(p + nb, nb, dx, dy);
            if (!(-0.5 <= xw && xw <= width - 0.5 && -0.5 <= yw && yw <= height - 0.5))
                return 0;
            const double g = sample_any(&pb->dfm, xw, yw);
            sgg += g * g;
            for (int a = 0; a < lanes / 4; ++a)
                acc[a] += load4d(Jk + 4 * a) * g;
        }
    }
    memcpy(w->SJg, acc, sizeof(double) * (size_t)lanes);
    *sgg_ = sgg;
    return 1;
}

/* pass_generic for affine warps and bicubic interpolation (the common, fast case), from the planes gx,
 * gy, fc: eight pixels of a subset row at a time (`sample_cubic36_row8`), their products with g summed
 * per lane, per row of the subset the gradients' sums and their dy-weighted sums; the interpolation's
 * factor 1/36 applied to the sums at the end. */
static int pass_affine_cubic(const Problem *pb, Work *w, const double *p, double x0, double y0, double *sgg_)
{
    const int half = pb->half, side = 2 * half + 1;
    const double width = pb->dfm.width, height = pb->dfm.height;
    const double a11 = 1.0 + p[1], a12 = p[2], a21 = p[4], a22 = 1.0 + p[5];
    /* the warped subset is a parallelogram: inside if its corners are */
    for (int cy = -half; cy <= half; cy += 2 * half) {
        for (int cx = -half; cx <= half; cx += 2 * half) {
            const double xw = x0 + p[0] + a11 * cx + a12 * cy, yw = y0 + p[3] + a21 * cx + a22 * cy;
            if (!(-0.5 <= xw && xw <= width - 0.5 && -0.5 <= yw && yw <= height - 0.5))
                return 0;
        }
    }
    const float *c = pb->dfm.c;
    const long stride = pb->dfm.stride;
    const double *GX = w->J, *GY = w->J + w->plane, *F = w->J + 2 * w->plane;
    const v8d lane = {0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0};
    v8d sx = {0.0}, sx_dx = {0.0}, sx_dy = {0.0}, sy = {0.0}, sy_dx = {0.0}, sy_dy = {0.0};
    v8d sf = {0.0}, sg = {0.0}, sgg = {0.0};
    for (int j = 0; j < side; ++j) {
        const double dy = j - half;
        const double *gx = GX + (long)j * side, *gy = GY + (long)j * side, *f = F + (long)j * side;
        const double xr = x0 + p[0] + a12 * dy - a11 * half, yr = y0 + p[3] + a22 * dy - a21 * half;
        v8d rx = {0.0}, ry = {0.0};
        for (int i = 0; i < side; i += 8) {
            /* a row's last group of fewer than 8: its other lanes' g are 0, and they read the next row's
             * (or the planes' zero padding) */
            const int count = side - i < 8 ? side - i : 8;
            v8d g = {0.0};
            if (count < 8 || !sample_cubic36_row8(c, stride, xr, yr, a11, a21, i, &g))
                for (int q = 0; q < count; ++q)
                    g[q] = sample_cubic36(c, stride, xr + a11 * (i + q), yr + a21 * (i + q));
            const v8d dx = lane + (double)(i - half);
            const v8d qx = load8d(gx + i) * g, qy = load8d(gy + i) * g;
            rx += qx;
            ry += qy;
            sx_dx += qx * dx;
            sy_dx += qy * dx;
            sf += load8d(f + i) * g;
            sg += g;
            sgg += g * g;
        }
        sx += rx;
        sy += ry;
        sx_dy += rx * dy;
        sy_dy += ry * dy;
    }
    const double s = 1.0 / 36.0;
    double *SJg = w->SJg;   /* J = (gx, gx dx, gx dy, gy, gy dx, gy dy), then fc, 1 */
    SJg[0] = sum8(sx) * s;
    SJg[1] = sum8(sx_dx) * s;
    SJg[2] = sum8(sx_dy) * s;
    SJg[3] = sum8(sy) * s;
    SJg[4] = sum8(sy_dx) * s;
    SJg[5] = sum8(sy_dy) * s;
    SJg[6] = sum8(sf) * s;
    SJg[7] = sum8(sg) * s;
    *sgg_ = sum8(sgg) * (s * s);
    return 1;
}

int solve_point(const Problem *pb, Work *w, double x0, double y0, const double *cached, double *p, double *zncc,
                int *iters)
{
    const int n = pb->nparams, nb = n / 2, half = pb->half, side = 2 * half + 1, m = side * side;
    double df, fmean;
    *zncc = NAN;
    *iters = 0;
    const int st = cached ? cached_side(pb, w, x0, y0, cached, &df) : reference_side(pb, w, x0, y0, &fmean, &df);
    if (st != OK)
        return st;
    const double h2 = 0.5 * half * half, hh = (double)half * half;
    const int fast = fast_path(pb);
    for (int it = 1; it <= pb->max_iter; ++it) {
        double sgg;
        *iters = it;
        const int inside = fast ? pass_affine_cubic(pb, w, p, x0, y0, &sgg) : pass_generic(pb, w, p, x0, y0, &sgg);
        if (!inside) {
            *zncc = NAN;
            return OUTSIDE;
        }
        const double sfg = w->SJg[n], sg = w->SJg[n + 1];
        const double gmean = sg / m, vg = sgg - sg * gmean;
        if (!(vg > 1e-10 * m)) {
            *zncc = NAN;
            return NO_TEXTURE;
        }
        const double dg = sqrt(vg);
        *zncc = sfg / (df * dg);
        const double ratio = df / dg;
        for (int a = 0; a < n; ++a)
            w->rhs[a] = -(w->JF[a] - ratio * (w->SJg[a] - gmean * w->JS[a]));
        cholesky_solve(w->H, w->rhs, n, w->dp);
        const double *dp = w->dp;
        double norm;
        if (nb == 3) {
            compose_affine(p, dp);
            norm = dp[0] * dp[0] + dp[3] * dp[3] + hh * (dp[1] * dp[1] + dp[2] * dp[2] + dp[4] * dp[4] + dp[5] * dp[5]);
        } else {
            compose_quadratic(p, dp, pb->fit, half);
            norm = dp[0] * dp[0] + dp[6] * dp[6]
                   + hh * (dp[1] * dp[1] + dp[2] * dp[2] + dp[7] * dp[7] + dp[8] * dp[8])
                   + h2 * h2 * (dp[3] * dp[3] + dp[4] * dp[4] + dp[5] * dp[5] + dp[9] * dp[9] + dp[10] * dp[10]
                                + dp[11] * dp[11]);
        }
        if (!isfinite(norm) || norm > 1e6)
            return DIVERGED;
        if (norm < pb->tol * pb->tol)
            return *zncc >= pb->min_zncc ? OK : LOW_ZNCC;
    }
    return DIVERGED;
}

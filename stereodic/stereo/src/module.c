/* stereodic.stereo._kernels: the compiled kernels of stereodic.stereo.triangulate, which documents them:
 * the fused triangulation of matched virtual positions and the signed distances of their rays.
 *
 * Arrays come in through the buffer protocol, checked by stereodic/src/buffers.h. The GIL is released
 * while a kernel runs; OpenMP threads share the points. */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <math.h>

#include "buffers.h"

/* The rectified pair's common plane and the rays' directions at its pixels. */
typedef struct {
    const double *origin, *eu, *ev;        /* (3,): the plane's origin, mm per pixel along u and v */
    const double *dir_l, *dir_r;           /* (H, W, 3): unit ray directions of the virtual pixels */
    Py_ssize_t height, width;
} Plane;

/* `stereodic.virtual.sampling.bilinear` of an (H, W, 3) field at (u, v) into out[3]: NaN off a finite
 * position, the border cells continued outside. */
static void bilinear3(const double *field, Py_ssize_t h, Py_ssize_t w, double u, double v, double out[3])
{
    if (!(isfinite(u) && isfinite(v))) {
        out[0] = out[1] = out[2] = NAN;
        return;
    }
    Py_ssize_t i = (Py_ssize_t)floor(u), j = (Py_ssize_t)floor(v);
    i = i < 0 ? 0 : (i > w - 2 ? w - 2 : i);
    j = j < 0 ? 0 : (j > h - 2 ? h - 2 : j);
    const double a = u - (double)i, b = v - (double)j;
    const double *p00 = field + (j * w + i) * 3, *p10 = p00 + 3, *p01 = p00 + w * 3, *p11 = p01 + 3;
    for (int c = 0; c < 3; ++c)
        out[c] = p00[c] + a * (p10[c] - p00[c]) + b * (p01[c] - p00[c]) + a * b * (p11[c] - p10[c] - p01[c] + p00[c]);
}

/* The point on the common plane at virtual pixel (x, r). */
static void on_plane(const Plane *pl, double x, double r, double out[3])
{
    for (int c = 0; c < 3; ++c)
        out[c] = pl->origin[c] + x * pl->eu[c] + r * pl->ev[c];
}

/* The plane's origin, axes and direction fields of a call; 0, or -1 with an exception set. */
static int plane(Buffers *bs, Plane *pl, PyObject *origin, PyObject *eu, PyObject *ev, PyObject *dir_l,
                 PyObject *dir_r)
{
    const Py_ssize_t three[1] = {3}, field[3] = {ANY, ANY, 3};
    Py_ssize_t found[3];
    if (!(pl->origin = array(bs, origin, 'd', 1, three, NULL, 0, "origin")) ||
        !(pl->eu = array(bs, eu, 'd', 1, three, NULL, 0, "eu")) ||
        !(pl->ev = array(bs, ev, 'd', 1, three, NULL, 0, "ev")) ||
        !(pl->dir_l = array(bs, dir_l, 'd', 3, field, found, 0, "dir_l")))
        return -1;
    const Py_ssize_t same[3] = {found[0], found[1], 3};
    if (!(pl->dir_r = array(bs, dir_r, 'd', 3, same, NULL, 0, "dir_r")))
        return -1;
    if (found[0] < 2 || found[1] < 2) {
        PyErr_SetString(PyExc_ValueError, "the direction fields need at least 2 x 2 pixels");
        return -1;
    }
    pl->height = found[0];
    pl->width = found[1];
    return 0;
}

/* The matches' four coordinate arrays (N,): xl, rl, xr, rr; 0 with *n = N, or -1. */
static int matches(Buffers *bs, PyObject *const o[4], const double *m[4], Py_ssize_t *n)
{
    static const char *names[4] = {"xl", "rl", "xr", "rr"};
    if (!(m[0] = array(bs, o[0], 'd', 1, NULL, n, 0, names[0])))
        return -1;
    for (int k = 1; k < 4; ++k)
        if (!(m[k] = array(bs, o[k], 'd', 1, n, NULL, 0, names[k])))
            return -1;
    return 0;
}

static PyObject *py_triangulate_all(PyObject *self, PyObject *args)
{
    PyObject *o[4], *origin, *eu, *ev, *dir_l, *dir_r, *centre_l, *centre_r, *points_o, *gap_o;
    int corrected;
    if (!PyArg_ParseTuple(args, "OOOOOOOOOOOpOO", &o[0], &o[1], &o[2], &o[3], &origin, &eu, &ev, &dir_l, &dir_r,
                          &centre_l, &centre_r, &corrected, &points_o, &gap_o))
        return NULL;
    Buffers bs = {.n = 0};
    Plane pl;
    const double *m[4], *c_l, *c_r;
    double *points, *gap;
    Py_ssize_t n[1];
    const Py_ssize_t three[1] = {3};
    if (plane(&bs, &pl, origin, eu, ev, dir_l, dir_r) < 0 || matches(&bs, o, m, n) < 0 ||
        !(c_l = array(&bs, centre_l, 'd', 1, three, NULL, 0, "c_l")) ||
        !(c_r = array(&bs, centre_r, 'd', 1, three, NULL, 0, "c_r")))
        goto fail;
    const Py_ssize_t pshape[2] = {n[0], 3};
    if (!(points = array(&bs, points_o, 'd', 2, pshape, NULL, 1, "points")) ||
        !(gap = array(&bs, gap_o, 'd', 1, n, NULL, 1, "gap")))
        goto fail;
    Py_BEGIN_ALLOW_THREADS
#pragma omp parallel for schedule(static)
    for (Py_ssize_t k = 0; k < n[0]; ++k) {
        double o1[3], o2[3], d1[3], d2[3];
        on_plane(&pl, m[0][k], m[1][k], o1);
        on_plane(&pl, m[2][k], m[3][k], o2);
        if (corrected) {
            bilinear3(pl.dir_l, pl.height, pl.width, m[0][k], m[1][k], d1);
            bilinear3(pl.dir_r, pl.height, pl.width, m[2][k], m[3][k], d2);
        } else {
            for (int c = 0; c < 3; ++c) {
                d1[c] = o1[c] - c_l[c];
                d2[c] = o2[c] - c_r[c];
            }
        }
        const double n1 = sqrt(d1[0] * d1[0] + d1[1] * d1[1] + d1[2] * d1[2]);
        const double n2 = sqrt(d2[0] * d2[0] + d2[1] * d2[1] + d2[2] * d2[2]);
        double b = 0.0, d = 0.0, e = 0.0;
        for (int c = 0; c < 3; ++c) {
            d1[c] /= n1;
            d2[c] /= n2;
        }
        for (int c = 0; c < 3; ++c) {
            const double w = o1[c] - o2[c];
            b += d1[c] * d2[c];
            d += d1[c] * w;
            e += d2[c] * w;
        }
        /* the closest points o1 + s d1 and o2 + t d2; NaN for parallel (or blank) rays */
        const double den = 1.0 - b * b;
        const double s = den > 1e-15 ? (b * e - d) / den : NAN;
        const double t = den > 1e-15 ? (e - b * d) / den : NAN;
        double g = 0.0;
        for (int c = 0; c < 3; ++c) {
            const double p1 = o1[c] + s * d1[c], p2 = o2[c] + t * d2[c];
            points[k * 3 + c] = (p1 + p2) / 2;
            g += (p1 - p2) * (p1 - p2);
        }
        gap[k] = sqrt(g);
    }
    Py_END_ALLOW_THREADS
    return finish(&bs, 0);
fail:
    return finish(&bs, -1);
}

static PyObject *py_distances_all(PyObject *self, PyObject *args)
{
    PyObject *o[4], *origin, *eu, *ev, *dir_l, *dir_r, *out_o;
    if (!PyArg_ParseTuple(args, "OOOOOOOOOO", &o[0], &o[1], &o[2], &o[3], &origin, &eu, &ev, &dir_l, &dir_r, &out_o))
        return NULL;
    Buffers bs = {.n = 0};
    Plane pl;
    const double *m[4];
    double *out;
    Py_ssize_t n[1];
    if (plane(&bs, &pl, origin, eu, ev, dir_l, dir_r) < 0 || matches(&bs, o, m, n) < 0 ||
        !(out = array(&bs, out_o, 'd', 1, n, NULL, 1, "out")))
        goto fail;
    Py_BEGIN_ALLOW_THREADS
#pragma omp parallel for schedule(static)
    for (Py_ssize_t k = 0; k < n[0]; ++k) {
        double d1[3], d2[3];
        bilinear3(pl.dir_l, pl.height, pl.width, m[0][k], m[1][k], d1);
        bilinear3(pl.dir_r, pl.height, pl.width, m[2][k], m[3][k], d2);
        const double nrm[3] = {d1[1] * d2[2] - d1[2] * d2[1], d1[2] * d2[0] - d1[0] * d2[2],
                               d1[0] * d2[1] - d1[1] * d2[0]};
        double dot = 0.0;
        for (int c = 0; c < 3; ++c)   /* o2 - o1, the two rays' points on the common plane, along n */
            dot += ((m[2][k] - m[0][k]) * pl.eu[c] + (m[3][k] - m[1][k]) * pl.ev[c]) * nrm[c];
        out[k] = dot / sqrt(nrm[0] * nrm[0] + nrm[1] * nrm[1] + nrm[2] * nrm[2]);
    }
    Py_END_ALLOW_THREADS
    return finish(&bs, 0);
fail:
    return finish(&bs, -1);
}

static PyMethodDef methods[] = {
    {"triangulate_all", py_triangulate_all, METH_VARARGS,
     "triangulate_all(xl, rl, xr, rr, origin, eu, ev, dir_l, dir_r, c_l, c_r, corrected, points, gap): the "
     "closest points' midpoints (N, 3) and distances (N,) of matched rays, mm, into points and gap."},
    {"distances_all", py_distances_all, METH_VARARGS,
     "distances_all(xl, rl, xr, rr, origin, eu, ev, dir_l, dir_r, out): the signed distances (N,) of matched "
     "rays, mm, into out."},
    {NULL, NULL, 0, NULL}};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_kernels", NULL, -1, methods};

PyMODINIT_FUNC PyInit__kernels(void)
{
    return PyModule_Create(&module);
}

/* stereodic.dic._kernels: the compiled kernels of the 2D DIC engine (B-splines, IC-GN, propagation) and of its maps
 * (raster cells),
 * called by stereodic.dic.interpolation, .icgn, .propagation and .maps, which document them.
 *
 * Arrays come in through the buffer protocol (numpy arrays, C-contiguous, of the dtype each function
 * names); every shape is checked (stereodic/src/buffers.h), so a wrong call raises ValueError instead of
 * reading out of bounds. The GIL is released while a kernel runs; OpenMP threads share the points. */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <math.h>
#include <string.h>

#include "buffers.h"
#include "propagation.h"
#include "raster.h"

/* A padded coefficient array of an image of width x height pixels and B-spline order 3 or 5. */
static int spline(Buffers *bs, PyObject *o, int order, int width, int height, Spline *s, const char *name)
{
    if (order != 3 && order != 5) {
        PyErr_Format(PyExc_ValueError, "B-spline order must be 3 or 5, got %d", order);
        return -1;
    }
    if (width < 1 || height < 1) {
        PyErr_SetString(PyExc_ValueError, "image size must be positive");
        return -1;
    }
    const Py_ssize_t shape[2] = {height + 2 * PAD, width + 2 * PAD};
    s->c = array(bs, o, 'f', 2, shape, NULL, 0, name);
    s->stride = width + 2 * PAD;
    s->width = width;
    s->height = height;
    s->order = order;
    return s->c ? 0 : -1;
}

/* The registration problem shared by solve_points, reference_status and propagate; fit may be NULL
 * where no warp is composed. */
static int problem(Buffers *bs, Problem *pb, PyObject *ref, PyObject *refpix, PyObject *dfm, int order, int width,
                   int height, int half, int nparams, PyObject *fit, int max_iter, double tol, double min_zncc)
{
    if (spline(bs, ref, order, width, height, &pb->ref, "ref") < 0 ||
        spline(bs, dfm, order, width, height, &pb->dfm, "dfm") < 0)
        return -1;
    const Py_ssize_t pix[3] = {3, height, width}, fshape[2] = {6, 9};
    if (!(pb->refpix = array(bs, refpix, 'f', 3, pix, NULL, 0, "refpix")))
        return -1;
    pb->fit = NULL;
    if (fit && !(pb->fit = array(bs, fit, 'd', 2, fshape, NULL, 0, "fit")))
        return -1;
    if (half < 1 || (nparams != 6 && nparams != 12) || max_iter < 1) {
        PyErr_Format(PyExc_ValueError, "bad subset half-width %d, parameter count %d or iteration count %d", half,
                     nparams, max_iter);
        return -1;
    }
    pb->cache = NULL;
    pb->rows = NULL;
    pb->half = half;
    pb->nparams = nparams;
    pb->max_iter = max_iter;
    pb->tol = tol;
    pb->min_zncc = min_zncc;
    return 0;
}

/* Points xs, ys (N) and their results P (N, n), zncc, iters, status; *count = N, *nparams = n. */
static int points(Buffers *bs, Points *pts, PyObject *xs, PyObject *ys, PyObject *P, PyObject *zncc, PyObject *iters,
                  PyObject *status, Py_ssize_t *count, Py_ssize_t *nparams)
{
    Py_ssize_t n[1], pshape[2];
    if (!(pts->xs = array(bs, xs, 'd', 1, NULL, n, 0, "xs")))
        return -1;
    const Py_ssize_t one[1] = {n[0]}, two[2] = {n[0], ANY};
    if (!(pts->ys = array(bs, ys, 'd', 1, one, NULL, 0, "ys")) ||
        !(pts->P = array(bs, P, 'd', 2, two, pshape, 1, "P")) ||
        !(pts->zncc = array(bs, zncc, 'd', 1, one, NULL, 1, "zncc")) ||
        !(pts->iters = array(bs, iters, 'i', 1, one, NULL, 1, "iters")) ||
        !(pts->status = array(bs, status, 'b', 1, one, NULL, 1, "status")))
        return -1;
    *count = n[0];
    *nparams = pshape[1];
    return 0;
}

/* The optional reference data of a problem's `count` points (`reference_data`): cache None, or (M,
 * reference_width) float64 with rows None (M = count, row k for point k) or (count,) int64 row indices. */
static int cache(Buffers *bs, Problem *pb, PyObject *data, PyObject *rows, Py_ssize_t count)
{
    if (data == Py_None)
        return 0;
    const Py_ssize_t shape[2] = {rows == Py_None ? count : ANY, reference_width(pb->nparams)};
    Py_ssize_t found[2];
    if (!(pb->cache = array(bs, data, 'd', 2, shape, found, 0, "cache")))
        return -1;
    if (rows == Py_None)
        return 0;
    const Py_ssize_t one[1] = {count};
    if (!(pb->rows = array(bs, rows, 'q', 1, one, NULL, 0, "rows")))
        return -1;
    for (Py_ssize_t k = 0; k < count; ++k) {
        if (pb->rows[k] < 0 || pb->rows[k] >= found[0]) {
            PyErr_Format(PyExc_ValueError, "rows: index %lld outside the cache's %zd rows", (long long)pb->rows[k],
                         found[0]);
            return -1;
        }
    }
    return 0;
}

static PyObject *py_spline_coefficients(PyObject *self, PyObject *args)
{
    PyObject *img, *out;
    int order;
    if (!PyArg_ParseTuple(args, "OiO", &img, &order, &out))
        return NULL;
    Buffers bs = {.n = 0};
    Py_ssize_t hw[2];
    const double *data = array(&bs, img, 'd', 2, NULL, hw, 0, "image");
    float *coef = NULL;
    if (data) {
        const Py_ssize_t shape[2] = {hw[0] + 2 * PAD, hw[1] + 2 * PAD};
        coef = array(&bs, out, 'f', 2, shape, NULL, 1, "out");
    }
    if (coef && order != 3 && order != 5)
        PyErr_Format(PyExc_ValueError, "B-spline order must be 3 or 5, got %d", order);
    if (!coef || PyErr_Occurred()) {
        release(&bs);
        return NULL;
    }
    int rc;
    Py_BEGIN_ALLOW_THREADS
    rc = spline_coefficients(data, (int)hw[0], (int)hw[1], order, coef);
    Py_END_ALLOW_THREADS
    return finish(&bs, rc);
}

static PyObject *py_pixel_gradients(PyObject *self, PyObject *args)
{
    PyObject *coef, *out;
    int order, width, height;
    if (!PyArg_ParseTuple(args, "OiiiO", &coef, &order, &width, &height, &out))
        return NULL;
    Buffers bs = {.n = 0};
    Spline s;
    const Py_ssize_t shape[3] = {3, height, width};
    float *o = NULL;
    if (spline(&bs, coef, order, width, height, &s, "coef") == 0)
        o = array(&bs, out, 'f', 3, shape, NULL, 1, "out");
    if (!o) {
        release(&bs);
        return NULL;
    }
    Py_BEGIN_ALLOW_THREADS
    pixel_gradients(&s, o);
    Py_END_ALLOW_THREADS
    release(&bs);
    Py_RETURN_NONE;
}

/* sample(coef, order, width, height, x, y, out) and gradient(..., x, y, gx, gy): NaN outside the image. */
static PyObject *evaluate(PyObject *args, int with_gradient)
{
    PyObject *coef, *xo, *yo, *ao, *bo = NULL;
    int order, width, height;
    if (with_gradient ? !PyArg_ParseTuple(args, "OiiiOOOO", &coef, &order, &width, &height, &xo, &yo, &ao, &bo)
                      : !PyArg_ParseTuple(args, "OiiiOOO", &coef, &order, &width, &height, &xo, &yo, &ao))
        return NULL;
    Buffers bs = {.n = 0};
    Spline s;
    Py_ssize_t n[1];
    const double *x = NULL, *y = NULL;
    double *a = NULL, *b = NULL;
    if (spline(&bs, coef, order, width, height, &s, "coef") == 0 && (x = array(&bs, xo, 'd', 1, NULL, n, 0, "x"))) {
        const Py_ssize_t one[1] = {n[0]};
        if ((y = array(&bs, yo, 'd', 1, one, NULL, 0, "y")) && (a = array(&bs, ao, 'd', 1, one, NULL, 1, "out")) &&
            with_gradient)
            b = array(&bs, bo, 'd', 1, one, NULL, 1, "out");
    }
    if (!a || (with_gradient && !b)) {
        release(&bs);
        return NULL;
    }
    Py_BEGIN_ALLOW_THREADS
    #pragma omp parallel for schedule(static)
    for (Py_ssize_t k = 0; k < n[0]; ++k) {
        const int inside = 0.0 <= x[k] && x[k] <= width - 1 && 0.0 <= y[k] && y[k] <= height - 1;
        if (!with_gradient) {
            a[k] = inside ? sample_any(&s, x[k], y[k]) : NAN;
        } else if (inside) {
            double v;
            sample_with_gradient(&s, x[k], y[k], &v, &a[k], &b[k]);
        } else {
            a[k] = b[k] = NAN;
        }
    }
    Py_END_ALLOW_THREADS
    release(&bs);
    Py_RETURN_NONE;
}

static PyObject *py_sample(PyObject *self, PyObject *args)
{
    return evaluate(args, 0);
}

static PyObject *py_gradient(PyObject *self, PyObject *args)
{
    return evaluate(args, 1);
}

static PyObject *py_shift_warp(PyObject *self, PyObject *args)
{
    PyObject *po, *oo;
    double ox, oy;
    if (!PyArg_ParseTuple(args, "OddO", &po, &ox, &oy, &oo))
        return NULL;
    Buffers bs = {.n = 0};
    Py_ssize_t n[1];
    const double *p = array(&bs, po, 'd', 1, NULL, n, 0, "p");
    double *out = NULL;
    if (p) {
        if (n[0] != 6 && n[0] != 12)
            PyErr_Format(PyExc_ValueError, "p: %zd parameters, expected 6 or 12", n[0]);
        else
            out = array(&bs, oo, 'd', 1, n, NULL, 1, "out");
    }
    if (out)
        shift_warp(p, (int)n[0], ox, oy, out);
    release(&bs);
    if (!out)
        return NULL;
    Py_RETURN_NONE;
}

static PyObject *py_solve_points(PyObject *self, PyObject *args)
{
    PyObject *ref, *refpix, *dfm, *xs, *ys, *P, *fit, *zncc, *iters, *status, *data, *rows;
    int order, width, height, half, max_iter;
    double tol, min_zncc;
    if (!PyArg_ParseTuple(args, "OOOiiiOOiOOiddOOOOO", &ref, &refpix, &dfm, &order, &width, &height, &xs, &ys, &half,
                          &P, &fit, &max_iter, &tol, &min_zncc, &zncc, &iters, &status, &data, &rows))
        return NULL;
    Buffers bs = {.n = 0};
    Points pts;
    Problem pb;
    Py_ssize_t count, nparams;
    int rc = -1;
    if (points(&bs, &pts, xs, ys, P, zncc, iters, status, &count, &nparams) == 0 &&
        problem(&bs, &pb, ref, refpix, dfm, order, width, height, half, (int)nparams, fit, max_iter, tol,
                min_zncc) == 0 && cache(&bs, &pb, data, rows, count) == 0) {
        Py_BEGIN_ALLOW_THREADS
        rc = solve_many(&pb, &pts, NULL, count);
        Py_END_ALLOW_THREADS
    }
    return finish(&bs, rc);
}

static PyObject *py_reference_status(PyObject *self, PyObject *args)
{
    PyObject *ref, *refpix, *xs, *ys, *status, *data = Py_None;
    int order, width, height, half, nparams;
    if (!PyArg_ParseTuple(args, "OOiiiOOiiO|O", &ref, &refpix, &order, &width, &height, &xs, &ys, &half, &nparams,
                          &status, &data))
        return NULL;
    Buffers bs = {.n = 0};
    Problem pb;
    Py_ssize_t n[1];
    const double *x, *y = NULL;
    int8_t *st = NULL;
    double *rows = NULL;
    int rc = -1;
    if ((x = array(&bs, xs, 'd', 1, NULL, n, 0, "xs"))) {
        const Py_ssize_t one[1] = {n[0]};
        if ((y = array(&bs, ys, 'd', 1, one, NULL, 0, "ys")))
            st = array(&bs, status, 'b', 1, one, NULL, 1, "status");
    }
    /* the reference side needs neither a deformed image (the reference stands in) nor a composition fit */
    if (st && problem(&bs, &pb, ref, refpix, ref, order, width, height, half, nparams, NULL, 1, 0.0, 0.0) == 0) {
        const Py_ssize_t two[2] = {n[0], reference_width(nparams)};
        if (data == Py_None || (rows = array(&bs, data, 'd', 2, two, NULL, 1, "data"))) {
            Py_BEGIN_ALLOW_THREADS
            rc = status_many(&pb, x, y, n[0], st, rows);
            Py_END_ALLOW_THREADS
        }
    }
    return finish(&bs, rc);
}

static PyObject *py_propagate(PyObject *self, PyObject *args)
{
    PyObject *ref, *refpix, *dfm, *xs, *ys, *P, *fit, *zncc, *iters, *status, *done, *data;
    int order, width, height, half, max_iter;
    long nx, stride;
    double tol, min_zncc;
    if (!PyArg_ParseTuple(args, "OOOiiiOOlliOOiddOOOOO", &ref, &refpix, &dfm, &order, &width, &height, &xs, &ys, &nx,
                          &stride, &half, &P, &fit, &max_iter, &tol, &min_zncc, &zncc, &iters, &status, &done, &data))
        return NULL;
    Buffers bs = {.n = 0};
    Points pts;
    Problem pb;
    Py_ssize_t count, nparams;
    int8_t *dn = NULL;
    long solved = -2;
    if (points(&bs, &pts, xs, ys, P, zncc, iters, status, &count, &nparams) == 0 &&
        problem(&bs, &pb, ref, refpix, dfm, order, width, height, half, (int)nparams, fit, max_iter, tol,
                min_zncc) == 0 && cache(&bs, &pb, data, Py_None, count) == 0) {
        const Py_ssize_t one[1] = {count};
        dn = array(&bs, done, 'b', 1, one, NULL, 1, "done");
        if (dn && (nx < 1 || count % nx != 0 || stride < 1))
            PyErr_Format(PyExc_ValueError, "%zd points do not make a grid of %ld columns (stride %ld)", count, nx, stride);
        else if (dn) {
            Py_BEGIN_ALLOW_THREADS
            solved = propagate(&pb, &pts, count, nx, stride, dn);
            Py_END_ALLOW_THREADS
            if (solved == -1)
                PyErr_NoMemory();
        }
    }
    release(&bs);
    if (solved < 0)
        return NULL;
    return PyLong_FromLong(solved);
}

static PyObject *py_guesses_from_lattice(PyObject *self, PyObject *args)
{
    PyObject *xs, *ys, *P, *zncc, *status, *done, *out;
    long nx, stride;
    if (!PyArg_ParseTuple(args, "OOllOOOOO", &xs, &ys, &nx, &stride, &P, &zncc, &status, &done, &out))
        return NULL;
    Buffers bs = {.n = 0};
    Points pts = {0};
    Py_ssize_t n[1], pshape[2];
    const int8_t *dn = NULL;
    int64_t *o = NULL;
    if ((pts.xs = array(&bs, xs, 'd', 1, NULL, n, 0, "xs"))) {
        const Py_ssize_t one[1] = {n[0]}, two[2] = {n[0], ANY};
        if ((pts.ys = array(&bs, ys, 'd', 1, one, NULL, 0, "ys")) && (pts.P = array(&bs, P, 'd', 2, two, pshape, 1, "P")) &&
            (pts.zncc = array(&bs, zncc, 'd', 1, one, NULL, 0, "zncc")) &&
            (pts.status = array(&bs, status, 'b', 1, one, NULL, 0, "status")) &&
            (dn = array(&bs, done, 'b', 1, one, NULL, 0, "done")))
            o = array(&bs, out, 'q', 1, one, NULL, 1, "out");
    }
    long count = -1;
    if (o && (nx < 1 || n[0] % nx != 0 || stride < 1 || (pshape[1] != 6 && pshape[1] != 12)))
        PyErr_SetString(PyExc_ValueError, "the points do not make a grid, or the warps are neither affine nor quadratic");
    else if (o)
        count = guesses_from_lattice(&pts, (int)pshape[1], n[0], nx, stride, dn, o);
    release(&bs);
    if (count < 0)
        return NULL;
    return PyLong_FromLong(count);
}

static PyObject *py_grid_cells(PyObject *self, PyObject *args)
{
    PyObject *px, *py, *triangle, *weights;
    long nx;
    double longest;
    if (!PyArg_ParseTuple(args, "OOldOO", &px, &py, &nx, &longest, &triangle, &weights))
        return NULL;
    Buffers bs = {.n = 0};
    Py_ssize_t n[1], raster[2];
    const double *x, *y = NULL;
    int64_t *tri = NULL;
    double *w = NULL;
    if ((x = array(&bs, px, 'd', 1, NULL, n, 0, "px"))) {
        const Py_ssize_t one[1] = {n[0]};
        if ((y = array(&bs, py, 'd', 1, one, NULL, 0, "py")) &&
            (tri = array(&bs, triangle, 'q', 2, NULL, raster, 1, "triangle"))) {
            const Py_ssize_t three[3] = {raster[0], raster[1], 2};
            w = array(&bs, weights, 'd', 3, three, NULL, 1, "weights");
        }
    }
    long found = -1;
    if (w && (nx < 1 || n[0] % nx != 0))
        PyErr_SetString(PyExc_ValueError, "the points do not make a grid");
    else if (w) {
        Py_BEGIN_ALLOW_THREADS
        found = grid_cells(x, y, n[0] / nx, nx, longest, (long)raster[0], (long)raster[1], tri, w);
        Py_END_ALLOW_THREADS
    }
    release(&bs);
    if (found < 0)
        return NULL;
    return PyLong_FromLong(found);
}

static PyMethodDef methods[] = {
    {"spline_coefficients", py_spline_coefficients, METH_VARARGS,
     "spline_coefficients(image, order, out): B-spline coefficients of a float64 image into the padded float32 out."},
    {"pixel_gradients", py_pixel_gradients, METH_VARARGS,
     "pixel_gradients(coef, order, width, height, out): value, d/dx, d/dy at every pixel centre."},
    {"sample", py_sample, METH_VARARGS, "sample(coef, order, width, height, x, y, out): values, NaN outside."},
    {"gradient", py_gradient, METH_VARARGS,
     "gradient(coef, order, width, height, x, y, gx, gy): gradients, NaN outside."},
    {"shift_warp", py_shift_warp, METH_VARARGS, "shift_warp(p, ox, oy, out): a warp moved by (ox, oy) pixels."},
    {"solve_points", py_solve_points, METH_VARARGS, "IC-GN of every point (see stereodic.dic.icgn)."},
    {"reference_status", py_reference_status, METH_VARARGS,
     "Reference-side status of every point, and optionally its reference data (see stereodic.dic.icgn)."},
    {"propagate", py_propagate, METH_VARARGS, "Reliability-guided propagation (see stereodic.dic.propagation)."},
    {"guesses_from_lattice", py_guesses_from_lattice, METH_VARARGS, "Guesses from the solved lattice."},
    {"grid_cells", py_grid_cells, METH_VARARGS,
     "grid_cells(px, py, nx, longest, triangle, weights): raster cells in a grid's triangles (see raster.c)."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_kernels", NULL, -1, methods};

PyMODINIT_FUNC PyInit__kernels(void)
{
    PyObject *m = PyModule_Create(&module);
    if (m && PyModule_AddIntConstant(m, "PAD", PAD) < 0) {
        Py_DECREF(m);
        return NULL;
    }
    return m;
}

/* stereodic.strain._kernels: the compiled kernel of stereodic.strain.fit (the 3-D strain fit of
 * `StrainFit`), which documents it.
 *
 * Arrays come in through the buffer protocol, checked by stereodic/src/buffers.h. The GIL is released
 * while the kernel runs; OpenMP threads share the grid's rows. */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <math.h>

#include "buffers.h"

/* Eigenvalues of the symmetric 3x3 `a` (overwritten) by cyclic Jacobi rotations; *l0 <= *l1 <= *l2 get
 * them, out[3] the unit eigenvector of l0. */
static void smallest_eigenvector(double a[3][3], double out[3], double *l0, double *l1, double *l2)
{
    double v[3][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
    static const int pairs[3][2] = {{0, 1}, {0, 2}, {1, 2}};
    for (int sweep = 0; sweep < 50; ++sweep) {
        const double off = a[0][1] * a[0][1] + a[0][2] * a[0][2] + a[1][2] * a[1][2];
        if (off <= 1e-36 * (a[0][0] * a[0][0] + a[1][1] * a[1][1] + a[2][2] * a[2][2]) || off == 0.0)
            break;
        for (int r = 0; r < 3; ++r) {
            const int p = pairs[r][0], q = pairs[r][1];
            if (a[p][q] == 0.0)
                continue;
            const double theta = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
            const double t = (theta >= 0 ? 1.0 : -1.0) / (fabs(theta) + sqrt(theta * theta + 1.0));
            const double c = 1.0 / sqrt(t * t + 1.0), s = t * c;
            for (int k = 0; k < 3; ++k) {   /* a <- J^T a J, J the rotation in the (p, q) plane */
                const double akp = a[k][p], akq = a[k][q];
                a[k][p] = c * akp - s * akq;
                a[k][q] = s * akp + c * akq;
            }
            for (int k = 0; k < 3; ++k) {
                const double apk = a[p][k], aqk = a[q][k];
                a[p][k] = c * apk - s * aqk;
                a[q][k] = s * apk + c * aqk;
            }
            for (int k = 0; k < 3; ++k) {
                const double vkp = v[k][p], vkq = v[k][q];
                v[k][p] = c * vkp - s * vkq;
                v[k][q] = s * vkp + c * vkq;
            }
        }
    }
    int i0 = 0;
    for (int i = 1; i < 3; ++i)
        if (a[i][i] < a[i0][i0])
            i0 = i;
    int i1 = (i0 + 1) % 3, i2 = (i0 + 2) % 3;
    if (a[i1][i1] > a[i2][i2]) {
        const int t = i1;
        i1 = i2;
        i2 = t;
    }
    for (int k = 0; k < 3; ++k)
        out[k] = v[k][i0];
    *l0 = a[i0][i0];
    *l1 = a[i1][i1];
    *l2 = a[i2][i2];
}

static int finite3(const double *p)
{
    return isfinite(p[0]) && isfinite(p[1]) && isfinite(p[2]);
}

/* The fit at grid point (i, j) of an ny x nx grid (`py_fit_all`'s docstring); the outputs at (i, j) are
 * set to their blank values first. */
static void fit_point(const double *X, const double *D, Py_ssize_t ny, Py_ssize_t nx, Py_ssize_t i, Py_ssize_t j,
                      int h, double min_count, double *exx, double *eyy, double *exy, char *ok, double *grad,
                      double *normal, double *e1)
{
    const Py_ssize_t at = i * nx + j;
    exx[at] = eyy[at] = exy[at] = NAN;
    ok[at] = 0;
    for (int a = 0; a < 3; ++a) {
        normal[at * 3 + a] = a == 2 ? 1.0 : 0.0;
        e1[at * 3 + a] = a == 0 ? 1.0 : 0.0;
        grad[(at * 3 + a) * 2] = grad[(at * 3 + a) * 2 + 1] = NAN;
    }
    const double *xc = X + at * 3;
    if (!(finite3(xc) && finite3(D + at * 3)))
        return;
    double count = 0.0, A[3] = {0, 0, 0}, SD[3] = {0, 0, 0}, B[3][3] = {{0}}, C[3][3] = {{0}};
    const Py_ssize_t i0 = i - h > 0 ? i - h : 0, i1 = i + h + 1 < ny ? i + h + 1 : ny;
    const Py_ssize_t j0 = j - h > 0 ? j - h : 0, j1 = j + h + 1 < nx ? j + h + 1 : nx;
    for (Py_ssize_t ii = i0; ii < i1; ++ii)
        for (Py_ssize_t jj = j0; jj < j1; ++jj) {
            const double *x = X + (ii * nx + jj) * 3, *d = D + (ii * nx + jj) * 3;
            if (!(finite3(x) && finite3(d)))
                continue;
            count += 1.0;
            const double p[3] = {x[0] - xc[0], x[1] - xc[1], x[2] - xc[2]};
            for (int a = 0; a < 3; ++a) {
                A[a] += p[a];
                SD[a] += d[a];
                for (int b = 0; b < 3; ++b) {
                    B[a][b] += p[a] * p[b];
                    C[a][b] += p[a] * d[b];
                }
            }
        }
    if (count < min_count)
        return;
    double cov[3][3], n[3], l0, l1, l2;
    for (int a = 0; a < 3; ++a)
        for (int b = 0; b < 3; ++b)
            cov[a][b] = B[a][b] / count - A[a] * A[b] / (count * count);
    smallest_eigenvector(cov, n, &l0, &l1, &l2);
    if (n[2] < 0)
        for (int a = 0; a < 3; ++a)
            n[a] = -n[a];
    double f1[3], f2[3];
    for (int a = 0; a < 3; ++a)
        f1[a] = (a == 0 ? 1.0 : 0.0) - n[0] * n[a];
    const double norm = sqrt(f1[0] * f1[0] + f1[1] * f1[1] + f1[2] * f1[2]);
    for (int a = 0; a < 3; ++a) {
        normal[at * 3 + a] = n[a];
        f1[a] /= norm > 1e-300 ? norm : 1e-300;
        e1[at * 3 + a] = f1[a];
    }
    if (!(l1 > 1e-6 * (l2 > 1e-300 ? l2 : 1e-300)) || !(norm > 1e-6))
        return;
    f2[0] = n[1] * f1[2] - n[2] * f1[1];
    f2[1] = n[2] * f1[0] - n[0] * f1[2];
    f2[2] = n[0] * f1[1] - n[1] * f1[0];
    /* normal equations of (1, s, t) and their right-hand sides (rows 1, s, t; columns D's components) */
    double N[3][3], Ni[3][3], rhs[3][3];
    N[0][0] = count;
    N[0][1] = N[1][0] = f1[0] * A[0] + f1[1] * A[1] + f1[2] * A[2];
    N[0][2] = N[2][0] = f2[0] * A[0] + f2[1] * A[1] + f2[2] * A[2];
    N[1][1] = N[1][2] = N[2][2] = 0.0;
    for (int a = 0; a < 3; ++a)
        for (int b = 0; b < 3; ++b) {
            N[1][1] += f1[a] * B[a][b] * f1[b];
            N[1][2] += f1[a] * B[a][b] * f2[b];
            N[2][2] += f2[a] * B[a][b] * f2[b];
        }
    N[2][1] = N[1][2];
    const double det = N[0][0] * (N[1][1] * N[2][2] - N[1][2] * N[2][1]) -
                       N[0][1] * (N[1][0] * N[2][2] - N[1][2] * N[2][0]) +
                       N[0][2] * (N[1][0] * N[2][1] - N[1][1] * N[2][0]);
    if (!(det > 0))
        return;
    for (int a = 0; a < 3; ++a)
        for (int b = 0; b < 3; ++b) {   /* the inverse from the cofactors (N is symmetric) */
            const int r0 = (b + 1) % 3, r1 = (b + 2) % 3, c0 = (a + 1) % 3, c1 = (a + 2) % 3;
            Ni[a][b] = (N[r0][c0] * N[r1][c1] - N[r0][c1] * N[r1][c0]) / det;
        }
    for (int b = 0; b < 3; ++b) {
        rhs[0][b] = SD[b];
        rhs[1][b] = f1[0] * C[0][b] + f1[1] * C[1][b] + f1[2] * C[2][b];
        rhs[2][b] = f2[0] * C[0][b] + f2[1] * C[1][b] + f2[2] * C[2][b];
    }
    double g11 = 0.0, g22 = 0.0, g12 = 0.0;
    for (int b = 0; b < 3; ++b) {   /* b: D's component; its slopes along s and t */
        const double ds = Ni[1][0] * rhs[0][b] + Ni[1][1] * rhs[1][b] + Ni[1][2] * rhs[2][b];
        const double dt = Ni[2][0] * rhs[0][b] + Ni[2][1] * rhs[1][b] + Ni[2][2] * rhs[2][b];
        grad[(at * 3 + b) * 2] = ds;
        grad[(at * 3 + b) * 2 + 1] = dt;
        const double u1 = f1[b] + ds, u2 = f2[b] + dt;
        g11 += u1 * u1;
        g22 += u2 * u2;
        g12 += u1 * u2;
    }
    exx[at] = 0.5 * (g11 - 1.0);
    eyy[at] = 0.5 * (g22 - 1.0);
    exy[at] = 0.5 * g12;
    ok[at] = 1;
}

static PyObject *py_fit_all(PyObject *self, PyObject *args)
{
    PyObject *X_o, *D_o, *exx_o, *eyy_o, *exy_o, *ok_o, *grad_o, *normal_o, *e1_o;
    int window;
    double min_count;
    if (!PyArg_ParseTuple(args, "OOidOOOOOOO", &X_o, &D_o, &window, &min_count, &exx_o, &eyy_o, &exy_o, &ok_o,
                          &grad_o, &normal_o, &e1_o))
        return NULL;
    if (window < 3 || window % 2 == 0) {
        PyErr_Format(PyExc_ValueError, "strain window must be odd and >= 3, got %d", window);
        return NULL;
    }
    Buffers bs = {.n = 0};
    const Py_ssize_t field[3] = {ANY, ANY, 3};
    Py_ssize_t g[3];
    const double *X, *D;
    double *exx, *eyy, *exy, *grad, *normal, *e1;
    char *ok;
    if (!(X = array(&bs, X_o, 'd', 3, field, g, 0, "X")))
        goto fail;
    const Py_ssize_t two[2] = {g[0], g[1]}, three[3] = {g[0], g[1], 3}, four[4] = {g[0], g[1], 3, 2};
    if (!(D = array(&bs, D_o, 'd', 3, three, NULL, 0, "D")) ||
        !(exx = array(&bs, exx_o, 'd', 2, two, NULL, 1, "exx")) ||
        !(eyy = array(&bs, eyy_o, 'd', 2, two, NULL, 1, "eyy")) ||
        !(exy = array(&bs, exy_o, 'd', 2, two, NULL, 1, "exy")) ||
        !(ok = array(&bs, ok_o, '?', 2, two, NULL, 1, "ok")) ||
        !(grad = array(&bs, grad_o, 'd', 4, four, NULL, 1, "grad")) ||
        !(normal = array(&bs, normal_o, 'd', 3, three, NULL, 1, "normal")) ||
        !(e1 = array(&bs, e1_o, 'd', 3, three, NULL, 1, "e1")))
        goto fail;
    const Py_ssize_t ny = g[0], nx = g[1];
    Py_BEGIN_ALLOW_THREADS
#pragma omp parallel for schedule(dynamic, 4)
    for (Py_ssize_t i = 0; i < ny; ++i)
        for (Py_ssize_t j = 0; j < nx; ++j)
            fit_point(X, D, ny, nx, i, j, window / 2, min_count, exx, eyy, exy, ok, grad, normal, e1);
    Py_END_ALLOW_THREADS
    return finish(&bs, 0);
fail:
    return finish(&bs, -1);
}

static PyMethodDef methods[] = {
    {"fit_all", py_fit_all, METH_VARARGS,
     "fit_all(X, D, window, min_count, exx, eyy, exy, ok, grad, normal, e1): the plane fits of StrainFit "
     "(stereodic.strain.fit) at every point of the (ny, nx) grid of surface points X (ny, nx, 3) and their "
     "displacements D, into the output arrays. Per centre point c: the moments of the window's valid points "
     "about c give the covariance, whose smallest eigenvector is the normal n (towards +z); e1 = x projected "
     "on the plane, e2 = n x e1; the plane D = a + b s + c t in (s, t) = ((X - c).e1, (X - c).e2) is solved "
     "from its 3x3 normal equations. A point is valid where it and its displacement are finite, its window "
     "holds min_count valid points, the points are not all on a line (second eigenvalue > 1e-6 of the "
     "largest), x is not along n, and the normal matrix is regular."},
    {NULL, NULL, 0, NULL}};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_kernels", NULL, -1, methods};

PyMODINIT_FUNC PyInit__kernels(void)
{
    return PyModule_Create(&module);
}

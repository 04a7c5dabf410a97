/* Arrays in and out of stereodic's compiled kernels (the extensions stereodic.dic._kernels,
 * stereodic.stereo._kernels, stereodic.strain._kernels): numpy arrays through the buffer protocol,
 * C-contiguous, each of the dtype and shape its function names, checked here so that a wrong call raises
 * ValueError or TypeError instead of reading out of bounds (`array`), and released when the call ends
 * (`finish`). Include after Python.h. */
#ifndef STEREODIC_BUFFERS_H
#define STEREODIC_BUFFERS_H

#define MAX_BUFFERS 24
#define ANY (-1)

typedef struct {
    Py_buffer b[MAX_BUFFERS];
    int n;
} Buffers;

static void release(Buffers *bs)
{
    for (int i = 0; i < bs->n; ++i)
        PyBuffer_Release(&bs->b[i]);
    bs->n = 0;
}

/* The data of array `o` (C-contiguous, element type 'd' float64, 'f' float32, 'b' int8, '?' bool, 'i'
 * int32 or 'q' int64), of `ndim` dimensions whose sizes must equal shape[] where not ANY; the sizes found go to
 * found[] (if not NULL). NULL with ValueError/TypeError set otherwise. */
static void *array(Buffers *bs, PyObject *o, char type, int ndim, const Py_ssize_t *shape, Py_ssize_t *found,
                   int writable, const char *name)
{
    if (bs->n == MAX_BUFFERS) {
        PyErr_SetString(PyExc_RuntimeError, "too many arrays in one call");
        return NULL;
    }
    Py_buffer *v = &bs->b[bs->n];
    if (PyObject_GetBuffer(o, v, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (writable ? PyBUF_WRITABLE : 0)) < 0)
        return NULL;
    bs->n++;
    const char *f = v->format ? v->format : "B";
    if (*f == '@' || *f == '=' || *f == '<')
        ++f;
    char kind = f[0];
    if (kind == 'l' || kind == 'q')
        kind = v->itemsize == 8 ? 'q' : (v->itemsize == 4 ? 'i' : '?');
    const Py_ssize_t size = type == 'd' || type == 'q' ? 8 : type == 'f' || type == 'i' ? 4 : 1;
    if (kind != type || f[1] != '\0' || v->itemsize != size) {
        PyErr_Format(PyExc_TypeError, "%s: expected element type '%c', got '%s'", name, type, v->format);
        return NULL;
    }
    if (v->ndim != ndim) {
        PyErr_Format(PyExc_ValueError, "%s: expected %d dimensions, got %d", name, ndim, v->ndim);
        return NULL;
    }
    for (int i = 0; i < ndim; ++i) {
        if (shape && shape[i] != ANY && v->shape[i] != shape[i]) {
            PyErr_Format(PyExc_ValueError, "%s: size %zd along axis %d, expected %zd", name, v->shape[i], i, shape[i]);
            return NULL;
        }
        if (found)
            found[i] = v->shape[i];
    }
    return v->buf;
}

/* The end of a kernel's Python function: the call's buffers released; None, or NULL where rc < 0: the
 * exception already set, else (a kernel that ran out of memory) MemoryError. */
static inline PyObject *finish(Buffers *bs, int rc)
{
    release(bs);
    if (rc < 0) {
        if (!PyErr_Occurred())
            PyErr_NoMemory();
        return NULL;
    }
    Py_RETURN_NONE;
}

#endif

/* canfdi._ckernel: the C core's face to CPython (limited API 3.11, one abi3 module for every
 * later Python). Each function takes the caller's buffers (numpy arrays, C-contiguous, of the
 * dtype the docstring says: canfdi.core.kernel makes them so) and their sizes, checks that
 * every buffer holds exactly what the sizes say, and runs the core on them in place. */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <string.h>

#include "cfdi.h"

typedef struct {
    Py_buffer view;
    int held;
} held_buffer;

static int take(PyObject *obj, held_buffer *b, int writable, Py_ssize_t bytes, const char *name)
{
    if (PyObject_GetBuffer(obj, &b->view, writable ? PyBUF_WRITABLE : PyBUF_SIMPLE) < 0) {
        return -1;
    }
    b->held = 1;
    if (b->view.len != bytes) {
        PyErr_Format(PyExc_ValueError, "%s: expected %zd bytes, got %zd", name, bytes,
                     b->view.len);
        return -1;
    }
    return 0;
}

static void release(held_buffer *b, size_t count)
{
    size_t i;
    for (i = 0; i < count; i++) {
        if (b[i].held) {
            PyBuffer_Release(&b[i].view);
            b[i].held = 0;
        }
    }
}

static int sizes_ok(Py_ssize_t a, Py_ssize_t b, Py_ssize_t c)
{
    /* every size >= 0 and their product far from overflowing */
    return a >= 0 && b >= 0 && c >= 0 && (b == 0 || a <= PY_SSIZE_T_MAX / 64 / (b ? b : 1))
           && (c == 0 || a * b <= PY_SSIZE_T_MAX / 64 / c);
}

PyDoc_STRVAR(fir_block_doc,
"fir_block(x, rows, width, coef, uses, S, m, out)\n\n"
"The residual bank's block form (cfdi_fir_block): x (rows, width) float64, coef and uses\n"
"(S+1, width, m) float64 and uint8, out (rows - S, m) float64, written.");

static PyObject *fir_block(PyObject *self, PyObject *args)
{
    PyObject *ox, *ocoef, *ouses, *oout;
    Py_ssize_t rows, width, S, m;
    held_buffer b[4];
    int status;
    (void)self;
    memset(b, 0, sizeof b);

    if (!PyArg_ParseTuple(args, "OnnOOnnO", &ox, &rows, &width, &ocoef, &ouses, &S, &m, &oout)) {
        return NULL;
    }
    if (!sizes_ok(rows, width, 1) || !sizes_ok(S + 1, width, m) || S < 0 || rows <= S
        || width == 0 || m == 0) {
        PyErr_SetString(PyExc_ValueError, "fir_block: sizes do not fit (rows > S >= 0, "
                                          "width and m > 0)");
        return NULL;
    }
    if (take(ox, &b[0], 0, rows * width * (Py_ssize_t)sizeof(cfdi_real), "x") < 0
        || take(ocoef, &b[1], 0, (S + 1) * width * m * (Py_ssize_t)sizeof(cfdi_real), "coef") < 0
        || take(ouses, &b[2], 0, (S + 1) * width * m, "uses") < 0
        || take(oout, &b[3], 1, (rows - S) * m * (Py_ssize_t)sizeof(cfdi_real), "out") < 0) {
        release(b, 4);
        return NULL;
    }
    Py_BEGIN_ALLOW_THREADS
    status = cfdi_fir_block((const cfdi_real *)b[0].view.buf, (size_t)rows, (size_t)width,
                            (const cfdi_real *)b[1].view.buf, (const uint8_t *)b[2].view.buf,
                            (size_t)S, (size_t)m, (cfdi_real *)b[3].view.buf);
    Py_END_ALLOW_THREADS
    release(b, 4);
    if (status != CFDI_OK) {
        PyErr_Format(PyExc_ValueError, "fir_block: status %d", status);
        return NULL;
    }
    Py_RETURN_NONE;
}

PyDoc_STRVAR(ph_block_doc,
"ph_block(k, x, n, c, delta, h, state, last_zero, g_up, g_down, alarm) -> done\n\n"
"Two-sided Page-Hinkley over a block to its first alarm row (cfdi_ph_block): k (n,) int64,\n"
"x (n, c) float64, delta and h (c,) float64, state (c, 2) float64 and last_zero (c, 2)\n"
"int64 updated, g_up and g_down (n, c) float64 and alarm (c,) int8 written.");

static PyObject *ph_block(PyObject *self, PyObject *args)
{
    PyObject *ok, *ox, *od, *oh, *ost, *olz, *ogu, *ogd, *oal;
    Py_ssize_t n, c;
    held_buffer b[9];
    size_t done = 0;
    int status;
    const Py_ssize_t R = (Py_ssize_t)sizeof(cfdi_real);
    (void)self;
    memset(b, 0, sizeof b);

    if (!PyArg_ParseTuple(args, "OOnnOOOOOOO", &ok, &ox, &n, &c, &od, &oh, &ost, &olz, &ogu,
                          &ogd, &oal)) {
        return NULL;
    }
    if (!sizes_ok(n, c, 2) || c == 0) {
        PyErr_SetString(PyExc_ValueError, "ph_block: sizes do not fit (n >= 0, c > 0)");
        return NULL;
    }
    if (take(ok, &b[0], 0, n * 8, "k") < 0 || take(ox, &b[1], 0, n * c * R, "x") < 0
        || take(od, &b[2], 0, c * R, "delta") < 0 || take(oh, &b[3], 0, c * R, "h") < 0
        || take(ost, &b[4], 1, 2 * c * R, "state") < 0
        || take(olz, &b[5], 1, 2 * c * 8, "last_zero") < 0
        || take(ogu, &b[6], 1, n * c * R, "g_up") < 0
        || take(ogd, &b[7], 1, n * c * R, "g_down") < 0
        || take(oal, &b[8], 1, c, "alarm") < 0) {
        release(b, 9);
        return NULL;
    }
    Py_BEGIN_ALLOW_THREADS
    status = cfdi_ph_block((const int64_t *)b[0].view.buf, (const cfdi_real *)b[1].view.buf,
                           (size_t)n, (size_t)c, (const cfdi_real *)b[2].view.buf,
                           (const cfdi_real *)b[3].view.buf, (cfdi_real *)b[4].view.buf,
                           (int64_t *)b[5].view.buf, (cfdi_real *)b[6].view.buf,
                           (cfdi_real *)b[7].view.buf, (int8_t *)b[8].view.buf, &done);
    Py_END_ALLOW_THREADS
    release(b, 9);
    if (status != CFDI_OK) {
        PyErr_Format(PyExc_ValueError, "ph_block: status %d", status);
        return NULL;
    }
    return PyLong_FromSize_t(done);
}

static PyMethodDef methods[] = {
    {"fir_block", fir_block, METH_VARARGS, fir_block_doc},
    {"ph_block", ph_block, METH_VARARGS, ph_block_doc},
    {NULL, NULL, 0, NULL}
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_ckernel",
    "canfdi's C core (canfdi/_c): the residual bank and the Page-Hinkley detectors.",
    -1, methods, NULL, NULL, NULL, NULL
};

PyMODINIT_FUNC PyInit__ckernel(void)
{
    return PyModule_Create(&module);
}

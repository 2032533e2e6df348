/* canfdi._ckernel: the C core's face to CPython (limited API 3.11, one abi3 module for every
 * later Python). Each function takes the caller's buffers (numpy arrays, C-contiguous, of the
 * dtype the docstring says: canfdi.core.kernel makes them so) and their sizes, checks that
 * every buffer holds exactly what the sizes say, and runs the core on them in place. */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <string.h>

#include "cfdi.h"
#include "decode.h"
#include "e2e.h"

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

PyDoc_STRVAR(decode_block_doc,
"decode_block(tables, n, id, dlc, flags, data, long_row, longdata, n_long, status, slot,\n"
"             values, counters)\n\n"
"Check and decode n frames from a drive's tables (cfdi_decode_block). tables: the tuple\n"
"(std_id, std_entry, n_std, ext_id, ext_entry, n_ext, entry, n_entries, n_slots, e2e_spec,\n"
"e2e_bytes, n_profiles, sig_int, sig_real, n_signals, ids_int, ids_real, n_ids, width) of\n"
"canfdi.bus.ctables.BusTables; the frames' id (n,) uint32, dlc and flags (n,) uint8, data\n"
"(n, 8) uint8, long_row (n,) int32, longdata (n_long, 64) uint8; status (n,) int8, slot (n,)\n"
"int16, values (n, width) float64 and counters (n,) int64 written.");

static PyObject *decode_block(PyObject *self, PyObject *args)
{
    PyObject *tables, *oid, *odlc, *oflags, *odata, *olr, *old, *ost, *osl, *ova, *oco;
    PyObject *t_sid, *t_std, *t_eid, *t_eent, *t_ent, *t_spec, *t_bytes, *t_si, *t_sr, *t_ii;
    PyObject *t_ir;
    Py_ssize_t n, n_long, n_std, n_ext, n_entries, n_slots, n_profiles, n_signals, n_ids, width;
    held_buffer b[22];
    cfdi_bus bus;
    int status;
    (void)self;
    memset(b, 0, sizeof b);

    if (!PyArg_ParseTuple(args, "O!nOOOOOOnOOOO", &PyTuple_Type, &tables, &n, &oid, &odlc,
                          &oflags, &odata, &olr, &old, &n_long, &ost, &osl, &ova, &oco)) {
        return NULL;
    }
    if (!PyArg_ParseTuple(tables, "OOnOOnOnnOOnOOnOOnn", &t_sid, &t_std, &n_std, &t_eid, &t_eent,
                          &n_ext, &t_ent, &n_entries, &n_slots, &t_spec, &t_bytes, &n_profiles,
                          &t_si, &t_sr, &n_signals, &t_ii, &t_ir, &n_ids, &width)) {
        return NULL;
    }
    if (!sizes_ok(n, 64, 8) || !sizes_ok(n_long, 64, 1) || !sizes_ok(n, width, 8)
        || !sizes_ok(n_std, 8, 1) || !sizes_ok(n_ext, 8, 1)
        || !sizes_ok(n_entries, CFDI_ENTRY_INTS, 8)
        || !sizes_ok(n_profiles, CFDI_E2E_INTS + CFDI_E2E_BYTES, 4)
        || !sizes_ok(n_signals, CFDI_SIG_INTS + CFDI_SIG_REALS, 8) || !sizes_ok(n_ids, 8, 1)
        || n_slots < 0 || n_slots > n_entries) {
        PyErr_SetString(PyExc_ValueError, "decode_block: sizes do not fit");
        return NULL;
    }
    if (take(t_sid, &b[21], 0, n_std * 8, "std_id") < 0
        || take(t_std, &b[0], 0, n_std * 4, "std_entry") < 0
        || take(t_eid, &b[1], 0, n_ext * 8, "ext_id") < 0
        || take(t_eent, &b[2], 0, n_ext * 4, "ext_entry") < 0
        || take(t_ent, &b[3], 0, n_entries * CFDI_ENTRY_INTS * 8, "entry") < 0
        || take(t_spec, &b[4], 0, n_profiles * CFDI_E2E_INTS * 4, "e2e_spec") < 0
        || take(t_bytes, &b[5], 0, n_profiles * CFDI_E2E_BYTES, "e2e_bytes") < 0
        || take(t_si, &b[6], 0, n_signals * CFDI_SIG_INTS * 8, "sig_int") < 0
        || take(t_sr, &b[7], 0, n_signals * CFDI_SIG_REALS * 8, "sig_real") < 0
        || take(t_ii, &b[8], 0, n_ids * 8, "ids_int") < 0
        || take(t_ir, &b[9], 0, n_ids * 8, "ids_real") < 0
        || take(oid, &b[10], 0, n * 4, "id") < 0 || take(odlc, &b[11], 0, n, "dlc") < 0
        || take(oflags, &b[12], 0, n, "flags") < 0 || take(odata, &b[13], 0, n * 8, "data") < 0
        || take(olr, &b[14], 0, n * 4, "long_row") < 0
        || take(old, &b[15], 0, n_long * 64, "longdata") < 0
        || take(ost, &b[16], 1, n, "status") < 0 || take(osl, &b[17], 1, n * 2, "slot") < 0
        || take(ova, &b[18], 1, n * width * 8, "values") < 0
        || take(oco, &b[19], 1, n * 8, "counters") < 0) {
        release(b, 22);
        return NULL;
    }
    bus.std_id = (const int64_t *)b[21].view.buf;
    bus.std_entry = (const int32_t *)b[0].view.buf;
    bus.n_std = (size_t)n_std;
    bus.ext_id = (const int64_t *)b[1].view.buf;
    bus.ext_entry = (const int32_t *)b[2].view.buf;
    bus.n_ext = (size_t)n_ext;
    bus.entry = (const int64_t *)b[3].view.buf;
    bus.n_entries = (size_t)n_entries;
    bus.n_slots = (size_t)n_slots;
    bus.e2e_spec = (const int32_t *)b[4].view.buf;
    bus.e2e_bytes = (const uint8_t *)b[5].view.buf;
    bus.n_profiles = (size_t)n_profiles;
    bus.sig_int = (const int64_t *)b[6].view.buf;
    bus.sig_real = (const double *)b[7].view.buf;
    bus.n_signals = (size_t)n_signals;
    bus.ids_int = (const int64_t *)b[8].view.buf;
    bus.ids_real = (const double *)b[9].view.buf;
    bus.n_ids = (size_t)n_ids;
    bus.width = (size_t)width;
    Py_BEGIN_ALLOW_THREADS
    status = cfdi_decode_block(&bus, (size_t)n, (const uint32_t *)b[10].view.buf,
                               (const uint8_t *)b[11].view.buf, (const uint8_t *)b[12].view.buf,
                               (const uint8_t *)b[13].view.buf, (const int32_t *)b[14].view.buf,
                               (const uint8_t *)b[15].view.buf, (size_t)n_long,
                               (int8_t *)b[16].view.buf, (int16_t *)b[17].view.buf,
                               (double *)b[18].view.buf, (int64_t *)b[19].view.buf);
    Py_END_ALLOW_THREADS
    release(b, 22);
    if (status != CFDI_OK) {
        PyErr_Format(PyExc_ValueError, "decode_block: the tables are malformed (status %d)",
                     status);
        return NULL;
    }
    Py_RETURN_NONE;
}

PyDoc_STRVAR(gate_block_doc,
"gate_block(state, bound, confirm, t, n_t, rows, n_rows, out, dropped, steps) -> (n_dropped,\n"
"n_steps, done)\n\n"
"The time gate over a block (cfdi_gate_block): state (7,) int64 updated, t (n_t,) int64,\n"
"rows (n_rows,) int64, out (n_t,) int64 written at rows, dropped (n_rows,) int64 and steps\n"
"(n_rows, 2) int64 written.");

static PyObject *gate_block(PyObject *self, PyObject *args)
{
    PyObject *ost, *ot, *orows, *oout, *odr, *osteps;
    Py_ssize_t n_t, n_rows;
    long long bound, confirm;
    held_buffer b[6];
    size_t n_dropped = 0, n_steps = 0, done = 0;
    int status;
    (void)self;
    memset(b, 0, sizeof b);

    if (!PyArg_ParseTuple(args, "OLLOnOnOOO", &ost, &bound, &confirm, &ot, &n_t, &orows, &n_rows,
                          &oout, &odr, &osteps)) {
        return NULL;
    }
    if (!sizes_ok(n_t, 8, 1) || !sizes_ok(n_rows, 16, 1)) {
        PyErr_SetString(PyExc_ValueError, "gate_block: sizes do not fit");
        return NULL;
    }
    if (take(ost, &b[0], 1, CFDI_GATE_STATE * 8, "state") < 0
        || take(ot, &b[1], 0, n_t * 8, "t") < 0 || take(orows, &b[2], 0, n_rows * 8, "rows") < 0
        || take(oout, &b[3], 1, n_t * 8, "out") < 0
        || take(odr, &b[4], 1, n_rows * 8, "dropped") < 0
        || take(osteps, &b[5], 1, n_rows * 16, "steps") < 0) {
        release(b, 6);
        return NULL;
    }
    Py_BEGIN_ALLOW_THREADS
    status = cfdi_gate_block((int64_t *)b[0].view.buf, (int64_t)bound, (int64_t)confirm,
                             (const int64_t *)b[1].view.buf, (size_t)n_t,
                             (const int64_t *)b[2].view.buf, (size_t)n_rows,
                             (int64_t *)b[3].view.buf, (int64_t *)b[4].view.buf, &n_dropped,
                             (int64_t *)b[5].view.buf, &n_steps, &done);
    Py_END_ALLOW_THREADS
    release(b, 6);
    if (status != CFDI_OK) {
        PyErr_Format(PyExc_ValueError, "gate_block: status %d", status);
        return NULL;
    }
    return Py_BuildValue("nnn", (Py_ssize_t)n_dropped, (Py_ssize_t)n_steps, (Py_ssize_t)done);
}

PyDoc_STRVAR(latest_block_doc,
"latest_block(ok, n_ok, slot, n, values, vwidth, t, dest, n_slots, cols, instants, upto,\n"
"             n_samples, max_age, value, time, width, out)\n\n"
"The trigger and grid clocks' samples (cfdi_latest_block): ok (n_ok,) int64, slot (n,)\n"
"int16, values (n, vwidth) float64, t (n,) int64, dest (n_slots, cols) int64, instants and\n"
"upto (n_samples,) int64, value (width,) float64 and time (width,) int64 updated, out\n"
"(n_samples, width) float64 written.");

static PyObject *latest_block(PyObject *self, PyObject *args)
{
    PyObject *ook, *osl, *ova, *ot, *ode, *oin, *oup, *ovl, *otm, *oout;
    Py_ssize_t n_ok, n, vwidth, n_slots, cols, n_samples, width;
    double max_age;
    held_buffer b[10];
    int status;
    (void)self;
    memset(b, 0, sizeof b);

    if (!PyArg_ParseTuple(args, "OnOnOnOOnnOOndOOnO", &ook, &n_ok, &osl, &n, &ova, &vwidth, &ot,
                          &ode, &n_slots, &cols, &oin, &oup, &n_samples, &max_age, &ovl, &otm,
                          &width, &oout)) {
        return NULL;
    }
    if (!sizes_ok(n_ok, 8, 1) || !sizes_ok(n, vwidth + 2, 8) || !sizes_ok(n_slots, cols, 8)
        || !sizes_ok(n_samples, width + 2, 8) || !sizes_ok(width, 16, 1)) {
        PyErr_SetString(PyExc_ValueError, "latest_block: sizes do not fit");
        return NULL;
    }
    if (take(ook, &b[0], 0, n_ok * 8, "ok") < 0 || take(osl, &b[1], 0, n * 2, "slot") < 0
        || take(ova, &b[2], 0, n * vwidth * 8, "values") < 0
        || take(ot, &b[3], 0, n * 8, "t") < 0
        || take(ode, &b[4], 0, n_slots * cols * 8, "dest") < 0
        || take(oin, &b[5], 0, n_samples * 8, "instants") < 0
        || take(oup, &b[6], 0, n_samples * 8, "upto") < 0
        || take(ovl, &b[7], 1, width * 8, "value") < 0
        || take(otm, &b[8], 1, width * 8, "time") < 0
        || take(oout, &b[9], 1, n_samples * width * 8, "out") < 0) {
        release(b, 10);
        return NULL;
    }
    Py_BEGIN_ALLOW_THREADS
    status = cfdi_latest_block((const int64_t *)b[0].view.buf, (size_t)n_ok,
                               (const int16_t *)b[1].view.buf, (size_t)n,
                               (const double *)b[2].view.buf, (size_t)vwidth,
                               (const int64_t *)b[3].view.buf, (const int64_t *)b[4].view.buf,
                               (size_t)n_slots, (size_t)cols, (const int64_t *)b[5].view.buf,
                               (const int64_t *)b[6].view.buf, (size_t)n_samples, max_age,
                               (double *)b[7].view.buf, (int64_t *)b[8].view.buf,
                               (size_t)width, (double *)b[9].view.buf);
    Py_END_ALLOW_THREADS
    release(b, 10);
    if (status != CFDI_OK) {
        PyErr_Format(PyExc_ValueError, "latest_block: status %d", status);
        return NULL;
    }
    Py_RETURN_NONE;
}

PyDoc_STRVAR(counter_run_doc,
"counter_run(state, buffer, width, rows, slots, counters, times, n_frames, values, n_values,\n"
"            vwidth, dest, n_slots, cols, mod, dt_ns, slack, status, n_status, ks, done,\n"
"            gaps, samples) -> (n_out, used)\n\n"
"The counter clock's state machine over a run of frames (cfdi_counter_run): state (12,)\n"
"int64 and buffer (width,) float64 updated; rows, slots, counters, times (n_frames,) int64;\n"
"values (n_values, vwidth) float64; dest (n_slots, cols) int64; status (n_status,) int8\n"
"updated; ks, done, gaps (2 n_frames,) int64 and samples (2 n_frames, width) float64\n"
"written.");

static PyObject *counter_run(PyObject *self, PyObject *args)
{
    PyObject *ost, *obuf, *orows, *oslots, *octr, *otimes, *oval, *odest, *ostatus;
    PyObject *oks, *odone, *ogaps, *osamples;
    Py_ssize_t width, n_frames, n_values, vwidth, n_slots, cols, n_status;
    long long mod;
    double dt_ns, slack;
    held_buffer b[13];
    size_t n_out = 0, used = 0;
    int status;
    (void)self;
    memset(b, 0, sizeof b);

    if (!PyArg_ParseTuple(args, "OOnOOOOnOnnOnnLddOnOOOO", &ost, &obuf, &width, &orows,
                          &oslots, &octr, &otimes, &n_frames, &oval, &n_values, &vwidth, &odest,
                          &n_slots, &cols, &mod, &dt_ns, &slack, &ostatus, &n_status, &oks,
                          &odone, &ogaps, &osamples)) {
        return NULL;
    }
    if (!sizes_ok(width, 16, 1) || !sizes_ok(n_frames, 2 * width + 8, 8)
        || !sizes_ok(n_values, vwidth + 1, 8) || !sizes_ok(n_slots, cols, 8)
        || !sizes_ok(n_status, 1, 1)) {
        PyErr_SetString(PyExc_ValueError, "counter_run: sizes do not fit");
        return NULL;
    }
    if (take(ost, &b[0], 1, CFDI_CTR_STATE * 8, "state") < 0
        || take(obuf, &b[1], 1, width * 8, "buffer") < 0
        || take(orows, &b[2], 0, n_frames * 8, "rows") < 0
        || take(oslots, &b[3], 0, n_frames * 8, "slots") < 0
        || take(octr, &b[4], 0, n_frames * 8, "counters") < 0
        || take(otimes, &b[5], 0, n_frames * 8, "times") < 0
        || take(oval, &b[6], 0, n_values * vwidth * 8, "values") < 0
        || take(odest, &b[7], 0, n_slots * cols * 8, "dest") < 0
        || take(ostatus, &b[8], 1, n_status, "status") < 0
        || take(oks, &b[9], 1, 2 * n_frames * 8, "ks") < 0
        || take(odone, &b[10], 1, 2 * n_frames * 8, "done") < 0
        || take(ogaps, &b[11], 1, 2 * n_frames * 8, "gaps") < 0
        || take(osamples, &b[12], 1, 2 * n_frames * width * 8, "samples") < 0) {
        release(b, 13);
        return NULL;
    }
    Py_BEGIN_ALLOW_THREADS
    status = cfdi_counter_run((int64_t *)b[0].view.buf, (double *)b[1].view.buf, (size_t)width,
                              (const int64_t *)b[2].view.buf, (const int64_t *)b[3].view.buf,
                              (const int64_t *)b[4].view.buf, (const int64_t *)b[5].view.buf,
                              (size_t)n_frames, (const double *)b[6].view.buf,
                              (size_t)n_values, (size_t)vwidth, (const int64_t *)b[7].view.buf,
                              (size_t)n_slots, (size_t)cols, (int64_t)mod, dt_ns, slack,
                              (int8_t *)b[8].view.buf, (size_t)n_status,
                              (int64_t *)b[9].view.buf, (int64_t *)b[10].view.buf,
                              (int64_t *)b[11].view.buf, (double *)b[12].view.buf, &n_out,
                              &used);
    Py_END_ALLOW_THREADS
    release(b, 13);
    if (status != CFDI_OK) {
        PyErr_Format(PyExc_ValueError, "counter_run: status %d", status);
        return NULL;
    }
    return Py_BuildValue("nn", (Py_ssize_t)n_out, (Py_ssize_t)used);
}

PyDoc_STRVAR(info_block_doc,
"info_block(q, p, m, S, Gz, Gu, sigma, H, d, columns, K, onsets, n, k, U, rn, gamma, J, h,\n"
"           meat, rr, n_eq, work)\n\n"
"A diagnosis' information sums over n samples (cfdi_info_block): Gz (q, m, S+1), Gu (p, m,\n"
"S+1), sigma (m,) float64, columns (H, d, 2) int32, onsets (K,) and k (n,) int64, U (n, S+1,\n"
"p), rn (n, m) and gamma (m, m) float64; J and meat (H, K, d, d), h (H, K, d), rr (1,)\n"
"float64 and n_eq (1,) int64 added to; work ((3 m + 2 d + 1) d) float64 scratch.");

static PyObject *info_block(PyObject *self, PyObject *args)
{
    PyObject *o[15];
    Py_ssize_t q, p, m, S, H, d, K, n;
    held_buffer b[15];
    int status;
    const Py_ssize_t R = (Py_ssize_t)sizeof(cfdi_real);
    (void)self;
    memset(b, 0, sizeof b);

    if (!PyArg_ParseTuple(args, "nnnnOOOnnOnOnOOOOOOOOOO", &q, &p, &m, &S, &o[0], &o[1], &o[2],
                          &H, &d, &o[3], &K, &o[4], &n, &o[5], &o[6], &o[7], &o[8], &o[9],
                          &o[10], &o[11], &o[12], &o[13], &o[14])) {
        return NULL;
    }
    if (q <= 0 || p <= 0 || m <= 0 || S < 0 || H <= 0 || d <= 0 || K <= 0 || n < 0
        || !sizes_ok(q + p, m, S + 1) || !sizes_ok(H * K, d, d) || !sizes_ok(n, S + 1, p)
        || !sizes_ok(n, m, 1) || !sizes_ok(m, m, 1) || !sizes_ok(H, K, 1)) {
        PyErr_SetString(PyExc_ValueError, "info_block: sizes do not fit (q, p, m, H, d, K > 0, "
                                          "S, n >= 0)");
        return NULL;
    }
    if (take(o[0], &b[0], 0, q * m * (S + 1) * R, "Gz") < 0
        || take(o[1], &b[1], 0, p * m * (S + 1) * R, "Gu") < 0
        || take(o[2], &b[2], 0, m * R, "sigma") < 0
        || take(o[3], &b[3], 0, H * d * 2 * 4, "columns") < 0
        || take(o[4], &b[4], 0, K * 8, "onsets") < 0
        || take(o[5], &b[5], 0, n * 8, "k") < 0
        || take(o[6], &b[6], 0, n * (S + 1) * p * R, "U") < 0
        || take(o[7], &b[7], 0, n * m * R, "rn") < 0
        || take(o[8], &b[8], 0, m * m * R, "gamma") < 0
        || take(o[9], &b[9], 1, H * K * d * d * R, "J") < 0
        || take(o[10], &b[10], 1, H * K * d * R, "h") < 0
        || take(o[11], &b[11], 1, H * K * d * d * R, "meat") < 0
        || take(o[12], &b[12], 1, R, "rr") < 0
        || take(o[13], &b[13], 1, 8, "n_eq") < 0
        || take(o[14], &b[14], 1, (Py_ssize_t)CFDI_INFO_WORK(m, d, S, p, H, H * d) * R,
                "work") < 0) {
        release(b, 15);
        return NULL;
    }
    Py_BEGIN_ALLOW_THREADS
    status = cfdi_info_block((size_t)q, (size_t)p, (size_t)m, (size_t)S,
                             (const cfdi_real *)b[0].view.buf, (const cfdi_real *)b[1].view.buf,
                             (const cfdi_real *)b[2].view.buf, (size_t)H, (size_t)d,
                             (const int32_t *)b[3].view.buf, (size_t)K,
                             (const int64_t *)b[4].view.buf, (size_t)n,
                             (const int64_t *)b[5].view.buf, (const cfdi_real *)b[6].view.buf,
                             (const cfdi_real *)b[7].view.buf, (const cfdi_real *)b[8].view.buf,
                             (cfdi_real *)b[9].view.buf, (cfdi_real *)b[10].view.buf,
                             (cfdi_real *)b[11].view.buf, (cfdi_real *)b[12].view.buf,
                             (int64_t *)b[13].view.buf, (cfdi_real *)b[14].view.buf,
                             (size_t)(b[14].view.len / R));
    Py_END_ALLOW_THREADS
    release(b, 15);
    if (status != CFDI_OK) {
        PyErr_Format(PyExc_ValueError, "info_block: status %d", status);
        return NULL;
    }
    Py_RETURN_NONE;
}

PyDoc_STRVAR(info_solve_doc,
"info_solve(count, d, J, h, rr, theta, P, cost, lu, perm) -> status\n\n"
"Every fit solved (cfdi_info_solve): J (count, d, d), h (count, d), rr (count,) float64;\n"
"theta (count, d), P (count, d, d), cost (count,) float64 written; lu (d, d) float64 and\n"
"perm (d,) size_t scratch. Returns 0, or -3 for a singular J.");

static PyObject *info_solve(PyObject *self, PyObject *args)
{
    PyObject *o[8];
    Py_ssize_t count, d;
    held_buffer b[8];
    int status;
    const Py_ssize_t R = (Py_ssize_t)sizeof(cfdi_real);
    (void)self;
    memset(b, 0, sizeof b);

    if (!PyArg_ParseTuple(args, "nnOOOOOOOO", &count, &d, &o[0], &o[1], &o[2], &o[3], &o[4],
                          &o[5], &o[6], &o[7])) {
        return NULL;
    }
    if (count < 0 || d <= 0 || !sizes_ok(count, d, d)) {
        PyErr_SetString(PyExc_ValueError, "info_solve: sizes do not fit (count >= 0, d > 0)");
        return NULL;
    }
    if (take(o[0], &b[0], 0, count * d * d * R, "J") < 0
        || take(o[1], &b[1], 0, count * d * R, "h") < 0
        || take(o[2], &b[2], 0, count * R, "rr") < 0
        || take(o[3], &b[3], 1, count * d * R, "theta") < 0
        || take(o[4], &b[4], 1, count * d * d * R, "P") < 0
        || take(o[5], &b[5], 1, count * R, "cost") < 0
        || take(o[6], &b[6], 1, d * d * R, "lu") < 0
        || take(o[7], &b[7], 1, d * (Py_ssize_t)sizeof(size_t), "perm") < 0) {
        release(b, 8);
        return NULL;
    }
    Py_BEGIN_ALLOW_THREADS
    status = cfdi_info_solve((size_t)count, (size_t)d, (const cfdi_real *)b[0].view.buf,
                             (const cfdi_real *)b[1].view.buf, (const cfdi_real *)b[2].view.buf,
                             (cfdi_real *)b[3].view.buf, (cfdi_real *)b[4].view.buf,
                             (cfdi_real *)b[5].view.buf, (cfdi_real *)b[6].view.buf,
                             (size_t *)b[7].view.buf);
    Py_END_ALLOW_THREADS
    release(b, 8);
    if (status != CFDI_OK && status != CFDI_ESINGULAR) {
        PyErr_Format(PyExc_ValueError, "info_solve: status %d", status);
        return NULL;
    }
    return PyLong_FromLong(status);
}

PyDoc_STRVAR(decide_doc,
"decide(H, d, p, K, kind, index, n_params, full, name_key, twins, penalty, max_samples,\n"
"       settings, theta, P, cost, rr, meat, u_abs, n_u, units, leftover, n_eq, since, named,\n"
"       best_onset, cost_h, order, near, result) -> scale\n\n"
"A diagnosis' decision at one sample (cfdi_decide). The hypotheses: kind (H,) int8, index,\n"
"n_params, full (H,) int32, name_key (H,) int64, twins (H, H) uint8, penalty (H,) float64;\n"
"settings (4,) float64: isolation_margin, settle_rel_std, settle_noise, max_fit_variance.\n"
"The fits: theta (H, K, d), P and meat (H, K, d, d), cost and rr (H, K), u_abs and n_u (p,),\n"
"units (H, d) float64, leftover (H,) int32. Written: best_onset, order (H,) int64, cost_h\n"
"(H,) float64, near (H,) uint8, result (5,) int32: action, best, kb, size_known,\n"
"form_known. Returns the best fit's noise scale.");

static PyObject *decide(PyObject *self, PyObject *args)
{
    PyObject *o[22];
    Py_ssize_t H, d, p, K;
    long long max_samples, n_eq, since;
    int named, status;
    held_buffer b[22];
    cfdi_hypotheses hy;
    cfdi_decide_settings st;
    cfdi_decision dec;
    const double *set;
    int32_t *result;
    const Py_ssize_t R = (Py_ssize_t)sizeof(cfdi_real);
    (void)self;
    memset(b, 0, sizeof b);

    if (!PyArg_ParseTuple(args, "nnnnOOOOOOOLOOOOOOOOOOLLiOOOOO", &H, &d, &p, &K, &o[0],
                          &o[1], &o[2], &o[3], &o[4], &o[5], &o[6], &max_samples, &o[7],
                          &o[8], &o[9], &o[10], &o[11], &o[12], &o[13], &o[14], &o[15],
                          &o[16], &n_eq, &since, &named, &o[17], &o[18], &o[19], &o[20],
                          &o[21])) {
        return NULL;
    }
    if (H <= 0 || d <= 0 || p <= 0 || K <= 0 || !sizes_ok(H, K, d * d) || !sizes_ok(H, H, 1)) {
        PyErr_SetString(PyExc_ValueError, "decide: sizes do not fit (H, d, p, K > 0)");
        return NULL;
    }
    if (take(o[0], &b[0], 0, H, "kind") < 0 || take(o[1], &b[1], 0, H * 4, "index") < 0
        || take(o[2], &b[2], 0, H * 4, "n_params") < 0 || take(o[3], &b[3], 0, H * 4, "full") < 0
        || take(o[4], &b[4], 0, H * 8, "name_key") < 0 || take(o[5], &b[5], 0, H * H, "twins") < 0
        || take(o[6], &b[6], 0, H * R, "penalty") < 0
        || take(o[7], &b[7], 0, 4 * (Py_ssize_t)sizeof(double), "settings") < 0
        || take(o[8], &b[8], 0, H * K * d * R, "theta") < 0
        || take(o[9], &b[9], 0, H * K * d * d * R, "P") < 0
        || take(o[10], &b[10], 0, H * K * R, "cost") < 0
        || take(o[11], &b[11], 0, H * K * R, "rr") < 0
        || take(o[12], &b[12], 0, H * K * d * d * R, "meat") < 0
        || take(o[13], &b[13], 0, p * R, "u_abs") < 0 || take(o[14], &b[14], 0, p * R, "n_u") < 0
        || take(o[15], &b[15], 0, H * d * R, "units") < 0
        || take(o[16], &b[16], 0, H * 4, "leftover") < 0
        || take(o[17], &b[17], 1, H * 8, "best_onset") < 0
        || take(o[18], &b[18], 1, H * R, "cost_h") < 0
        || take(o[19], &b[19], 1, H * 8, "order") < 0 || take(o[20], &b[20], 1, H, "near") < 0
        || take(o[21], &b[21], 1, 5 * 4, "result") < 0) {
        release(b, 22);
        return NULL;
    }
    hy.H = (size_t)H;
    hy.d = (size_t)d;
    hy.p = (size_t)p;
    hy.kind = (const int8_t *)b[0].view.buf;
    hy.index = (const int32_t *)b[1].view.buf;
    hy.n_params = (const int32_t *)b[2].view.buf;
    hy.full = (const int32_t *)b[3].view.buf;
    hy.name_key = (const int64_t *)b[4].view.buf;
    hy.twins = (const uint8_t *)b[5].view.buf;
    hy.penalty = (const cfdi_real *)b[6].view.buf;
    set = (const double *)b[7].view.buf;
    st.max_samples = (int64_t)max_samples;
    st.isolation_margin = set[0];
    st.settle_rel_std = set[1];
    st.settle_noise = set[2];
    st.max_fit_variance = set[3];
    status = cfdi_decide(&hy, &st, (size_t)K, (const cfdi_real *)b[8].view.buf,
                         (const cfdi_real *)b[9].view.buf, (const cfdi_real *)b[10].view.buf,
                         (const cfdi_real *)b[11].view.buf, (int64_t)n_eq,
                         (const cfdi_real *)b[12].view.buf, (const cfdi_real *)b[13].view.buf,
                         (const cfdi_real *)b[14].view.buf, (const cfdi_real *)b[15].view.buf,
                         (const int32_t *)b[16].view.buf, (int64_t)since, named,
                         (int64_t *)b[17].view.buf, (cfdi_real *)b[18].view.buf,
                         (int64_t *)b[19].view.buf, (uint8_t *)b[20].view.buf, &dec);
    if (status == CFDI_OK) {
        result = (int32_t *)b[21].view.buf;
        result[0] = dec.action;
        result[1] = dec.best;
        result[2] = dec.kb;
        result[3] = dec.size_known;
        result[4] = dec.form_known;
    }
    release(b, 22);
    if (status != CFDI_OK) {
        PyErr_Format(PyExc_ValueError, "decide: status %d (a table entry out of range)", status);
        return NULL;
    }
    return PyFloat_FromDouble((double)dec.scale);
}

static PyMethodDef methods[] = {
    {"fir_block", fir_block, METH_VARARGS, fir_block_doc},
    {"ph_block", ph_block, METH_VARARGS, ph_block_doc},
    {"decode_block", decode_block, METH_VARARGS, decode_block_doc},
    {"gate_block", gate_block, METH_VARARGS, gate_block_doc},
    {"latest_block", latest_block, METH_VARARGS, latest_block_doc},
    {"counter_run", counter_run, METH_VARARGS, counter_run_doc},
    {"info_block", info_block, METH_VARARGS, info_block_doc},
    {"info_solve", info_solve, METH_VARARGS, info_solve_doc},
    {"decide", decide, METH_VARARGS, decide_doc},
    {NULL, NULL, 0, NULL}
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_ckernel",
    "canfdi's C core (canfdi/_c): frame decode with E2E, the time gate, the sample clocks'\n"
    "state machine and samples, the residual bank and the Page-Hinkley detectors.",
    -1, methods, NULL, NULL, NULL, NULL
};

PyMODINIT_FUNC PyInit__ckernel(void)
{
    return PyModule_Create(&module);
}

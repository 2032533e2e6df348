/* One drive's monitor frame by frame (drive.h): the block functions called with blocks of one,
 * in the order the daemon's Python calls them (canfdi.bus.assembler.SampleAssembler.push_batch,
 * then canfdi.methods.parity.diagnoser.ParityDiagnoser.update up to its first alarm). */
#include <math.h>
#include <string.h>

#include "drive.h"
#include "e2e.h"

static size_t width_of(const cfdi_drive_tables *t)
{
    return t->p + t->q;
}

int cfdi_drive_init(cfdi_drive *d, const cfdi_drive_tables *t, const cfdi_drive_memory *mem)
{
    size_t i, n;
    if (!d || !t || !mem || !t->bus || !t->dest || !t->coef || !t->uses || !t->sigma
        || !t->delta || !t->h || !mem->values || !mem->buffer || !mem->samples || !mem->ring
        || !mem->r || !mem->ph || !mem->last_zero || !mem->g_up || !mem->g_down
        || !mem->alarm) {
        return CFDI_EBADARG;
    }
    if (cfdi_bus_check(t->bus) != CFDI_OK || t->m == 0 || width_of(t) == 0 || t->mod <= 0
        || t->gate_bound <= 0 || t->gate_confirm < 1 || t->n_slots == 0 || t->cols == 0
        || t->n_slots > t->bus->n_slots || t->n_slots > 62 || !(t->dt_ns > 0.0)
        || (t->fault != NULL && cfdi_message_check(t->fault) != CFDI_OK)) {
        return CFDI_ESHAPE;
    }
    for (i = 0; i < t->n_slots * t->cols; i++) {
        if (t->dest[i] >= (int64_t)width_of(t)) {
            return CFDI_ESHAPE;
        }
    }
    for (i = 0; i < t->m; i++) {
        if (!(t->sigma[i] > 0)) {
            return CFDI_ESHAPE;
        }
    }
    memset(d, 0, sizeof *d);
    d->t = t;
    d->mem = *mem;
    d->ctr[CFDI_CTR_K] = -1;
    d->ctr[CFDI_CTR_LAST_COMPLETE] = -1;
    d->ctr[CFDI_CTR_LAST_DELIVERED] = -1;
    d->last_k = -1;
    n = (t->S + 1) * width_of(t);
    for (i = 0; i < n; i++) {
        mem->ring[i] = (cfdi_real)NAN;
    }
    for (i = 0; i < 2 * t->m; i++) {
        mem->ph[i] = 0;
        mem->last_zero[i] = -1;
    }
    memset(mem->alarm, 0, t->m);
    return CFDI_OK;
}

/* The bank forgets its window (a gap longer than it): every residual resumes after its own
 * window (ResidualBank.restart), or `count` rows are missing (ResidualBank.skip). */
static void ring_skip(cfdi_drive *d, int64_t count)
{
    const cfdi_drive_tables *t = d->t;
    size_t w = width_of(t), rows = t->S + 1, i, keep;
    cfdi_real *ring = d->mem.ring;
    if (count <= 0) {
        return;
    }
    keep = (uint64_t)count >= rows ? 0 : rows - (size_t)count;
    memmove(ring, ring + (rows - keep) * w, keep * w * sizeof *ring);
    for (i = keep * w; i < rows * w; i++) {
        ring[i] = (cfdi_real)NAN;
    }
}

/* The detection's FDI_FAULT queued (canfdi.monitor.Monitor.fault_frames of the "detected"
 * event): the tables' values, the alarm's sample modulo 2^32, the message's alive counter. */
static void queue_fault(cfdi_drive *d, int64_t k)
{
    const cfdi_message *msg = d->t->fault;
    double roles[CFDI_N_ROLES];
    cfdi_tx_frame *f;
    if (msg == NULL) {
        return;
    }
    if (d->tx_count == CFDI_TX_QUEUE) {
        d->tx_dropped += 1;
        return;
    }
    memcpy(roles, d->t->fault_roles, sizeof roles);
    roles[CFDI_ROLE_SAMPLE] = (double)((uint64_t)k & 0xFFFFFFFFu);
    f = &d->tx[(d->tx_head + d->tx_count) % CFDI_TX_QUEUE];
    /* (the message was checked at init: neither can fail) */
    if (cfdi_encode(msg, roles, f->data) != CFDI_OK
        || cfdi_e2e_protect(msg->e2e_spec, msg->e2e_bytes, f->data, msg->length,
                            d->fault_counter) != CFDI_OK) {
        d->tx_dropped += 1;
        return;
    }
    d->fault_counter += 1;
    f->id = msg->id;
    f->extended = msg->extended;
    f->len = msg->length;
    d->tx_count += 1;
}

/* One sample into the bank and, before the first alarm, the detectors
 * (ParityDiagnoser.update in MONITOR mode). row: [u, z] as the clock gives it. */
static int take_sample(cfdi_drive *d, int64_t k, const double *row)
{
    const cfdi_drive_tables *t = d->t;
    const cfdi_drive_memory *mem = &d->mem;
    size_t w = width_of(t), rows = t->S + 1, i;
    cfdi_real *last;
    int any = 0, status;
    size_t done = 0;
    if (d->last_k >= 0 && k != d->last_k + 1) {
        int64_t missing = k - d->last_k - 1;
        ring_skip(d, (missing > 0 && (uint64_t)missing <= t->S) ? missing : (int64_t)rows);
    }
    d->last_k = k;
    ring_skip(d, 1);
    last = mem->ring + (rows - 1) * w;
    for (i = 0; i < t->q; i++) {
        last[i] = (cfdi_real)row[t->p + i];
    }
    for (i = 0; i < t->p; i++) {
        last[t->q + i] = (cfdi_real)row[i];
    }
    status = cfdi_fir_block(mem->ring, rows, w, t->coef, t->uses, t->S, t->m, mem->r);
    if (status != CFDI_OK) {
        return status;
    }
    for (i = 0; i < t->m; i++) {
        mem->r[i] = mem->r[i] / t->sigma[i];
        any |= !isnan(mem->r[i]);
    }
    if (!any || d->alarmed) {
        return CFDI_OK; /* no residual yet (ParityDiagnoser.update returns none) */
    }
    status = cfdi_ph_block(&k, mem->r, 1, t->m, t->delta, t->h, mem->ph, mem->last_zero,
                           mem->g_up, mem->g_down, mem->alarm, &done);
    if (status != CFDI_OK) {
        return status;
    }
    if (done == 0) {
        /* ChangePointDetector.change_point: the earliest last zero of an alarming statistic,
         * plus one (an alarming statistic is above its threshold: not zero on this row). */
        int64_t onset = INT64_MAX;
        for (i = 0; i < t->m; i++) {
            if (mem->alarm[i] != 0) {
                int64_t z = mem->last_zero[2 * i + (mem->alarm[i] > 0 ? 0 : 1)];
                onset = z < onset ? z : onset;
            }
        }
        d->alarmed = 1;
        d->alarm_k = k;
        d->alarm_onset = onset + 1;
        queue_fault(d, k);
    }
    return CFDI_OK;
}

static int take_samples(cfdi_drive *d, const int64_t *ks, size_t n)
{
    size_t i, w = width_of(d->t);
    for (i = 0; i < n; i++) {
        int status = take_sample(d, ks[i], d->mem.samples + i * w);
        if (status != CFDI_OK) {
            return status;
        }
        d->samples += 1;
    }
    return CFDI_OK;
}

int cfdi_drive_on_frame(cfdi_drive *d, uint32_t id, uint8_t len, uint8_t flags,
                        const uint8_t *data, int64_t t_ns)
{
    const cfdi_drive_tables *t;
    uint8_t first[8] = {0}, whole[CFDI_MAX_PAYLOAD] = {0};
    int32_t long_row = 0;
    int8_t status = 0;
    int16_t slot = -1;
    int64_t counter = -1, row0 = 0, when = t_ns, dropped = 0, steps[2], ks[2], times[2],
            gaps[2], slot64, rc;
    size_t n_dropped = 0, n_steps = 0, done = 0, n_out = 0, used = 0;
    if (!d || !d->t || (len > 0 && !data) || len > CFDI_MAX_PAYLOAD) {
        return CFDI_EBADARG;
    }
    t = d->t;
    if (len > 0) {
        memcpy(whole, data, len);
    }
    memcpy(first, whole, 8);
    rc = cfdi_decode_checked(t->bus, 1, &id, &len, &flags, first, len > 8 ? &long_row : NULL,
                             whole, len > 8 ? 1 : 0, &status, &slot, d->mem.values, &counter);
    if (rc != CFDI_OK) {
        return (int)rc;
    }
    if (status == CFDI_ST_OK) {
        rc = cfdi_gate_block(d->gate, t->gate_bound, t->gate_confirm, &t_ns, 1, &row0, 1, &when,
                             &dropped, &n_dropped, steps, &n_steps, &done);
        if (rc != CFDI_OK) {
            return (int)rc;
        }
        d->clock_steps += (int64_t)n_steps;
        if (done != 1) {
            return CFDI_ESHAPE; /* a time near int64's ends: the daemon's Python takes those */
        }
        if (n_dropped) {
            status = CFDI_ST_TIME_JUMP;
        }
    }
    if (status == CFDI_ST_OK) {
        slot64 = slot;
        if (slot < 0 || (size_t)slot >= t->n_slots) {
            return CFDI_ESHAPE;
        }
        rc = cfdi_counter_run(d->ctr, d->mem.buffer, width_of(t), &row0, &slot64, &counter,
                              &when, 1, d->mem.values, 1, t->bus->width, t->dest, t->n_slots,
                              t->cols, t->mod, t->dt_ns, t->slack, &status, 1, ks, times, gaps,
                              d->mem.samples, &n_out, &used);
        if (rc != CFDI_OK) {
            return (int)rc;
        }
        if (used != 1) {
            return CFDI_ESHAPE;
        }
    }
    if (status < 0 || status >= CFDI_N_STATUS) {
        return CFDI_ESHAPE;
    }
    d->status_count[(size_t)status] += 1;
    rc = take_samples(d, ks, n_out);
    return rc != CFDI_OK ? (int)rc : status;
}

int cfdi_drive_finish(cfdi_drive *d)
{
    int64_t ks[1], times[1], gaps[1];
    size_t n_out = 0;
    int rc;
    if (!d || !d->t) {
        return CFDI_EBADARG;
    }
    rc = cfdi_counter_close(d->ctr, d->mem.buffer, width_of(d->t), d->t->dest, d->t->n_slots,
                            d->t->cols, ks, times, gaps, d->mem.samples, &n_out);
    return rc != CFDI_OK ? rc : take_samples(d, ks, n_out);
}

int cfdi_drive_poll_tx(cfdi_drive *d, cfdi_tx_frame *out)
{
    if (!d || !out) {
        return CFDI_EBADARG;
    }
    if (d->tx_count == 0) {
        return 0;
    }
    *out = d->tx[d->tx_head];
    d->tx_head = (d->tx_head + 1) % CFDI_TX_QUEUE;
    d->tx_count -= 1;
    return 1;
}

/* One drive's monitor frame by frame (drive.h): the block functions called with blocks of one,
 * in the order the daemon's Python calls them (canfdi.bus.assembler.SampleAssembler.push_batch,
 * then canfdi.methods.parity.diagnoser.ParityDiagnoser.update: monitoring up to its first
 * alarm, then that alarm's diagnosis up to its decision). */
#include <math.h>
#include <string.h>

#include "drive.h"
#include "e2e.h"

static size_t width_of(const cfdi_drive_tables *t)
{
    return t->p + t->q;
}

/* A diagnosis' tables and memory: every pointer there, sizes that fit (the tables' entries
 * are checked again where info.c and decide.c read them). */
static int diag_check(const cfdi_drive_tables *t, const cfdi_diag_memory *m)
{
    const cfdi_diag_tables *g = t->diag;
    const cfdi_hypotheses *hy = &g->hyp;
    if (!hy->kind || !hy->index || !hy->n_params || !hy->full || !hy->name_key || !hy->twins
        || !hy->penalty || !g->columns || !g->Gz || !g->Gu || !g->gamma || !g->units
        || !m->recent || !m->window || !m->U || !m->rn || !m->onsets || !m->J || !m->meat
        || !m->P || !m->h || !m->theta || !m->rr || !m->cost || !m->lu || !m->perm
        || !m->work || !m->u_abs || !m->n_u || !m->best_onset || !m->order || !m->cost_h
        || !m->near || !m->leftover) {
        return CFDI_EBADARG;
    }
    if (hy->H == 0 || hy->d == 0 || hy->p != t->p || g->max_onsets == 0 || g->lookback == 0
        || hy->d > CFDI_MAX_FAULTS || !(g->prior_precision > 0) || g->min_samples < 0) {
        return CFDI_ESHAPE;
    }
    return CFDI_OK;
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
    if (t->diag != NULL) {
        int status = diag_check(t, &mem->diag);
        if (status != CFDI_OK) {
            return status;
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

/* An FDI_FAULT queued (canfdi.monitor.Monitor.fault_frames): the tables' values, with the
 * state (0 detected, 1 named, 2 accepted), the channel's kind and index, the sample modulo
 * 2^32, the message's alive counter. */
static void queue_fault(cfdi_drive *d, int state, int32_t target, int32_t index, int64_t k)
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
    roles[CFDI_ROLE_STATE] = d->t->fault_states[state];
    roles[CFDI_ROLE_KIND] = d->t->fault_kinds[target];
    roles[CFDI_ROLE_INDEX] = (double)index;
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

/* -- the recent samples (canfdi.methods.parity.recent.RecentWindows) ------------------------
 * A ring of lookback + S + 1 rows [z, u] as the bank took them (a missing sample a row of
 * NaN), the newest's sample rec_last_k: the rows are consecutive samples, so a row's sample is
 * its distance from the newest. Residuals are not kept: a kept sample's are its window's
 * through the bank again, the same numbers. */
static size_t rec_size(const cfdi_drive *d)
{
    return d->t->diag->lookback + d->t->S + 1;
}

static void rec_push(cfdi_drive *d, int64_t k, const cfdi_real *row)
{
    size_t w = width_of(d->t), size = rec_size(d);
    memcpy(d->mem.diag.recent + d->rec_next * w, row, w * sizeof *row);
    d->rec_next = (d->rec_next + 1) % size;
    d->rec_wrapped |= d->rec_count + 1 > size;
    d->rec_count = d->rec_count + 1 > size ? size : d->rec_count + 1;
    d->rec_last_k = k;
}

/* The i-th held row, oldest first (i < rec_count). */
static const cfdi_real *rec_row(const cfdi_drive *d, size_t i)
{
    size_t size = rec_size(d);
    return d->mem.diag.recent + ((d->rec_next + size - d->rec_count + i) % size)
                                * width_of(d->t);
}

/* The window of the i-th held row (S + 1 rows ending at it, NaN before the first held) into
 * mem.diag.window, and its normalised residuals into mem.diag.rn: 1 when it has any. A row
 * whose window reaches rows overwritten is not offered (0). */
static int rec_window(cfdi_drive *d, size_t i)
{
    const cfdi_drive_tables *t = d->t;
    size_t w = width_of(t), rows = t->S + 1, r, c;
    cfdi_real *win = d->mem.diag.window;
    int any = 0;
    if (d->rec_wrapped && i < rows - 1) {
        return 0;
    }
    for (r = 0; r < rows; r++) {
        size_t back = rows - 1 - r; /* rows before row i */
        for (c = 0; c < w; c++) {
            win[r * w + c] = back > i ? (cfdi_real)NAN : rec_row(d, i - back)[c];
        }
    }
    if (cfdi_fir_block(win, rows, w, t->coef, t->uses, t->S, t->m, d->mem.diag.rn) != CFDI_OK) {
        return 0;
    }
    for (c = 0; c < t->m; c++) {
        d->mem.diag.rn[c] = d->mem.diag.rn[c] / t->sigma[c];
        any |= !isnan(d->mem.diag.rn[c]);
    }
    return any;
}

/* -- the diagnosis (canfdi.methods.parity.diagnoser: _start_diagnosis, _accumulate,
 * _diagnose) ---------------------------------------------------------------------------- */

/* numpy's nan_to_num of a command (info.c's reading of it). */
static cfdi_real finite_command(cfdi_real u)
{
    if (u != u) {
        return 0;
    }
    if (u > CFDI_REAL_MAX) {
        return CFDI_REAL_MAX;
    }
    return u < -CFDI_REAL_MAX ? -CFDI_REAL_MAX : u;
}

/* One sample into every fit: its window (S + 1 rows [z, u]) and residuals rn. */
static int absorb(cfdi_drive *d, int64_t k, const cfdi_real *window, const cfdi_real *rn)
{
    const cfdi_drive_tables *t = d->t;
    const cfdi_diag_tables *g = t->diag;
    cfdi_diag_memory *dm = &d->mem.diag;
    size_t w = width_of(t), r, j;
    for (r = 0; r <= t->S; r++) {
        for (j = 0; j < t->p; j++) {
            dm->U[r * t->p + j] = window[r * w + t->q + j];
        }
    }
    for (j = 0; j < t->p; j++) {
        cfdi_real u = dm->U[t->S * t->p + j];
        if (!isnan(u)) {
            dm->u_abs[j] += (cfdi_real)fabs(finite_command(u));
            dm->n_u[j] += 1;
        }
    }
    return cfdi_info_block(t->q, t->p, t->m, t->S, g->Gz, g->Gu, t->sigma, g->hyp.H, g->hyp.d,
                           g->columns, d->n_onsets, dm->onsets, 1, &k, dm->U, rn, g->gamma,
                           dm->J, dm->h, dm->meat, &d->rr, &d->n_eq, dm->work);
}

/* Up to `share` of the kept samples not yet absorbed (catch_k up to the alarm), oldest first. */
static int catch_up(cfdi_drive *d, size_t share)
{
    int64_t oldest = d->rec_last_k - (int64_t)d->rec_count + 1;
    int status;
    for (; share > 0 && d->catch_k <= d->alarm_k; share--, d->catch_k++) {
        if (d->catch_k >= oldest && rec_window(d, (size_t)(d->catch_k - oldest))) {
            status = absorb(d, d->catch_k, d->mem.diag.window, d->mem.diag.rn);
            if (status != CFDI_OK) {
                return status;
            }
        }
    }
    return CFDI_OK;
}

/* The alarm at k dated at change_point: the onsets tried (detect.onset_candidates, "ends"),
 * every fit reset (J0 = prior I), and the kept samples from the first onset on to absorb. */
static int start_diagnosis(cfdi_drive *d, int64_t k, int64_t change_point)
{
    const cfdi_diag_tables *g = d->t->diag;
    cfdi_diag_memory *dm = &d->mem.diag;
    size_t H = g->hyp.H, dd = g->hyp.d, K, n, i, c, head, total;
    int64_t first = k, lo, kf, oldest;
    /* The oldest sample kept with its window and residuals. */
    oldest = d->rec_last_k - (int64_t)d->rec_count + 1;
    for (i = 0; i < d->rec_count; i++) {
        if (rec_window(d, i)) {
            first = oldest + (int64_t)i;
            break;
        }
    }
    lo = change_point - (int64_t)g->onset_before;
    lo = lo > first ? lo : first;
    total = lo <= k ? (size_t)(k - lo + 1) : 0;
    K = total > g->max_onsets ? g->max_onsets : total;
    head = g->max_onsets / 2;
    for (i = 0; i < K; i++) {
        dm->onsets[i] = total > g->max_onsets && i >= head
                        ? k - (int64_t)(K - 1 - i) : lo + (int64_t)i;
    }
    if (K == 0) {
        dm->onsets[0] = k;
        K = 1;
    }
    d->n_onsets = K;
    n = H * K;
    for (i = 0; i < n; i++) {
        for (c = 0; c < dd * dd; c++) {
            dm->J[i * dd * dd + c] = c % (dd + 1) == 0 ? g->prior_precision : 0;
            dm->meat[i * dd * dd + c] = 0;
        }
        for (c = 0; c < dd; c++) {
            dm->h[i * dd + c] = 0;
        }
    }
    for (i = 0; i < g->hyp.p; i++) {
        dm->u_abs[i] = 0;
        dm->n_u[i] = 0;
    }
    for (i = 0; i < H; i++) { /* nothing accepted before: no leftover to tell apart */
        dm->leftover[i] = -1;
    }
    d->rr = 0;
    d->n_eq = 0;
    d->named = 0;
    d->diagnosing = 1;
    /* The kept samples from the first onset to the alarm are absorbed a share at a time,
     * this frame and the next min_samples: all of them before the first decision, none
     * overwritten before its turn (a share of one or more a sample outruns the ring), and no
     * frame paying for all at once. */
    kf = dm->onsets[0] > oldest ? dm->onsets[0] : oldest;
    d->catch_k = kf;
    n = kf <= k ? (size_t)(k - kf + 1) : 0;
    d->catch_share = n / (size_t)(g->min_samples + 1) + 1;
    return catch_up(d, d->catch_share);
}
static void record(cfdi_drive *d, int32_t event, int32_t target, int32_t index, int64_t k,
                   int64_t onset, cfdi_real value, cfdi_real eta)
{
    cfdi_event *e;
    if (d->n_events == sizeof d->events / sizeof d->events[0]) {
        return; /* (a naming and CFDI_MAX_FAULTS acceptances at most: init checked d) */
    }
    e = &d->events[d->n_events++];
    e->event = event;
    e->target = target;
    e->index = index;
    e->sample = k;
    e->onset = onset;
    e->value = value;
    e->eta = eta;
}

/* The channel an event names: 1 for an actuator (either form), 2 for a sensor. */
static int32_t target_of(int8_t kind)
{
    return kind == CFDI_HYP_ACTUATOR || kind == CFDI_HYP_ACTUATOR_BIAS ? 1 : 2;
}

/* NAMED (ParityDiagnoser._name): the faulty channel before its form and size are known; an
 * actuator by the offset it acts with now (its bias-only fit, where there is one). */
static void name_fault(cfdi_drive *d, const cfdi_decision *dec, int64_t k)
{
    const cfdi_hypotheses *hy = &d->t->diag->hyp;
    const cfdi_diag_memory *dm = &d->mem.diag;
    size_t src = (size_t)dec->best, i, K = d->n_onsets, kb;
    const cfdi_real *th;
    if (hy->kind[src] == CFDI_HYP_ACTUATOR) {
        for (i = 0; i < hy->H; i++) {
            if (hy->kind[i] == CFDI_HYP_ACTUATOR_BIAS && hy->index[i] == hy->index[src]) {
                src = i;
                break;
            }
        }
    }
    kb = (size_t)dm->best_onset[src];
    th = dm->theta + (src * K + kb) * hy->d;
    d->named = 1;
    record(d, CFDI_EVENT_NAMED, target_of(hy->kind[src]), hy->index[src], k, dm->onsets[kb],
           hy->kind[src] == CFDI_HYP_ACTUATOR ? th[1] : th[0], (cfdi_real)NAN);
    queue_fault(d, 1, target_of(hy->kind[src]), hy->index[src], k);
}

/* ACCEPTED (ParityDiagnoser._accept, a first fault): the best fit's channel with its
 * estimates; of a joint fit of sensors, each member whose bias is significant (beyond 5 of
 * its standard deviations), the alarm unexplained when none is. */
static void accept_fault(cfdi_drive *d, const cfdi_decision *dec, int64_t k)
{
    const cfdi_diag_tables *g = d->t->diag;
    const cfdi_hypotheses *hy = &g->hyp;
    const cfdi_diag_memory *dm = &d->mem.diag;
    size_t best = (size_t)dec->best, kb = (size_t)dec->kb, dd = hy->d, at, c;
    const cfdi_real *th;
    int64_t onset = dm->onsets[kb];
    int any = 0;
    at = best * d->n_onsets + kb;
    th = dm->theta + at * dd;
    switch (hy->kind[best]) {
    case CFDI_HYP_ACTUATOR:
        record(d, CFDI_EVENT_ACCEPTED, 1, hy->index[best], k, onset, th[1], 1 + th[0]);
        break;
    case CFDI_HYP_ACTUATOR_BIAS:
        record(d, CFDI_EVENT_ACCEPTED, 1, hy->index[best], k, onset, th[0], 1);
        break;
    case CFDI_HYP_SENSOR:
        record(d, CFDI_EVENT_ACCEPTED, 2, hy->index[best], k, onset, th[0], (cfdi_real)NAN);
        break;
    default: /* several sensors: the members' columns name them */
        for (c = 0; c < (size_t)hy->n_params[best]; c++) {
            cfdi_real var = cfdi_sandwich(dm->P + at * dd * dd, dm->meat + at * dd * dd, dd, c)
                            * dec->scale;
            if (fabs(th[c]) > 5 * sqrt(var)) {
                record(d, CFDI_EVENT_ACCEPTED, 2, g->columns[(best * dd + c) * 2 + 1], k, onset,
                       th[c], (cfdi_real)NAN);
                any = 1;
            }
        }
        if (!any) {
            record(d, CFDI_EVENT_UNEXPLAINED, 0, 0, k, onset, 0, (cfdi_real)NAN);
        }
    }
    for (c = 0; c < d->n_events; c++) {
        if (d->events[c].event == CFDI_EVENT_ACCEPTED) {
            queue_fault(d, 2, d->events[c].target, d->events[c].index, k);
        }
    }
}

/* A diagnosed sample (ParityDiagnoser._diagnose): absorbed into every fit, then from
 * min_samples after the alarm every fit solved and decided on. */
static int diagnose(cfdi_drive *d, int64_t k)
{
    const cfdi_diag_tables *g = d->t->diag;
    cfdi_diag_memory *dm = &d->mem.diag;
    size_t n, i;
    cfdi_decision dec;
    int status = absorb(d, k, d->mem.ring, d->mem.r);
    if (status != CFDI_OK || k - d->alarm_k < g->min_samples) {
        return status;
    }
    n = g->hyp.H * d->n_onsets;
    for (i = 0; i < n; i++) {
        dm->rr[i] = d->rr;
    }
    status = cfdi_info_solve(n, g->hyp.d, dm->J, dm->h, dm->rr, dm->theta, dm->P, dm->cost,
                             dm->lu, dm->perm);
    if (status == CFDI_ESINGULAR) { /* (numpy raises: J0 > 0 keeps it from happening) */
        d->singular += 1;
        return CFDI_OK;
    }
    if (status == CFDI_OK) {
        status = cfdi_decide(&g->hyp, &g->settings, d->n_onsets, dm->theta, dm->P, dm->cost,
                             dm->rr, d->n_eq, dm->meat, dm->u_abs, dm->n_u, g->units,
                             dm->leftover, k - d->alarm_k, d->named, dm->best_onset,
                             dm->cost_h, dm->order, dm->near, &dec);
    }
    if (status != CFDI_OK) {
        return status;
    }
    switch (dec.action) {
    case CFDI_DECIDE_NAME:
        name_fault(d, &dec, k);
        return CFDI_OK;
    case CFDI_DECIDE_ACCEPT:
    case CFDI_DECIDE_ACCEPT_NEAR:
        accept_fault(d, &dec, k);
        break;
    case CFDI_DECIDE_UNEXPLAINED:
        record(d, CFDI_EVENT_UNEXPLAINED, 0, 0, k, dm->onsets[dec.kb], 0, (cfdi_real)NAN);
        break;
    default:
        return CFDI_OK;
    }
    d->diagnosing = 0;
    d->decided = 1;
    return CFDI_OK;
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
    if (d->diagnosing && d->catch_k <= d->alarm_k) { /* (all before a gap changes the ring) */
        status = catch_up(d, d->last_k >= 0 && k != d->last_k + 1 ? SIZE_MAX : d->catch_share);
        if (status != CFDI_OK) {
            return status;
        }
    }
    if (d->last_k >= 0 && k != d->last_k + 1) {
        int64_t missing = k - d->last_k - 1, j;
        int short_gap = missing > 0 && (uint64_t)missing <= t->S;
        ring_skip(d, short_gap ? missing : (int64_t)rows);
        if (t->diag != NULL && short_gap) { /* lost samples: rows of NaN */
            for (j = 0; j < (int64_t)w; j++) {
                mem->diag.window[j] = (cfdi_real)NAN;
            }
            for (j = missing; j > 0; j--) {
                rec_push(d, k - j, mem->diag.window);
            }
        } else if (t->diag != NULL) {
            d->rec_count = d->rec_next = 0;
            d->rec_wrapped = 0;
        }
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
    if (t->diag != NULL) {
        rec_push(d, k, last);
    }
    if (!any) {
        return CFDI_OK; /* no residual yet (ParityDiagnoser.update returns none) */
    }
    if (d->diagnosing) {
        return diagnose(d, k);
    }
    if (d->alarmed) {
        return CFDI_OK;
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
        queue_fault(d, 0, 0, 0, k);
        if (t->diag != NULL) {
            return start_diagnosis(d, k, d->alarm_onset);
        }
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

/* One drive's monitor frame by frame (drive.h): the block functions called with blocks of one,
 * in the order the daemon's Python calls them (canfdi.bus.assembler.SampleAssembler.push_batch,
 * then canfdi.methods.parity.diagnoser.ParityDiagnoser.update), the samples kept for the
 * diagnoses, and what the monitor announces. The diagnosis itself is diagnose.c's, the
 * compensation compensate.c's. */
#include <math.h>
#include <string.h>

#include "drive_impl.h"
#include "e2e.h"

static size_t width_of(const cfdi_drive_tables *t)
{
    return t->p + t->q;
}

/* -- the memory block ------------------------------------------------------------------ */

typedef struct {
    unsigned char *base; /* NULL: only count */
    size_t used;
} carver;

static void *take(carver *c, size_t bytes)
{
    void *at = c->base ? c->base + c->used : NULL;
    c->used += CFDI_ALIGN8(bytes);
    return at;
}

/* The sizes a drive's memory is laid out by (drive.h's CFDI_DRIVE_MEMORY). */
typedef struct {
    size_t W, VW, S, M, P, H, D, K, R, Y, NC, NP, T, X, L;
} sizes;

static size_t longest_message(const cfdi_drive_tables *t)
{
    size_t L = 0;
    const cfdi_message *m[3];
    int i;
    m[0] = t->fault.msg;
    m[1] = t->estimate.msg;
    m[2] = t->status.msg;
    for (i = 0; i < 3; i++) {
        if (m[i] && m[i]->length > L) {
            L = m[i]->length;
        }
    }
    return L;
}

static sizes sizes_of(const cfdi_drive_tables *t)
{
    sizes z;
    const cfdi_diag_tables *g = t->diag;
    memset(&z, 0, sizeof z);
    z.W = width_of(t);
    z.VW = t->bus->width;
    z.S = t->S;
    z.M = t->m;
    z.P = t->p;
    z.X = t->tx_frames;
    z.L = longest_message(t);
    if (g) {
        size_t before = t->S + (size_t)(g->min_samples > (int64_t)(2 * t->S)
                                         ? g->min_samples : (int64_t)(2 * t->S));
        z.H = g->hyp.H;
        z.D = g->hyp.d;
        z.K = g->max_onsets + g->max_earlier;
        z.R = g->lookback + before + 1;
        z.Y = t->S + g->onset_before + 1;
        z.NC = g->lagged.n_cols;
        z.NP = g->lagged.n_pairs;
        z.T = g->track.max_params;
    }
    return z;
}

/* Every part of the memory block, in order (c->base NULL: the bytes only). */
static void carve(cfdi_drive *d, const cfdi_drive_tables *t, carver *c)
{
    sizes z = sizes_of(t);
    const size_t R = sizeof(cfdi_real);
    size_t fits;
    d->values = take(c, 8 * z.VW);
    d->row_raw = take(c, sizeof(cfdi_real) * z.W);
    d->buffer = take(c, 8 * z.W);
    d->samples = take(c, 16 * z.W);
    d->ring = take(c, R * (z.S + 1) * z.W);
    d->r = take(c, R * z.M);
    d->r_raw = take(c, R * z.M);
    d->ph = take(c, R * 2 * z.M);
    d->g_up = take(c, R * z.M);
    d->g_down = take(c, R * z.M);
    d->last_zero = take(c, 16 * z.M);
    d->alarm = take(c, z.M);
    d->tx = take(c, z.X * (6 + z.L));
    d->chan = take(c, sizeof(cfdi_comp_channel) * z.W);
    if (!t->diag) {
        return;
    }
    d->recent = take(c, R * (z.R + z.Y) * z.W);
    d->history = d->recent ? d->recent + z.R * z.W : NULL;
    d->window = take(c, R * (z.S + 1) * (z.W + z.P));
    d->U = d->window ? d->window + (z.S + 1) * z.W : NULL;
    d->work = take(c, R * (CFDI_INFO_WORK(z.M, z.D, z.S, z.P, z.H) + z.D * z.D * 3 + z.D * 2));
    d->fit_scratch = d->work ? d->work + CFDI_INFO_WORK(z.M, z.D, z.S, z.P, z.H) : NULL;
    d->onsets = take(c, 8 * z.K);
    /* the fits (a diagnosis') and the tracking's scratch (only between diagnoses) share */
    fits = z.H * z.K * (2 * z.D * z.D + z.D + 1);
    d->J = take(c, R * (fits > CFDI_TRACK_WORK(z.M, z.T) ? fits : CFDI_TRACK_WORK(z.M, z.T)));
    d->meat = d->J ? d->J + z.H * z.K * z.D * z.D : NULL;
    d->hc = d->J ? d->meat + z.H * z.K * z.D * z.D : NULL;
    d->track.work = d->J;
    d->u_abs = take(c, R * (2 * z.P + z.H));
    d->n_u = d->u_abs ? d->u_abs + z.P : NULL;
    d->cost_h = d->u_abs ? d->u_abs + 2 * z.P : NULL;
    d->perm = take(c, 8 * z.D);
    d->best_onset = take(c, 8 * z.H);
    d->order = take(c, 8 * z.H);
    d->near = take(c, z.H);
    d->leftover = take(c, 4 * z.H);
    d->lagged.psi = take(c, R * (z.S + 1) * (z.W - z.P) * z.NC);
    d->lagged.steady = take(c, R * z.K * z.NP);
    d->lagged.gram = take(c, R * z.NP);
    d->lagged.rows = take(c, R * z.M * z.NC);
    d->lagged.local = take(c, R * 2 * z.S * (z.W - z.P) * z.D);
    d->track.items = take(c, sizeof(cfdi_tracked) * z.T);
    d->track.fixes = take(c, sizeof(cfdi_correction) * z.T);
    d->track.J = take(c, R * (4 * z.T * z.T + 2 * z.T + z.P));
    if (d->track.J) {
        d->track.M = d->track.J + z.T * z.T;
        d->track.sJ = d->track.M + z.T * z.T;
        d->track.sM = d->track.sJ + z.T * z.T;
        d->track.h = d->track.sM + z.T * z.T;
        d->track.sh = d->track.h + z.T;
        d->track.u_abs = d->track.sh + z.T;
    }
}

/* -- checks ---------------------------------------------------------------------------- */

static int message_ok(const cfdi_monitor_message *m)
{
    return m->msg == NULL || cfdi_message_check(m->msg) == CFDI_OK;
}

/* A diagnosis' tables: every pointer there, sizes and entries that fit the drive. */
static int diag_check(const cfdi_drive_tables *t)
{
    const cfdi_diag_tables *g = t->diag;
    const cfdi_lagged_tables *lg = &g->lagged;
    const cfdi_track_tables *tk = &g->track;
    size_t i, H = g->hyp.H, d = g->hyp.d, K = g->max_onsets + g->max_earlier;
    if (!g->columns || !g->Gz || !g->Gu || !g->gamma || !g->units || !lg->cols
        || !lg->hyp_cols || !lg->pairs || !lg->hyp_pairs || !lg->noise || !lg->steady || !tk->chi2
        || !tk->ratio || !tk->unit || !g->twin_order || !g->twin_ratio) {
        return CFDI_EBADARG;
    }
    if (cfdi_hypotheses_check(&g->hyp, K) != CFDI_OK || g->hyp.p != t->p || g->max_onsets == 0
        || g->lookback == 0 || d > CFDI_MAX_FAULTS || !(g->prior_precision > 0)
        || g->min_samples < 0 || width_of(t) > CFDI_MAX_CHANNELS || t->m > 32
        || lg->S != t->S || lg->q != t->q || lg->m != t->m || lg->n_cols == 0
        || lg->n_pairs == 0 || tk->p != t->p || tk->n_channels != width_of(t)
        || tk->max_params == 0 || tk->max_params > 64 || tk->first_check < 1
        || t->tx_frames == 0) {
        return CFDI_ESHAPE;
    }
    for (i = 0; i < H * d; i++) {
        int32_t source = g->columns[2 * i], channel = g->columns[2 * i + 1];
        if (source < CFDI_COL_NONE || source > CFDI_COL_BIAS || channel < 0
            || (source == CFDI_COL_SENSOR && (size_t)channel >= t->q)
            || (source != CFDI_COL_SENSOR && source != CFDI_COL_NONE
                && (size_t)channel >= t->p)) {
            return CFDI_ESHAPE;
        }
        if (lg->hyp_cols[i] < -1 || (lg->hyp_cols[i] >= 0
                                     && (size_t)lg->hyp_cols[i] >= lg->n_cols)) {
            return CFDI_ESHAPE;
        }
    }
    for (i = 0; i < H * d * d; i++) {
        if (lg->hyp_pairs[i] < -1 || (lg->hyp_pairs[i] >= 0
                                      && (size_t)lg->hyp_pairs[i] >= lg->n_pairs)) {
            return CFDI_ESHAPE;
        }
    }
    for (i = 0; i < H; i++) { /* every parameter of a hypothesis has its column and pairs */
        size_t a, b, n = (size_t)g->hyp.n_params[i];
        for (a = 0; a < n; a++) {
            if (lg->hyp_cols[i * d + a] < 0) {
                return CFDI_ESHAPE;
            }
            for (b = 0; b < n; b++) {
                if (lg->hyp_pairs[(i * d + a) * d + b] < 0) {
                    return CFDI_ESHAPE;
                }
            }
        }
    }
    for (i = 0; i < lg->n_cols; i++) {
        int32_t source = lg->cols[2 * i], channel = lg->cols[2 * i + 1];
        if (source <= CFDI_COL_NONE || source > CFDI_COL_BIAS || channel < 0
            || (size_t)channel >= (source == CFDI_COL_SENSOR ? t->q : t->p)) {
            return CFDI_ESHAPE;
        }
    }
    for (i = 0; i < 2 * lg->n_pairs; i++) {
        if (lg->pairs[i] < 0 || (size_t)lg->pairs[i] >= lg->n_cols) {
            return CFDI_ESHAPE;
        }
    }
    return CFDI_OK;
}

static int tables_check(const cfdi_drive_tables *t)
{
    size_t i;
    if (!t || !t->bus || !t->dest || !t->coef || !t->uses || !t->sigma || !t->delta || !t->h
        || !t->valid_status) {
        return CFDI_EBADARG;
    }
    if (cfdi_bus_check(t->bus) != CFDI_OK || t->m == 0 || width_of(t) == 0 || t->mod <= 0
        || t->gate_bound <= 0 || t->gate_confirm < 1 || t->n_slots == 0 || t->cols == 0
        || t->n_slots > t->bus->n_slots || t->n_slots > 62 || !(t->dt_ns > 0.0)
        || !message_ok(&t->fault) || !message_ok(&t->estimate) || !message_ok(&t->status)
        || longest_message(t) > CFDI_MAX_PAYLOAD) {
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
    return t->diag != NULL ? diag_check(t) : CFDI_OK;
}

size_t cfdi_drive_memory_size(const cfdi_drive_tables *t)
{
    cfdi_drive scratch;
    carver c;
    if (tables_check(t) != CFDI_OK) {
        return 0;
    }
    c.base = NULL;
    c.used = 0;
    carve(&scratch, t, &c);
    return c.used;
}

int cfdi_drive_init(cfdi_drive *d, const cfdi_drive_tables *t, void *memory, size_t bytes)
{
    size_t i, n;
    carver c;
    int status;
    if (!d || !memory) {
        return CFDI_EBADARG;
    }
    status = tables_check(t);
    if (status != CFDI_OK) {
        return status;
    }
    if ((uintptr_t)memory % 8 != 0 || bytes < cfdi_drive_memory_size(t)) {
        return CFDI_ESHAPE;
    }
    memset(d, 0, sizeof *d);
    memset(memory, 0, bytes);
    c.base = memory;
    c.used = 0;
    carve(d, t, &c);
    d->t = t;
    d->ctr[CFDI_CTR_K] = -1;
    d->ctr[CFDI_CTR_LAST_COMPLETE] = -1;
    d->ctr[CFDI_CTR_LAST_DELIVERED] = -1;
    d->last_k = -1;
    n = (t->S + 1) * width_of(t);
    for (i = 0; i < n; i++) {
        d->ring[i] = (cfdi_real)NAN;
    }
    cfdi_restart_detector(d, -1);
    cfdi_comp_reset(d);
    cfdi_track_clear(&d->track);
    d->rec_rows = sizes_of(t).R;
    d->hist_rows = sizes_of(t).Y;
    d->rec_offer_k = INT64_MIN;
    return CFDI_OK;
}

/* -- the queues ------------------------------------------------------------------------ */

static size_t tx_stride(const cfdi_drive *d)
{
    return 6 + longest_message(d->t);
}

/* A monitor frame queued: the message's values by role (each wrapped and capped as the
 * monitor's are), encoded, protected with its E2E (its own alive counter). */
static void queue_frame(cfdi_drive *d, const cfdi_monitor_message *m, uint64_t *counter,
                        double *roles)
{
    uint8_t *f;
    size_t i;
    if (m->msg == NULL) {
        return;
    }
    if (d->tx_count == d->t->tx_frames) {
        d->tx_dropped += 1;
        return;
    }
    for (i = 0; i < CFDI_N_ROLES; i++) {
        if (m->wrap[i] > 0) {
            roles[i] = fmod(roles[i], m->wrap[i]);
            roles[i] = roles[i] < 0 ? roles[i] + m->wrap[i] : roles[i];
        }
        if (m->cap[i] > 0 && roles[i] > m->cap[i]) {
            roles[i] = m->cap[i];
        }
    }
    f = d->tx + ((d->tx_head + d->tx_count) % d->t->tx_frames) * tx_stride(d);
    /* (the message was checked at init: neither can fail) */
    if (cfdi_encode(m->msg, roles, f + 6) != CFDI_OK
        || cfdi_e2e_protect(m->msg->e2e_spec, m->msg->e2e_bytes, f + 6, m->msg->length,
                            *counter) != CFDI_OK) {
        d->tx_dropped += 1;
        return;
    }
    *counter += 1;
    memcpy(f, &m->msg->id, 4);
    f[4] = m->msg->extended;
    f[5] = m->msg->length;
    d->tx_count += 1;
}

static void roles_clear(const cfdi_drive *d, double *roles)
{
    size_t i;
    for (i = 0; i < CFDI_N_ROLES; i++) {
        roles[i] = 0;
    }
    roles[CFDI_ROLE_DRIVE] = d->t->drive_index;
}

/* FDI_ESTIMATE of one estimate (param 0 eta, 1 lambda, 2 bias) and, with a variance, of its
 * standard deviation (Monitor.fault_frames). */
static void queue_estimate(cfdi_drive *d, const cfdi_event *ev, int param, cfdi_real value,
                           int has_var, cfdi_real var)
{
    double roles[CFDI_N_ROLES];
    roles_clear(d, roles);
    roles[CFDI_ROLE_KIND] = d->t->kinds[ev->ch.target];
    roles[CFDI_ROLE_INDEX] = (double)ev->ch.index;
    roles[CFDI_ROLE_PARAM] = d->t->params[param];
    roles[CFDI_ROLE_VALUE] = (double)value;
    queue_frame(d, &d->t->estimate, &d->counters[1], roles);
    if (has_var) {
        roles_clear(d, roles);
        roles[CFDI_ROLE_KIND] = d->t->kinds[ev->ch.target];
        roles[CFDI_ROLE_INDEX] = (double)ev->ch.index;
        roles[CFDI_ROLE_PARAM] = d->t->params[param] + d->t->std_param;
        roles[CFDI_ROLE_VALUE] = sqrt(var > 0 ? (double)var : 0.0);
        queue_frame(d, &d->t->estimate, &d->counters[1], roles);
    }
}

void cfdi_announce(cfdi_drive *d, const cfdi_event *ev)
{
    double roles[CFDI_N_ROLES];
    if (d->ev_count == CFDI_EVENT_QUEUE) {
        d->events_dropped += 1;
    } else {
        d->events[(d->ev_head + d->ev_count) % CFDI_EVENT_QUEUE] = *ev;
        d->ev_count += 1;
    }
    if (ev->kind == CFDI_EVENT_UNEXPLAINED) {
        return;
    }
    if (ev->kind != CFDI_EVENT_REFINED) { /* a refinement updates a fault known already */
        int state = ev->kind == CFDI_EVENT_DETECTED ? 0 : ev->kind == CFDI_EVENT_NAMED ? 1 : 2;
        roles_clear(d, roles);
        roles[CFDI_ROLE_STATE] = d->t->fault_states[state];
        roles[CFDI_ROLE_KIND] = d->t->kinds[ev->ch.target];
        roles[CFDI_ROLE_INDEX] = (double)ev->ch.index;
        roles[CFDI_ROLE_SAMPLE] = (double)ev->sample;
        queue_frame(d, &d->t->fault, &d->counters[0], roles);
    }
    if (ev->kind == CFDI_EVENT_DETECTED) {
        return;
    }
    if (ev->ch.target == CFDI_TARGET_SENSOR) {
        queue_estimate(d, ev, 2, ev->ch.est[0], ev->has_var, ev->var[0]);
    } else if (ev->ch.n_est == 2) {
        queue_estimate(d, ev, 0, ev->ch.est[0], ev->has_var, ev->var[0]);
        queue_estimate(d, ev, 1, ev->ch.est[1], ev->has_var, ev->var[1]);
    } else {
        queue_estimate(d, ev, 1, ev->ch.est[1], ev->has_var, ev->var[1]);
    }
}

int cfdi_drive_state(const cfdi_drive *d)
{
    return !d->alarmed ? 0 : d->named ? 2 : 1;
}

int cfdi_drive_active_faults(const cfdi_drive *d)
{
    size_t c;
    int n = 0;
    for (c = 0; c < width_of(d->t); c++) {
        n += d->chan[c].has;
    }
    return n;
}

int cfdi_drive_status(cfdi_drive *d)
{
    double roles[CFDI_N_ROLES];
    uint64_t invalid = 0;
    size_t i;
    if (!d || !d->t) {
        return CFDI_EBADARG;
    }
    for (i = 0; i < CFDI_N_STATUS; i++) {
        invalid += d->t->valid_status[i] ? 0 : d->status_count[i];
    }
    roles_clear(d, roles);
    roles[CFDI_ROLE_STATE] = d->t->status_states[cfdi_drive_state(d)];
    roles[CFDI_ROLE_ACTIVE] = (double)cfdi_drive_active_faults(d);
    roles[CFDI_ROLE_SAMPLE] = (double)d->samples_taken;
    roles[CFDI_ROLE_INVALID] = (double)invalid;
    queue_frame(d, &d->t->status, &d->counters[2], roles);
    return CFDI_OK;
}

int cfdi_drive_poll_tx(cfdi_drive *d, cfdi_tx_frame *out)
{
    const uint8_t *f;
    if (!d || !out) {
        return CFDI_EBADARG;
    }
    if (d->tx_count == 0) {
        return 0;
    }
    f = d->tx + d->tx_head * tx_stride(d);
    memset(out, 0, sizeof *out);
    memcpy(&out->id, f, 4);
    out->extended = f[4];
    out->len = f[5];
    memcpy(out->data, f + 6, out->len);
    d->tx_head = (d->tx_head + 1) % d->t->tx_frames;
    d->tx_count -= 1;
    return 1;
}

int cfdi_drive_poll_event(cfdi_drive *d, cfdi_event *out)
{
    if (!d || !out) {
        return CFDI_EBADARG;
    }
    if (d->ev_count == 0) {
        return 0;
    }
    *out = d->events[d->ev_head];
    d->ev_head = (d->ev_head + 1) % CFDI_EVENT_QUEUE;
    d->ev_count -= 1;
    return 1;
}

/* -- the samples kept (canfdi.methods.parity.recent.RecentWindows, raw) -------------------
 * A ring of rows [z, u] as the clock gave them (a missing sample a row of NaN), the newest's
 * sample rec_last_k: the rows are consecutive samples, so a row's sample is its distance from
 * the newest. Rows are kept raw and compensated when read: the compensation changes only at an
 * acceptance or a refinement, and the window rebuilt then replaces the rows (as the Python's
 * reload clears its ring). A diagnosis freezes the ring from freeze_k on, so that the samples
 * near its onsets are there when an event reports its variances. */

static void rec_push(cfdi_drive *d, int64_t k, const cfdi_real *row)
{
    size_t w = width_of(d->t);
    if (d->rec_frozen) {
        return;
    }
    memcpy(d->recent + d->rec_next * w, row, w * sizeof *row);
    d->rec_next = (d->rec_next + 1) % d->rec_rows;
    d->rec_wrapped |= d->rec_count + 1 > d->rec_rows;
    d->rec_count = d->rec_count + 1 > d->rec_rows ? d->rec_rows : d->rec_count + 1;
    d->rec_last_k = k;
}

static void rec_clear(cfdi_drive *d)
{
    d->rec_count = d->rec_next = 0;
    d->rec_wrapped = 0;
}

const cfdi_real *cfdi_rec_row(const cfdi_drive *d, int64_t k)
{
    int64_t back = d->rec_last_k - k;
    if (d->rec_count == 0 || back < 0 || back >= (int64_t)d->rec_count) {
        return NULL;
    }
    return d->recent + ((d->rec_next + d->rec_rows - 1 - (size_t)back) % d->rec_rows)
                       * width_of(d->t);
}

/* Whether sample k's row is held with its whole window (the S rows before it held too, or
 * missing since a clear) and may be offered to a diagnosis. */
int cfdi_rec_offered(const cfdi_drive *d, int64_t k)
{
    int64_t oldest = d->rec_last_k - (int64_t)d->rec_count + 1;
    if (d->rec_count == 0 || k < oldest || k > d->rec_last_k || k < d->rec_offer_k) {
        return 0;
    }
    return !(d->rec_wrapped && k - oldest < (int64_t)d->t->S);
}

/* Sample k's window (S + 1 rows [z, u], compensated; NaN before the first held) into window
 * and its normalised residuals into rn: 1 when it is offered and has any, else 0. */
int cfdi_rec_window(cfdi_drive *d, int64_t k, cfdi_real *window, cfdi_real *rn)
{
    const cfdi_drive_tables *t = d->t;
    size_t w = width_of(t), rows = t->S + 1, r, c;
    int any = 0;
    if (!cfdi_rec_offered(d, k)) {
        return 0;
    }
    for (r = 0; r < rows; r++) {
        const cfdi_real *row = cfdi_rec_row(d, k - (int64_t)(rows - 1 - r));
        if (row) {
            cfdi_comp_row(d, k - (int64_t)(rows - 1 - r), row, window + r * w);
        } else {
            for (c = 0; c < w; c++) {
                window[r * w + c] = (cfdi_real)NAN;
            }
        }
    }
    if (cfdi_fir_block(window, rows, w, t->coef, t->uses, t->S, t->m, rn) != CFDI_OK) {
        return 0;
    }
    for (c = 0; c < t->m; c++) {
        rn[c] = rn[c] / t->sigma[c];
        any |= !isnan(rn[c]);
    }
    return any;
}

/* The history: the latest consecutive samples, raw (ParityDiagnoser._history, cleared at any
 * gap). */
static void hist_push(cfdi_drive *d, int64_t k, const cfdi_real *row)
{
    size_t w = width_of(d->t);
    memcpy(d->history + d->hist_next * w, row, w * sizeof *row);
    d->hist_next = (d->hist_next + 1) % d->hist_rows;
    d->hist_count = d->hist_count + 1 > d->hist_rows ? d->hist_rows : d->hist_count + 1;
    d->hist_last_k = k;
}

static const cfdi_real *hist_row(const cfdi_drive *d, size_t i) /* oldest first */
{
    return d->history + ((d->hist_next + d->hist_rows - d->hist_count + i) % d->hist_rows)
                        * width_of(d->t);
}

/* The recent ring replaced by the history's rows (offered from `offer_k` on; their first S not
 * offered when `context`: their windows reach before the history). */
static void rec_from_history(cfdi_drive *d, int64_t offer_k, int context)
{
    size_t i;
    d->rec_frozen = 0;
    rec_clear(d);
    for (i = 0; i < d->hist_count; i++) {
        rec_push(d, d->hist_last_k - (int64_t)(d->hist_count - 1 - i), hist_row(d, i));
    }
    d->rec_wrapped = context;
    d->rec_offer_k = offer_k;
}

/* The output-error paper's Section 3.3 (ParityDiagnoser._reload_window): the bank's window
 * rebuilt from the history compensated as it now is, the recent ring replaced by the history,
 * which later samples' windows start with (offered from the next sample on). */
void cfdi_reload_window(cfdi_drive *d, int64_t k)
{
    const cfdi_drive_tables *t = d->t;
    size_t w = width_of(t), rows = t->S + 1, i, c, n = d->hist_count;
    for (i = 0; i < rows * w; i++) {
        d->ring[i] = (cfdi_real)NAN;
    }
    for (i = n > rows ? n - rows : 0; i < n; i++) {
        size_t at = rows - (n - i);
        cfdi_comp_row(d, d->hist_last_k - (int64_t)(n - 1 - i), hist_row(d, i),
                      d->ring + at * w);
    }
    (void)c;
    if (t->diag) {
        rec_from_history(d, k + 1, 0);
    }
}

/* The diagnosis ends undecided (ParityDiagnoser._unexplained) or the detector restarts after
 * an acceptance: zero statistics, a change point no earlier than k + 1. */
void cfdi_restart_detector(cfdi_drive *d, int64_t k)
{
    size_t i;
    const cfdi_drive_tables *t = d->t;
    for (i = 0; i < 2 * t->m; i++) {
        d->ph[i] = 0;
        d->last_zero[i] = k;
    }
    memset(d->alarm, 0, t->m);
    d->alarmed = 0;
    d->named = 0;
    d->restart_k = k;
    if (t->diag && d->rec_frozen) {
        /* (a frozen ring's rows end at freeze_k: the history's follow; those of the diagnosis
         * are offered as the Python's ring keeps offering them) */
        rec_from_history(d, d->rec_offer_k, 1);
    }
}

/* -- the samples ------------------------------------------------------------------------ */

/* The bank forgets its window (a gap longer than it): every residual resumes after its own
 * window (ResidualBank.restart), or `count` rows are missing (ResidualBank.skip). */
static void ring_skip(cfdi_drive *d, int64_t count)
{
    const cfdi_drive_tables *t = d->t;
    size_t w = width_of(t), rows = t->S + 1, i, keep;
    cfdi_real *ring = d->ring;
    if (count <= 0) {
        return;
    }
    keep = (uint64_t)count >= rows ? 0 : rows - (size_t)count;
    memmove(ring, ring + (rows - keep) * w, keep * w * sizeof *ring);
    for (i = keep * w; i < rows * w; i++) {
        ring[i] = (cfdi_real)NAN;
    }
}

/* Page-Hinkley on the sample's residuals; at an alarm, the detection announced and (with a
 * diagnosis) the diagnosis started. */
static int monitor(cfdi_drive *d, int64_t k, int64_t t_ns)
{
    const cfdi_drive_tables *t = d->t;
    size_t done = 0, i;
    int status = cfdi_ph_block(&k, d->r, 1, t->m, t->delta, t->h, d->ph, d->last_zero,
                               d->g_up, d->g_down, d->alarm, &done);
    if (status != CFDI_OK || done != 0) {
        return status;
    }
    {
        /* ChangePointDetector.change_point: the earliest last zero of an alarming statistic,
         * plus one (an alarming statistic is above its threshold: not zero on this row). */
        int64_t onset = INT64_MAX;
        cfdi_event ev;
        memset(&ev, 0, sizeof ev);
        for (i = 0; i < t->m; i++) {
            if (d->alarm[i] != 0) {
                int64_t z = d->last_zero[2 * i + (d->alarm[i] > 0 ? 0 : 1)];
                onset = z < onset ? z : onset;
                ev.residuals |= (uint32_t)1 << i;
            }
        }
        d->alarmed = 1;
        d->detections += 1;
        d->alarm_k = k;
        d->alarm_t = t_ns;
        d->alarm_onset = onset + 1;
        ev.kind = CFDI_EVENT_DETECTED;
        ev.sample = k;
        ev.timestamp_ns = t_ns;
        ev.onset = d->alarm_onset;
        ev.detected = k;
        ev.accepted = -1;
        cfdi_announce(d, &ev);
        if (t->diag != NULL) {
            return cfdi_diag_start(d, k, t_ns, d->alarm_onset);
        }
    }
    return CFDI_OK;
}

/* One sample (ParityDiagnoser.update). row: [u, z] as the clock gives it. */
static int take_sample(cfdi_drive *d, int64_t k, int64_t t_ns, const double *row)
{
    const cfdi_drive_tables *t = d->t;
    size_t w = width_of(t), rows = t->S + 1, i;
    cfdi_real *last, *raw = d->row_raw;
    int any = 0, status;
    int gap = d->last_k >= 0 && k != d->last_k + 1;
    if (t->diag && d->alarmed && d->cursor <= d->last_k && gap) {
        /* the kept samples all absorbed before a gap changes the ring */
        status = cfdi_diag_catch_up(d, SIZE_MAX, d->last_k);
        if (status != CFDI_OK) {
            return status;
        }
    }
    if (gap) {
        int64_t missing = k - d->last_k - 1, j;
        int short_gap = missing > 0 && (uint64_t)missing <= t->S;
        ring_skip(d, short_gap ? missing : (int64_t)rows);
        if (t->diag != NULL && short_gap) { /* lost samples: rows of NaN */
            for (j = 0; j < (int64_t)w; j++) {
                raw[j] = (cfdi_real)NAN;
            }
            for (j = missing; j > 0; j--) {
                rec_push(d, k - j, raw);
            }
        } else if (t->diag != NULL && !d->rec_frozen) {
            rec_clear(d);
        }
        d->hist_count = 0;
    }
    d->last_k = k;
    d->last_t = t_ns;
    for (i = 0; i < t->q; i++) {
        raw[i] = (cfdi_real)row[t->p + i];
    }
    for (i = 0; i < t->p; i++) {
        raw[t->q + i] = (cfdi_real)row[i];
    }
    ring_skip(d, 1);
    last = d->ring + (rows - 1) * w;
    if (t->diag != NULL) {
        hist_push(d, k, raw);
        if (d->alarmed && k >= d->freeze_k) {
            d->rec_frozen = 1;
        }
        rec_push(d, k, raw);
        cfdi_comp_row(d, k, raw, last);
    } else {
        memcpy(last, raw, w * sizeof *raw);
    }
    status = cfdi_fir_block(d->ring, rows, w, t->coef, t->uses, t->S, t->m, d->r);
    if (status != CFDI_OK) {
        return status;
    }
    for (i = 0; i < t->m; i++) {
        d->r[i] = d->r[i] / t->sigma[i];
        any |= !isnan(d->r[i]);
    }
    if (!any) {
        return CFDI_OK; /* no residual yet (ParityDiagnoser.update returns none) */
    }
    if (d->alarmed) {
        return t->diag != NULL ? cfdi_diag_sample(d, k, t_ns) : CFDI_OK;
    }
    if (t->diag != NULL && d->track.n > 0) {
        for (i = 0; i < rows; i++) { /* the window's commands, compensated */
            memcpy(d->U + i * t->p, d->ring + i * w + t->q, t->p * sizeof *d->U);
        }
        {
            cfdi_signatures g;
            g.q = t->q;
            g.p = t->p;
            g.m = t->m;
            g.S = t->S;
            g.Gz = t->diag->Gz;
            g.Gu = t->diag->Gu;
            g.sigma = t->sigma;
            g.gamma = t->diag->gamma;
            cfdi_track_absorb(&d->track, &t->diag->track, &g, k, d->U, d->r);
        }
    }
    status = monitor(d, k, t_ns);
    if (status != CFDI_OK) {
        return status;
    }
    if (t->diag != NULL && !d->alarmed && cfdi_track_due(&d->track)) {
        return cfdi_diag_refine(d, k, t_ns);
    }
    return CFDI_OK;
}

static int take_samples(cfdi_drive *d, const int64_t *ks, const int64_t *times, size_t n)
{
    size_t i, w = width_of(d->t);
    for (i = 0; i < n; i++) {
        int status = take_sample(d, ks[i], times[i], d->samples + i * w);
        if (status != CFDI_OK) {
            return status;
        }
        d->samples_taken += 1;
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
                             whole, len > 8 ? 1 : 0, &status, &slot, d->values, &counter);
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
        rc = cfdi_counter_run(d->ctr, d->buffer, width_of(t), &row0, &slot64, &counter,
                              &when, 1, d->values, 1, t->bus->width, t->dest, t->n_slots,
                              t->cols, t->mod, t->dt_ns, t->slack, &status, 1, ks, times, gaps,
                              d->samples, &n_out, &used);
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
    rc = take_samples(d, ks, times, n_out);
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
    rc = cfdi_counter_close(d->ctr, d->buffer, width_of(d->t), d->t->dest, d->t->n_slots,
                            d->t->cols, ks, times, gaps, d->samples, &n_out);
    return rc != CFDI_OK ? rc : take_samples(d, ks, times, n_out);
}

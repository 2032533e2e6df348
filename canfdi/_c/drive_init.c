/* A drive's tables checked and its memory laid out (drive.h's cfdi_drive_init and
 * cfdi_drive_memory_size): run once, at start. */
#include <math.h>
#include <string.h>

#include "drive_impl.h"

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
    z.W = CFDI_WIDTH(t);
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
    size_t fits, work, lend;
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
    /* (the scratch of a sample's sums, lent to what an event's variances walk: its time's
     * squares before the onset, a sample's regressors) */
    work = CFDI_INFO_WORK(z.M, z.D, z.S, z.P, z.H, z.NC);
    lend = 2 * z.S * (z.W - z.P) * z.D + z.M * (z.NC > z.D ? z.NC : z.D) + 2 * z.M + z.D;
    d->work_len = work > lend ? work : lend;
    d->work = take(c, R * (d->work_len + z.D * z.D * 3 + z.D * 2));
    d->fit_scratch = d->work ? d->work + d->work_len : NULL;
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
    d->lagged.rows = d->work ? d->work + 2 * z.S * (z.W - z.P) * z.D : NULL;
    d->lagged.local = d->work;
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
        || g->min_samples < 0 || CFDI_WIDTH(t) > CFDI_MAX_CHANNELS || t->m > 32
        || lg->S != t->S || lg->q != t->q || lg->m != t->m || lg->n_cols == 0
        || lg->n_pairs == 0 || tk->p != t->p || tk->n_channels != CFDI_WIDTH(t)
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
    if (cfdi_bus_check(t->bus) != CFDI_OK || t->m == 0 || CFDI_WIDTH(t) == 0 || t->mod <= 0
        || t->gate_bound <= 0 || t->gate_confirm < 1 || t->n_slots == 0 || t->cols == 0
        || t->n_slots > t->bus->n_slots || t->n_slots > 62 || !(t->dt_ns > 0.0)
        || !message_ok(&t->fault) || !message_ok(&t->estimate) || !message_ok(&t->status)
        || longest_message(t) > CFDI_MAX_PAYLOAD) {
        return CFDI_ESHAPE;
    }
    for (i = 0; i < t->n_slots * t->cols; i++) {
        if (t->dest[i] >= (int64_t)CFDI_WIDTH(t)) {
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
    n = (t->S + 1) * CFDI_WIDTH(t);
    for (i = 0; i < n; i++) {
        d->ring[i] = (cfdi_real)NAN;
    }
    cfdi_restart_detector(d, -1);
    cfdi_comp_reset(d);
    cfdi_track_clear(&d->track);
    d->rec_rows = sizes_of(t).R;
    d->hist_rows = sizes_of(t).Y;
    d->rec_offer_k = INT64_MIN;
    d->win_k = -1;
    d->tx_stride = 6 + longest_message(t);
    return CFDI_OK;
}


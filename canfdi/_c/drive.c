/* One drive's monitor frame by frame (drive.h): the block functions called with blocks of one,
 * in the order the daemon's Python calls them (canfdi.bus.assembler.SampleAssembler.push_batch,
 * then canfdi.methods.parity.diagnoser.ParityDiagnoser.update), and the samples kept for the
 * diagnoses. The tables' checks and the memory's layout are drive_init.c's, what the monitor
 * sends announce.c's, the diagnosis diagnose.c's and decisions.c's, the compensation
 * compensate.c's. */
#include <math.h>
#include <string.h>

#include "drive_impl.h"

/* -- the samples kept (canfdi.methods.parity.recent.RecentWindows, raw) -------------------
 * A ring of rows [z, u] as the clock gave them (a missing sample a row of NaN), the newest's
 * sample rec_last_k: the rows are consecutive samples, so a row's sample is its distance from
 * the newest. Rows are kept raw and compensated when read: the compensation changes only at an
 * acceptance or a refinement, and the window rebuilt then replaces the rows (as the Python's
 * reload clears its ring). A diagnosis freezes the ring from freeze_k on, so that the samples
 * near its onsets are there when an event reports its variances. */

static void rec_push(cfdi_drive *d, int64_t k, const cfdi_real *row)
{
    size_t w = CFDI_WIDTH(d->t);
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
    d->win_k = -1;
}

const cfdi_real *cfdi_rec_row(const cfdi_drive *d, int64_t k)
{
    int64_t back = d->rec_last_k - k;
    if (d->rec_count == 0 || back < 0 || back >= (int64_t)d->rec_count) {
        return NULL;
    }
    return d->recent + ((d->rec_next + d->rec_rows - 1 - (size_t)back) % d->rec_rows)
                       * CFDI_WIDTH(d->t);
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

/* Sample k's window (S + 1 rows [z, u], compensated; NaN where no row is held) into
 * d->window: rolled on by one row from the window before it when that is the one there (the
 * compensation holds through a diagnosis; a rebuilt window or a new alarm forgets it). */
static void rec_window_rows(cfdi_drive *d, int64_t k)
{
    const cfdi_drive_tables *t = d->t;
    size_t w = CFDI_WIDTH(t), rows = t->S + 1, r, c;
    cfdi_real *window = d->window;
    const cfdi_real *row;
    if (d->win_k >= 0 && d->win_k == k - 1) {
        memmove(window, window + w, (rows - 1) * w * sizeof *window);
        r = rows - 1;
    } else {
        r = 0;
    }
    for (; r < rows; r++) {
        int64_t at = k - (int64_t)(rows - 1 - r);
        row = cfdi_rec_row(d, at);
        if (row) {
            cfdi_comp_row(d, at, row, window + r * w);
        } else {
            for (c = 0; c < w; c++) {
                window[r * w + c] = (cfdi_real)NAN;
            }
        }
    }
    d->win_k = k;
}

int cfdi_rec_window(cfdi_drive *d, int64_t k, cfdi_real *rn)
{
    const cfdi_drive_tables *t = d->t;
    size_t w = CFDI_WIDTH(t), c;
    int any = 0;
    if (!cfdi_rec_offered(d, k)) {
        return 0;
    }
    rec_window_rows(d, k);
    if (cfdi_fir_row(d->window, w, t->coef, t->uses, t->S, t->m, rn) != CFDI_OK) {
        return 0;
    }
    for (c = 0; c < t->m; c++) {
        rn[c] = rn[c] / t->sigma[c];
        any |= !isnan(rn[c]);
    }
    return any;
}

int cfdi_rec_seen(cfdi_drive *d, int64_t k, cfdi_real *rn)
{
    const cfdi_drive_tables *t = d->t;
    size_t n = (t->S + 1) * CFDI_WIDTH(t), i;
    if (!cfdi_rec_offered(d, k)) {
        return 0;
    }
    rec_window_rows(d, k);
    for (i = 0; i < n && d->window[i] == d->window[i]; i++) {
    }
    if (i < n) { /* a value missing: which residuals read it, by the bank itself */
        d->win_k = -1;
        return cfdi_rec_window(d, k, rn);
    }
    for (i = 0; i < t->m; i++) {
        rn[i] = 0; /* (every residual there: its value is not read) */
    }
    return 1;
}

/* The history: the latest consecutive samples, raw (ParityDiagnoser._history, cleared at any
 * gap). */
static void hist_push(cfdi_drive *d, int64_t k, const cfdi_real *row)
{
    size_t w = CFDI_WIDTH(d->t);
    memcpy(d->history + d->hist_next * w, row, w * sizeof *row);
    d->hist_next = (d->hist_next + 1) % d->hist_rows;
    d->hist_count = d->hist_count + 1 > d->hist_rows ? d->hist_rows : d->hist_count + 1;
    d->hist_last_k = k;
}

static const cfdi_real *hist_row(const cfdi_drive *d, size_t i) /* oldest first */
{
    return d->history + ((d->hist_next + d->hist_rows - d->hist_count + i) % d->hist_rows)
                        * CFDI_WIDTH(d->t);
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
    size_t w = CFDI_WIDTH(t), rows = t->S + 1, i, c, n = d->hist_count;
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
    size_t w = CFDI_WIDTH(t), rows = t->S + 1, i, keep;
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
    size_t w = CFDI_WIDTH(t), rows = t->S + 1, i;
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
    status = cfdi_fir_row(d->ring, w, t->coef, t->uses, t->S, t->m, d->r);
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
    size_t i, w = CFDI_WIDTH(d->t);
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
        rc = cfdi_counter_run(d->ctr, d->buffer, CFDI_WIDTH(t), &row0, &slot64, &counter,
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
    if (rc == CFDI_OK && n_out == 0 && t->diag && d->alarmed && d->cursor <= d->last_k) {
        /* the kept samples a diagnosis still has to absorb take the frames between samples
         * too (a sample is made of several frames) */
        rc = cfdi_diag_catch_up(d, d->share, d->last_k);
    }
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
    rc = cfdi_counter_close(d->ctr, d->buffer, CFDI_WIDTH(d->t), d->t->dest, d->t->n_slots,
                            d->t->cols, ks, times, gaps, d->samples, &n_out);
    return rc != CFDI_OK ? rc : take_samples(d, ks, times, n_out);
}

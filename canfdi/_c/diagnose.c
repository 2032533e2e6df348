/* An alarm's diagnosis, as canfdi.methods.parity.diagnoser.ParityDiagnoser runs it
 * (_monitor's onsets, _start_diagnosis, _accumulate, _diagnose, _name, _accept, _unexplained,
 * _track_compensated, _refine_tracked): every hypothesis fitted at every onset tried, from the
 * samples kept before the alarm (a share a sample, in order, so that no frame pays for all of
 * them and every one is in before the first decision) and each sample after it; from
 * min_samples on every fit solved and decided on; a fault named, accepted or refined (folded
 * into the compensation, the window rebuilt, the detector restarted, the tracking restarted),
 * or the alarm unexplained. */
#include <math.h>
#include <string.h>

#include "drive_impl.h"

static size_t width_of(const cfdi_drive_tables *t)
{
    return t->p + t->q;
}

static cfdi_signatures signatures_of(const cfdi_drive *d)
{
    const cfdi_drive_tables *t = d->t;
    cfdi_signatures g;
    g.q = t->q;
    g.p = t->p;
    g.m = t->m;
    g.S = t->S;
    g.Gz = t->diag->Gz;
    g.Gu = t->diag->Gu;
    g.sigma = t->sigma;
    g.gamma = t->diag->gamma;
    return g;
}

/* The compensation channel of a hypothesis (diagnoser._channel): its input or output; a joint
 * fit of sensors has none (-1). */
static int32_t channel_of(const cfdi_drive *d, size_t hyp)
{
    const cfdi_hypotheses *hy = &d->t->diag->hyp;
    switch (hy->kind[hyp]) {
    case CFDI_HYP_ACTUATOR:
    case CFDI_HYP_ACTUATOR_BIAS:
        return hy->index[hyp];
    case CFDI_HYP_SENSOR:
        return (int32_t)d->t->p + hy->index[hyp];
    default:
        return -1;
    }
}

static cfdi_real *fit_h(const cfdi_drive *d)
{
    return d->hc;
}

static cfdi_real *fit_cost(const cfdi_drive *d)
{
    return d->hc + d->t->diag->hyp.H * (d->t->diag->max_onsets + d->t->diag->max_earlier)
                   * d->t->diag->hyp.d;
}

/* -- absorbing samples ------------------------------------------------------------------ */

/* One sample into every fit (its window, S + 1 rows [z, u] compensated, and normalised
 * residuals rn), and into the lagged middles' squares. */
static int absorb(cfdi_drive *d, int64_t k, const cfdi_real *window, const cfdi_real *rn)
{
    const cfdi_drive_tables *t = d->t;
    const cfdi_diag_tables *g = t->diag;
    const cfdi_lagged_tables *lt = &g->lagged;
    cfdi_signatures sig = signatures_of(d);
    size_t w = width_of(t), r, j, a, c;
    int status, all_seen;
    for (r = 0; r <= t->S; r++) {
        for (j = 0; j < t->p; j++) {
            d->U[r * t->p + j] = window[r * w + t->q + j];
        }
    }
    for (j = 0; j < t->p; j++) {
        cfdi_real u = d->U[t->S * t->p + j];
        if (!isnan(u)) {
            d->u_abs[j] += CFDI_FABS(u > CFDI_REAL_MAX ? CFDI_REAL_MAX
                                          : u < -CFDI_REAL_MAX ? -CFDI_REAL_MAX : u);
            d->n_u[j] += 1;
        }
    }
    status = cfdi_info_block(t->q, t->p, t->m, t->S, g->Gz, g->Gu, t->sigma, g->hyp.H, g->hyp.d,
                             g->columns, d->n_onsets, d->onsets, 1, &k, d->U, rn, g->gamma,
                             d->J, fit_h(d), d->meat, &d->rr, &d->n_eq, d->work);
    if (status != CFDI_OK) {
        return status;
    }
    for (a = 0; a < t->m && rn[a] == rn[a]; a++) {
    }
    all_seen = a == t->m;
    for (c = 0; c < lt->n_cols; c++) { /* every column's steady regressor, where seen */
        cfdi_real *col = d->work;
        if (all_seen && lt->cols[2 * c] != CFDI_COL_SCALE) {
            continue; /* (the table's) */
        }
        cfdi_column(&sig, lt->cols[2 * c], lt->cols[2 * c + 1], k, k - (int64_t)t->S, d->U, col);
        for (a = 0; a < t->m; a++) {
            d->lagged.rows[a * lt->n_cols + c] = rn[a] == rn[a] ? col[a] : 0;
        }
    }
    cfdi_lagged_absorb(&d->lagged, lt, d->n_onsets, d->onsets, k, d->lagged.rows, all_seen);
    return CFDI_OK;
}

/* Up to `share` samples from the cursor to `upto`, from the samples kept: those with residuals
 * absorbed, in order. */
int cfdi_diag_catch_up(cfdi_drive *d, size_t share, int64_t upto)
{
    cfdi_real *window = d->window, *rn = d->r_raw;
    for (; share > 0 && d->cursor <= upto; share--, d->cursor++) {
        if (cfdi_rec_window(d, d->cursor, window, rn)) {
            int status = absorb(d, d->cursor, window, rn);
            if (status != CFDI_OK) {
                return status;
            }
        }
    }
    return CFDI_OK;
}

/* -- the onsets ----------------------------------------------------------------------- */

int cfdi_diag_start(cfdi_drive *d, int64_t k, int64_t t_ns, int64_t change_point)
{
    const cfdi_drive_tables *t = d->t;
    const cfdi_diag_tables *g = t->diag;
    size_t H = g->hyp.H, dd = g->hyp.d, K, n, i, c, head, total, n_earlier = 0;
    int64_t first = k, lo, start, oldest, floor_k, *cand;
    (void)t_ns;
    /* The oldest sample kept with residuals (RecentWindows.first), no further back than the
     * drive keeps: lookback samples before the alarm. */
    oldest = d->rec_last_k - (int64_t)d->rec_count + 1;
    floor_k = k - (int64_t)g->lookback + 1;
    for (i = 0; i < d->rec_count; i++) {
        int64_t at = oldest + (int64_t)i;
        if (at >= floor_k && cfdi_rec_window(d, at, d->window, d->r_raw)) {
            first = at;
            break;
        }
    }
    /* The compensated channels' fault onsets before the first onset tried (their leftovers
     * act from there), ascending, then the onsets around the change point
     * (detect.onset_candidates, "ends"). */
    lo = change_point - (int64_t)g->onset_before;
    lo = lo > first ? lo : first;
    total = lo <= k ? (size_t)(k - lo + 1) : 0;
    K = total > g->max_onsets ? g->max_onsets : total;
    for (c = 0; c < width_of(t); c++) {
        int64_t o = d->chan[c].fault_onset;
        size_t j;
        if (!d->chan[c].has || o < 0 || o >= (K ? lo : k)) {
            continue;
        }
        for (j = 0; j < n_earlier && d->onsets[j] != o; j++) {
        }
        if (j == n_earlier && n_earlier < g->max_earlier) {
            for (j = n_earlier; j > 0 && d->onsets[j - 1] > o; j--) {
                d->onsets[j] = d->onsets[j - 1];
            }
            d->onsets[j] = o;
            n_earlier++;
        }
    }
    cand = d->onsets + n_earlier;
    head = g->max_onsets / 2;
    for (i = 0; i < K; i++) {
        cand[i] = total > g->max_onsets && i >= head ? k - (int64_t)(K - 1 - i) : lo + (int64_t)i;
    }
    if (K == 0) {
        cand[0] = k;
        K = 1;
    }
    /* (an earlier onset at or after the first tried is none: onset_candidates' first) */
    while (n_earlier > 0 && d->onsets[n_earlier - 1] >= cand[0]) {
        memmove(d->onsets + n_earlier - 1, d->onsets + n_earlier, K * sizeof *d->onsets);
        n_earlier--;
        cand = d->onsets + n_earlier;
    }
    d->n_earlier = n_earlier;
    d->n_onsets = n_earlier + K;
    start = n_earlier ? d->onsets[0] : cand[0];
    if (n_earlier && cand[0] - (int64_t)g->earlier_lookback > start) {
        start = cand[0] - (int64_t)g->earlier_lookback;
    }
    start = start > first ? start : first;
    /* Each hypothesis' channel's latest fault, dated at one of the onsets tried: a fit from
     * there that costs about as little is what its estimate left. */
    for (i = 0; i < H; i++) {
        int32_t ch = channel_of(d, i);
        d->leftover[i] = -1;
        if (ch >= 0 && d->chan[ch].has) {
            for (c = 0; c < d->n_onsets; c++) {
                if (d->onsets[c] == d->chan[ch].fault_onset) {
                    d->leftover[i] = (int32_t)c;
                    break;
                }
            }
        }
    }
    n = H * d->n_onsets;
    for (i = 0; i < n; i++) {
        for (c = 0; c < dd * dd; c++) {
            d->J[i * dd * dd + c] = c % (dd + 1) == 0 ? g->prior_precision : 0;
            d->meat[i * dd * dd + c] = 0;
        }
        for (c = 0; c < dd; c++) {
            fit_h(d)[i * dd + c] = 0;
        }
    }
    for (i = 0; i < t->p; i++) {
        d->u_abs[i] = 0;
        d->n_u[i] = 0;
    }
    d->rr = 0;
    d->n_eq = 0;
    d->named = 0;
    cfdi_lagged_reset(&d->lagged, &g->lagged, d->n_onsets);
    /* The kept samples from `start` to the alarm, and the samples after it, are absorbed a
     * share a sample, in order: all in by min_samples after the alarm (the first decision),
     * the ring frozen only once the last sample an event's variances read is in. */
    d->cursor = start;
    d->diag_start = start;
    n = (size_t)(k - start + 1) + (size_t)g->min_samples;
    d->share = n / (size_t)(g->min_samples + 1) + 1;
    d->freeze_k = k + (g->min_samples > (int64_t)(2 * t->S) ? g->min_samples
                                                             : (int64_t)(2 * t->S));
    return cfdi_diag_catch_up(d, d->share, k);
}

/* -- what an event reports ------------------------------------------------------------ */

/* Fit (hyp, kb) solved: theta (d,) and, with P, P = J^-1 (d, d). */
static int solve_fit(cfdi_drive *d, size_t hyp, size_t kb, cfdi_real *theta, cfdi_real *P)
{
    size_t dd = d->t->diag->hyp.d, at = hyp * d->n_onsets + kb;
    cfdi_real *lu = d->fit_scratch + 2 * dd + dd * dd;
    return cfdi_fit_solve(dd, d->J + at * dd * dd, fit_h(d) + at * dd, theta, P, lu, d->perm);
}

/* The variances an event reports for fit (hyp, kb) (ParityDiagnoser._reported): the sandwich
 * P M P with the middle lag by lag over every sample absorbed, times the fit's noise scale. */
static int reported(cfdi_drive *d, size_t hyp, size_t kb, cfdi_real *var)
{
    const cfdi_drive_tables *t = d->t;
    const cfdi_diag_tables *g = t->diag;
    cfdi_signatures sig = signatures_of(d);
    size_t dd = g->hyp.d, np = (size_t)g->hyp.n_params[hyp], a, col, i;
    size_t at = hyp * d->n_onsets + kb;
    int64_t onset = d->onsets[kb], i_k, last;
    cfdi_real *P = d->fit_scratch + 2 * dd, *M = d->fit_scratch + 2 * dd + 2 * dd * dd;
    cfdi_real *theta = d->work;
    cfdi_real *rows = d->work + dd, *column = rows + t->m * dd, scale;
    int status;
    memset(d->lagged.local, 0, 2 * t->S * t->q * dd * sizeof *d->lagged.local);
    /* the samples absorbed within 2S of the onset, their regressors at it */
    last = onset + 2 * (int64_t)t->S - 1;
    last = last < d->last_k ? last : d->last_k;
    for (i_k = onset > d->diag_start ? onset : d->diag_start; i_k <= last; i_k++) {
        if (!cfdi_rec_window(d, i_k, d->window, d->r_raw)) {
            continue; /* not absorbed: no residual */
        }
        for (i = 0; i <= t->S; i++) {
            for (a = 0; a < t->p; a++) {
                d->U[i * t->p + a] = d->window[i * width_of(t) + t->q + a];
            }
        }
        for (a = 0; a < t->m * dd; a++) {
            rows[a] = 0;
        }
        for (col = 0; col < np; col++) {
            const int32_t *src = g->columns + (hyp * dd + col) * 2;
            cfdi_column(&sig, src[0], src[1], i_k, onset, d->U, column);
            for (a = 0; a < t->m; a++) {
                rows[a * dd + col] = d->r_raw[a] == d->r_raw[a] ? column[a] : 0;
            }
        }
        cfdi_lagged_local(&g->lagged, onset, i_k, rows, dd, d->lagged.local);
    }
    cfdi_lagged_middle(&d->lagged, &g->lagged, kb, onset, hyp, np, dd, d->lagged.local, M);
    status = solve_fit(d, hyp, kb, theta, P);
    if (status != CFDI_OK) {
        return status;
    }
    scale = cfdi_noise_scale(fit_cost(d)[at], d->n_eq, (int32_t)np);
    for (a = 0; a < dd; a++) {
        var[a] = a < np ? cfdi_sandwich(P, M, dd, a) * scale : 0;
    }
    return CFDI_OK;
}

/* -- the events ------------------------------------------------------------------------- */

static void event_of(const cfdi_drive *d, cfdi_event *ev, int32_t kind, int64_t k, int64_t t_ns)
{
    memset(ev, 0, sizeof *ev);
    ev->kind = kind;
    ev->sample = k;
    ev->timestamp_ns = t_ns;
    ev->onset = -1;
    ev->detected = d->alarm_k;
    ev->accepted = -1;
    ev->ch.hyp = -1;
}

/* A hypothesis at its fit theta, without variances (diagnoser._describe). */
static void describe(const cfdi_drive *d, size_t hyp, const cfdi_real *theta, cfdi_channel *out)
{
    const cfdi_hypotheses *hy = &d->t->diag->hyp;
    memset(out, 0, sizeof *out);
    out->hyp = (int16_t)hyp;
    out->index = (int16_t)hy->index[hyp];
    switch (hy->kind[hyp]) {
    case CFDI_HYP_ACTUATOR:
        out->target = CFDI_TARGET_ACTUATOR;
        out->n_est = 2;
        out->est[0] = 1 + theta[0];
        out->est[1] = theta[1];
        break;
    case CFDI_HYP_ACTUATOR_BIAS:
        out->target = CFDI_TARGET_ACTUATOR;
        out->n_est = 2;
        out->est[0] = 1;
        out->est[1] = theta[0];
        break;
    case CFDI_HYP_SENSOR:
        out->target = CFDI_TARGET_SENSOR;
        out->n_est = 1;
        out->est[0] = theta[0];
        break;
    default:
        out->target = CFDI_TARGET_SENSORS;
        out->n_est = (int16_t)(hy->n_params[hyp] < 2 ? hy->n_params[hyp] : 2);
        out->est[0] = theta[0];
        out->est[1] = hy->n_params[hyp] > 1 ? theta[1] : 0;
    }
}

static int same_channel(const cfdi_channel *a, const cfdi_channel *b)
{
    return a->target == b->target && a->index == b->index;
}

/* The single-sensor hypothesis of output j, or -1. */
static int32_t sensor_hypothesis(const cfdi_drive *d, int32_t j)
{
    const cfdi_hypotheses *hy = &d->t->diag->hyp;
    size_t i;
    for (i = 0; i < hy->H; i++) {
        if (hy->kind[i] == CFDI_HYP_SENSOR && hy->index[i] == j) {
            return (int32_t)i;
        }
    }
    return -1;
}

/* The channels whose bias shows in the residuals exactly as sensor j's (diagnoser.
 * _sensor_twins): j itself, then its twins by kind and index, each with the size that would
 * explain the data; none without twins. */
static void sensor_twins(const cfdi_drive *d, int32_t j, cfdi_real bias, cfdi_event *ev)
{
    const cfdi_diag_tables *g = d->t->diag;
    size_t H = g->hyp.H, i;
    int32_t hs = sensor_hypothesis(d, j);
    cfdi_channel *c;
    ev->n_candidates = 0;
    if (hs < 0 || g->twin_order[(size_t)hs * H] < 0) {
        return;
    }
    c = &ev->candidates[ev->n_candidates++];
    memset(c, 0, sizeof *c);
    c->target = CFDI_TARGET_SENSOR;
    c->hyp = (int16_t)hs;
    c->index = (int16_t)j;
    c->n_est = 1;
    c->est[0] = bias;
    for (i = 0; i < H && ev->n_candidates < CFDI_MAX_CANDIDATES; i++) {
        int32_t tw = g->twin_order[(size_t)hs * H + i];
        cfdi_real size;
        if (tw < 0) {
            break;
        }
        size = bias * g->twin_ratio[(size_t)hs * H + i];
        c = &ev->candidates[ev->n_candidates++];
        memset(c, 0, sizeof *c);
        c->hyp = (int16_t)tw;
        c->index = (int16_t)g->hyp.index[tw];
        c->n_est = 1;
        if (g->hyp.kind[tw] == CFDI_HYP_SENSOR) {
            c->target = CFDI_TARGET_SENSOR;
            c->est[0] = size;
        } else { /* an actuator's lambda enters as a sensor's bias does */
            c->target = CFDI_TARGET_ACTUATOR;
            c->est[1] = size;
        }
    }
}

/* UNEXPLAINED (ParityDiagnoser._unexplained): no fault explains the alarm; the three best
 * fits its candidates; the detector restarts. */
static int unexplained(cfdi_drive *d, int64_t k, int64_t t_ns)
{
    cfdi_event ev;
    cfdi_real *theta = d->fit_scratch;
    size_t i, H = d->t->diag->hyp.H;
    event_of(d, &ev, CFDI_EVENT_UNEXPLAINED, k, t_ns);
    for (i = 0; i < H && i < CFDI_MAX_CANDIDATES; i++) {
        size_t hyp = (size_t)d->order[i];
        if (solve_fit(d, hyp, (size_t)d->best_onset[hyp], theta, NULL) != CFDI_OK) {
            break;
        }
        describe(d, hyp, theta, &ev.candidates[ev.n_candidates++]);
    }
    cfdi_announce(d, &ev);
    cfdi_restart_detector(d, k);
    return CFDI_OK;
}

/* NAMED (ParityDiagnoser._name): the faulty channel before its form and size are known, once
 * a diagnosis; an actuator by the offset it acts with now (its bias-only fit, where there is
 * one). */
static int name_fault(cfdi_drive *d, const cfdi_decision *dec, int64_t k, int64_t t_ns)
{
    const cfdi_hypotheses *hy = &d->t->diag->hyp;
    size_t src = (size_t)dec->best, i, kb;
    cfdi_real theta[CFDI_MAX_FAULTS], var[CFDI_MAX_FAULTS];
    cfdi_event ev;
    int status;
    if (hy->kind[src] == CFDI_HYP_ACTUATOR) {
        for (i = 0; i < hy->H; i++) {
            if (hy->kind[i] == CFDI_HYP_ACTUATOR_BIAS && hy->index[i] == hy->index[src]) {
                src = i;
                break;
            }
        }
    }
    kb = (size_t)d->best_onset[src];
    status = reported(d, src, kb, var);
    if (status == CFDI_OK) {
        status = solve_fit(d, src, kb, theta, NULL);
    }
    if (status != CFDI_OK) {
        return status;
    }
    event_of(d, &ev, CFDI_EVENT_NAMED, k, t_ns);
    ev.onset = d->onsets[kb];
    ev.ch.hyp = (int16_t)src;
    ev.ch.index = (int16_t)hy->index[src];
    ev.has_var = 1;
    ev.undecided = (dec->form_known ? 0 : CFDI_UNDECIDED_FORM)
                   | (dec->size_known ? 0 : CFDI_UNDECIDED_SIZE);
    if (hy->kind[src] == CFDI_HYP_SENSOR) {
        ev.ch.target = CFDI_TARGET_SENSOR;
        ev.ch.n_est = 1;
        ev.ch.est[0] = theta[0];
        ev.var[0] = var[0];
        sensor_twins(d, hy->index[src], theta[0], &ev);
    } else { /* the offset it acts as now; its scale is what "form" waits for */
        int full = hy->kind[src] == CFDI_HYP_ACTUATOR;
        ev.ch.target = CFDI_TARGET_ACTUATOR;
        ev.ch.n_est = 1;
        ev.ch.est[1] = theta[full ? 1 : 0];
        ev.var[1] = var[full ? 1 : 0];
    }
    d->named = 1;
    cfdi_announce(d, &ev);
    return CFDI_OK;
}

/* inv(inv(A) + inv(B)) of n x n information matrices (n <= 2) into out. */
static int combine_new_fault(size_t n, const cfdi_real *A, const cfdi_real *B, cfdi_real *out)
{
    cfdi_real zero[2] = {0, 0}, x[2], lu[4], ia[4], ib[4];
    size_t perm[2], i;
    if (cfdi_fit_solve(n, A, zero, x, ia, lu, perm) != CFDI_OK
        || cfdi_fit_solve(n, B, zero, x, ib, lu, perm) != CFDI_OK) {
        return CFDI_ESINGULAR;
    }
    for (i = 0; i < n * n; i++) {
        ia[i] += ib[i];
    }
    return cfdi_fit_solve(n, ia, zero, x, out, lu, perm);
}

/* The tracking restarted over every compensated channel (ParityDiagnoser._track_compensated):
 * the ones just accepted with their fit's information (a refinement's added to what the
 * channel's tracking knew; a new fault on a channel tracked already adds its uncertainty to the
 * earlier one's), the others as they were tracked; by channel, inputs first. */
static int track_compensated(cfdi_drive *d, const cfdi_tracked *fresh, const int *new_fault,
                             size_t n_fresh)
{
    cfdi_track *tr = &d->track;
    const cfdi_diag_tables *g = d->t->diag;
    cfdi_signatures sig = signatures_of(d);
    size_t i, j, n = tr->n;
    for (i = 0; i < n_fresh; i++) {
        cfdi_tracked item = fresh[i];
        int32_t ch = item.kind == CFDI_HYP_SENSOR ? (int32_t)d->t->p + item.index : item.index;
        size_t np = cfdi_track_params(item.kind), at = n;
        for (j = 0; j < n; j++) {
            const cfdi_tracked *b = &tr->items[j];
            int32_t bch = b->kind == CFDI_HYP_SENSOR ? (int32_t)d->t->p + b->index : b->index;
            if (bch == ch) {
                at = j;
                break;
            }
        }
        if (at < n && tr->items[at].kind == item.kind) {
            const cfdi_real *before = tr->items[at].precision;
            if (new_fault[i]) {
                cfdi_real both[4];
                if (combine_new_fault(np, item.precision, before, both) != CFDI_OK) {
                    return CFDI_ESINGULAR;
                }
                memcpy(item.precision, both, np * np * sizeof *both);
            } else {
                for (j = 0; j < np * np; j++) {
                    item.precision[j] += before[j];
                }
            }
        }
        item.onset = d->chan[ch].first_onset;
        if (at == n) { /* a channel not tracked yet: in channel order */
            if (n == g->track.max_params) {
                return CFDI_ESHAPE;
            }
            for (at = n; at > 0; at--) {
                const cfdi_tracked *b = &tr->items[at - 1];
                int32_t bch = b->kind == CFDI_HYP_SENSOR ? (int32_t)d->t->p + b->index
                                                         : b->index;
                if (bch < ch) {
                    break;
                }
                tr->items[at] = tr->items[at - 1];
            }
            n++;
        }
        tr->items[at] = item;
    }
    return cfdi_track_restart(tr, &g->track, &sig, tr->items, n);
}

/* ACCEPTED (ParityDiagnoser._accept): the best fit's channel with its estimates, or each
 * significant member of a joint fit of sensors (none: the alarm unexplained), each folded
 * into the compensation (a fault of its own, or what an earlier estimate left: refined);
 * then the window rebuilt, the detector and the tracking restarted. */
static int accept_fault(cfdi_drive *d, const cfdi_decision *dec, int64_t k, int64_t t_ns)
{
    const cfdi_drive_tables *t = d->t;
    const cfdi_diag_tables *g = t->diag;
    const cfdi_hypotheses *hy = &g->hyp;
    size_t best = (size_t)dec->best, kb = (size_t)dec->kb, dd = hy->d, K = d->n_onsets, i;
    size_t at = best * K + kb, n_faults = 0, n_alike = 0, c, a, b;
    int64_t onset = d->onsets[kb];
    int8_t kind = hy->kind[best];
    cfdi_real theta[CFDI_MAX_FAULTS], var[CFDI_MAX_FAULTS], eta_var = 0;
    cfdi_channel named, alike[CFDI_MAX_CANDIDATES];
    cfdi_event ev_store, *ev = &ev_store;
    cfdi_tracked items[CFDI_MAX_FAULTS];
    int new_fault[CFDI_MAX_FAULTS], status, leftover = 0;
    status = solve_fit(d, best, kb, theta, NULL);
    if (status == CFDI_OK) {
        status = reported(d, best, kb, var);
    }
    if (status == CFDI_OK && kind == CFDI_HYP_ACTUATOR_BIAS && hy->full[best] >= 0) {
        cfdi_real full_var[CFDI_MAX_FAULTS];
        size_t full = (size_t)hy->full[best];
        status = reported(d, full, (size_t)d->best_onset[full], full_var);
        eta_var = full_var[0];
    }
    if (status != CFDI_OK) {
        return status;
    }
    describe(d, best, theta, &named);
    if (dec->action == CFDI_DECIDE_ACCEPT_NEAR) {
        /* (what tells near twins apart, a transient, is buried in the noise: the best is named
         * with every channel within the margin as its candidates) */
        cfdi_real th[CFDI_MAX_FAULTS];
        for (i = 0; i < hy->H && n_alike < CFDI_MAX_CANDIDATES - 1; i++) {
            size_t o = (size_t)d->order[i];
            if (!d->near[o] || hy->kind[o] == CFDI_HYP_SENSORS
                || solve_fit(d, o, (size_t)d->best_onset[o], th, NULL) != CFDI_OK) {
                continue;
            }
            describe(d, o, th, &alike[n_alike]);
            if (!same_channel(&alike[n_alike], &named)) {
                n_alike++;
            }
        }
    }
    if (kind != CFDI_HYP_SENSORS) { /* what the channel's latest estimate left? */
        int32_t ch = channel_of(d, best);
        if (d->chan[ch].has) {
            for (c = 0; c < K; c++) {
                if (d->onsets[c] == d->chan[ch].fault_onset) {
                    cfdi_real *cost = fit_cost(d) + best * K;
                    leftover = cost[c] - cost[kb] < (cfdi_real)g->settings.isolation_margin;
                    break;
                }
            }
        }
    }
    for (c = 0; c < (size_t)hy->n_params[best] && n_faults < CFDI_MAX_FAULTS; c++) {
        cfdi_found f;
        cfdi_tracked *item = &items[n_faults];
        int32_t index = kind == CFDI_HYP_SENSORS ? g->columns[(best * dd + c) * 2 + 1]
                                                 : hy->index[best];
        size_t np;
        if (kind == CFDI_HYP_SENSORS && !(CFDI_FABS(theta[c]) > 5 * CFDI_SQRT(var[c]))) {
            continue; /* in a joint fit a member with no significant bias is healthy */
        }
        if ((kind == CFDI_HYP_ACTUATOR || kind == CFDI_HYP_ACTUATOR_BIAS) && c > 0) {
            break;
        }
        if (kind == CFDI_HYP_SENSOR && c > 0) {
            break;
        }
        memset(&f, 0, sizeof f);
        f.onset = onset;
        f.correction = leftover;
        event_of(d, ev, CFDI_EVENT_ACCEPTED, k, t_ns);
        if (kind == CFDI_HYP_ACTUATOR || kind == CFDI_HYP_ACTUATOR_BIAS) {
            int full = kind == CFDI_HYP_ACTUATOR;
            f.channel = index;
            f.eta = full ? 1 + theta[0] : 1;
            f.lam = full ? theta[1] : theta[0];
            f.var[0] = full ? var[0] : eta_var;
            f.var[1] = full ? var[1] : var[0];
            f.has_var[0] = f.has_var[1] = 1;
            f.fixed_eta = !full;
            if (n_alike) {
                ev->candidates[ev->n_candidates++] = named;
                for (i = 0; i < n_alike && ev->n_candidates < CFDI_MAX_CANDIDATES; i++) {
                    ev->candidates[ev->n_candidates++] = alike[i];
                }
            }
        } else {
            f.channel = (int32_t)t->p + index;
            f.bias = theta[c];
            f.var[0] = var[c];
            f.has_var[0] = 1;
            sensor_twins(d, index, theta[c], ev);
            if (n_alike && kind == CFDI_HYP_SENSOR) {
                if (ev->n_candidates == 0) {
                    ev->candidates[ev->n_candidates++] = named;
                }
                for (i = 0; i < n_alike && ev->n_candidates < CFDI_MAX_CANDIDATES; i++) {
                    ev->candidates[ev->n_candidates++] = alike[i];
                }
            }
        }
        cfdi_comp_fold(d, &f, ev);
        ev->sample = k;
        ev->accepted = k;
        ev->ch.hyp = (int16_t)best;
        /* what the fit knows of the channel's parameters, for the tracking's prior */
        memset(item, 0, sizeof *item);
        item->index = index;
        if (kind == CFDI_HYP_SENSORS) {
            item->kind = CFDI_HYP_SENSOR;
            item->precision[0] = d->J[at * dd * dd + c * dd + c] / dec->scale;
        } else {
            item->kind = kind;
            np = cfdi_track_params(kind);
            for (a = 0; a < np; a++) {
                for (b = 0; b < np; b++) {
                    item->precision[a * np + b] = d->J[at * dd * dd + a * dd + b] / dec->scale;
                }
            }
        }
        new_fault[n_faults] = ev->kind == CFDI_EVENT_ACCEPTED;
        n_faults++;
        cfdi_announce(d, ev); /* (what it sends does not depend on what follows) */
    }
    if (n_faults == 0) {
        /* the best fit is a joint sensor bias with no member significant: no persistent fault
         * explains the alarm (a transient, such as one corrupt sample) */
        return unexplained(d, k, t_ns);
    }
    cfdi_reload_window(d, k);
    cfdi_restart_detector(d, k);
    return track_compensated(d, items, new_fault, n_faults);
}

/* -- each sample of a diagnosis --------------------------------------------------------- */

int cfdi_diag_sample(cfdi_drive *d, int64_t k, int64_t t_ns)
{
    const cfdi_diag_tables *g = d->t->diag;
    const cfdi_hypotheses *hy = &g->hyp;
    size_t n, e, i, dd = hy->d, K;
    int64_t since = k - d->alarm_k;
    cfdi_rank rank;
    cfdi_fit_view best, full;
    cfdi_decision dec;
    cfdi_real *theta = d->fit_scratch, *theta_f = d->fit_scratch + dd;
    cfdi_real *P = d->fit_scratch + 2 * dd, *P_f = d->work;
    int status;
    if (d->cursor < k) {
        status = cfdi_diag_catch_up(d, since >= g->min_samples ? SIZE_MAX : d->share, k - 1);
        if (status != CFDI_OK) {
            return status;
        }
    }
    if (d->cursor == k) { /* the live sample: the bank's window, the residuals just made */
        status = absorb(d, k, d->ring, d->r);
        if (status != CFDI_OK) {
            return status;
        }
        d->cursor = k + 1;
    }
    if (d->cursor != k + 1 || since < g->min_samples) {
        return CFDI_OK;
    }
    /* every fit's cost (its theta and P only for the fits the decision reads) */
    K = d->n_onsets;
    n = hy->H * K;
    for (e = 0; e < n; e++) {
        cfdi_real dot = 0;
        status = cfdi_fit_solve(dd, d->J + e * dd * dd, fit_h(d) + e * dd, theta, NULL,
                                d->fit_scratch + 2 * dd + dd * dd, d->perm);
        if (status == CFDI_ESINGULAR) { /* (numpy raises: J0 > 0 keeps it from happening) */
            d->singular += 1;
            return CFDI_OK;
        }
        for (i = 0; i < dd; i++) {
            dot += theta[i] * fit_h(d)[e * dd + i];
        }
        fit_cost(d)[e] = d->rr - dot;
    }
    status = cfdi_decide_rank(hy, &g->settings, K, fit_cost(d), d->best_onset, d->cost_h,
                              d->order, d->near, &rank);
    if (status != CFDI_OK) {
        return status;
    }
    e = (size_t)rank.best * K + (size_t)rank.kb;
    status = solve_fit(d, (size_t)rank.best, (size_t)rank.kb, theta, P);
    best.theta = theta;
    best.P = P;
    best.meat = d->meat + e * dd * dd;
    best.cost = fit_cost(d)[e];
    best.rr = d->rr;
    if (status == CFDI_OK && rank.full >= 0) {
        e = (size_t)rank.full * K + (size_t)rank.full_kb;
        status = solve_fit(d, (size_t)rank.full, (size_t)rank.full_kb, theta_f, P_f);
        full.theta = theta_f;
        full.P = P_f;
        full.meat = d->meat + e * dd * dd;
        full.cost = fit_cost(d)[e];
        full.rr = d->rr;
    }
    if (status == CFDI_OK) {
        status = cfdi_decide_judge(hy, &g->settings, K, &rank, &best,
                                   rank.full >= 0 ? &full : NULL, fit_cost(d), d->n_eq,
                                   d->u_abs, d->n_u, g->units, d->leftover, since, d->named,
                                   &dec);
    }
    if (status != CFDI_OK) {
        return status;
    }
    switch (dec.action) {
    case CFDI_DECIDE_NAME:
        return name_fault(d, &dec, k, t_ns);
    case CFDI_DECIDE_ACCEPT:
    case CFDI_DECIDE_ACCEPT_NEAR:
        return accept_fault(d, &dec, k, t_ns);
    case CFDI_DECIDE_UNEXPLAINED:
        return unexplained(d, k, t_ns);
    default:
        return CFDI_OK;
    }
}

/* -- the tracking's checkpoints (ParityDiagnoser._refine_tracked) ------------------------ */

int cfdi_diag_refine(cfdi_drive *d, int64_t k, int64_t t_ns)
{
    cfdi_correction *fixes = d->track.fixes;
    cfdi_event ev;
    int n = cfdi_track_correction(&d->track, &d->t->diag->track, fixes), i;
    if (n < 0) {
        return CFDI_OK; /* (no solution: nothing folded; numpy would raise) */
    }
    for (i = 0; i < n; i++) {
        const cfdi_tracked *it = &d->track.items[fixes[i].item];
        cfdi_found f;
        memset(&f, 0, sizeof f);
        f.onset = it->onset;
        f.correction = 1;
        if (it->kind == CFDI_HYP_SENSOR) {
            f.channel = (int32_t)d->t->p + it->index;
            f.bias = fixes[i].delta[0];
            f.var[0] = fixes[i].var[0];
            f.has_var[0] = 1;
        } else {
            int full = it->kind == CFDI_HYP_ACTUATOR;
            f.channel = it->index;
            f.eta = full ? 1 + fixes[i].delta[0] : 1;
            f.lam = full ? fixes[i].delta[1] : fixes[i].delta[0];
            f.var[0] = full ? fixes[i].var[0] : 0;
            f.var[1] = full ? fixes[i].var[1] : fixes[i].var[0];
            f.has_var[0] = f.has_var[1] = 1;
        }
        event_of(d, &ev, CFDI_EVENT_REFINED, k, t_ns);
        cfdi_comp_fold(d, &f, &ev);
        ev.detected = -1;
        ev.accepted = k;
        cfdi_announce(d, &ev); /* (what it sends does not depend on the window rebuilt) */
    }
    if (n > 0) {
        cfdi_reload_window(d, k);
    }
    return CFDI_OK;
}

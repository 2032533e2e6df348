/* An alarm's diagnosis, as canfdi.methods.parity.diagnoser.ParityDiagnoser runs it
 * (_monitor's onsets, _start_diagnosis, _accumulate, _diagnose): every hypothesis fitted at
 * every onset tried, from the samples kept before the alarm (their work spread over the frames
 * to the first decision, in order, so that no frame pays for all of them and every one is in
 * before it) and each sample after it; from min_samples on every fit solved and decided on,
 * and what a decision makes of it (decisions.c). The variances an event reports are made here
 * too (_reported): the fit's middle lag by lag (lagged.c). */
#include <math.h>
#include <string.h>

#include "drive_impl.h"

cfdi_signatures cfdi_diag_signatures(const cfdi_drive *d)
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
int32_t cfdi_diag_channel(const cfdi_drive *d, size_t hyp)
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

cfdi_real *cfdi_fit_h(const cfdi_drive *d)
{
    return d->hc;
}

cfdi_real *cfdi_fit_cost(const cfdi_drive *d)
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
    cfdi_signatures sig = cfdi_diag_signatures(d);
    size_t w = CFDI_WIDTH(t), r, j, a, c;
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
                             d->J, cfdi_fit_h(d), d->meat, &d->rr, &d->n_eq, d->work, d->work_len);
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

/* What absorbing sample k costs, in quarters of a sample whose every fit is steady: four, and
 * one more for each onset within its window (each its own first lag: its own sums; measured on
 * the M4F, a quarter of the rest). */
static size_t weight_of(const cfdi_drive *d, int64_t k)
{
    size_t i, w = 4;
    for (i = 0; i < d->n_onsets; i++) {
        w += d->onsets[i] <= k && k - d->onsets[i] < (int64_t)d->t->S;
    }
    return w;
}

/* Samples from the cursor to `upto`, from the samples kept (those with residuals absorbed, in
 * order), up to `share` of their weight (at least one sample). */
int cfdi_diag_catch_up(cfdi_drive *d, size_t share, int64_t upto)
{
    cfdi_real *rn = d->r_raw;
    size_t spent = 0;
    for (; d->cursor <= upto; d->cursor++) {
        size_t w = share == SIZE_MAX ? 0 : weight_of(d, d->cursor);
        if (spent > 0 && spent + w > share) {
            break;
        }
        spent += w;
        if (cfdi_rec_window(d, d->cursor, rn)) {
            int status = absorb(d, d->cursor, d->window, rn);
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
        if (at >= floor_k && cfdi_rec_window(d, at, d->r_raw)) {
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
    for (c = 0; c < CFDI_WIDTH(t); c++) {
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
        int32_t ch = cfdi_diag_channel(d, i);
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
            cfdi_fit_h(d)[i * dd + c] = 0;
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
    d->win_k = -1;
    /* (the work to the first decision, spread over the frames after this one, which has
     * done the alarm's: n_slots a sample) */
    for (n = 0, i = 0; i <= (size_t)(k - start) + (size_t)g->min_samples; i++) {
        n += weight_of(d, start + (int64_t)i);
    }
    i = (size_t)g->min_samples * t->n_slots;
    d->share = n / (i > 0 ? i : 1) + 4; /* (a sample's worth more: early rather than late) */
    d->freeze_k = k + (g->min_samples > (int64_t)(2 * t->S) ? g->min_samples
                                                             : (int64_t)(2 * t->S));
    return CFDI_OK;
}

/* -- what an event reports ------------------------------------------------------------ */

/* Fit (hyp, kb) solved: theta (d,) and, with P, P = J^-1 (d, d). */
int cfdi_solve_fit(cfdi_drive *d, size_t hyp, size_t kb, cfdi_real *theta, cfdi_real *P)
{
    size_t dd = d->t->diag->hyp.d, at = hyp * d->n_onsets + kb;
    cfdi_real *lu = d->fit_scratch + 2 * dd + dd * dd;
    return cfdi_fit_solve(dd, d->J + at * dd * dd, cfdi_fit_h(d) + at * dd, theta, P, lu, d->perm);
}

/* The variances an event reports for fit (hyp, kb) (ParityDiagnoser._reported): the sandwich
 * P M P with the middle lag by lag over every sample absorbed, times the fit's noise scale. */
int cfdi_reported(cfdi_drive *d, size_t hyp, size_t kb, cfdi_real *var)
{
    const cfdi_drive_tables *t = d->t;
    const cfdi_diag_tables *g = t->diag;
    cfdi_signatures sig = cfdi_diag_signatures(d);
    size_t dd = g->hyp.d, np = (size_t)g->hyp.n_params[hyp], a, col, i;
    size_t at = hyp * d->n_onsets + kb;
    int64_t onset = d->onsets[kb], i_k, last;
    cfdi_real *P = d->fit_scratch + 2 * dd, *M = d->fit_scratch + 2 * dd + 2 * dd * dd;
    cfdi_real *theta = d->work + 2 * t->S * t->q * dd; /* (after the local times' squares) */
    cfdi_real *rows = theta + dd, *column = rows + t->m * dd, scale;
    int status;
    memset(d->lagged.local, 0, 2 * t->S * t->q * np * sizeof *d->lagged.local);
    /* the samples absorbed within 2S of the onset, their regressors at it */
    last = onset + 2 * (int64_t)t->S - 1;
    last = last < d->last_k ? last : d->last_k;
    for (i_k = onset > d->diag_start ? onset : d->diag_start; i_k <= last; i_k++) {
        if (!cfdi_rec_seen(d, i_k, d->r_raw)) {
            continue; /* not absorbed: no residual */
        }
        for (i = 0; i <= t->S; i++) {
            for (a = 0; a < t->p; a++) {
                d->U[i * t->p + a] = d->window[i * CFDI_WIDTH(t) + t->q + a];
            }
        }
        for (col = 0; col < np; col++) {
            const int32_t *src = g->columns + (hyp * dd + col) * 2;
            cfdi_column(&sig, src[0], src[1], i_k, onset, d->U, column);
            for (a = 0; a < t->m; a++) {
                rows[a * np + col] = d->r_raw[a] == d->r_raw[a] ? column[a] : 0;
            }
        }
        cfdi_lagged_local(&g->lagged, onset, i_k, rows, np, d->lagged.local);
    }
    cfdi_lagged_middle(&d->lagged, &g->lagged, kb, onset, hyp, np, dd, d->lagged.local, M);
    status = cfdi_solve_fit(d, hyp, kb, theta, P);
    if (status != CFDI_OK) {
        return status;
    }
    scale = cfdi_noise_scale(cfdi_fit_cost(d)[at], d->n_eq, (int32_t)np);
    for (a = 0; a < dd; a++) {
        var[a] = a < np ? cfdi_sandwich(P, M, dd, a) * scale : 0;
    }
    return CFDI_OK;
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
        status = cfdi_fit_solve(dd, d->J + e * dd * dd, cfdi_fit_h(d) + e * dd, theta, NULL,
                                d->fit_scratch + 2 * dd + dd * dd, d->perm);
        if (status == CFDI_ESINGULAR) { /* (numpy raises: J0 > 0 keeps it from happening) */
            d->singular += 1;
            return CFDI_OK;
        }
        for (i = 0; i < dd; i++) {
            dot += theta[i] * cfdi_fit_h(d)[e * dd + i];
        }
        cfdi_fit_cost(d)[e] = d->rr - dot;
    }
    status = cfdi_decide_rank(hy, &g->settings, K, cfdi_fit_cost(d), d->best_onset, d->cost_h,
                              d->order, d->near, &rank);
    if (status != CFDI_OK) {
        return status;
    }
    e = (size_t)rank.best * K + (size_t)rank.kb;
    status = cfdi_solve_fit(d, (size_t)rank.best, (size_t)rank.kb, theta, P);
    best.theta = theta;
    best.P = P;
    best.meat = d->meat + e * dd * dd;
    best.cost = cfdi_fit_cost(d)[e];
    best.rr = d->rr;
    if (status == CFDI_OK && rank.full >= 0) {
        e = (size_t)rank.full * K + (size_t)rank.full_kb;
        status = cfdi_solve_fit(d, (size_t)rank.full, (size_t)rank.full_kb, theta_f, P_f);
        full.theta = theta_f;
        full.P = P_f;
        full.meat = d->meat + e * dd * dd;
        full.cost = cfdi_fit_cost(d)[e];
        full.rr = d->rr;
    }
    if (status == CFDI_OK) {
        status = cfdi_decide_judge(hy, &g->settings, K, &rank, &best,
                                   rank.full >= 0 ? &full : NULL, cfdi_fit_cost(d), d->n_eq,
                                   d->u_abs, d->n_u, g->units, d->leftover, since, d->named,
                                   &dec);
    }
    if (status != CFDI_OK) {
        return status;
    }
    switch (dec.action) {
    case CFDI_DECIDE_NAME:
        return cfdi_name_fault(d, &dec, k, t_ns);
    case CFDI_DECIDE_ACCEPT:
    case CFDI_DECIDE_ACCEPT_NEAR:
        return cfdi_accept_fault(d, &dec, k, t_ns);
    case CFDI_DECIDE_UNEXPLAINED:
        return cfdi_unexplained(d, k, t_ns);
    default:
        return CFDI_OK;
    }
}


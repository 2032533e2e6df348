/* A diagnosis' decision at one sample, from its fits: canfdi.methods.parity.decide's
 * decide_reference, rule for rule (which hypothesis and onset, then accept, name, wait or give
 * up). The sandwich's variances are summed as numpy's (P M) P is, so the decisions agree but
 * where a test sits within rounding of its bound. */
#include <float.h>
#include <math.h>

#include "cfdi.h"

#ifdef CFDI_FLOAT32
#define REAL_TINY ((cfdi_real)1e-30) /* decide.spread's floor on the noise scale */
#else
#define REAL_TINY 1e-300
#endif

/* Whether a sorts after b: greater, or NaN where b is not (numpy's argsort puts NaN last). */
static int after(cfdi_real a, cfdi_real b)
{
    return a > b || (a != a && b == b);
}

cfdi_real cfdi_sandwich(const cfdi_real *P, const cfdi_real *M, size_t d, size_t i)
{
    cfdi_real v = 0;
    size_t a, b;
    for (b = 0; b < d; b++) {
        cfdi_real pm = 0;
        for (a = 0; a < d; a++) {
            pm += P[i * d + a] * M[a * d + b];
        }
        v += pm * P[b * d + i];
    }
    return v;
}

cfdi_real cfdi_noise_scale(cfdi_real cost, int64_t n_eq, int32_t n_params)
{
    int64_t dof = n_eq - n_params;
    cfdi_real scale = cost / (cfdi_real)(dof > 1 ? dof : 1);
    return scale > REAL_TINY ? scale : REAL_TINY;
}

/* The mean size of command j since the alarm (|u_c| over the known ones, at least one). */
static cfdi_real mean_command(const cfdi_real *u_abs, const cfdi_real *n_u, int32_t j)
{
    cfdi_real n = n_u[j];
    return u_abs[j] / ((cfdi_real)1 > n ? (cfdi_real)1 : n);
}

static int within(cfdi_real sd, double fraction, cfdi_real unit)
{
    return fraction > 0.0 && sd <= (cfdi_real)fraction * unit;
}

int cfdi_hypotheses_check(const cfdi_hypotheses *hy, size_t K)
{
    size_t i;
    if (!hy || hy->H == 0 || hy->d == 0 || hy->p == 0 || K == 0 || K > INT32_MAX
        || hy->H > INT32_MAX || !hy->kind || !hy->index || !hy->n_params || !hy->full
        || !hy->name_key || !hy->twins || !hy->penalty) {
        return CFDI_ESHAPE;
    }
    for (i = 0; i < hy->H; i++) {
        int actuator = hy->kind[i] == CFDI_HYP_ACTUATOR || hy->kind[i] == CFDI_HYP_ACTUATOR_BIAS;
        if (hy->kind[i] < CFDI_HYP_ACTUATOR || hy->kind[i] > CFDI_HYP_SENSORS
            || hy->n_params[i] < 1 || (size_t)hy->n_params[i] > hy->d || hy->index[i] < 0
            || (actuator && (size_t)hy->index[i] >= hy->p)
            || (hy->kind[i] == CFDI_HYP_ACTUATOR && hy->n_params[i] != 2)
            || hy->full[i] < -1 || (hy->full[i] >= 0 && ((size_t)hy->full[i] >= hy->H
                                    || hy->kind[hy->full[i]] != CFDI_HYP_ACTUATOR
                                    || hy->index[hy->full[i]] != hy->index[i]))) {
            return CFDI_ESHAPE;
        }
    }
    return CFDI_OK;
}

static int leftover_ok(const cfdi_hypotheses *hy, size_t K, const int32_t *leftover)
{
    size_t i;
    for (i = 0; i < hy->H; i++) {
        if (leftover[i] < -1 || (leftover[i] >= 0 && (size_t)leftover[i] >= K)) {
            return 0;
        }
    }
    return 1;
}

/* Whether the data rule a scale out for a bias-only actuator fit (decide._scale_ruled_out):
 * its full fit (at its own cheapest onset) knows eta - 1 as the settling test asks and finds it
 * within 3 standard deviations of 0. */
static int scale_ruled_out(const cfdi_hypotheses *hy, const cfdi_decide_settings *s,
                           const cfdi_fit_view *full, int64_t n_eq, const cfdi_real *u_abs,
                           const cfdi_real *n_u, const cfdi_real *units, int32_t which)
{
    size_t d = hy->d;
    cfdi_real sd_eta, u_mean, unit;
    if (which < 0) {
        return 1;
    }
    sd_eta = CFDI_SQRT(cfdi_sandwich(full->P, full->meat, d, 0)
                             * cfdi_noise_scale(full->cost, n_eq, 2));
    u_mean = mean_command(u_abs, n_u, hy->index[which]);
    unit = u_mean > 0 ? units[(size_t)which * d] / u_mean : (cfdi_real)INFINITY;
    return (sd_eta <= (cfdi_real)s->settle_rel_std || within(sd_eta, s->settle_noise, unit))
           && CFDI_FABS(full->theta[0]) <= 3 * sd_eta;
}

int cfdi_decide_rank(const cfdi_hypotheses *hy, const cfdi_decide_settings *s, size_t K,
                     const cfdi_real *cost, int64_t *best_onset, cfdi_real *cost_h,
                     int64_t *order, uint8_t *near, cfdi_rank *out)
{
    size_t H, i, o, first, best;
    cfdi_real tol, margin;
    int margin_ok = 1;
    if (!hy || !s || !cost || !best_onset || !cost_h || !order || !near || !out) {
        return CFDI_EBADARG;
    }
    H = hy->H;
    margin = (cfdi_real)s->isolation_margin;
    /* Each hypothesis' cheapest onset (numpy's argmin: the first minimum, or the first NaN). */
    for (i = 0; i < H; i++) {
        const cfdi_real *c = cost + i * K;
        size_t kb = 0;
        for (o = 1; o < K && c[kb] == c[kb]; o++) {
            if (c[o] < c[kb] || c[o] != c[o]) {
                kb = o;
            }
        }
        best_onset[i] = (int64_t)kb;
        cost_h[i] = c[kb] + hy->penalty[i];
    }
    /* The hypotheses by penalised cost, stably (insertion sort: H is a handful). */
    for (i = 0; i < H; i++) {
        size_t j = i;
        while (j > 0 && after(cost_h[order[j - 1]], cost_h[i])) {
            order[j] = order[j - 1];
            j--;
        }
        order[j] = (int64_t)i;
    }
    /* The best names its group of twins: its first channel in config order. */
    first = (size_t)order[0];
    best = first;
    tol = (cfdi_real)(1e-6 * (1.0 + fabs((double)cost_h[first])));
    for (i = 0; i < H; i++) {
        if (hy->twins[first * H + i] && hy->n_params[i] == hy->n_params[first]
            && CFDI_FABS(cost_h[i] - cost_h[first]) <= tol && hy->name_key[i] < hy->name_key[best]) {
            best = i;
        }
    }
    for (i = 0; i < H; i++) {
        int outside = i != best && !hy->twins[best * H + i];
        cfdi_real gap = cost_h[i] - cost_h[best];
        margin_ok &= !outside || gap >= margin;
        near[i] = (uint8_t)(outside && gap < margin);
    }
    out->best = (int32_t)best;
    out->kb = (int32_t)best_onset[best];
    out->full = hy->kind[best] == CFDI_HYP_ACTUATOR_BIAS ? hy->full[best] : -1;
    out->full_kb = out->full >= 0 ? (int32_t)best_onset[out->full] : -1;
    out->margin_ok = margin_ok;
    return CFDI_OK;
}

int cfdi_decide_judge(const cfdi_hypotheses *hy, const cfdi_decide_settings *s, size_t K,
                      const cfdi_rank *rank, const cfdi_fit_view *fit,
                      const cfdi_fit_view *full, const cfdi_real *cost, int64_t n_eq,
                      const cfdi_real *u_abs, const cfdi_real *n_u, const cfdi_real *units,
                      const int32_t *leftover, int64_t since, int named, cfdi_decision *out)
{
    size_t d, i, best;
    int32_t n_b, kind;
    cfdi_real margin, scale, u_mean = 0;
    int size_known = 1, form_known, fits, at_end;
    if (!hy || !s || !rank || !fit || !fit->theta || !fit->P || !fit->meat || !cost || !u_abs
        || !n_u || !units || !leftover || !out
        || (rank->full >= 0 && (!full || !full->theta || !full->P || !full->meat))) {
        return CFDI_EBADARG;
    }
    d = hy->d;
    best = (size_t)rank->best;
    margin = (cfdi_real)s->isolation_margin;
    n_b = hy->n_params[best];
    kind = hy->kind[best];
    scale = cfdi_noise_scale(fit->cost, n_eq, n_b);
    if (kind == CFDI_HYP_ACTUATOR) {
        u_mean = mean_command(u_abs, n_u, hy->index[best]);
    }
    for (i = 0; i < (size_t)n_b; i++) {
        cfdi_real sd = CFDI_SQRT(cfdi_sandwich(fit->P, fit->meat, d, i) * scale);
        cfdi_real size = CFDI_FABS(fit->theta[i]);
        cfdi_real unit = units[best * d + i];
        if (kind == CFDI_HYP_ACTUATOR && i == 0) {
            size = CFDI_FABS(1 + fit->theta[0]);
            unit = u_mean > 0 ? unit / u_mean : (cfdi_real)INFINITY;
        } else if (kind == CFDI_HYP_ACTUATOR) {
            cfdi_real scaled = (cfdi_real)0.1 * CFDI_FABS(fit->theta[0]) * u_mean;
            size = scaled > size ? scaled : size;
        }
        size_known &= sd <= (cfdi_real)s->settle_rel_std * size
                      || within(sd, s->settle_noise, unit);
    }
    form_known = kind != CFDI_HYP_ACTUATOR_BIAS
                 || scale_ruled_out(hy, s, full, n_eq, u_abs, n_u, units, rank->full);
    fits = scale <= (cfdi_real)s->max_fit_variance && (fit->rr - fit->cost) / scale >= margin;
    at_end = since >= s->max_samples;
    out->best = rank->best;
    out->kb = rank->kb;
    out->scale = scale;
    out->size_known = size_known;
    out->form_known = form_known;
    if (rank->margin_ok && fits && ((size_known && form_known) || at_end)) {
        out->action = CFDI_DECIDE_ACCEPT;
    } else if (rank->margin_ok && fits && !named && kind != CFDI_HYP_SENSORS
               && !(leftover[best] >= 0
                    && cost[best * K + (size_t)leftover[best]] - fit->cost < margin)) {
        out->action = CFDI_DECIDE_NAME;
    } else if (fits && at_end) {
        out->action = CFDI_DECIDE_ACCEPT_NEAR;
    } else if (at_end) {
        out->action = CFDI_DECIDE_UNEXPLAINED;
    } else {
        out->action = CFDI_DECIDE_WAIT;
    }
    return CFDI_OK;
}

int cfdi_decide(const cfdi_hypotheses *hy, const cfdi_decide_settings *s, size_t K,
                const cfdi_real *theta, const cfdi_real *P, const cfdi_real *cost,
                const cfdi_real *rr, int64_t n_eq, const cfdi_real *meat,
                const cfdi_real *u_abs, const cfdi_real *n_u, const cfdi_real *units,
                const int32_t *leftover, int64_t since, int named, int64_t *best_onset,
                cfdi_real *cost_h, int64_t *order, uint8_t *near, cfdi_decision *out)
{
    cfdi_rank rank;
    cfdi_fit_view fit, full;
    size_t d, at;
    int status;
    if (!hy || !s || !theta || !P || !cost || !rr || !meat || !u_abs || !n_u || !units
        || !leftover || !best_onset || !cost_h || !order || !near || !out) {
        return CFDI_EBADARG;
    }
    if (cfdi_hypotheses_check(hy, K) != CFDI_OK || !leftover_ok(hy, K, leftover)) {
        return CFDI_ESHAPE;
    }
    status = cfdi_decide_rank(hy, s, K, cost, best_onset, cost_h, order, near, &rank);
    if (status != CFDI_OK) {
        return status;
    }
    d = hy->d;
    at = (size_t)rank.best * K + (size_t)rank.kb;
    fit.theta = theta + at * d;
    fit.P = P + at * d * d;
    fit.meat = meat + at * d * d;
    fit.cost = cost[at];
    fit.rr = rr[at];
    if (rank.full >= 0) {
        at = (size_t)rank.full * K + (size_t)rank.full_kb;
        full.theta = theta + at * d;
        full.P = P + at * d * d;
        full.meat = meat + at * d * d;
        full.cost = cost[at];
        full.rr = rr[at];
    }
    return cfdi_decide_judge(hy, s, K, &rank, &fit, rank.full >= 0 ? &full : NULL, cost, n_eq,
                             u_abs, n_u, units, leftover, since, named, out);
}

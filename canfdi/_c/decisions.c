/* What a diagnosis' decision makes (ParityDiagnoser._name, _accept, _unexplained,
 * _track_compensated, _refine_tracked): a fault named, accepted or refined (folded into the
 * compensation, the window rebuilt, the detector and the tracking restarted), the alarm
 * unexplained, a tracker's corrections folded in; each an event, announced. */
#include <math.h>
#include <string.h>

#include "drive_impl.h"

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
int cfdi_unexplained(cfdi_drive *d, int64_t k, int64_t t_ns)
{
    cfdi_event ev;
    cfdi_real *theta = d->fit_scratch;
    size_t i, H = d->t->diag->hyp.H;
    event_of(d, &ev, CFDI_EVENT_UNEXPLAINED, k, t_ns);
    for (i = 0; i < H && i < CFDI_MAX_CANDIDATES; i++) {
        size_t hyp = (size_t)d->order[i];
        if (cfdi_solve_fit(d, hyp, (size_t)d->best_onset[hyp], theta, NULL) != CFDI_OK) {
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
int cfdi_name_fault(cfdi_drive *d, const cfdi_decision *dec, int64_t k, int64_t t_ns)
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
    status = cfdi_reported(d, src, kb, var);
    if (status == CFDI_OK) {
        status = cfdi_solve_fit(d, src, kb, theta, NULL);
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
    cfdi_signatures sig = cfdi_diag_signatures(d);
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
int cfdi_accept_fault(cfdi_drive *d, const cfdi_decision *dec, int64_t k, int64_t t_ns)
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
    status = cfdi_solve_fit(d, best, kb, theta, NULL);
    if (status == CFDI_OK) {
        status = cfdi_reported(d, best, kb, var);
    }
    if (status == CFDI_OK && kind == CFDI_HYP_ACTUATOR_BIAS && hy->full[best] >= 0) {
        cfdi_real full_var[CFDI_MAX_FAULTS];
        size_t full = (size_t)hy->full[best];
        status = cfdi_reported(d, full, (size_t)d->best_onset[full], full_var);
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
                || cfdi_solve_fit(d, o, (size_t)d->best_onset[o], th, NULL) != CFDI_OK) {
                continue;
            }
            describe(d, o, th, &alike[n_alike]);
            if (!same_channel(&alike[n_alike], &named)) {
                n_alike++;
            }
        }
    }
    if (kind != CFDI_HYP_SENSORS) { /* what the channel's latest estimate left? */
        int32_t ch = cfdi_diag_channel(d, best);
        if (d->chan[ch].has) {
            for (c = 0; c < K; c++) {
                if (d->onsets[c] == d->chan[ch].fault_onset) {
                    cfdi_real *cost = cfdi_fit_cost(d) + best * K;
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
        return cfdi_unexplained(d, k, t_ns);
    }
    cfdi_reload_window(d, k);
    cfdi_restart_detector(d, k);
    return track_compensated(d, items, new_fault, n_faults);
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

/* The compensation (canfdi.core.records: compensate, fold, latest_fault, fault_onset): every
 * accepted fault undone from its onset on, in the order they were accepted; a diagnosis or a
 * tracker's correction on a channel compensated already folded in as the records module folds
 * it. */
#include <math.h>
#include <string.h>

#include "drive_impl.h"

int cfdi_is_actuator(const cfdi_drive *d, int32_t channel)
{
    return channel >= 0 && (size_t)channel < d->t->p;
}

void cfdi_comp_reset(cfdi_drive *d)
{
    size_t c;
    d->n_comp = 0;
    for (c = 0; c < d->t->p + d->t->q; c++) {
        cfdi_comp_channel *ch = &d->chan[c];
        memset(ch, 0, sizeof *ch);
        ch->fault_onset = -1;
        ch->first_onset = -1;
        ch->eta = ch->base_eta = 1;
    }
}

/* One entry applied to a sample [z (q), u (p)]: a sensor's measurement less its bias, an
 * actuator's command become eta u + lambda. */
static void apply(const cfdi_drive *d, int32_t channel, cfdi_real eta, cfdi_real lam,
                  cfdi_real bias, cfdi_real *row)
{
    size_t p = d->t->p, q = d->t->q;
    if (cfdi_is_actuator(d, channel)) {
        cfdi_real *u = row + q + (size_t)channel;
        *u = eta * *u + lam;
    } else {
        row[(size_t)channel - p] -= bias;
    }
}

void cfdi_comp_row(const cfdi_drive *d, int64_t k, const cfdi_real *raw, cfdi_real *out)
{
    size_t w = d->t->p + d->t->q, i, c;
    memcpy(out, raw, w * sizeof *out);
    if (d->comp_composed) { /* the entries composed into each channel's base come first */
        for (c = 0; c < w; c++) {
            const cfdi_comp_channel *ch = &d->chan[c];
            if (ch->has && (ch->base_eta != 1 || ch->base_lam != 0 || ch->base_bias != 0)) {
                apply(d, (int32_t)c, ch->base_eta, ch->base_lam, ch->base_bias, out);
            }
        }
    }
    for (i = 0; i < d->n_comp; i++) {
        const cfdi_comp_entry *e = &d->comp[i];
        if (k >= e->onset) {
            apply(d, e->channel, e->eta, e->lam, e->bias, out);
        }
    }
}

/* records._own_fault: the diagnosis' parameters relative to the compensation (eta - 1, lambda;
 * a bias) differ from none beyond the chi-square at OWN_FAULT_SIGMA, their variance its own
 * plus the channel's latest estimate's; a parameter held fixed is no evidence, and one the
 * latest estimate held fixed but this one estimates completes that fault's form. */
static int own_fault(const cfdi_drive *d, const cfdi_found *f, const cfdi_comp_channel *ch)
{
    const cfdi_diag_tables *g = d->t->diag;
    cfdi_real delta[2];
    double stat = 0;
    int n = cfdi_is_actuator(d, f->channel) ? 2 : 1, key, dof = 0;
    delta[0] = n == 2 ? f->eta - 1 : f->bias;
    delta[1] = f->lam;
    for (key = 0; key < n; key++) {
        cfdi_real own, var;
        if (n == 2 && key == 0 && f->fixed_eta) {
            continue;
        }
        own = f->has_var[key] ? f->var[key] : 0;
        if (n == 2 && key == 0 && ch->fixed_eta && own > 0) {
            return 0;
        }
        var = own + (ch->has_var[key] ? ch->var[key] : 0);
        if (var > 0 && isfinite(var)) {
            stat += (double)delta[key] * (double)delta[key] / (double)var;
            dof++;
        }
    }
    return dof > 0 && stat > g->own_chi2[dof];
}

/* The oldest entry composed into its channel's base (the list is full): it then applies to
 * every sample, as it does to every one from its onset on. */
static void compose_oldest(cfdi_drive *d)
{
    const cfdi_comp_entry *e = &d->comp[0];
    cfdi_comp_channel *ch = &d->chan[e->channel];
    ch->base_eta = e->eta * ch->base_eta;
    ch->base_lam = e->eta * ch->base_lam + e->lam;
    ch->base_bias += e->bias;
    memmove(d->comp, d->comp + 1, (d->n_comp - 1) * sizeof *d->comp);
    d->n_comp -= 1;
    d->comp_composed += 1;
}

int cfdi_comp_fold(cfdi_drive *d, const cfdi_found *f, cfdi_event *ev)
{
    cfdi_comp_channel *ch = &d->chan[f->channel];
    int actuator = cfdi_is_actuator(d, f->channel), correction = f->correction, key;
    cfdi_real var[2];
    cfdi_comp_entry *e;
    var[0] = f->var[0];
    var[1] = f->var[1];
    if (ch->has && !correction) {
        if (own_fault(d, f, ch)) { /* measured against the earlier estimate: its variance too */
            for (key = 0; key < 2; key++) {
                var[key] += f->has_var[key] && ch->has_var[key] ? ch->var[key] : 0;
            }
        } else {
            correction = 1;
        }
    }
    if (d->n_comp == CFDI_MAX_COMP) {
        compose_oldest(d);
    }
    e = &d->comp[d->n_comp++];
    e->channel = f->channel;
    e->onset = f->onset;
    e->eta = actuator ? f->eta : 1;
    e->lam = actuator ? f->lam : 0;
    e->bias = actuator ? 0 : f->bias;
    if (!ch->has || f->onset < ch->first_onset) {
        ch->first_onset = f->onset;
    }
    ch->has = 1;
    if (!correction) { /* a fault of its own: the channel's latest */
        ch->fault_onset = f->onset;
        ch->eta = e->eta;
        ch->lam = e->lam;
        ch->bias = e->bias;
    } else { /* records._composed: eta2 (eta1 u + lam1) + lam2; biases add */
        ch->lam = e->eta * ch->lam + e->lam;
        ch->eta = e->eta * ch->eta;
        ch->bias += e->bias;
    }
    for (key = 0; key < 2; key++) {
        ch->var[key] = var[key];
        ch->has_var[key] = f->has_var[key];
    }
    ch->fixed_eta = f->fixed_eta;
    ev->kind = correction ? CFDI_EVENT_REFINED : CFDI_EVENT_ACCEPTED;
    ev->ch.target = actuator ? CFDI_TARGET_ACTUATOR : CFDI_TARGET_SENSOR;
    ev->ch.index = actuator ? f->channel : f->channel - (int32_t)d->t->p;
    if (actuator) {
        ev->ch.n_est = 2;
        ev->ch.est[0] = correction ? ch->eta : e->eta;
        ev->ch.est[1] = correction ? ch->lam : e->lam;
    } else {
        ev->ch.n_est = 1;
        ev->ch.est[0] = correction ? ch->bias : e->bias;
        ev->ch.est[1] = 0;
    }
    ev->var[0] = var[0];
    ev->var[1] = var[1];
    ev->has_var = f->has_var[0] || f->has_var[1];
    ev->onset = f->onset;
    return ev->kind;
}

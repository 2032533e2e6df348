/* What the monitor sends and tells (drive.h): its frames queued as canfdi.monitor encodes them
 * (FDI_FAULT, FDI_ESTIMATE, FDI_STATUS: the monitor DBC's layouts, each message's E2E), its
 * events queued, both polled by the caller. */
#include <math.h>
#include <string.h>

#include "drive_impl.h"
#include "e2e.h"

/* -- the queues ------------------------------------------------------------------------ */

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
        if (m->wrap[i] > 0) { /* (a count: an integer, not negative) */
            roles[i] = (double)((uint64_t)roles[i] % (uint64_t)m->wrap[i]);
        }
        if (m->cap[i] > 0 && roles[i] > m->cap[i]) {
            roles[i] = m->cap[i];
        }
    }
    f = d->tx + ((d->tx_head + d->tx_count) % d->t->tx_frames) * d->tx_stride;
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
        /* (the real type's root: for a float, the float nearest the true root, as the double
         * one is once the message's 32-bit value takes it) */
        roles[CFDI_ROLE_VALUE] = (double)CFDI_SQRT(var > 0 ? var : 0);
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
    for (c = 0; c < CFDI_WIDTH(d->t); c++) {
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
    f = d->tx + d->tx_head * d->tx_stride;
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


/* The accepted faults' tracking (track.h): canfdi.methods.parity.tracking.AcceptedFaultTracker
 * step for step; its checkpoints are track_check.c's. */
#include <float.h>
#include <math.h>
#include <string.h>

#include "track.h"

size_t cfdi_track_params(int32_t kind)
{
    return kind == CFDI_HYP_ACTUATOR ? 2 : 1;
}

void cfdi_track_clear(cfdi_track *tr)
{
    tr->n = 0;
    tr->D = 0;
    tr->absorbed = 0;
    tr->next_check = 0;
    tr->u_n = 0;
}

/* The channel's table row: inputs first, then outputs. */
static size_t row_of(const cfdi_signatures *g, const cfdi_tracked *it)
{
    return it->kind == CFDI_HYP_SENSOR ? g->p + (size_t)it->index : (size_t)it->index;
}

int cfdi_track_restart(cfdi_track *tr, const cfdi_track_tables *t, const cfdi_signatures *g,
                       const cfdi_tracked *items, size_t n)
{
    size_t i, a, b, D = 0, at = 0;
    for (i = 0; i < n; i++) {
        D += cfdi_track_params(items[i].kind);
    }
    if (D > t->max_params) {
        return CFDI_ESHAPE;
    }
    cfdi_track_clear(tr);
    if (n == 0) {
        return CFDI_OK;
    }
    memmove(tr->items, items, n * sizeof *items);
    tr->n = n;
    tr->D = D;
    memset(tr->J, 0, D * D * sizeof *tr->J);
    memset(tr->M, 0, D * D * sizeof *tr->M);
    memset(tr->h, 0, D * sizeof *tr->h);
    memset(tr->sJ, 0, D * D * sizeof *tr->sJ);
    memset(tr->sM, 0, D * D * sizeof *tr->sM);
    memset(tr->sh, 0, D * sizeof *tr->sh);
    memset(tr->u_abs, 0, g->p * sizeof *tr->u_abs);
    for (i = 0; i < n; i++) {
        size_t np = cfdi_track_params(tr->items[i].kind);
        cfdi_real ratio = t->ratio[row_of(g, &tr->items[i])];
        for (a = 0; a < np; a++) {
            for (b = 0; b < np; b++) {
                cfdi_real p = tr->items[i].precision[a * np + b];
                tr->J[(at + a) * D + at + b] = p;
                tr->M[(at + a) * D + at + b] = ratio * p;
            }
        }
        at += np;
    }
    tr->next_check = t->first_check;
    return CFDI_OK;
}

/* numpy's nan_to_num of a command (info.c's reading of it). */
static cfdi_real finite(cfdi_real u)
{
    if (u != u) {
        return 0;
    }
    if (u > CFDI_REAL_MAX) {
        return CFDI_REAL_MAX;
    }
    return u < -CFDI_REAL_MAX ? -CFDI_REAL_MAX : u;
}

void cfdi_track_absorb(cfdi_track *tr, const cfdi_track_tables *t, const cfdi_signatures *g,
                       int64_t k, const cfdi_real *U, const cfdi_real *rn)
{
    size_t D = tr->D, m = g->m, i, a, b, c, col = 0;
    cfdi_real *phi = tr->work, *gphi = tr->work + m * D;
    (void)t;
    if (tr->n == 0) {
        return;
    }
    /* The regressors (m, D): each channel's columns at its own onset, zero where a residual
     * is missing. */
    for (i = 0; i < tr->n; i++) {
        const cfdi_tracked *it = &tr->items[i];
        int32_t sources[2];
        size_t np = cfdi_track_params(it->kind), s;
        cfdi_real *column = tr->work + 2 * m * D;
        if (it->kind == CFDI_HYP_SENSOR) {
            sources[0] = CFDI_COL_SENSOR;
        } else if (it->kind == CFDI_HYP_ACTUATOR) {
            sources[0] = CFDI_COL_SCALE;
            sources[1] = CFDI_COL_BIAS;
        } else {
            sources[0] = CFDI_COL_BIAS;
        }
        for (s = 0; s < np; s++, col++) {
            cfdi_column(g, sources[s], it->index, k, it->onset, U, column);
            for (a = 0; a < m; a++) {
                phi[a * D + col] = rn[a] == rn[a] ? column[a] : 0;
            }
        }
    }
    for (a = 0; a < m; a++) { /* Gamma phi */
        for (c = 0; c < D; c++) {
            cfdi_real sum = 0;
            for (b = 0; b < m; b++) {
                sum += g->gamma[a * m + b] * phi[b * D + c];
            }
            gphi[a * D + c] = sum;
        }
    }
    for (a = 0; a < D; a++) {
        cfdi_real dot = 0;
        for (b = 0; b < D; b++) {
            cfdi_real info = 0, mid = 0;
            for (c = 0; c < m; c++) {
                info += phi[c * D + a] * phi[c * D + b];
                mid += phi[c * D + a] * gphi[c * D + b];
            }
            tr->sJ[a * D + b] += info;
            tr->sM[a * D + b] += mid;
        }
        for (c = 0; c < m; c++) {
            if (rn[c] == rn[c]) {
                dot += phi[c * D + a] * rn[c];
            }
        }
        tr->sh[a] += dot;
    }
    for (a = 0; a < g->p; a++) {
        tr->u_abs[a] += CFDI_FABS(finite(U[g->S * g->p + a]));
    }
    tr->u_n += 1;
    tr->absorbed += 1;
}

int cfdi_track_due(const cfdi_track *tr)
{
    return tr->n > 0 && tr->absorbed >= tr->next_check;
}


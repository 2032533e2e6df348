/* The estimates' variances lag by lag, without keeping the samples (lagged.h). */
#include <string.h>

#include "lagged.h"

/* The ring slot of time t: t mod (S+1), in 32 bits where an M4F divides in hardware (the
 * times of one diagnosis lie within 2^31 of its first). */
static size_t slot_of(int64_t origin, int64_t t, size_t S)
{
    uint32_t since = (uint32_t)(t - origin);
    return (size_t)(since % (uint32_t)(S + 1));
}

void cfdi_lagged_reset(cfdi_lagged *lg, const cfdi_lagged_tables *t, size_t K)
{
    memset(lg->steady, 0, K * t->n_pairs * sizeof *lg->steady);
    lg->started = 0;
    lg->next = 0;
    lg->newest = 0;
}

/* Time tt is final: its squares, column pair by pair, added to every onset's sum it belongs to
 * (tt >= onset + S: the onsets are ascending). */
static void finish(cfdi_lagged *lg, const cfdi_lagged_tables *t, size_t K,
                   const int64_t *onsets, int64_t tt)
{
    const cfdi_real *psi = lg->psi + slot_of(lg->origin, tt, t->S) * t->q * t->n_cols;
    size_t pr, c, kb;
    for (pr = 0; pr < t->n_pairs; pr++) {
        size_t a = (size_t)t->pairs[2 * pr], b = (size_t)t->pairs[2 * pr + 1];
        cfdi_real sum = 0;
        for (c = 0; c < t->q; c++) {
            sum += psi[c * t->n_cols + a] * psi[c * t->n_cols + b];
        }
        lg->gram[pr] = sum;
    }
    for (kb = 0; kb < K && onsets[kb] <= tt - (int64_t)t->S; kb++) {
        cfdi_real *acc = lg->steady + kb * t->n_pairs;
        for (pr = 0; pr < t->n_pairs; pr++) {
            acc[pr] += lg->gram[pr];
        }
    }
}

/* rows (m, n) of sample k added to the times k - S .. k of psi ((q, n) a time), those from lo
 * to hi - 1 only: time tt at psi's slot tt - lo (ring 0: the local times) or tt mod (S+1). */
static void contribute(const cfdi_lagged_tables *t, int64_t k, const cfdi_real *rows, size_t n,
                       cfdi_real *psi, int64_t lo, int64_t hi, int64_t origin, int ring,
                       int all_seen)
{
    size_t l, c, col, a, S = t->S, qn = t->q * n;
    for (l = 0; l <= S; l++) {
        int64_t tt = k - (int64_t)S + (int64_t)l;
        const cfdi_real *N = t->noise + l * t->q * t->m;
        cfdi_real *out;
        if (tt < lo || tt >= hi) {
            continue;
        }
        out = psi + (ring ? slot_of(origin, tt, S) : (size_t)(tt - lo)) * qn;
        if (all_seen) { /* the steady columns' from the table (a scale's entries are 0) */
            const cfdi_real *add = t->steady + l * qn;
            for (a = 0; a < qn; a++) {
                out[a] += add[a];
            }
        }
        for (col = 0; col < n; col++) {
            if (all_seen && t->cols[2 * col] != CFDI_COL_SCALE) {
                continue;
            }
            for (c = 0; c < t->q; c++) {
                const cfdi_real *Nc = N + c * t->m;
                cfdi_real sum = 0;
                for (a = 0; a < t->m; a++) {
                    sum += Nc[a] * rows[a * n + col];
                }
                out[c * n + col] += sum;
            }
        }
    }
}

void cfdi_lagged_absorb(cfdi_lagged *lg, const cfdi_lagged_tables *t, size_t K,
                        const int64_t *onsets, int64_t k, const cfdi_real *rows, int all_seen)
{
    int64_t S = (int64_t)t->S, tt;
    size_t width = t->q * t->n_cols;
    if (!lg->started) {
        lg->started = 1;
        lg->next = k - S;
        lg->newest = k - S - 1;
        lg->origin = k - S;
    }
    /* The times no later sample reaches are final. */
    while (lg->next < k - S && lg->next <= lg->newest) {
        finish(lg, t, K, onsets, lg->next++);
    }
    if (lg->next < k - S) {
        lg->next = k - S;
    }
    for (tt = lg->newest + 1 > k - S ? lg->newest + 1 : k - S; tt <= k; tt++) {
        memset(lg->psi + slot_of(lg->origin, tt, t->S) * width, 0, width * sizeof *lg->psi);
    }
    lg->newest = k;
    contribute(t, k, rows, t->n_cols, lg->psi, k - S, k + 1, lg->origin, 1, all_seen);
    finish(lg, t, K, onsets, k - S);
    lg->next = k - S + 1;
}

void cfdi_lagged_local(const cfdi_lagged_tables *t, int64_t onset, int64_t k,
                       const cfdi_real *rows, size_t d, cfdi_real *psi_local)
{
    int64_t S = (int64_t)t->S;
    contribute(t, k, rows, d, psi_local, onset - S, onset + S, 0, 0, 0);
}

void cfdi_lagged_middle(const cfdi_lagged *lg, const cfdi_lagged_tables *t, size_t kb,
                        int64_t onset, size_t hyp, size_t n, size_t d,
                        const cfdi_real *psi_local, cfdi_real *out)
{
    size_t a, b, c, S = t->S, nc = t->n_cols;
    int64_t tt;
    for (a = 0; a < d * d; a++) {
        out[a] = 0;
    }
    for (a = 0; a < n; a++) {
        for (b = 0; b < n; b++) {
            int32_t pr = t->hyp_pairs[(hyp * d + a) * d + b];
            size_t ca = (size_t)t->hyp_cols[hyp * d + a], cb = (size_t)t->hyp_cols[hyp * d + b];
            cfdi_real sum = 0;
            size_t i;
            for (i = 0; i < 2 * S; i++) { /* the times before onset + S */
                const cfdi_real *psi = psi_local + i * t->q * n;
                for (c = 0; c < t->q; c++) {
                    sum += psi[c * n + a] * psi[c * n + b];
                }
            }
            if (lg->started) {
                sum += lg->steady[kb * t->n_pairs + (size_t)pr];
                /* the times from onset + S on that later samples still reach */
                for (tt = lg->next > onset + (int64_t)S ? lg->next : onset + (int64_t)S;
                     tt <= lg->newest; tt++) {
                    const cfdi_real *psi = lg->psi + slot_of(lg->origin, tt, S) * t->q * nc;
                    for (c = 0; c < t->q; c++) {
                        sum += psi[c * nc + ca] * psi[c * nc + cb];
                    }
                }
            }
            out[a * d + b] = sum;
        }
    }
}

/* Two-sided Page-Hinkley detectors over a block of rows, stopping at the first alarm row,
 * with change dating: canfdi.core.detect.ChangePointDetector.update_block (its cumulative-sum
 * form, `_run_plain` and `_lindley`, op for op). */
#include <math.h>

#include "cfdi.h"

/* One statistic's closed form over a segment: s = cumulative sum of the increments, lift =
 * s - min(0, running min of s), g = max(g0 + s, lift); numpy computes exactly these. */
typedef struct {
    cfdi_real g0;    /* the statistic at the segment's start */
    cfdi_real sum;   /* S_k */
    cfdi_real low;   /* min_j S_j so far (j >= 1) */
    int started;     /* whether low holds a value */
} cfdi_lindley;

static cfdi_real lindley_step(cfdi_lindley *t, cfdi_real z)
{
    cfdi_real lift, g;

    t->sum = t->started ? t->sum + z : z;
    t->low = (!t->started || t->sum < t->low) ? t->sum : t->low;
    t->started = 1;
    lift = t->low < 0 ? t->low : 0;
    lift = t->sum - lift;
    g = t->sum + t->g0;
    return g > lift ? g : lift;
}

int cfdi_ph_block(const int64_t *k, const cfdi_real *x, size_t n, size_t c,
                  const cfdi_real *delta, const cfdi_real *h, cfdi_real *state,
                  int64_t *last_zero, cfdi_real *g_up, cfdi_real *g_down, int8_t *alarm,
                  size_t *done)
{
    size_t row, col;

    if (k == NULL || x == NULL || delta == NULL || h == NULL || state == NULL
        || last_zero == NULL || g_up == NULL || g_down == NULL || alarm == NULL
        || done == NULL || c == 0) {
        return CFDI_EBADARG;
    }
    for (col = 0; col < c; col++) {
        alarm[col] = 0;
    }
    *done = n;
    for (col = 0; col < c; col++) {
        cfdi_lindley up, down;
        cfdi_real d = delta[col], hh = h[col];

        up.g0 = state[2 * col];
        down.g0 = state[2 * col + 1];
        up.started = down.started = 0;
        up.sum = down.sum = up.low = down.low = 0;
        for (row = 0; row < n; row++) {
            cfdi_real u = x[row * c + col], zu, zd, gu, gd;
            int present = !isnan(u);

            if (row > 0 && row % CFDI_PH_BLOCK == 0) {
                /* numpy restarts the sums from the last row's statistics */
                up.g0 = g_up[(row - 1) * c + col];
                down.g0 = g_down[(row - 1) * c + col];
                up.started = down.started = 0;
            }
            zu = present ? u - d : 0;
            zd = present ? -u - d : 0;
            gu = lindley_step(&up, zu);
            gd = lindley_step(&down, zd);
            g_up[row * c + col] = gu;
            g_down[row * c + col] = gd;
            if ((gu > gd ? gu : gd) >= hh && row < *done) {
                *done = row;  /* rows after the first alarm row need not be run: stop here */
            }
            if (row >= *done) {
                break;
            }
        }
    }
    /* A later column may have found an earlier alarm row: every column's statistics are
     * written through that row (each ran until its own first alarm or the end, and no column
     * stops before the block's first alarm row). */
    if (*done < n) {
        size_t a = *done;
        for (col = 0; col < c; col++) {
            cfdi_real gu = g_up[a * c + col], gd = g_down[a * c + col];
            if ((gu > gd ? gu : gd) >= h[col]) {
                alarm[col] = gu >= gd ? 1 : -1;
            }
        }
    }
    for (col = 0; col < c; col++) {
        for (row = 0; row < *done; row++) {
            if (!isnan(x[row * c + col])) {
                if (g_up[row * c + col] == 0) {
                    last_zero[2 * col] = k[row];
                }
                if (g_down[row * c + col] == 0) {
                    last_zero[2 * col + 1] = k[row];
                }
            }
        }
        if (*done > 0) {
            state[2 * col] = g_up[(*done - 1) * c + col];
            state[2 * col + 1] = g_down[(*done - 1) * c + col];
        }
    }
    return CFDI_OK;
}

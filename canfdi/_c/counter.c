/* The counter clock's state machine over a run of accepted drive frames
 * (canfdi.bus.assembler.SampleAssembler._slow_run, _place, _accept, _close_broken): each
 * frame's alive counter unwrapped against the latest sample by the time elapsed, then joined
 * to the pending sample, or opening the next (closing the pending one as broken), or judged a
 * duplicate, stale or a jump.
 *
 * The arithmetic is Python's where it matters: the modulo is non-negative, the elapsed periods
 * are the time difference converted to double then divided, n is floor(x + 0.5) of doubles.
 * Times and sample indices stay far inside int64 (the time gate bounds every frame's time to
 * its drive's; the machine stops where one does not, and the caller goes on in Python). */
#include <math.h>
#include <string.h>

#include "cfdi.h"
#include "decode.h"

#define ST(f) state[CFDI_CTR_##f]

static int fits(int64_t v)
{
    return v > -2 * CFDI_GATE_SAFE && v < 2 * CFDI_GATE_SAFE; /* |v| < 2^62 */
}

/* Close the pending sample as broken: its row, NaN for the slots not seen, to the output. */
static void close_broken(int64_t *state, const double *buffer, size_t width,
                         const int64_t *dest, size_t n_slots, size_t cols, int64_t *ks,
                         int64_t *done, int64_t *gaps, double *samples, size_t *n_out)
{
    size_t s, c, at = *n_out;
    double *row = samples + at * width;
    ST(OPEN) = 0;
    ST(BROKEN) += 1;
    memcpy(row, buffer, width * sizeof *row);
    for (s = 0; s < n_slots; s++) {
        if (!((ST(SEEN) >> s) & 1)) {
            for (c = 0; c < cols; c++) {
                if (dest[s * cols + c] >= 0) {
                    row[dest[s * cols + c]] = (double)NAN;
                }
            }
        }
    }
    ks[at] = ST(K);
    done[at] = ST(T_REF);
    gaps[at] = ST(LAST_DELIVERED) < 0 ? 0 : ST(K) - ST(LAST_DELIVERED) - 1;
    ST(LAST_DELIVERED) = ST(K);
    *n_out = at + 1;
}

/* The status of one valid drive frame (_place); on CFDI_ST_OK the pending sample is its. */
static int8_t place(int64_t *state, size_t slot, int64_t counter, int64_t t, int64_t mod,
                    double dt_ns, double slack, const double *buffer, size_t width,
                    const int64_t *dest, size_t n_slots, size_t cols, int64_t *ks,
                    int64_t *done, int64_t *gaps, double *samples, size_t *n_out)
{
    int64_t k_cur = ST(K), k;
    if (k_cur < 0) {
        k = counter; /* the first frame ever: its counter is its sample index */
    } else {
        int64_t d = ((counter - k_cur) % mod + mod) % mod;
        double elapsed = (double)(t - ST(T_REF)) / dt_ns;
        int64_t n;
        if (elapsed < 0.0) {
            elapsed = 0.0;
        }
        n = (int64_t)floor((elapsed - (double)d) / (double)mod + 0.5);
        k = k_cur + d + mod * n;
        if (k == k_cur) {
            if ((ST(SEEN) >> slot) & 1) {
                return CFDI_ST_DUPLICATE;
            }
            if (!ST(OPEN)) {
                return CFDI_ST_STALE;
            }
            ST(T_REF) = t;
            ST(JUMP_SET) = 0;
            return CFDI_ST_OK;
        }
        if (k < k_cur) {
            return CFDI_ST_STALE;
        }
        if ((double)(k - k_cur) > elapsed + slack) {
            /* ahead of the clock: a frame of garbage, or a restart its next frame confirms */
            if (!ST(JUMP_SET) || !(k - ST(JUMP) >= 0 && k - ST(JUMP) <= 1)) {
                ST(JUMP_SET) = 1;
                ST(JUMP) = k;
                return CFDI_ST_JUMP;
            }
        }
        if (ST(OPEN)) {
            close_broken(state, buffer, width, dest, n_slots, cols, ks, done, gaps, samples,
                         n_out);
        }
        ST(MISSING) += k - k_cur - 1;
    }
    ST(K) = k;
    ST(SEEN) = 0;
    ST(OPEN) = 1;
    ST(T_REF) = t;
    ST(JUMP_SET) = 0;
    return CFDI_ST_OK;
}

int cfdi_counter_run(int64_t *state, double *buffer, size_t width, const int64_t *rows,
                     const int64_t *slots, const int64_t *counters, const int64_t *times,
                     size_t n_frames, const double *values, size_t n_values, size_t vwidth,
                     const int64_t *dest, size_t n_slots, size_t cols, int64_t mod,
                     double dt_ns, double slack, int8_t *status, size_t n_status,
                     int64_t *ks, int64_t *done, int64_t *gaps, double *samples,
                     size_t *n_out, size_t *used)
{
    size_t r, c;
    int64_t full;
    if (state == NULL || buffer == NULL || n_out == NULL || used == NULL
        || (n_frames && (rows == NULL || slots == NULL || counters == NULL || times == NULL
                         || values == NULL || status == NULL || ks == NULL || done == NULL
                         || gaps == NULL || samples == NULL))
        || (n_slots && cols && dest == NULL)) {
        return CFDI_EBADARG;
    }
    if (n_slots == 0 || n_slots > 62 || mod < 2 || mod > CFDI_GATE_SAFE || !(dt_ns > 0)
        || cols > vwidth || width == 0) {
        return CFDI_EBADARG;
    }
    for (r = 0; r < n_slots * cols; r++) {
        if (dest[r] < -1 || dest[r] >= (int64_t)width) {
            return CFDI_ESHAPE;
        }
    }
    full = ((int64_t)1 << n_slots) - 1;
    *n_out = 0;
    *used = 0;
    for (r = 0; r < n_frames; r++) {
        int64_t i = rows[r], s = slots[r], t = times[r];
        int8_t code;
        if (i < 0 || (uint64_t)i >= (uint64_t)n_status || (uint64_t)i >= (uint64_t)n_values
            || s < 0 || (uint64_t)s >= (uint64_t)n_slots) {
            return CFDI_ESHAPE;
        }
        if (!fits(t) || !fits(ST(T_REF)) || !fits(ST(K)) || !fits(counters[r])
            || !fits(ST(JUMP)) || !fits(ST(LAST_DELIVERED))) {
            return CFDI_OK; /* *used frames taken; the rest is Python's */
        }
        code = place(state, (size_t)s, counters[r], t, mod, dt_ns, slack, buffer, width, dest,
                     n_slots, cols, ks, done, gaps, samples, n_out);
        *used = r + 1;
        if (code != CFDI_ST_OK) {
            status[i] = code;
            continue;
        }
        for (c = 0; c < cols; c++) {
            int64_t to = dest[(size_t)s * cols + c];
            if (to >= 0) {
                buffer[to] = values[(size_t)i * vwidth + c];
            }
        }
        ST(SEEN) |= (int64_t)1 << s;
        if (ST(SEEN) == full) { /* _accept: the sample is complete */
            size_t at = *n_out;
            ST(OPEN) = 0;
            ST(LAST_GAP) = ST(LAST_DELIVERED) < 0 ? 0 : ST(K) - ST(LAST_DELIVERED) - 1;
            ST(LAST_COMPLETE) = ST(LAST_DELIVERED) = ST(K);
            ST(COMPLETE) += 1;
            ks[at] = ST(K);
            done[at] = t;
            gaps[at] = ST(LAST_GAP);
            memcpy(samples + at * width, buffer, width * sizeof *samples);
            *n_out = at + 1;
        }
    }
    return CFDI_OK;
}

int cfdi_counter_close(int64_t *state, const double *buffer, size_t width, const int64_t *dest,
                       size_t n_slots, size_t cols, int64_t *ks, int64_t *done, int64_t *gaps,
                       double *samples, size_t *n_out)
{
    if (!state || !buffer || !dest || !ks || !done || !gaps || !samples || !n_out || !width) {
        return CFDI_EBADARG;
    }
    *n_out = 0;
    if (ST(OPEN)) {
        close_broken(state, buffer, width, dest, n_slots, cols, ks, done, gaps, samples, n_out);
    }
    return CFDI_OK;
}

/* A drive's time checked frame by frame (canfdi.bus.timegate.TimeGate.step over a block): a
 * frame further than the bound from the drive's time is a time jump, dropped; `confirm` such
 * frames in a row that agree with each other are a step of the clock, followed.
 *
 * Python's integers do not overflow; int64 does. Every time, offset and reference below
 * CFDI_GATE_SAFE in magnitude keeps every sum and difference here inside int64, so the gate
 * stops at the first frame where one is not and says how far it got: the caller (canfdi's
 * kernel) takes the rest of the block through the Python reference, with its state. */
#include "cfdi.h"

static int64_t magnitude(int64_t v)
{
    return v < 0 ? -v : v; /* callers pass |v| < CFDI_GATE_SAFE: no overflow */
}

static int safe(int64_t v)
{
    return v > -CFDI_GATE_SAFE && v < CFDI_GATE_SAFE;
}

int cfdi_gate_block(int64_t *state, int64_t bound, int64_t confirm, const int64_t *t,
                    size_t n_t, const int64_t *rows, size_t n_rows, int64_t *out,
                    int64_t *dropped, size_t *n_dropped, int64_t *steps, size_t *n_steps,
                    size_t *done)
{
    size_t i;
    int64_t *has_ref = &state[CFDI_GATE_HAS_REF], *ref = &state[CFDI_GATE_REF];
    int64_t *offset = &state[CFDI_GATE_OFFSET], *count = &state[CFDI_GATE_CHAIN_COUNT];
    int64_t *first = &state[CFDI_GATE_CHAIN_FIRST], *last = &state[CFDI_GATE_CHAIN_LAST];
    int64_t *jumps = &state[CFDI_GATE_JUMPS];

    if (state == NULL || (n_rows && (t == NULL || rows == NULL || out == NULL
                                     || dropped == NULL || steps == NULL))
        || n_dropped == NULL || n_steps == NULL || done == NULL) {
        return CFDI_EBADARG;
    }
    if (bound <= 0 || !safe(bound) || confirm < 1) {
        return CFDI_EBADARG;
    }
    *n_dropped = *n_steps = *done = 0;
    for (i = 0; i < n_rows; i++) {
        int64_t raw, c;
        if (rows[i] < 0 || (uint64_t)rows[i] >= (uint64_t)n_t) {
            return CFDI_ESHAPE;
        }
        raw = t[rows[i]];
        if (!safe(raw) || !safe(*offset) || (*has_ref && !safe(*ref))
            || (*count && (!safe(*first) || !safe(*last)))) {
            return CFDI_OK; /* *done frames checked; the rest is the reference's */
        }
        c = raw - *offset;
        if (!*has_ref) {
            *has_ref = 1;
            *ref = c;
            out[rows[i]] = c;
        } else if (magnitude(c - *ref) <= bound) {
            *count = 0;
            *first = *last = 0;
            if (c > *ref) {
                *ref = c;
            }
            out[rows[i]] = c;
        } else {
            if (*count && magnitude(raw - *last) <= bound) {
                *count += 1;
                *last = raw;
            } else {
                *count = 1;
                *first = *last = raw;
            }
            if (*count < confirm) {
                *jumps += 1;
                dropped[(*n_dropped)++] = (int64_t)i;
            } else {
                int64_t landed = *ref + bound;
                steps[2 * *n_steps] = *first;
                steps[2 * *n_steps + 1] = *first - *offset - *ref;
                *n_steps += 1;
                *offset = raw - landed; /* = offset + c - landed, without the sum */
                *count = 0;
                *first = *last = 0;
                *ref = landed;
                out[rows[i]] = landed;
            }
        }
        *done = i + 1;
    }
    return CFDI_OK;
}

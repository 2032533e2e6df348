/* The trigger and grid clocks' samples: at each sample instant, the newest value of each
 * signal received up to that instant's last row, if not older than max_age
 * (canfdi.bus.clock.LatestValueClock._values_at_reference).
 *
 * Times are compared as numpy compares them: the int64 difference (wrapping as numpy's does,
 * computed in unsigned arithmetic here) converted to double, against max_age in double. */
#include <math.h>
#include <string.h>

#include "cfdi.h"

static double age(int64_t instant, int64_t t)
{
    uint64_t d = (uint64_t)instant - (uint64_t)t;
    int64_t s;
    memcpy(&s, &d, sizeof s);
    return (double)s;
}

int cfdi_latest_block(const int64_t *ok, size_t n_ok, const int16_t *slot, size_t n,
                      const double *values, size_t vwidth, const int64_t *t,
                      const int64_t *dest, size_t n_slots, size_t cols,
                      const int64_t *instants, const int64_t *upto, size_t n_samples,
                      double max_age, double *value, int64_t *time, size_t width, double *out)
{
    size_t i, j = 0, c, d;

    if ((n_ok && (ok == NULL || slot == NULL || values == NULL || t == NULL))
        || (n_samples && (instants == NULL || upto == NULL || out == NULL))
        || (n_slots > 0 && cols > 0 && dest == NULL) || value == NULL || time == NULL || cols > vwidth) {
        return CFDI_EBADARG;
    }
    for (i = 0; i < n_slots * cols; i++) {
        if (dest[i] < -1 || dest[i] >= (int64_t)width) {
            return CFDI_ESHAPE;
        }
    }
    for (i = 0; i < n_ok; i++) {
        if (ok[i] < 0 || (uint64_t)ok[i] >= (uint64_t)n || (i && ok[i] <= ok[i - 1])
            || slot[ok[i]] < 0 || (size_t)slot[ok[i]] >= n_slots) {
            return CFDI_ESHAPE;
        }
    }
    for (i = 0; i < n_samples; i++) {
        if (upto[i] < -1 || (i && upto[i] < upto[i - 1])) {
            return CFDI_ESHAPE; /* the rows a sample counts only ever grow */
        }
    }
    for (i = 0; i <= n_samples; i++) {
        /* Take the frames up to this sample's last row (after the last sample: all). */
        while (j < n_ok && (i == n_samples || ok[j] <= upto[i])) {
            size_t r = (size_t)ok[j], s = (size_t)slot[r];
            for (c = 0; c < cols; c++) {
                int64_t to = dest[s * cols + c];
                if (to >= 0) {
                    value[to] = values[r * vwidth + c];
                    time[to] = t[r];
                }
            }
            j++;
        }
        if (i == n_samples) {
            break;
        }
        for (d = 0; d < width; d++) {
            out[i * width + d] = (double)NAN; /* a position no field maps: never received */
        }
        for (c = 0; c < n_slots * cols; c++) {
            int64_t to = dest[c];
            if (to >= 0) {
                out[i * width + (size_t)to] = age(instants[i], time[to]) <= max_age
                                              ? value[to] : (double)NAN;
            }
        }
    }
    return CFDI_OK;
}

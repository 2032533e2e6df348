/* A drive's frames checked and decoded from its compiled tables: the statuses, slots,
 * values and counters of canfdi.bus.dbc.BusMap.decode_frames, frame by frame.
 *
 * The values are cantools' (and canfdi.bus.codec's) to the bit: the same raw bits, the same
 * integer arithmetic where scale and offset are integers, the same one rounding to double
 * elsewhere (-ffp-contract=off keeps a multiply and an add two roundings, as numpy does). */
#include <math.h>
#include <string.h>

#include "decode.h"
#include "e2e.h"

#define ENTRY(bus, e, f) ((bus)->entry[(size_t)(e) * CFDI_ENTRY_INTS + (f)])
#define SIGI(bus, s, f) ((bus)->sig_int[(size_t)(s) * CFDI_SIG_INTS + (f)])
#define SIGR(bus, s, f) ((bus)->sig_real[(size_t)(s) * CFDI_SIG_REALS + (f)])

/* The byte after the last one a signal reads, or -1 when its place is malformed. */
static int64_t signal_end(int64_t start, int64_t n, int big)
{
    if (start < 0 || start >= 8 * CFDI_MAX_PAYLOAD || n < 1 || n > 64) {
        return -1;
    }
    if (big) {
        int64_t msb = 8 * (start / 8) + 7 - start % 8;
        return (msb + n - 1) / 8 + 1;
    }
    return (start + n - 1) / 8 + 1;
}

int cfdi_bus_check(const cfdi_bus *bus)
{
    size_t e, s, i;
    if (bus == NULL || bus->entry == NULL
        || (bus->n_std && (bus->std_id == NULL || bus->std_entry == NULL))
        || (bus->n_ext && (bus->ext_id == NULL || bus->ext_entry == NULL))
        || (bus->n_profiles && (bus->e2e_spec == NULL || bus->e2e_bytes == NULL))
        || (bus->n_signals && (bus->sig_int == NULL || bus->sig_real == NULL))
        || (bus->n_ids && (bus->ids_int == NULL || bus->ids_real == NULL))
        || bus->n_slots > bus->n_entries || bus->n_entries > INT32_MAX) {
        return CFDI_EBADARG;
    }
    for (i = 0; i < bus->n_std; i++) {
        if (bus->std_entry[i] < 0 || bus->std_entry[i] >= (int64_t)bus->n_entries
            || (i > 0 && bus->std_id[i] <= bus->std_id[i - 1])) {
            return CFDI_ESHAPE;
        }
    }
    for (i = 0; i < bus->n_ext; i++) {
        if (bus->ext_entry[i] < 0 || bus->ext_entry[i] >= (int64_t)bus->n_entries
            || (i > 0 && bus->ext_id[i] <= bus->ext_id[i - 1])) {
            return CFDI_ESHAPE;
        }
    }
    for (i = 0; i < bus->n_profiles; i++) {
        if (cfdi_e2e_spec_check(bus->e2e_spec + i * CFDI_E2E_INTS,
                                bus->e2e_bytes + i * CFDI_E2E_BYTES) != CFDI_OK) {
            return CFDI_ESHAPE;
        }
    }
    for (e = 0; e < bus->n_entries; e++) {
        int64_t kind = ENTRY(bus, e, CFDI_ENTRY_KIND), length = ENTRY(bus, e, CFDI_ENTRY_LENGTH);
        int64_t at = ENTRY(bus, e, CFDI_ENTRY_SIG_AT), count = ENTRY(bus, e, CFDI_ENTRY_SIG_COUNT);
        int64_t columns = ENTRY(bus, e, CFDI_ENTRY_COLUMNS);
        if ((kind != CFDI_ST_OK && kind != CFDI_ST_MONITOR && kind != CFDI_ST_UNUSED)
            || length < 0 || length > CFDI_MAX_PAYLOAD
            || ENTRY(bus, e, CFDI_ENTRY_PROFILE) < 0
            || ENTRY(bus, e, CFDI_ENTRY_PROFILE) >= (int64_t)bus->n_profiles
            || at < 0 || count < 0 || count > CFDI_SLOT_SIGNALS
            || at > (int64_t)bus->n_signals - count
            || columns < 0 || columns > (int64_t)bus->width
            || (e >= bus->n_slots && count != 0)) {
            return CFDI_ESHAPE;
        }
        for (s = (size_t)at; s < (size_t)(at + count); s++) {
            int64_t flags = SIGI(bus, s, CFDI_SIG_FLAGS), n = SIGI(bus, s, CFDI_SIG_LENGTH);
            int64_t parent = SIGI(bus, s, CFDI_SIG_PARENT), col = SIGI(bus, s, CFDI_SIG_COLUMN);
            int64_t ids_at = SIGI(bus, s, CFDI_SIG_IDS_AT);
            int64_t ids_count = SIGI(bus, s, CFDI_SIG_IDS_COUNT);
            int64_t end = signal_end(SIGI(bus, s, CFDI_SIG_START), n, (flags & CFDI_SIGF_BIG) != 0);
            int64_t conv = SIGI(bus, s, CFDI_SIG_CONV), num = SIGI(bus, s, CFDI_SIG_NUMBER);
            if (end < 0 || end > length || flags < 0 || flags > 31
                || ((flags & CFDI_SIGF_FLOAT) && n != 16 && n != 32 && n != 64)
                || conv < CFDI_CONV_IDENTITY || conv > CFDI_CONV_LINEAR
                || ((flags & CFDI_SIGF_FLOAT) && conv != CFDI_CONV_IDENTITY
                    && conv != CFDI_CONV_LINEAR)
                || num < CFDI_NUM_INT || num > CFDI_NUM_REAL
                /* a multiplexer before what it selects: the parent's row comes first */
                || parent < -1 || parent >= (int64_t)(s - (size_t)at)
                || (parent >= 0 && !(SIGI(bus, (size_t)at + (size_t)parent, CFDI_SIG_FLAGS)
                                     & CFDI_SIGF_MUX))
                || ids_at < 0 || ids_count < 0 || ids_at > (int64_t)bus->n_ids - ids_count
                || col < -1 || col >= columns) {
                return CFDI_ESHAPE;
            }
        }
    }
    return CFDI_OK;
}

/* The signal's bits (the low n of the result), zero beyond. */
static uint64_t signal_bits(const uint8_t *p, int64_t start, int64_t n, int big)
{
    uint64_t v = 0;
    int64_t i, first, last, shift;
    if (big) {
        int64_t msb = 8 * (start / 8) + 7 - start % 8, lsb = msb + n - 1;
        first = msb / 8;
        last = lsb / 8;
        for (i = first; i <= last; i++) {
            shift = lsb - (8 * i + 7); /* where the byte's lowest bit lands in the value */
            if (shift >= 0) {
                v |= shift < 64 ? (uint64_t)p[i] << shift : 0;
            } else {
                v |= (uint64_t)p[i] >> -shift;
            }
        }
    } else {
        first = start / 8;
        last = (start + n - 1) / 8;
        for (i = first; i <= last; i++) {
            shift = 8 * (i - first) - start % 8;
            if (shift >= 0) {
                v |= shift < 64 ? (uint64_t)p[i] << shift : 0;
            } else {
                v |= (uint64_t)p[i] >> -shift;
            }
        }
    }
    return n < 64 ? v & (((uint64_t)1 << n) - 1) : v;
}

static double half_to_double(uint64_t h)
{
    int e = (int)((h >> 10) & 0x1F);
    double f = (double)(h & 0x3FF), v;
    if (e == 0) {
        v = ldexp(f, -24);
    } else if (e == 31) {
        v = f != 0 ? (double)NAN : (double)INFINITY;
    } else {
        v = ldexp(f + 1024.0, e - 25);
    }
    return (h & 0x8000) ? -v : v;
}

/* A signal's raw value: an integer (int64, or uint64 bits) or a float. */
typedef struct {
    int64_t i;
    uint64_t u;
    double f;
} raw_value;

static raw_value signal_raw(const cfdi_bus *bus, size_t s, const uint8_t *p)
{
    int64_t flags = SIGI(bus, s, CFDI_SIG_FLAGS), n = SIGI(bus, s, CFDI_SIG_LENGTH);
    uint64_t bits = signal_bits(p, SIGI(bus, s, CFDI_SIG_START), n, (flags & CFDI_SIGF_BIG) != 0);
    raw_value r;
    r.u = bits;
    r.f = 0;
    if (flags & CFDI_SIGF_FLOAT) {
        if (n == 16) {
            r.f = half_to_double(bits);
        } else if (n == 32) {
            uint32_t b32 = (uint32_t)bits;
            float f32;
            memcpy(&f32, &b32, sizeof f32);
            r.f = (double)f32;
        } else {
            memcpy(&r.f, &bits, sizeof r.f);
        }
        r.i = 0;
        return r;
    }
    if ((flags & CFDI_SIGF_SIGNED) && n < 64 && (bits >> (n - 1)) & 1) {
        bits |= ~(((uint64_t)1 << n) - 1);
    }
    memcpy(&r.i, &bits, sizeof r.i); /* two's complement, as numpy's view */
    r.u = bits;
    return r;
}

static int is_u64(const cfdi_bus *bus, size_t s)
{
    int64_t flags = SIGI(bus, s, CFDI_SIG_FLAGS);
    return !(flags & (CFDI_SIGF_FLOAT | CFDI_SIGF_SIGNED)) && SIGI(bus, s, CFDI_SIG_LENGTH) == 64;
}

/* The raw value as a double: a float's own; an unsigned 64-bit field's from uint64, any other
 * integer's from int64 (numpy's conversions, each one rounding). */
static double raw_double(const cfdi_bus *bus, size_t s, raw_value r)
{
    if (SIGI(bus, s, CFDI_SIG_FLAGS) & CFDI_SIGF_FLOAT) {
        return r.f;
    }
    return is_u64(bus, s) ? (double)r.u : (double)r.i;
}

static double signal_physical(const cfdi_bus *bus, size_t s, raw_value r)
{
    int64_t conv = SIGI(bus, s, CFDI_SIG_CONV);
    double x, offset = SIGR(bus, s, CFDI_SIG_OFFSET);
    if (conv == CFDI_CONV_INTEGER || conv == CFDI_CONV_INTEGER_FLOAT) {
        /* Python checked at compile time that raw * iscale (+ ioffset) fits int64; unsigned
         * arithmetic keeps a table that lies from undefined behaviour. */
        uint64_t prod = (uint64_t)r.i * (uint64_t)SIGI(bus, s, CFDI_SIG_ISCALE);
        int64_t v;
        if (conv == CFDI_CONV_INTEGER) {
            prod += (uint64_t)SIGI(bus, s, CFDI_SIG_IOFFSET);
            memcpy(&v, &prod, sizeof v);
            return (double)v;
        }
        memcpy(&v, &prod, sizeof v);
        x = (double)v;
        return x + offset;
    }
    x = raw_double(bus, s, r);
    if (conv == CFDI_CONV_LINEAR) {
        x = x * SIGR(bus, s, CFDI_SIG_SCALE);
        if (offset != 0) {
            x = x + offset;
        }
    }
    return x;
}

/* Whether multiplexer m's raw value is one of ids[at .. at + count). */
static int mux_selects(const cfdi_bus *bus, size_t m, raw_value r, int64_t at, int64_t count)
{
    int64_t kind = SIGI(bus, m, CFDI_SIG_NUMBER), conv = SIGI(bus, m, CFDI_SIG_CONV), i;
    if (kind == CFDI_NUM_REAL) {
        double v = trunc(raw_double(bus, m, r) * SIGR(bus, m, CFDI_SIG_SCALE)
                         + SIGR(bus, m, CFDI_SIG_OFFSET));
        for (i = at; i < at + count; i++) {
            if (v == bus->ids_real[i]) {
                return 1;
            }
        }
        return 0;
    }
    if (kind == CFDI_NUM_UINT) {
        for (i = at; i < at + count; i++) {
            uint64_t id;
            memcpy(&id, &bus->ids_int[i], sizeof id);
            if (r.u == id) {
                return 1;
            }
        }
        return 0;
    }
    {
        int64_t v = r.i;
        if (conv == CFDI_CONV_INTEGER) {
            uint64_t w = (uint64_t)r.i * (uint64_t)SIGI(bus, m, CFDI_SIG_ISCALE)
                         + (uint64_t)SIGI(bus, m, CFDI_SIG_IOFFSET);
            memcpy(&v, &w, sizeof v);
        }
        for (i = at; i < at + count; i++) {
            if (v == bus->ids_int[i]) {
                return 1;
            }
        }
    }
    return 0;
}

/* A slot's values of one frame that passed its checks: the status it ends with. */
static int8_t decode_slot(const cfdi_bus *bus, size_t e, const uint8_t *p, double *row)
{
    size_t at = (size_t)ENTRY(bus, e, CFDI_ENTRY_SIG_AT);
    size_t count = (size_t)ENTRY(bus, e, CFDI_ENTRY_SIG_COUNT);
    size_t k;
    /* (a bit a signal, count <= CFDI_SLOT_SIGNALS == 64; a multiplexer's raw value read again
     * for each signal it selects: a stack of bytes, not of a raw value a signal, on an MCU) */
    uint64_t selected = 0;
    for (k = 0; k < count; k++) {
        size_t s = at + k;
        int64_t flags = SIGI(bus, s, CFDI_SIG_FLAGS), parent = SIGI(bus, s, CFDI_SIG_PARENT);
        int64_t col = SIGI(bus, s, CFDI_SIG_COLUMN);
        int on;
        if (flags & CFDI_SIGF_NEVER) {
            on = 0;
        } else if (parent >= 0) {
            size_t mux = at + (size_t)parent;
            on = ((selected >> parent) & 1u)
                 && mux_selects(bus, mux, signal_raw(bus, mux, p), SIGI(bus, s, CFDI_SIG_IDS_AT),
                                SIGI(bus, s, CFDI_SIG_IDS_COUNT));
        } else {
            on = 1;
        }
        selected |= (uint64_t)on << k;
        if (col >= 0) {
            row[col] = on ? signal_physical(bus, s, signal_raw(bus, s, p)) : (double)NAN;
        }
    }
    if (ENTRY(bus, e, CFDI_ENTRY_CHECKED)) {
        for (k = 0; k < count; k++) {
            int64_t col = SIGI(bus, at + k, CFDI_SIG_COLUMN);
            if (col >= 0 && !(row[col] >= SIGR(bus, at + k, CFDI_SIG_LOW)
                              && row[col] <= SIGR(bus, at + k, CFDI_SIG_HIGH))) {
                return CFDI_ST_IMPLAUSIBLE;
            }
        }
    }
    for (k = 0; k < count; k++) {
        int64_t col = SIGI(bus, at + k, CFDI_SIG_COLUMN);
        if (col >= 0 && (row[col] <= SIGR(bus, at + k, CFDI_SIG_CLIP_LOW)
                         || row[col] >= SIGR(bus, at + k, CFDI_SIG_CLIP_HIGH))) {
            return CFDI_ST_SATURATED;
        }
    }
    return CFDI_ST_OK;
}

static int32_t entry_of(const cfdi_bus *bus, uint32_t id, int extended)
{
    const int64_t *ids = extended ? bus->ext_id : bus->std_id;
    const int32_t *entries = extended ? bus->ext_entry : bus->std_entry;
    size_t lo = 0, n = extended ? bus->n_ext : bus->n_std, hi = n;
    while (lo < hi) { /* the first known ID >= id */
        size_t mid = lo + (hi - lo) / 2;
        if (ids[mid] < (int64_t)id) {
            lo = mid + 1;
        } else {
            hi = mid;
        }
    }
    return lo < n && ids[lo] == (int64_t)id ? entries[lo] : -1;
}

int cfdi_decode_block(const cfdi_bus *bus, size_t n, const uint32_t *id, const uint8_t *dlc,
                      const uint8_t *flags, const uint8_t *data, const int32_t *long_row,
                      const uint8_t *longdata, size_t n_long, int8_t *status, int16_t *slot,
                      double *values, int64_t *counters)
{
    int rc = cfdi_bus_check(bus);
    if (rc != CFDI_OK) {
        return rc;
    }
    return cfdi_decode_checked(bus, n, id, dlc, flags, data, long_row, longdata, n_long, status,
                               slot, values, counters);
}

int cfdi_decode_checked(const cfdi_bus *bus, size_t n, const uint32_t *id, const uint8_t *dlc,
                        const uint8_t *flags, const uint8_t *data, const int32_t *long_row,
                        const uint8_t *longdata, size_t n_long, int8_t *status, int16_t *slot,
                        double *values, int64_t *counters)
{
    size_t i, c, width;
    if (bus == NULL) {
        return CFDI_EBADARG;
    }
    if (n && (id == NULL || dlc == NULL || flags == NULL || data == NULL || status == NULL
              || slot == NULL || counters == NULL || (bus->width && values == NULL)
              || (n_long && (long_row == NULL || longdata == NULL)))) {
        return CFDI_EBADARG;
    }
    width = bus->width;
    for (i = 0; i < n; i++) {
        uint8_t f = flags[i];
        int extended = (f & CFDI_FLAG_EXTENDED) != 0, fd = (f & CFDI_FLAG_FD) != 0;
        int32_t e = entry_of(bus, id[i], extended);
        int8_t st;
        double *row = values + i * width;
        for (c = 0; c < width; c++) {
            row[c] = (double)NAN;
        }
        counters[i] = -1;
        slot[i] = -1;
        if (f & CFDI_FLAG_ERROR) {
            status[i] = CFDI_ST_ERROR;
            continue;
        }
        if (f & CFDI_FLAG_REMOTE) {
            status[i] = e >= 0 ? CFDI_ST_UNUSED : CFDI_ST_REMOTE;
            continue;
        }
        if (e < 0) {
            status[i] = fd ? CFDI_ST_FD : extended ? CFDI_ST_EXTENDED : CFDI_ST_UNKNOWN_ID;
            continue;
        }
        if ((size_t)e < bus->n_slots) {
            slot[i] = (int16_t)e;
        }
        if (fd != (ENTRY(bus, e, CFDI_ENTRY_FD) != 0)) {
            status[i] = CFDI_ST_FD;
            continue;
        }
        if ((int64_t)dlc[i] != ENTRY(bus, e, CFDI_ENTRY_LENGTH)) {
            status[i] = CFDI_ST_DLC;
            continue;
        }
        {
            uint8_t payload[CFDI_MAX_PAYLOAD];
            size_t len = dlc[i], profile = (size_t)ENTRY(bus, e, CFDI_ENTRY_PROFILE);
            const int32_t *spec = bus->e2e_spec + profile * CFDI_E2E_INTS;
            const uint8_t *bytes = bus->e2e_bytes + profile * CFDI_E2E_BYTES;
            int ok;
            memset(payload, 0, sizeof payload);
            memcpy(payload, data + i * 8, len < 8 ? len : 8);
            if (len > 8 && long_row != NULL && long_row[i] >= 0
                && (size_t)long_row[i] < n_long) {
                memcpy(payload + 8, longdata + (size_t)long_row[i] * CFDI_MAX_PAYLOAD + 8,
                       len - 8);
            }
            ok = cfdi_e2e_check_valid(spec, bytes, payload, len); /* checked by cfdi_bus_check */
            if (ok <= 0) {
                status[i] = CFDI_ST_CRC;
                continue;
            }
            if ((size_t)e >= bus->n_slots) {
                status[i] = (int8_t)ENTRY(bus, e, CFDI_ENTRY_KIND);
                continue;
            }
            st = decode_slot(bus, (size_t)e, payload, row);
            status[i] = st;
            if (st != CFDI_ST_OK) {
                for (c = 0; c < width; c++) {
                    row[c] = (double)NAN;
                }
                continue;
            }
            counters[i] = cfdi_e2e_counter_valid(spec, bytes, payload, len);
        }
    }
    return CFDI_OK;
}

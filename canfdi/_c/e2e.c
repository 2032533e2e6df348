/* The E2E profiles' check and counter read of one payload, and the sender's protection, from
 * a profile's compiled tables (e2e.h): canfdi.bus.e2e's `profile.check(payload)`,
 * `profile.counter(payload)` and `profile.protect(payload, counter)`, answer for answer. One
 * routine for every profile; what differs between them is table data. */
#include "e2e.h"

#define HALF_MAX 0xFFFF

static int in_range(int32_t value, int32_t low, int32_t high)
{
    return value >= low && value <= high;
}

/* Whether spec[from .. to - 1] are all 0. */
static int all_zero(const int32_t *spec, int from, int to)
{
    int i;
    for (i = from; i < to; i++) {
        if (spec[i] != 0) {
            return 0;
        }
    }
    return 1;
}

/* A 32-bit value stored as two 16-bit halves (both checked in range before). */
static uint64_t halves(const int32_t *spec, int high)
{
    return ((uint64_t)spec[high] << 16) | (uint64_t)spec[high + 1];
}

/* Whether the field whose piece count is spec[count_at] (pieces from spec[at]) is well
 * formed: count 0..CFDI_E2E_PIECES, each piece inside a byte below min_len with its value
 * bits inside 32, the unused piece slots 0. */
static int field_ok(const int32_t *spec, int count_at, int at, int32_t min_len)
{
    int32_t count = spec[count_at];
    int k;

    if (!in_range(count, 0, CFDI_E2E_PIECES)) {
        return 0;
    }
    for (k = 0; k < CFDI_E2E_PIECES; k++) {
        const int32_t *piece = spec + at + k * CFDI_E2E_PIECE_INTS;
        int32_t byte = piece[CFDI_E2E_PIECE_BYTE], bit = piece[CFDI_E2E_PIECE_BIT];
        int32_t width = piece[CFDI_E2E_PIECE_WIDTH], shift = piece[CFDI_E2E_PIECE_SHIFT];

        if (k >= count) {
            if (!all_zero(piece, 0, CFDI_E2E_PIECE_INTS)) {
                return 0;
            }
            continue;
        }
        if (!in_range(byte, 0, min_len - 1) || !in_range(bit, 0, 7)
            || !in_range(width, 1, 8 - bit) || !in_range(shift, 0, 32 - width)) {
            return 0;
        }
    }
    return 1;
}

/* The field's value, bytes at or beyond len read as 0 (the field must be well formed). */
static uint64_t field_read(const int32_t *spec, int count_at, int at, const uint8_t *payload,
                           size_t len)
{
    uint64_t value = 0;
    int32_t k;

    for (k = 0; k < spec[count_at]; k++) {
        const int32_t *piece = spec + at + k * CFDI_E2E_PIECE_INTS;
        size_t byte = (size_t)piece[CFDI_E2E_PIECE_BYTE];
        unsigned bits = byte < len ? payload[byte] : 0u;
        unsigned mask = (1u << piece[CFDI_E2E_PIECE_WIDTH]) - 1u;

        bits = (bits >> piece[CFDI_E2E_PIECE_BIT]) & mask;
        value |= (uint64_t)bits << piece[CFDI_E2E_PIECE_SHIFT];
    }
    return value;
}

/* The CRC byte a payload of len >= MIN_LEN bytes with this counter must carry (a KIND_CRC
 * table, well formed): the register from seed[counter & SEED_MASK] over the covered bytes but
 * the CRC's own, then (TRAIL) trail[counter & TRAIL_MASK], XORed with XOR_OUT. */
static unsigned crc_of(const int32_t *spec, const uint8_t *bytes, const uint8_t *payload,
                       size_t len, uint64_t counter)
{
    const uint8_t *table = bytes + CFDI_E2E_TABLE;
    size_t j, crc_byte = (size_t)spec[CFDI_E2E_CRC_BYTE];  /* < MIN_LEN <= len */
    size_t end = spec[CFDI_E2E_CRC_TO_LENGTH] ? len : (size_t)spec[CFDI_E2E_CRC_END]; /* <= len */
    unsigned reg = bytes[CFDI_E2E_SEEDS + (size_t)(counter & (uint64_t)spec[CFDI_E2E_SEED_MASK])];

    for (j = (size_t)spec[CFDI_E2E_CRC_FIRST]; j < end; j++) {
        if (j != crc_byte) {
            reg = table[reg ^ payload[j]];
        }
    }
    if (spec[CFDI_E2E_TRAIL]) {
        size_t trail = (size_t)(counter & (uint64_t)spec[CFDI_E2E_TRAIL_MASK]);
        reg = table[reg ^ bytes[CFDI_E2E_TRAILS + trail]];
    }
    return reg ^ (unsigned)spec[CFDI_E2E_XOR_OUT];
}

/* Write value into the field (its bits only; bytes beyond len untouched, the field must be
 * well formed and below MIN_LEN <= len). */
static void field_write(const int32_t *spec, int count_at, int at, uint8_t *payload,
                        uint64_t value)
{
    int32_t k;

    for (k = 0; k < spec[count_at]; k++) {
        const int32_t *piece = spec + at + k * CFDI_E2E_PIECE_INTS;
        size_t byte = (size_t)piece[CFDI_E2E_PIECE_BYTE];
        unsigned mask = (1u << piece[CFDI_E2E_PIECE_WIDTH]) - 1u;
        unsigned bits = (unsigned)(value >> piece[CFDI_E2E_PIECE_SHIFT]) & mask;
        unsigned bit = (unsigned)piece[CFDI_E2E_PIECE_BIT];

        payload[byte] = (uint8_t)((payload[byte] & ~(mask << bit)) | (bits << bit));
    }
}

int cfdi_e2e_spec_check(const int32_t *spec, const uint8_t *bytes)
{
    int32_t kind, min_len;
    int i;

    if (spec == NULL || bytes == NULL) {
        return CFDI_EBADARG;
    }
    for (i = 0; i < CFDI_E2E_INTS; i++) {
        if (spec[i] < 0) {
            return CFDI_EBADARG;
        }
    }
    kind = spec[CFDI_E2E_KIND];
    min_len = spec[CFDI_E2E_MIN_LEN];
    if (!in_range(kind, CFDI_E2E_KIND_NONE, CFDI_E2E_KIND_CRC)
        || spec[CFDI_E2E_MAX_LEN] < min_len) {
        return CFDI_EBADARG;
    }
    if (kind == CFDI_E2E_KIND_NONE) {
        return all_zero(spec, CFDI_E2E_COUNTER_MAX_HI, CFDI_E2E_INTS) ? CFDI_OK : CFDI_EBADARG;
    }
    if (spec[CFDI_E2E_COUNTER_MAX_HI] > HALF_MAX || spec[CFDI_E2E_COUNTER_MAX_LO] > HALF_MAX
        || spec[CFDI_E2E_EXTRA_VALUE_HI] > HALF_MAX || spec[CFDI_E2E_EXTRA_VALUE_LO] > HALF_MAX
        || !field_ok(spec, CFDI_E2E_COUNTER_PIECES, CFDI_E2E_COUNTER_AT, min_len)
        || !field_ok(spec, CFDI_E2E_EXTRA_PIECES, CFDI_E2E_EXTRA_AT, min_len)
        || (spec[CFDI_E2E_EXTRA_PIECES] == 0
            && !all_zero(spec, CFDI_E2E_EXTRA_VALUE_HI, CFDI_E2E_EXTRA_VALUE_LO + 1))) {
        return CFDI_EBADARG;
    }
    if (kind == CFDI_E2E_KIND_COUNTER) {
        return all_zero(spec, CFDI_E2E_CRC_BYTE, CFDI_E2E_INTS) ? CFDI_OK : CFDI_EBADARG;
    }
    if (!in_range(spec[CFDI_E2E_CRC_BYTE], 0, min_len - 1)
        || !in_range(spec[CFDI_E2E_CRC_TO_LENGTH], 0, 1)
        || !in_range(spec[CFDI_E2E_CRC_FIRST], 0, min_len)
        || !in_range(spec[CFDI_E2E_SEED_MASK], 0, CFDI_E2E_N_SEEDS - 1)
        || !in_range(spec[CFDI_E2E_TRAIL], 0, 1)
        || !in_range(spec[CFDI_E2E_TRAIL_MASK], 0, CFDI_E2E_N_TRAILS - 1)
        || (spec[CFDI_E2E_TRAIL] == 0 && spec[CFDI_E2E_TRAIL_MASK] != 0)
        || !in_range(spec[CFDI_E2E_XOR_OUT], 0, 0xFF)) {
        return CFDI_EBADARG;
    }
    if (spec[CFDI_E2E_CRC_TO_LENGTH] ? spec[CFDI_E2E_CRC_END] != 0
        : !in_range(spec[CFDI_E2E_CRC_END], spec[CFDI_E2E_CRC_FIRST], min_len)) {
        return CFDI_EBADARG;
    }
    return CFDI_OK;
}

int cfdi_e2e_check(const int32_t *spec, const uint8_t *bytes, const uint8_t *payload, size_t len)
{
    int status = cfdi_e2e_spec_check(spec, bytes);

    return status != CFDI_OK ? status : cfdi_e2e_check_valid(spec, bytes, payload, len);
}

int cfdi_e2e_check_valid(const int32_t *spec, const uint8_t *bytes, const uint8_t *payload,
                         size_t len)
{
    uint64_t counter;

    if (payload == NULL && len > 0) {
        return CFDI_EBADARG;
    }
    if (len < (size_t)spec[CFDI_E2E_MIN_LEN] || len > (size_t)spec[CFDI_E2E_MAX_LEN]) {
        return 0;
    }
    if (spec[CFDI_E2E_KIND] == CFDI_E2E_KIND_NONE) {
        return 1;
    }
    /* From here len >= MIN_LEN: every byte below is read from inside the payload. */
    counter = field_read(spec, CFDI_E2E_COUNTER_PIECES, CFDI_E2E_COUNTER_AT, payload, len);
    if (counter > halves(spec, CFDI_E2E_COUNTER_MAX_HI)) {
        return 0;
    }
    if (spec[CFDI_E2E_EXTRA_PIECES] > 0
        && field_read(spec, CFDI_E2E_EXTRA_PIECES, CFDI_E2E_EXTRA_AT, payload, len)
           != halves(spec, CFDI_E2E_EXTRA_VALUE_HI)) {
        return 0;
    }
    if (spec[CFDI_E2E_KIND] == CFDI_E2E_KIND_COUNTER) {
        return 1;
    }
    return payload[(size_t)spec[CFDI_E2E_CRC_BYTE]]
           == crc_of(spec, bytes, payload, len, counter);
}

int64_t cfdi_e2e_counter(const int32_t *spec, const uint8_t *bytes, const uint8_t *payload,
                         size_t len)
{
    int status = cfdi_e2e_spec_check(spec, bytes);

    return status != CFDI_OK ? status : cfdi_e2e_counter_valid(spec, bytes, payload, len);
}

int64_t cfdi_e2e_counter_valid(const int32_t *spec, const uint8_t *bytes,
                               const uint8_t *payload, size_t len)
{
    (void)bytes;
    if (payload == NULL && len > 0) {
        return CFDI_EBADARG;
    }
    if (spec[CFDI_E2E_KIND] == CFDI_E2E_KIND_NONE) {
        return -1;
    }
    return (int64_t)field_read(spec, CFDI_E2E_COUNTER_PIECES, CFDI_E2E_COUNTER_AT, payload,
                               len);
}

int cfdi_e2e_protect(const int32_t *spec, const uint8_t *bytes, uint8_t *payload, size_t len,
                     uint64_t counter)
{
    int status = cfdi_e2e_spec_check(spec, bytes);

    if (status != CFDI_OK) {
        return status;
    }
    if ((payload == NULL && len > 0) || len < (size_t)spec[CFDI_E2E_MIN_LEN]
        || len > (size_t)spec[CFDI_E2E_MAX_LEN]) {
        return CFDI_EBADARG;
    }
    if (spec[CFDI_E2E_KIND] == CFDI_E2E_KIND_NONE) {
        return CFDI_OK;
    }
    counter %= halves(spec, CFDI_E2E_COUNTER_MAX_HI) + 1;
    field_write(spec, CFDI_E2E_COUNTER_PIECES, CFDI_E2E_COUNTER_AT, payload, counter);
    if (spec[CFDI_E2E_EXTRA_PIECES] > 0) {
        field_write(spec, CFDI_E2E_EXTRA_PIECES, CFDI_E2E_EXTRA_AT, payload,
                    halves(spec, CFDI_E2E_EXTRA_VALUE_HI));
    }
    if (spec[CFDI_E2E_KIND] == CFDI_E2E_KIND_CRC) {
        payload[(size_t)spec[CFDI_E2E_CRC_BYTE]] = (uint8_t)crc_of(spec, bytes, payload, len,
                                                                   counter);
    }
    return CFDI_OK;
}

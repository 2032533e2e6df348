/* The monitor's messages encoded from compiled tables (encode.h): each signal's raw value from
 * its physical one as canfdi.bus.codec's _to_raw makes it (clipped to the physical range,
 * scaled, rounded half to even, clipped to the raw range; a float rounded to its width), its
 * bits ORed into a zeroed payload where the DBC places them. */
#include <float.h>
#include <math.h>
#include <string.h>

#include "decode.h"
#include "e2e.h"
#include "encode.h"

#define SI(msg, s, f) ((msg)->sig_int[(size_t)(s) * CFDI_ENC_INTS + (f)])
#define SR(msg, s, f) ((msg)->sig_real[(size_t)(s) * CFDI_ENC_REALS + (f)])

/* The payload bit (byte * 8 + bit, bit 0 the least significant) of the signal's value bit k
 * (0: its least significant), or -1 outside 64 bytes. */
static int64_t place_of(int64_t start, int64_t n, int big, int64_t k)
{
    int64_t at;
    if (big) { /* Motorola: the MSB at start, then on in network order (byte 0's bit 7 first) */
        int64_t msb = 8 * (start / 8) + 7 - start % 8, network = msb + (n - 1 - k);
        at = 8 * (network / 8) + 7 - network % 8;
    } else {
        at = start + k;
    }
    return at >= 0 && at < 8 * CFDI_MAX_PAYLOAD ? at : -1;
}

int cfdi_message_check(const cfdi_message *msg)
{
    size_t s;
    if (msg == NULL || (msg->n_signals && (msg->sig_int == NULL || msg->sig_real == NULL))
        || msg->length < 1 || msg->length > CFDI_MAX_PAYLOAD) {
        return CFDI_EBADARG;
    }
    if (cfdi_e2e_spec_check(msg->e2e_spec, msg->e2e_bytes) != CFDI_OK
        || (size_t)msg->e2e_spec[CFDI_E2E_MIN_LEN] > msg->length
        || (size_t)msg->e2e_spec[CFDI_E2E_MAX_LEN] < msg->length) {
        return CFDI_ESHAPE;
    }
    for (s = 0; s < msg->n_signals; s++) {
        int64_t start = SI(msg, s, CFDI_ENC_START), n = SI(msg, s, CFDI_ENC_LENGTH);
        int64_t flags = SI(msg, s, CFDI_ENC_FLAGS), role = SI(msg, s, CFDI_ENC_ROLE);
        int big = (flags & CFDI_SIGF_BIG) != 0;
        int64_t a, b;
        if (start < 0 || start >= 8 * CFDI_MAX_PAYLOAD || n < 1 || n > 64
            || (flags & ~(int64_t)(CFDI_SIGF_BIG | CFDI_SIGF_SIGNED | CFDI_SIGF_FLOAT)) != 0
            || ((flags & CFDI_SIGF_FLOAT) && n != 32 && n != 64)
            || role < CFDI_ROLE_NONE || role >= CFDI_N_ROLES) {
            return CFDI_ESHAPE;
        }
        a = place_of(start, n, big, 0);
        b = place_of(start, n, big, n - 1);
        if (a < 0 || b < 0 || a / 8 >= msg->length || b / 8 >= msg->length) {
            return CFDI_ESHAPE;
        }
    }
    return CFDI_OK;
}

/* A double rounded to float as IEEE 754 does (numpy's astype(float32)): beyond the largest
 * float by half an ulp or more, an infinity (a C conversion out of range is undefined). */
static float to_float(double v)
{
    const double edge = (double)FLT_MAX + ldexp(1.0, 103); /* FLT_MAX + half its ulp */
    if (v >= edge) {
        return (float)INFINITY;
    }
    if (v <= -edge) {
        return -(float)INFINITY;
    }
    if (v > (double)FLT_MAX) {
        return FLT_MAX;
    }
    if (v < -(double)FLT_MAX) {
        return -FLT_MAX;
    }
    return (float)v;
}

/* The signal's raw bits (the low n of the result) for physical value v. */
static uint64_t raw_bits(const cfdi_message *msg, size_t s, double v)
{
    int64_t n = SI(msg, s, CFDI_ENC_LENGTH), flags = SI(msg, s, CFDI_ENC_FLAGS);
    double lo = SR(msg, s, CFDI_ENC_LO), hi = SR(msg, s, CFDI_ENC_HI);
    uint64_t bits;
    if (flags & CFDI_SIGF_FLOAT) {
        if (isfinite(v) && (v < lo || v > hi)) {
            v = v < lo ? lo : hi;
        }
        v = (v - SR(msg, s, CFDI_ENC_OFFSET)) / SR(msg, s, CFDI_ENC_SCALE);
        if (n == 32) {
            float f = to_float(v);
            uint32_t b32;
            memcpy(&b32, &f, sizeof b32);
            return b32;
        }
        memcpy(&bits, &v, sizeof bits);
        return bits;
    }
    if (!(v >= lo && v <= hi)) {
        v = v != v ? 0.0 : v > DBL_MAX ? DBL_MAX : v < -DBL_MAX ? -DBL_MAX : v;
        v = v < lo ? lo : v > hi ? hi : v;
    }
    v = nearbyint((v - SR(msg, s, CFDI_ENC_OFFSET)) / SR(msg, s, CFDI_ENC_SCALE));
    if (v != v) {
        v = 0.0; /* a table whose scale is 0 or NaN: no value to give */
    }
    v = v < SR(msg, s, CFDI_ENC_RAW_LO) ? SR(msg, s, CFDI_ENC_RAW_LO) : v;
    v = v > SR(msg, s, CFDI_ENC_RAW_HI) ? SR(msg, s, CFDI_ENC_RAW_HI) : v;
    if (v >= 9223372036854775808.0) { /* an unsigned 64-bit signal's upper half */
        bits = (uint64_t)(v - 9223372036854775808.0) + ((uint64_t)1 << 63);
    } else if (v <= -9223372036854775808.0) {
        bits = (uint64_t)1 << 63;
    } else {
        int64_t i = (int64_t)v;
        memcpy(&bits, &i, sizeof bits);
    }
    return n < 64 ? bits & (((uint64_t)1 << n) - 1) : bits;
}

int cfdi_encode(const cfdi_message *msg, const double *by_role, uint8_t *payload)
{
    size_t s;
    int rc = cfdi_message_check(msg);
    if (rc != CFDI_OK) {
        return rc;
    }
    if (by_role == NULL || payload == NULL) {
        return CFDI_EBADARG;
    }
    memset(payload, 0, msg->length);
    for (s = 0; s < msg->n_signals; s++) {
        int64_t role = SI(msg, s, CFDI_ENC_ROLE), n = SI(msg, s, CFDI_ENC_LENGTH), k;
        int64_t start = SI(msg, s, CFDI_ENC_START);
        int big = (SI(msg, s, CFDI_ENC_FLAGS) & CFDI_SIGF_BIG) != 0;
        uint64_t bits;
        if (role == CFDI_ROLE_NONE) {
            continue;
        }
        bits = raw_bits(msg, s, by_role[role]);
        for (k = 0; k < n; k++) {
            if ((bits >> k) & 1u) {
                int64_t at = place_of(start, n, big, k); /* inside: checked above */
                payload[at / 8] = (uint8_t)(payload[at / 8] | (1u << (at % 8)));
            }
        }
    }
    return CFDI_OK;
}

/* The E2E profiles' receiver side from compiled tables: canfdi.bus.e2e's `check` and
 * `counter` of one payload, for every profile of the registry (none, counter, canfdi,
 * autosar_p01, autosar_p02).
 *
 * Tables, not logic: a profile is one int32 row `spec` [CFDI_E2E_INTS] and one uint8 row
 * `bytes` [CFDI_E2E_BYTES] that Python builds (each profile's `c_spec()`, laid out by
 * canfdi.bus.e2e.cspec, the one place in Python that knows this layout) and that
 * `canfdi codegen` writes as const data. One generic routine reads them; the indices here and
 * in cspec.py are the same, and a test compares them.
 *
 * What a frame must pass, in the table's terms (a check that fails on one condition fails):
 *   1. MIN_LEN <= len <= MAX_LEN;
 *   2. KIND >= COUNTER: the counter (an unsigned bit field) <= COUNTER_MAX;
 *      the extra field (EXTRA_PIECES > 0) == EXTRA_VALUE;
 *   3. KIND == CRC: byte CRC_BYTE == the CRC register, run with the 256-byte table from
 *      seed[counter & SEED_MASK] over bytes CRC_FIRST .. end - 1 (end: CRC_END, or len when
 *      CRC_TO_LENGTH) except byte CRC_BYTE, then (TRAIL) over trail[counter & TRAIL_MASK],
 *      XORed with XOR_OUT.
 * Every byte the check reads lies below MIN_LEN (or below len, for a CRC run to the length):
 * a table that says otherwise is malformed. The counter read pads the payload with zeros.
 *
 * An unsigned field is up to CFDI_E2E_PIECES pieces (byte, lowest bit, width, value shift),
 * one per payload byte it touches (canfdi.bus.e2e.bitfield.BitField): value |= ((payload[byte]
 * >> bit) & (2**width - 1)) << shift. A value of up to 32 bits does not fit a non-negative
 * int32, so COUNTER_MAX and EXTRA_VALUE are two 16-bit halves (HI << 16 | LO).
 */
#ifndef CFDI_E2E_H
#define CFDI_E2E_H

#include <stddef.h>
#include <stdint.h>

#include "cfdi.h"

/* KIND: what the profile has. */
#define CFDI_E2E_KIND_NONE 0     /* nothing: every frame within the lengths passes, no counter */
#define CFDI_E2E_KIND_COUNTER 1  /* a counter (and the extra field), no CRC */
#define CFDI_E2E_KIND_CRC 2      /* a counter, the extra field and a CRC */

/* MAX_LEN of a profile that takes payloads of any length. */
#define CFDI_E2E_ANY_LENGTH 2147483647
#define CFDI_E2E_PIECES 5        /* the most pieces of a field (32 bits from any bit: 5 bytes) */
#define CFDI_E2E_PIECE_INTS 4    /* one piece: byte, lowest bit, width (1..8), value shift */
#define CFDI_E2E_PIECE_BYTE 0    /* 0 .. MIN_LEN - 1 */
#define CFDI_E2E_PIECE_BIT 1     /* 0..7 */
#define CFDI_E2E_PIECE_WIDTH 2   /* 1..8, bit + width <= 8 */
#define CFDI_E2E_PIECE_SHIFT 3   /* 0..31, shift + width <= 32 */

/* spec: int32 [CFDI_E2E_INTS]; every value >= 0, and 0 in the parts a KIND does not have
 * (KIND_NONE: everything but MIN_LEN and MAX_LEN; KIND_COUNTER: CRC_BYTE .. XOR_OUT). */
#define CFDI_E2E_KIND 0           /* CFDI_E2E_KIND_* */
#define CFDI_E2E_MIN_LEN 1        /* the shortest payload that passes, bytes */
#define CFDI_E2E_MAX_LEN 2        /* the longest, >= MIN_LEN; CFDI_E2E_ANY_LENGTH: no bound */
#define CFDI_E2E_COUNTER_MAX_HI 3 /* the largest counter that passes (modulus - 1): high and */
#define CFDI_E2E_COUNTER_MAX_LO 4 /*   low 16 bits, each 0..0xFFFF */
#define CFDI_E2E_COUNTER_PIECES 5 /* the counter's pieces, 0..CFDI_E2E_PIECES (0: reads 0) */
#define CFDI_E2E_COUNTER_AT 6     /* its piece k at COUNTER_AT + k * CFDI_E2E_PIECE_INTS */
#define CFDI_E2E_EXTRA_PIECES 26  /* a field that must equal EXTRA_VALUE, 0..PIECES (0: none) */
#define CFDI_E2E_EXTRA_AT 27      /* its pieces, as the counter's */
#define CFDI_E2E_EXTRA_VALUE_HI 47 /* the value it must have: high and low 16 bits */
#define CFDI_E2E_EXTRA_VALUE_LO 48
#define CFDI_E2E_CRC_BYTE 49      /* the byte holding the CRC, 0 .. MIN_LEN - 1 */
#define CFDI_E2E_CRC_FIRST 50     /* the first byte the CRC covers, 0 .. MIN_LEN */
#define CFDI_E2E_CRC_END 51       /* one past the last, CRC_FIRST .. MIN_LEN (0 with TO_LENGTH) */
#define CFDI_E2E_CRC_TO_LENGTH 52 /* 1: the CRC covers CRC_FIRST .. len - 1 instead; 0 */
#define CFDI_E2E_SEED_MASK 53     /* the seed of a frame: seeds[counter & SEED_MASK], 0..15 */
#define CFDI_E2E_TRAIL 54         /* 1: one byte more after the data, trail[counter & MASK] */
#define CFDI_E2E_TRAIL_MASK 55    /* 0..15 */
#define CFDI_E2E_XOR_OUT 56       /* the final XOR, 0..255 */
#define CFDI_E2E_INTS 57

/* bytes: uint8 [CFDI_E2E_BYTES]. */
#define CFDI_E2E_TABLE 0          /* [256] the CRC's table: register = table[register ^ byte] */
#define CFDI_E2E_SEEDS 256        /* [CFDI_E2E_N_SEEDS] start registers */
#define CFDI_E2E_N_SEEDS 16
#define CFDI_E2E_TRAILS 272       /* [CFDI_E2E_N_TRAILS] trailing bytes (Profile 2's Data IDs) */
#define CFDI_E2E_N_TRAILS 16
#define CFDI_E2E_BYTES 288

/* CFDI_OK when spec and bytes are a well-formed profile (every value in its range, every byte
 * the check reads below MIN_LEN), else CFDI_EBADARG. The two functions below check this first,
 * on every call. */
int cfdi_e2e_spec_check(const int32_t *spec, const uint8_t *bytes);

/* Whether a received payload of len bytes passes (the profile's `check(payload)`): 1 when it
 * passes, 0 when it fails, CFDI_EBADARG for a malformed table or a null pointer (payload may
 * be NULL when len is 0). Reads payload[0 .. len - 1] only. */
int cfdi_e2e_check(const int32_t *spec, const uint8_t *bytes, const uint8_t *payload, size_t len);

/* The alive counter of a payload of len bytes, read as zero-padded (the profile's
 * `counter(payload)`), 0 .. 2**32 - 1; -1 for a profile without one (KIND_NONE). A malformed
 * table or a null pointer gives CFDI_EBADARG, also -1: cfdi_e2e_spec_check tells them apart. */
int64_t cfdi_e2e_counter(const int32_t *spec, const uint8_t *bytes, const uint8_t *payload,
                         size_t len);

/* The two above for a table cfdi_e2e_spec_check has passed (the decoder checks each of its
 * profiles once, not once per frame): the same answers, without checking the table again. */
int cfdi_e2e_check_valid(const int32_t *spec, const uint8_t *bytes, const uint8_t *payload,
                         size_t len);
int64_t cfdi_e2e_counter_valid(const int32_t *spec, const uint8_t *bytes,
                               const uint8_t *payload, size_t len);
/* The sender's side (the profile's `protect(payload, counter)`): write the counter (reduced
 * modulo COUNTER_MAX + 1), the extra field's value and the CRC into a payload of len bytes,
 * MIN_LEN <= len <= MAX_LEN, leaving every other bit as it is: CFDI_OK, or CFDI_EBADARG for a
 * malformed table, a null pointer or a length the profile does not take (payload untouched). */
int cfdi_e2e_protect(const int32_t *spec, const uint8_t *bytes, uint8_t *payload, size_t len,
                     uint64_t counter);

#endif

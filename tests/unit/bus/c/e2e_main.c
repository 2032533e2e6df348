/* A test driver for the C core's E2E profiles built alone (tests/unit/bus/test_e2e_c.py):
 * reads cases from stdin in a plain binary layout, runs them, writes the results to stdout.
 * Built with -pedantic under AddressSanitizer and UndefinedBehaviorSanitizer: any read or
 * write outside a buffer, any undefined operation, aborts the run. Every buffer the core sees
 * is allocated at its exact size (the spec, the bytes table, each payload), so a read one
 * past its end is caught. (The driver may use stdio; the core not.)
 *
 * Mode "r" (rows), cases until the end of the input, each:
 *   in : int32 spec[CFDI_E2E_INTS], uint8 bytes[CFDI_E2E_BYTES], int64 n,
 *        n x (uint8 payload[64], int64 length 0..64)
 *   out: int64 cfdi_e2e_spec_check, n x (int64 check, int64 counter)
 *   (a payload of length 0 is passed as NULL).
 * Mode "p" (protect), cases until the end of the input, each:
 *   in : int32 spec[CFDI_E2E_INTS], uint8 bytes[CFDI_E2E_BYTES], int64 n,
 *        n x (uint8 payload[64], int64 length 0..64, uint64 counter)
 *   out: n x (int64 cfdi_e2e_protect, uint8 payload[64]: the first length bytes protected)
 * Mode "n" (null pointers), one case:
 *   in : int32 spec[CFDI_E2E_INTS], uint8 bytes[CFDI_E2E_BYTES]
 *   out: int64 x 11: check and counter with spec NULL, with bytes NULL, with payload NULL
 *        and length 5, spec_check(NULL, NULL), spec_check(spec, bytes), and protect with
 *        spec NULL, bytes NULL, payload NULL and length 5.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "e2e.h"
#include "driver_io.h"

#define ROW 64

/* A case's profile (spec, bytes, each allocated at its size) and its row count n: 1, or 0 at
 * a clean end of the input (nothing allocated). */
static int read_profile(int32_t **spec, uint8_t **bytes, int64_t *n)
{
    *spec = must_alloc(CFDI_E2E_INTS * sizeof **spec);
    *bytes = must_alloc(CFDI_E2E_BYTES);
    if (!read_exact(*spec, sizeof **spec, CFDI_E2E_INTS, 1)) {
        free(*spec);
        free(*bytes);
        return 0;
    }
    read_exact(*bytes, 1, CFDI_E2E_BYTES, 0);
    read_exact(n, sizeof *n, 1, 0);
    return 1;
}

/* The first length bytes of row (0..ROW, else the driver exits) in a buffer of exactly that
 * size; NULL for length 0. */
static uint8_t *exact_copy(const uint8_t *row, int64_t length)
{
    uint8_t *payload;
    if (length < 0 || length > ROW) {
        exit(5);
    }
    if (length == 0) {
        return NULL;
    }
    payload = must_alloc((size_t)length);
    memcpy(payload, row, (size_t)length);
    return payload;
}

/* One case of mode "r"; 0 at the end of the input. */
static int run_case(void)
{
    int32_t *spec;
    uint8_t *bytes;
    uint8_t row[ROW];
    int64_t n = 0, i, length = 0;

    if (!read_profile(&spec, &bytes, &n)) {
        return 0;
    }
    put(cfdi_e2e_spec_check(spec, bytes));
    for (i = 0; i < n; i++) {
        uint8_t *payload;
        read_exact(row, 1, ROW, 0);
        read_exact(&length, sizeof length, 1, 0);
        payload = exact_copy(row, length);
        put(cfdi_e2e_check(spec, bytes, payload, (size_t)length));
        put(cfdi_e2e_counter(spec, bytes, payload, (size_t)length));
        free(payload);
    }
    free(spec);
    free(bytes);
    return 1;
}

/* One case of mode "p"; 0 at the end of the input. */
static int protect_case(void)
{
    int32_t *spec;
    uint8_t *bytes;
    uint8_t row[ROW];
    int64_t n = 0, i, length = 0;
    uint64_t counter = 0;

    if (!read_profile(&spec, &bytes, &n)) {
        return 0;
    }
    for (i = 0; i < n; i++) {
        uint8_t *payload;
        read_exact(row, 1, ROW, 0);
        read_exact(&length, sizeof length, 1, 0);
        read_exact(&counter, sizeof counter, 1, 0);
        payload = exact_copy(row, length);
        put(cfdi_e2e_protect(spec, bytes, payload, (size_t)length, counter));
        if (length > 0) {
            memcpy(row, payload, (size_t)length);
        }
        fwrite(row, 1, ROW, stdout);
        free(payload);
    }
    free(spec);
    free(bytes);
    return 1;
}

static int run_nulls(void)
{
    int32_t *spec = must_alloc(CFDI_E2E_INTS * sizeof *spec);
    uint8_t *bytes = must_alloc(CFDI_E2E_BYTES);
    uint8_t payload[8] = {0};

    read_exact(spec, sizeof *spec, CFDI_E2E_INTS, 0);
    read_exact(bytes, 1, CFDI_E2E_BYTES, 0);
    put(cfdi_e2e_check(NULL, bytes, payload, 8));
    put(cfdi_e2e_counter(NULL, bytes, payload, 8));
    put(cfdi_e2e_check(spec, NULL, payload, 8));
    put(cfdi_e2e_counter(spec, NULL, payload, 8));
    put(cfdi_e2e_check(spec, bytes, NULL, 5));
    put(cfdi_e2e_counter(spec, bytes, NULL, 5));
    put(cfdi_e2e_spec_check(NULL, NULL));
    put(cfdi_e2e_spec_check(spec, bytes));
    put(cfdi_e2e_protect(NULL, bytes, payload, 8, 1));
    put(cfdi_e2e_protect(spec, NULL, payload, 8, 1));
    put(cfdi_e2e_protect(spec, bytes, NULL, 5, 1));
    free(spec);
    free(bytes);
    return 0;
}

int main(int argc, char **argv)
{
    if (argc != 2) {
        return 2;
    }
    if (argv[1][0] == 'r') {
        while (run_case()) {
        }
        return 0;
    }
    if (argv[1][0] == 'p') {
        while (protect_case()) {
        }
        return 0;
    }
    if (argv[1][0] == 'n') {
        return run_nulls();
    }
    return 2;
}

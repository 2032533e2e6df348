/* A test driver for the C core's message encoder built alone (tests/unit/bus/test_encode_c.py):
 * reads cases from stdin in a plain binary layout, encodes, writes the payloads to stdout.
 * Built with -pedantic under AddressSanitizer and UndefinedBehaviorSanitizer (float casts
 * too): any read or write outside a buffer, any undefined operation, aborts the run. Every
 * table the core sees is allocated at its exact size. (The driver may use stdio; the core
 * not.)
 *
 * Cases until the end of the input, each:
 *   in : int64 length, int64 n_signals, int64 sig_int[n][CFDI_ENC_INTS],
 *        double sig_real[n][CFDI_ENC_REALS], int32 spec[CFDI_E2E_INTS],
 *        uint8 bytes[CFDI_E2E_BYTES], int64 rows, rows x double by_role[CFDI_N_ROLES]
 *   out: int64 cfdi_message_check, rows x (int64 cfdi_encode, uint8 payload[64])
 *   (the payload's bytes beyond the length, and all of them when refused, stay 0xEE).
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "e2e.h"
#include "encode.h"
#include "driver_io.h"

static int run_case(void)
{
    int64_t length = 0, n = 0, rows = 0, i;
    int64_t *sig_int;
    double *sig_real, by_role[CFDI_N_ROLES];
    int32_t *spec = must_alloc(CFDI_E2E_INTS * sizeof *spec);
    uint8_t *bytes = must_alloc(CFDI_E2E_BYTES), payload[64];
    cfdi_message msg;

    if (!read_exact(&length, sizeof length, 1, 1)) {
        free(spec);
        free(bytes);
        return 0;
    }
    read_exact(&n, sizeof n, 1, 0);
    if (n < 0 || n > 64 || length < 0 || length > 255) {
        exit(5);
    }
    sig_int = must_alloc((size_t)n * CFDI_ENC_INTS * sizeof *sig_int);
    sig_real = must_alloc((size_t)n * CFDI_ENC_REALS * sizeof *sig_real);
    read_exact(sig_int, sizeof *sig_int, (size_t)n * CFDI_ENC_INTS, 0);
    read_exact(sig_real, sizeof *sig_real, (size_t)n * CFDI_ENC_REALS, 0);
    read_exact(spec, sizeof *spec, CFDI_E2E_INTS, 0);
    read_exact(bytes, 1, CFDI_E2E_BYTES, 0);
    read_exact(&rows, sizeof rows, 1, 0);
    msg.id = 0x123;
    msg.extended = 0;
    msg.length = (uint8_t)length;
    msg.e2e_spec = spec;
    msg.e2e_bytes = bytes;
    msg.sig_int = sig_int;
    msg.sig_real = sig_real;
    msg.n_signals = (size_t)n;
    put(cfdi_message_check(&msg));
    for (i = 0; i < rows; i++) {
        read_exact(by_role, sizeof by_role[0], CFDI_N_ROLES, 0);
        memset(payload, 0xEE, sizeof payload);
        put(cfdi_encode(&msg, by_role, payload));
        fwrite(payload, 1, sizeof payload, stdout);
    }
    free(sig_int);
    free(sig_real);
    free(spec);
    free(bytes);
    return 1;
}

int main(void)
{
    while (run_case()) {
    }
    return 0;
}

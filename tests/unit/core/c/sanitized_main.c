/* A test driver for the C core built alone (tests/unit/core/test_c_sanitized.py): reads one
 * case from stdin in a plain binary layout, runs it, writes the results to stdout. Built with
 * -pedantic under AddressSanitizer and UndefinedBehaviorSanitizer: any read or write outside a
 * buffer, any undefined operation, aborts the run. (The driver may use stdio; the core not.) */
#include <stdio.h>
#include <stdlib.h>

#include "cfdi.h"
#include "decode.h"
#include "e2e.h"

static int64_t read_i64(void)
{
    int64_t v = 0;
    if (fread(&v, sizeof v, 1, stdin) != 1) {
        exit(3);
    }
    return v;
}

static void *read_block(size_t count, size_t size)
{
    void *p = malloc(count * size > 0 ? count * size : 1);
    if (p == NULL || (count > 0 && fread(p, size, count, stdin) != count)) {
        exit(3);
    }
    return p;
}

static int run_fir(void)
{
    size_t rows = (size_t)read_i64(), width = (size_t)read_i64(), S = (size_t)read_i64();
    size_t m = (size_t)read_i64(), n = rows > S ? rows - S : 0;
    cfdi_real *x = read_block(rows * width, sizeof *x);
    cfdi_real *coef = read_block((S + 1) * width * m, sizeof *coef);
    uint8_t *uses = read_block((S + 1) * width * m, 1);
    cfdi_real *out = malloc(n * m > 0 ? n * m * sizeof *out : 1);
    int64_t status = cfdi_fir_block(x, rows, width, coef, uses, S, m, out);

    fwrite(&status, sizeof status, 1, stdout);
    if (status == CFDI_OK) {
        fwrite(out, sizeof *out, n * m, stdout);
    }
    free(x);
    free(coef);
    free(uses);
    free(out);
    return 0;
}

static int run_ph(void)
{
    size_t n = (size_t)read_i64(), c = (size_t)read_i64(), done = 0;
    int64_t *k = read_block(n, sizeof *k);
    cfdi_real *x = read_block(n * c, sizeof *x);
    cfdi_real *delta = read_block(c, sizeof *delta), *h = read_block(c, sizeof *h);
    cfdi_real *state = read_block(2 * c, sizeof *state);
    int64_t *last_zero = read_block(2 * c, sizeof *last_zero);
    cfdi_real *g_up = malloc(n * c > 0 ? n * c * sizeof *g_up : 1);
    cfdi_real *g_down = malloc(n * c > 0 ? n * c * sizeof *g_down : 1);
    int8_t *alarm = malloc(c > 0 ? c : 1);
    int64_t status = cfdi_ph_block(k, x, n, c, delta, h, state, last_zero, g_up, g_down,
                                   alarm, &done);
    int64_t d = (int64_t)done;
    size_t rows = done < n ? done + 1 : n;

    fwrite(&status, sizeof status, 1, stdout);
    if (status == CFDI_OK) {
        fwrite(&d, sizeof d, 1, stdout);
        fwrite(g_up, sizeof *g_up, rows * c, stdout);
        fwrite(g_down, sizeof *g_down, rows * c, stdout);
        fwrite(alarm, 1, c, stdout);
        fwrite(state, sizeof *state, 2 * c, stdout);
        fwrite(last_zero, sizeof *last_zero, 2 * c, stdout);
    }
    free(k);
    free(x);
    free(delta);
    free(h);
    free(state);
    free(last_zero);
    free(g_up);
    free(g_down);
    free(alarm);
    return 0;
}

/* A drive's tables, then n frames: each array exactly as long as its size says (so that a
 * read past one is the sanitizer's to see). */
static int run_decode(void)
{
    cfdi_bus bus;
    size_t n_std = (size_t)read_i64(), n_ext = (size_t)read_i64();
    size_t n_entries = (size_t)read_i64();
    size_t n_slots = (size_t)read_i64(), n_profiles = (size_t)read_i64();
    size_t n_signals = (size_t)read_i64(), n_ids = (size_t)read_i64();
    size_t width = (size_t)read_i64(), n = (size_t)read_i64(), n_long = (size_t)read_i64();
    int64_t *std_id = read_block(n_std, sizeof *std_id);
    int32_t *std_entry = read_block(n_std, sizeof *std_entry);
    int64_t *ext_id = read_block(n_ext, sizeof *ext_id);
    int32_t *ext_entry = read_block(n_ext, sizeof *ext_entry);
    int64_t *entry = read_block(n_entries * CFDI_ENTRY_INTS, sizeof *entry);
    int32_t *spec = read_block(n_profiles * CFDI_E2E_INTS, sizeof *spec);
    uint8_t *bytes = read_block(n_profiles * CFDI_E2E_BYTES, 1);
    int64_t *sig_int = read_block(n_signals * CFDI_SIG_INTS, sizeof *sig_int);
    double *sig_real = read_block(n_signals * CFDI_SIG_REALS, sizeof *sig_real);
    int64_t *ids_int = read_block(n_ids, sizeof *ids_int);
    double *ids_real = read_block(n_ids, sizeof *ids_real);
    uint32_t *id = read_block(n, sizeof *id);
    uint8_t *dlc = read_block(n, 1), *flags = read_block(n, 1), *data = read_block(n * 8, 1);
    int32_t *long_row = read_block(n, sizeof *long_row);
    uint8_t *longdata = read_block(n_long * 64, 1);
    int8_t *status = malloc(n ? n : 1);
    int16_t *slot = malloc(n ? n * sizeof *slot : 1);
    double *values = malloc(n * width > 0 ? n * width * sizeof *values : 1);
    int64_t *counters = malloc(n ? n * sizeof *counters : 1), rc;

    bus.std_id = std_id;
    bus.std_entry = std_entry;
    bus.n_std = n_std;
    bus.ext_id = ext_id;
    bus.ext_entry = ext_entry;
    bus.n_ext = n_ext;
    bus.entry = entry;
    bus.n_entries = n_entries;
    bus.n_slots = n_slots;
    bus.e2e_spec = spec;
    bus.e2e_bytes = bytes;
    bus.n_profiles = n_profiles;
    bus.sig_int = sig_int;
    bus.sig_real = sig_real;
    bus.n_signals = n_signals;
    bus.ids_int = ids_int;
    bus.ids_real = ids_real;
    bus.n_ids = n_ids;
    bus.width = width;
    rc = cfdi_decode_block(&bus, n, id, dlc, flags, data, long_row, longdata, n_long, status,
                           slot, values, counters);
    fwrite(&rc, sizeof rc, 1, stdout);
    if (rc == CFDI_OK) {
        fwrite(status, 1, n, stdout);
        fwrite(slot, sizeof *slot, n, stdout);
        fwrite(values, sizeof *values, n * width, stdout);
        fwrite(counters, sizeof *counters, n, stdout);
    }
    free(std_id);
    free(std_entry);
    free(ext_id);
    free(ext_entry);
    free(entry);
    free(spec);
    free(bytes);
    free(sig_int);
    free(sig_real);
    free(ids_int);
    free(ids_real);
    free(id);
    free(dlc);
    free(flags);
    free(data);
    free(long_row);
    free(longdata);
    free(status);
    free(slot);
    free(values);
    free(counters);
    return 0;
}

int main(int argc, char **argv)
{
    if (argc != 2) {
        return 2;
    }
    if (argv[1][0] == 'f') {
        return run_fir();
    }
    if (argv[1][0] == 'p') {
        return run_ph();
    }
    if (argv[1][0] == 'd') {
        return run_decode();
    }
    return 2;
}

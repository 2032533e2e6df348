/* A test driver for the C core built alone (tests/unit/core/test_c_sanitized.py): reads one
 * case from stdin in a plain binary layout, runs it, writes the results to stdout. Built with
 * -pedantic under AddressSanitizer and UndefinedBehaviorSanitizer: any read or write outside a
 * buffer, any undefined operation, aborts the run. (The driver may use stdio; the core not.) */
#include <stdio.h>
#include <stdlib.h>

#include "cfdi.h"

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
    return 2;
}

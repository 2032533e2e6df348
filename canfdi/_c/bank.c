/* The residual bank's block form: r(k) = sum_l M_l x(k - S + l), a residual missing where
 * it reads a missing value. Mirrors canfdi.core.residuals.ResidualBank.batch: a missing
 * value is read as 0 and the residuals that use one are NaN. The sums have numpy's shape (a
 * product per lag over the entries, the lags added in order); numpy's BLAS may still order
 * or fuse an entry sum otherwise, so the two agree to rounding, not bit for bit.
 *
 * Speed: one residual's sum is a chain of dependent additions, so the rows are taken
 * CFDI_FIR_ROWS at a time and each coefficient multiplies into that many independent chains,
 * named locals the compiler keeps in vector registers (no sum is reordered). A tile whose
 * window holds no missing value (the usual case) skips the missing-value test. */
#include <math.h>
#include <string.h>

#include "cfdi.h"

#define CFDI_FIR_ROWS 8
/* A clean tile's window is copied column by column into this many values on the stack (2 KiB
 * of doubles: an MCU's stack holds it), so that the rows of one entry are contiguous; a wider
 * window takes the strided path. */
#define CFDI_FIR_STAGE 256

/* A clean, full tile from its window staged by column: xt[col * span + row], span = S + ROWS.
 * Eight rows' chains in named locals, which the compiler keeps in vector registers. */
static void clean_tile(const cfdi_real *xt, size_t span, size_t width, const cfdi_real *coef,
                       size_t S, size_t m, size_t r, cfdi_real *out)
{
    size_t lag, col, j;
    for (j = 0; j < m; j++) {
        cfdi_real a0 = 0, a1 = 0, a2 = 0, a3 = 0, a4 = 0, a5 = 0, a6 = 0, a7 = 0;
        cfdi_real *o = out + r * m + j;
        for (lag = 0; lag <= S; lag++) {
            cfdi_real p0 = 0, p1 = 0, p2 = 0, p3 = 0, p4 = 0, p5 = 0, p6 = 0, p7 = 0;
            const cfdi_real *c = coef + lag * width * m + j;
            const cfdi_real *v = xt + lag;
            for (col = 0; col < width; col++, c += m, v += span) {
                const cfdi_real k = *c;
                p0 += v[0] * k; p1 += v[1] * k; p2 += v[2] * k; p3 += v[3] * k;
                p4 += v[4] * k; p5 += v[5] * k; p6 += v[6] * k; p7 += v[7] * k;
            }
            if (lag == 0) {
                a0 = p0; a1 = p1; a2 = p2; a3 = p3; a4 = p4; a5 = p5; a6 = p6; a7 = p7;
            } else {
                a0 += p0; a1 += p1; a2 += p2; a3 += p3; a4 += p4; a5 += p5; a6 += p6; a7 += p7;
            }
        }
        o[0] = a0; o[m] = a1; o[2 * m] = a2; o[3 * m] = a3;
        o[4 * m] = a4; o[5 * m] = a5; o[6 * m] = a6; o[7 * m] = a7;
    }
}

/* One clean row (a drive loop's sample by sample: drive.c), the tiles' sums in their order. */
static void clean_row(const cfdi_real *x, size_t width, const cfdi_real *coef, size_t S,
                      size_t m, cfdi_real *out)
{
    size_t lag, col, j;
    for (j = 0; j < m; j++) {
        cfdi_real acc = 0;
        for (lag = 0; lag <= S; lag++) {
            const cfdi_real *c = coef + lag * width * m + j;
            const cfdi_real *v = x + lag * width;
            cfdi_real part = 0;
            for (col = 0; col < width; col++, c += m) {
                part += v[col] * *c;
            }
            acc = lag == 0 ? part : acc + part;
        }
        out[j] = acc;
    }
}

/* Rows r .. r + count - 1 of the output (count <= CFDI_FIR_ROWS), residual j. */
static void tile(const cfdi_real *x, size_t width, const cfdi_real *coef, const uint8_t *uses,
                 size_t S, size_t m, size_t r, size_t count, int clean, cfdi_real *out)
{
    size_t lag, col, i, j;
    for (j = 0; j < m; j++) {
        cfdi_real acc[CFDI_FIR_ROWS], part[CFDI_FIR_ROWS];
        uint8_t missing[CFDI_FIR_ROWS];
        memset(missing, 0, sizeof missing);
        for (lag = 0; lag <= S; lag++) {
            const cfdi_real *base = x + (r + lag) * width;
            for (i = 0; i < CFDI_FIR_ROWS; i++) {
                part[i] = 0;
            }
            for (col = 0; col < width; col++) {
                const cfdi_real c = coef[(lag * width + col) * m + j];
                if (clean && count == CFDI_FIR_ROWS) {
                    for (i = 0; i < CFDI_FIR_ROWS; i++) {
                        part[i] += base[i * width + col] * c;
                    }
                } else {
                    const int used = uses[(lag * width + col) * m + j] != 0;
                    for (i = 0; i < count; i++) {
                        cfdi_real v = base[i * width + col];
                        if (isnan(v)) {
                            missing[i] |= (uint8_t)used;
                            v = 0;
                        }
                        part[i] += v * c;
                    }
                }
            }
            for (i = 0; i < CFDI_FIR_ROWS; i++) {
                acc[i] = lag == 0 ? part[i] : acc[i] + part[i];
            }
        }
        for (i = 0; i < count; i++) {
            out[(r + i) * m + j] = missing[i] ? (cfdi_real)NAN : acc[i];
        }
    }
}

int cfdi_fir_row(const cfdi_real *x, size_t width, const cfdi_real *coef, const uint8_t *uses,
                 size_t S, size_t m, cfdi_real *out)
{
    size_t e, last = (S + 1) * width;
    int clean = 1;
    if (x == NULL || coef == NULL || uses == NULL || out == NULL || width == 0 || m == 0) {
        return CFDI_EBADARG;
    }
    for (e = 0; e < last && clean; e++) {
        clean = !isnan(x[e]);
    }
    if (clean) {
        clean_row(x, width, coef, S, m, out);
    } else {
        tile(x, width, coef, uses, S, m, 0, 1, 0, out);
    }
    return CFDI_OK;
}

int cfdi_fir_block(const cfdi_real *x, size_t rows, size_t width, const cfdi_real *coef,
                   const uint8_t *uses, size_t S, size_t m, cfdi_real *out)
{
    size_t n, r, count, e, last, span = S + CFDI_FIR_ROWS, row, col;
    cfdi_real xt[CFDI_FIR_STAGE];
    const int staged = width <= CFDI_FIR_STAGE / span;

    if (x == NULL || coef == NULL || uses == NULL || out == NULL || width == 0 || m == 0) {
        return CFDI_EBADARG;
    }
    if (rows <= S) {
        return CFDI_ESHAPE;
    }
    n = rows - S;
    if (n == 1) {
        return cfdi_fir_row(x, width, coef, uses, S, m, out);
    }
    for (r = 0; r < n; r += count) {
        int clean = 1;
        count = n - r < CFDI_FIR_ROWS ? n - r : CFDI_FIR_ROWS;
        last = (r + count + S) * width; /* the tile reads x[r * width .. last) */
        for (e = r * width; e < last && clean; e++) {
            clean = !isnan(x[e]);
        }
        if (clean && staged && count == CFDI_FIR_ROWS) {
            for (row = 0; row < span; row++) {
                for (col = 0; col < width; col++) {
                    xt[col * span + row] = x[(r + row) * width + col];
                }
            }
            clean_tile(xt, span, width, coef, S, m, r, out);
        } else {
            tile(x, width, coef, uses, S, m, r, count, clean, out);
        }
    }
    return CFDI_OK;
}

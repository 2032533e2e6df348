/* The residual bank's block form: r(k) = sum_l M_l x(k - S + l), a residual missing where
 * it reads a missing value. Mirrors canfdi.core.residuals.ResidualBank.batch: a missing
 * value is read as 0 and the residuals that use one are NaN. The sums have numpy's shape (a
 * product per lag over the entries, the lags added in order); numpy's BLAS may still order
 * or fuse an entry sum otherwise, so the two agree to rounding, not bit for bit. */
#include <math.h>

#include "cfdi.h"

int cfdi_fir_block(const cfdi_real *x, size_t rows, size_t width, const cfdi_real *coef,
                   const uint8_t *uses, size_t S, size_t m, cfdi_real *out)
{
    size_t n, r, lag, col, j;

    if (x == NULL || coef == NULL || uses == NULL || out == NULL || width == 0 || m == 0) {
        return CFDI_EBADARG;
    }
    if (rows <= S) {
        return CFDI_ESHAPE;
    }
    n = rows - S;
    for (r = 0; r < n; r++) {
        for (j = 0; j < m; j++) {
            cfdi_real acc = 0;
            int missing = 0;
            for (lag = 0; lag <= S; lag++) {
                const cfdi_real *row = x + (r + lag) * width;
                const cfdi_real *blk = coef + lag * width * m + j;
                const uint8_t *use = uses + lag * width * m + j;
                cfdi_real part = 0;
                for (col = 0; col < width; col++) {
                    cfdi_real v = row[col];
                    if (isnan(v)) {
                        missing |= use[col * m] != 0;
                        v = 0;
                    }
                    part += v * blk[col * m];
                }
                acc = lag == 0 ? part : acc + part;
            }
            out[r * m + j] = missing ? (cfdi_real)NAN : acc;
        }
    }
    return CFDI_OK;
}

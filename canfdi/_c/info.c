/* A diagnosis' least squares in information form, n samples at once: every fault hypothesis'
 * regressors at every candidate onset, and the sums they add to its fit. Mirrors
 * canfdi.methods.parity.hypotheses.information_increments (block_regressors, then the
 * information, the sandwich's middle and the residuals' sum of squares); the sums agree to
 * rounding (numpy's einsum may order a sum otherwise). */
#include <math.h>
#include <string.h>

#include "cfdi.h"

/* numpy's nan_to_num: a lost command (NaN) reads 0 (it enters only residuals that are missing
 * anyway), an infinite one the largest finite value of its sign. */
static cfdi_real finite(cfdi_real u)
{
    if (u != u) {
        return 0;
    }
    if (u > CFDI_REAL_MAX) {
        return CFDI_REAL_MAX;
    }
    if (u < -CFDI_REAL_MAX) {
        return -CFDI_REAL_MAX;
    }
    return u;
}

/* The first lag s of the window of sample k (positions k - S + s) at or after the onset:
 * S + 1 when none is (no int64 arithmetic that could wrap). */
static size_t first_lag(int64_t k, int64_t onset, size_t S)
{
    uint64_t since;
    if (k < onset) {
        return S + 1;
    }
    since = (uint64_t)k - (uint64_t)onset;
    return since >= (uint64_t)S ? 0 : S - (size_t)since;
}

/* One regressor term: column col's signature at residual row and lag s, times the command
 * for a scale. */
static cfdi_real term(const int32_t *col, const cfdi_real *Gz, const cfdi_real *Gu, size_t m,
                      size_t W, size_t row, size_t s, const cfdi_real *u, size_t p)
{
    size_t j = (size_t)col[1];
    const cfdi_real *g = (col[0] == CFDI_COL_SENSOR ? Gz : Gu) + (j * m + row) * W;
    return col[0] == CFDI_COL_SCALE ? g[s] * finite(u[s * p + j]) : g[s];
}

/* One sample's increments of one hypothesis' fit, from its regressors' sums over the window
 * (raw: (m, used), lags first..S, before the noise): phi = raw / sigma on the rows seen, then
 * inc = [phi^T phi (d, d), phi^T Gamma phi (d, d), phi^T r (d)] over its `used` columns (the
 * others, zero columns, add zeros: inc holds zeros there). */
static void increments(size_t m, size_t d, size_t used, const cfdi_real *raw,
                       const cfdi_real *sigma, const cfdi_real *r, const cfdi_real *gamma,
                       cfdi_real *phi, cfdi_real *gphi, cfdi_real *inc)
{
    size_t row, c, a, b;
    for (row = 0; row < m; row++) {
        for (c = 0; c < used; c++) {
            phi[row * d + c] = r[row] == r[row] ? raw[row * d + c] / sigma[row] : 0;
        }
    }
    for (row = 0; row < m; row++) { /* Gamma phi */
        for (c = 0; c < used; c++) {
            cfdi_real sum = 0;
            for (a = 0; a < m; a++) {
                sum += gamma[row * m + a] * phi[a * d + c];
            }
            gphi[row * d + c] = sum;
        }
    }
    for (a = 0; a < used; a++) {
        cfdi_real dot = 0;
        for (b = 0; b < used; b++) {
            cfdi_real info = 0, mid = 0;
            for (row = 0; row < m; row++) {
                info += phi[row * d + a] * phi[row * d + b];
                mid += phi[row * d + a] * gphi[row * d + b];
            }
            inc[a * d + b] = info;
            inc[d * d + a * d + b] = mid;
        }
        for (row = 0; row < m; row++) {
            if (r[row] == r[row]) {
                dot += phi[row * d + a] * r[row];
            }
        }
        inc[2 * d * d + a] = dot;
    }
}

int cfdi_info_block(size_t q, size_t p, size_t m, size_t S, const cfdi_real *Gz,
                    const cfdi_real *Gu, const cfdi_real *sigma, size_t H, size_t d,
                    const int32_t *columns, size_t K, const int64_t *onsets, size_t n,
                    const int64_t *k, const cfdi_real *U, const cfdi_real *rn,
                    const cfdi_real *gamma, cfdi_real *J, cfdi_real *h, cfdi_real *meat,
                    cfdi_real *rr, int64_t *n_eq, cfdi_real *work)
{
    size_t i, hyp, o, row, a, W = S + 1;
    cfdi_real *phi = work, *gphi = work + m * d, *raw = work + 2 * m * d,
              *inc = work + 3 * m * d;
    if (Gz == NULL || Gu == NULL || sigma == NULL || columns == NULL || onsets == NULL
        || gamma == NULL || J == NULL || h == NULL || meat == NULL || rr == NULL
        || n_eq == NULL || work == NULL || (n && (k == NULL || U == NULL || rn == NULL))) {
        return CFDI_EBADARG;
    }
    if (q == 0 || p == 0 || m == 0 || H == 0 || d == 0 || K == 0) {
        return CFDI_EBADARG;
    }
    for (hyp = 0; hyp < H * d; hyp++) {
        int32_t source = columns[2 * hyp], channel = columns[2 * hyp + 1];
        if (source < CFDI_COL_NONE || source > CFDI_COL_BIAS || channel < 0
            || (source == CFDI_COL_SENSOR && (size_t)channel >= q)
            || ((source == CFDI_COL_SCALE || source == CFDI_COL_BIAS) && (size_t)channel >= p)) {
            return CFDI_ESHAPE;
        }
    }
    for (i = 0; i < n; i++) {
        const cfdi_real *r = rn + i * m, *u = U + i * W * p;
        int64_t present = 0;
        for (row = 0; row < m; row++) {
            if (r[row] == r[row]) {
                present++;
                *rr += r[row] * r[row];
            }
        }
        *n_eq += present;
        for (hyp = 0; hyp < H; hyp++) {
            const int32_t *cols = columns + 2 * hyp * d;
            size_t used = 0, done = W, cached = W + 1, c;
            while (used < d && cols[2 * used] != CFDI_COL_NONE) {
                used++; /* (a hypothesis' columns come first, zero columns after) */
            }
            for (a = 0; a < 2 * d * d + d; a++) {
                inc[a] = 0;
            }
            /* The increments depend on the onset only through the window's first lag at or
             * after it: onsets sharing it (every one a window or more before the sample)
             * share them, and the regressors' sums grow lag by lag from the window's end, so
             * the onsets are taken latest first. */
            for (o = K; o-- > 0;) {
                size_t first = first_lag(k[i], onsets[o], S), at = (hyp * K + o) * d;
                cfdi_real *Jo = J + at * d, *ho = h + at, *mo = meat + at * d;
                if (first == W) {
                    continue; /* an onset after the sample: no regressor, nothing to add */
                }
                if (first != cached) {
                    if (first > done) { /* (onsets out of order: start the sums again) */
                        done = W;
                    }
                    if (done == W) {
                        for (a = 0; a < m * d; a++) {
                            raw[a] = 0;
                        }
                    }
                    for (; done > first; done--) {
                        for (row = 0; row < m; row++) {
                            for (c = 0; c < used; c++) {
                                raw[row * d + c] += term(cols + 2 * c, Gz, Gu, m, W, row,
                                                         done - 1, u, p);
                            }
                        }
                    }
                    increments(m, d, used, raw, sigma, r, gamma, phi, gphi, inc);
                    cached = first;
                }
                for (a = 0; a < d * d; a++) {
                    Jo[a] += inc[a];
                    mo[a] += inc[d * d + a];
                }
                for (a = 0; a < d; a++) {
                    ho[a] += inc[2 * d * d + a];
                }
            }
        }
    }
    return CFDI_OK;
}

int cfdi_info_solve(size_t count, size_t d, const cfdi_real *J, const cfdi_real *h,
                    const cfdi_real *rr, cfdi_real *theta, cfdi_real *P, cfdi_real *cost,
                    cfdi_real *lu, size_t *perm)
{
    size_t e, i, j, k, col;
    if (J == NULL || h == NULL || rr == NULL || theta == NULL || P == NULL || cost == NULL
        || lu == NULL || perm == NULL || d == 0) {
        return CFDI_EBADARG;
    }
    for (e = 0; e < count; e++) {
        const cfdi_real *A = J + e * d * d, *b = h + e * d;
        cfdi_real *x = theta + e * d, *inv = P + e * d * d, dot = 0;
        memcpy(lu, A, d * d * sizeof *lu);
        /* LU with partial pivoting (LAPACK's getrf): the largest magnitude in the column
         * below the diagonal, the first of equals, becomes the pivot. */
        for (j = 0; j < d; j++) {
            size_t p = j;
            cfdi_real best = fabs(lu[j * d + j]);
            for (i = j + 1; i < d; i++) {
                if (fabs(lu[i * d + j]) > best) {
                    best = fabs(lu[i * d + j]);
                    p = i;
                }
            }
            perm[j] = p;
            if (lu[p * d + j] == 0) {
                return CFDI_ESINGULAR;
            }
            if (p != j) {
                for (k = 0; k < d; k++) {
                    cfdi_real t = lu[j * d + k];
                    lu[j * d + k] = lu[p * d + k];
                    lu[p * d + k] = t;
                }
            }
            for (i = j + 1; i < d; i++) {
                cfdi_real l = lu[i * d + j] / lu[j * d + j];
                lu[i * d + j] = l;
                for (k = j + 1; k < d; k++) {
                    lu[i * d + k] -= l * lu[j * d + k];
                }
            }
        }
        /* theta = J^-1 h, then each column of P = J^-1 (the identity's columns solved). */
        for (col = 0; col <= d; col++) {
            cfdi_real *y = col == 0 ? x : inv; /* inv's column col - 1, strided by d */
            size_t step = col == 0 ? 1 : d, off = col == 0 ? 0 : col - 1;
            for (i = 0; i < d; i++) {
                y[i * step + off] = col == 0 ? b[i] : (cfdi_real)(i == col - 1);
            }
            for (j = 0; j < d; j++) { /* the row swaps, in order */
                if (perm[j] != j) {
                    cfdi_real t = y[j * step + off];
                    y[j * step + off] = y[perm[j] * step + off];
                    y[perm[j] * step + off] = t;
                }
            }
            for (i = 1; i < d; i++) { /* L y = P b, L unit lower */
                cfdi_real s = y[i * step + off];
                for (k = 0; k < i; k++) {
                    s -= lu[i * d + k] * y[k * step + off];
                }
                y[i * step + off] = s;
            }
            for (i = d; i-- > 0;) { /* U x = y */
                cfdi_real s = y[i * step + off];
                for (k = i + 1; k < d; k++) {
                    s -= lu[i * d + k] * y[k * step + off];
                }
                y[i * step + off] = s / lu[i * d + i];
            }
        }
        for (i = 0; i < d; i++) {
            dot += x[i] * b[i];
        }
        cost[e] = rr[e] - dot;
    }
    return CFDI_OK;
}

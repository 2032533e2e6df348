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

/* The terms of `used` columns at lags first .. done - 1 added to raw (m, d), from the window's
 * end as the sums grow: column c's signature at each residual row and lag s, times the
 * command for a scale (uf: the window's commands, nan_to_num'ed). */
static void grow(const int32_t *cols, size_t used, size_t d, const cfdi_real *Gz,
                 const cfdi_real *Gu, size_t m, size_t W, const cfdi_real *uf, size_t p,
                 size_t first, size_t done, cfdi_real *raw)
{
    size_t c, row, s;
    for (c = 0; c < used; c++) {
        int32_t source = cols[2 * c];
        size_t j = (size_t)cols[2 * c + 1];
        const cfdi_real *g = (source == CFDI_COL_SENSOR ? Gz : Gu) + j * m * W;
        for (row = 0; row < m; row++) {
            const cfdi_real *gr = g + row * W;
            cfdi_real acc = raw[row * d + c];
            if (source == CFDI_COL_SCALE) {
                for (s = done; s-- > first;) {
                    acc += gr[s] * uf[s * p + j];
                }
            } else {
                for (s = done; s-- > first;) {
                    acc += gr[s];
                }
            }
            raw[row * d + c] = acc;
        }
    }
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

/* The distinct columns the hypotheses use (at most 64 parameters in all: else hypothesis by
 * hypothesis), and each hypothesis parameter's. */
typedef struct {
    size_t n;
    const int32_t *of[64];        /* each one's (source, channel) */
    unsigned char map[64];        /* each hypothesis parameter's column */
} distinct_cols;

static int distinct_of(const int32_t *columns, size_t H, size_t d, distinct_cols *dc)
{
    size_t hyp, c, j;
    dc->n = 0;
    if (H * d > 64) {
        return 0;
    }
    for (hyp = 0; hyp < H; hyp++) {
        for (c = 0; c < d; c++) {
            const int32_t *col = columns + 2 * (hyp * d + c);
            if (col[0] == CFDI_COL_NONE) {
                dc->map[hyp * d + c] = 255;
                continue;
            }
            for (j = 0; j < dc->n && (dc->of[j][0] != col[0] || dc->of[j][1] != col[1]); j++) {
            }
            if (j == dc->n) {
                dc->of[dc->n++] = col;
            }
            dc->map[hyp * d + c] = (unsigned char)j;
        }
    }
    return 1;
}

/* The scratch of one sample's increments from the distinct columns at one first lag. */
typedef struct {
    size_t NC, m, d;
    cfdi_real *raw, *phi, *gphi;  /* (m, NC) the columns' sums, regressors, Gamma times them */
    cfdi_real *info, *mid, *dot;  /* (NC, NC), (NC, NC), (NC,) their products, made once */
    unsigned char *known;         /* (2 NC NC + NC) which products are made */
} column_sums;

/* The distinct columns' regressors at the first lag the sums have reached (phi = raw / sigma
 * on the rows seen, 0 elsewhere) and Gamma times them; no product made yet. */
static void columns_at(column_sums *cs, const cfdi_real *sigma, const cfdi_real *r,
                       const cfdi_real *gamma)
{
    size_t NC = cs->NC, m = cs->m, row, a, b;
    for (row = 0; row < m; row++) {
        for (a = 0; a < NC; a++) {
            cs->phi[row * NC + a] = r[row] == r[row] ? cs->raw[row * NC + a] / sigma[row] : 0;
        }
    }
    for (row = 0; row < m; row++) {
        for (a = 0; a < NC; a++) {
            cfdi_real sum = 0;
            for (b = 0; b < m; b++) {
                sum += gamma[row * m + b] * cs->phi[b * NC + a];
            }
            cs->gphi[row * NC + a] = sum;
        }
    }
    memset(cs->known, 0, 2 * NC * NC + NC);
}

/* One hypothesis' increments (inc: [phi^T phi, phi^T Gamma phi, phi^T r], as `increments`
 * makes them) gathered from the distinct columns' products, each made once. */
static void gather(column_sums *cs, const unsigned char *map, size_t used, const cfdi_real *r,
                   cfdi_real *inc)
{
    size_t NC = cs->NC, m = cs->m, d = cs->d, a, b, row;
    for (a = 0; a < used; a++) {
        size_t ca = map[a];
        for (b = 0; b < used; b++) {
            size_t cb = map[b], lo = ca < cb ? ca : cb, hi = ca < cb ? cb : ca;
            if (!cs->known[lo * NC + hi]) {
                cfdi_real info = 0;
                for (row = 0; row < m; row++) {
                    info += cs->phi[row * NC + ca] * cs->phi[row * NC + cb];
                }
                cs->info[lo * NC + hi] = info;
                cs->known[lo * NC + hi] = 1;
            }
            if (!cs->known[NC * NC + ca * NC + cb]) {
                cfdi_real mid = 0;
                for (row = 0; row < m; row++) {
                    mid += cs->phi[row * NC + ca] * cs->gphi[row * NC + cb];
                }
                cs->mid[ca * NC + cb] = mid;
                cs->known[NC * NC + ca * NC + cb] = 1;
            }
            inc[a * d + b] = cs->info[lo * NC + hi];
            inc[d * d + a * d + b] = cs->mid[ca * NC + cb];
        }
        if (!cs->known[2 * NC * NC + ca]) {
            cfdi_real dot = 0;
            for (row = 0; row < m; row++) {
                if (r[row] == r[row]) {
                    dot += cs->phi[row * NC + ca] * r[row];
                }
            }
            cs->dot[ca] = dot;
            cs->known[2 * NC * NC + ca] = 1;
        }
        inc[2 * d * d + a] = cs->dot[ca];
    }
}

static void add_to_fit(size_t d, const cfdi_real *inc, cfdi_real *Jo, cfdi_real *mo,
                       cfdi_real *ho)
{
    size_t a;
    for (a = 0; a < d * d; a++) {
        Jo[a] += inc[a];
        mo[a] += inc[d * d + a];
    }
    for (a = 0; a < d; a++) {
        ho[a] += inc[2 * d * d + a];
    }
}

int cfdi_info_block(size_t q, size_t p, size_t m, size_t S, const cfdi_real *Gz,
                    const cfdi_real *Gu, const cfdi_real *sigma, size_t H, size_t d,
                    const int32_t *columns, size_t K, const int64_t *onsets, size_t n,
                    const int64_t *k, const cfdi_real *U, const cfdi_real *rn,
                    const cfdi_real *gamma, cfdi_real *J, cfdi_real *h, cfdi_real *meat,
                    cfdi_real *rr, int64_t *n_eq, cfdi_real *work, size_t work_len)
{
    size_t i, hyp, o, row, a, W = S + 1, per = 2 * d * d + d;
    cfdi_real *phi = work, *gphi = work + m * d, *raw = work + 2 * m * d,
              *inc = work + 3 * m * d, *uf = inc + per, *hinc = uf + W * p, *rest = hinc + H * per;
    column_sums cs;
    distinct_cols dc;
    int ascending = 1, distinct;
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
    for (o = 1; o < K; o++) {
        ascending &= onsets[o] > onsets[o - 1];
    }
    /* With the onsets ascending and at most 64 hypothesis parameters, the increments come
     * from the distinct columns the hypotheses share, made once a first lag for all of them;
     * otherwise hypothesis by hypothesis. The same sums either way, in the same order. */
    dc.n = 0;
    distinct = ascending && distinct_of(columns, H, d, &dc);
    if (work_len < CFDI_INFO_WORK(m, d, S, p, H, dc.n)) {
        return CFDI_ESHAPE;
    }
    cs.NC = dc.n;
    cs.m = m;
    cs.d = d;
    cs.raw = rest;
    cs.phi = cs.raw + m * cs.NC;
    cs.gphi = cs.phi + m * cs.NC;
    cs.info = cs.gphi + m * cs.NC;
    cs.mid = cs.info + cs.NC * cs.NC;
    cs.dot = cs.mid + cs.NC * cs.NC;
    cs.known = (unsigned char *)(cs.dot + cs.NC);
    for (i = 0; i < n; i++) {
        const cfdi_real *r = rn + i * m, *u = U + i * W * p;
        int64_t present = 0;
        size_t upto = K; /* the onsets at or before the sample (the rest add nothing) */
        for (a = 0; a < W * p; a++) {
            uf[a] = finite(u[a]);
        }
        for (row = 0; row < m; row++) {
            if (r[row] == r[row]) {
                present++;
                *rr += r[row] * r[row];
            }
        }
        *n_eq += present;
        if (ascending) {
            while (upto > 0 && onsets[upto - 1] > k[i]) {
                upto--;
            }
        }
        if (distinct) {
            /* The onsets latest first: their first lags fall, so the columns' sums grow lag
             * by lag from the window's end; onsets sharing a first lag share the
             * increments. */
            size_t done = W, cached = W + 1, c;
            for (a = 0; a < m * cs.NC; a++) {
                cs.raw[a] = 0;
            }
            for (o = upto; o-- > 0;) {
                size_t first = first_lag(k[i], onsets[o], S);
                if (first == W) {
                    continue;
                }
                if (first != cached) {
                    for (c = 0; c < cs.NC; c++) {
                        for (row = 0; row < m; row++) {
                            raw[row * d] = cs.raw[row * cs.NC + c];
                        }
                        grow(dc.of[c], 1, d, Gz, Gu, m, W, uf, p, first, done, raw);
                        for (row = 0; row < m; row++) {
                            cs.raw[row * cs.NC + c] = raw[row * d];
                        }
                    }
                    done = first;
                    columns_at(&cs, sigma, r, gamma);
                    for (hyp = 0; hyp < H; hyp++) {
                        size_t used = 0;
                        while (used < d && columns[2 * (hyp * d + used)] != CFDI_COL_NONE) {
                            used++;
                        }
                        for (a = 0; a < per; a++) {
                            hinc[hyp * per + a] = 0;
                        }
                        gather(&cs, dc.map + hyp * d, used, r, hinc + hyp * per);
                    }
                    cached = first;
                }
                for (hyp = 0; hyp < H; hyp++) {
                    size_t at = (hyp * K + o) * d;
                    add_to_fit(d, hinc + hyp * per, J + at * d, meat + at * d, h + at);
                }
            }
            continue;
        }
        for (hyp = 0; hyp < H; hyp++) {
            const int32_t *cols = columns + 2 * hyp * d;
            size_t used = 0, done = W, cached = W + 1;
            while (used < d && cols[2 * used] != CFDI_COL_NONE) {
                used++; /* (a hypothesis' columns come first, zero columns after) */
            }
            for (a = 0; a < per; a++) {
                inc[a] = 0;
            }
            /* The increments depend on the onset only through the window's first lag at or
             * after it: onsets sharing it (every one a window or more before the sample)
             * share them, and the regressors' sums grow lag by lag from the window's end, so
             * the onsets are taken latest first. */
            for (o = upto; o-- > 0;) {
                size_t first = first_lag(k[i], onsets[o], S), at = (hyp * K + o) * d;
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
                    grow(cols, used, d, Gz, Gu, m, W, uf, p, first, done, raw);
                    done = first;
                    increments(m, d, used, raw, sigma, r, gamma, phi, gphi, inc);
                    cached = first;
                }
                add_to_fit(d, inc, J + at * d, meat + at * d, h + at);
            }
        }
    }
    return CFDI_OK;
}

int cfdi_fit_solve(size_t d, const cfdi_real *J, const cfdi_real *h, cfdi_real *theta,
                   cfdi_real *P, cfdi_real *lu, size_t *perm)
{
    size_t i, j, k, col;
    memcpy(lu, J, d * d * sizeof *lu);
    /* LU with partial pivoting (LAPACK's getrf): the largest magnitude in the column below
     * the diagonal, the first of equals, becomes the pivot. */
    for (j = 0; j < d; j++) {
        size_t p = j;
        cfdi_real best = CFDI_FABS(lu[j * d + j]);
        for (i = j + 1; i < d; i++) {
            if (CFDI_FABS(lu[i * d + j]) > best) {
                best = CFDI_FABS(lu[i * d + j]);
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
    for (col = 0; col <= (P ? d : 0); col++) {
        cfdi_real *y = col == 0 ? theta : P; /* P's column col - 1, strided by d */
        size_t step = col == 0 ? 1 : d, off = col == 0 ? 0 : col - 1;
        for (i = 0; i < d; i++) {
            y[i * step + off] = col == 0 ? h[i] : (cfdi_real)(i == col - 1);
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
    return CFDI_OK;
}

int cfdi_info_solve(size_t count, size_t d, const cfdi_real *J, const cfdi_real *h,
                    const cfdi_real *rr, cfdi_real *theta, cfdi_real *P, cfdi_real *cost,
                    cfdi_real *lu, size_t *perm)
{
    size_t e, i;
    if (J == NULL || h == NULL || rr == NULL || theta == NULL || P == NULL || cost == NULL
        || lu == NULL || perm == NULL || d == 0) {
        return CFDI_EBADARG;
    }
    for (e = 0; e < count; e++) {
        const cfdi_real *b = h + e * d;
        cfdi_real *x = theta + e * d, dot = 0;
        int status = cfdi_fit_solve(d, J + e * d * d, b, x, P + e * d * d, lu, perm);
        if (status != CFDI_OK) {
            return status;
        }
        for (i = 0; i < d; i++) {
            dot += x[i] * b[i];
        }
        cost[e] = rr[e] - dot;
    }
    return CFDI_OK;
}

void cfdi_column(const cfdi_signatures *g, int32_t source, int32_t channel, int64_t k,
                 int64_t onset, const cfdi_real *U, cfdi_real *out)
{
    size_t W = g->S + 1, first = first_lag(k, onset, g->S), a, s;
    const cfdi_real *G;
    if (source == CFDI_COL_NONE || first == W) {
        for (a = 0; a < g->m; a++) {
            out[a] = 0;
        }
        return;
    }
    G = (source == CFDI_COL_SENSOR ? g->Gz : g->Gu) + (size_t)channel * g->m * W;
    for (a = 0; a < g->m; a++) {
        const cfdi_real *gr = G + a * W;
        cfdi_real raw = 0;
        if (source == CFDI_COL_SCALE) {
            for (s = W; s-- > first;) {
                raw += gr[s] * finite(U[s * g->p + (size_t)channel]);
            }
        } else {
            for (s = W; s-- > first;) {
                raw += gr[s];
            }
        }
        out[a] = raw / g->sigma[a];
    }
}

/* The estimates' variances as canfdi's diagnoser reports them: the sandwich's middle counting
 * the residuals' correlation lag by lag over every sample a diagnosis absorbed
 * (canfdi.methods.parity.thresholds.lagged_middle, ParityDiagnoser._lagged_meat), without
 * keeping those samples.
 *
 * Parity residuals are r(k) = sum_l N_l e(k - S + l) of white measurement noise e, so the
 * middle sum_{i,j} phi_i^T C[k_i - k_j] phi_j over the fit's regressors phi_i equals
 * sum_t psi_t^T psi_t, psi_t = sum_i N_{t - k_i + S}^T phi_i: one square per measurement time t,
 * each final once the S samples after it are in. A fit's regressors at onset o are those of a
 * fault present all along (its steady ones) at every sample from o + S on, so its middle is the
 * squares of the times from o + S on, built from the steady regressors of every column once for
 * all the fits (kept per onset as the times finish: `steady`), plus those of the times before
 * o + S, from the samples within 2S of the onset (`cfdi_lagged_local`, for the one fit an event
 * reports). The same numbers to rounding: the order of the sums differs. */
#ifndef CFDI_LAGGED_H
#define CFDI_LAGGED_H

#include <stddef.h>
#include <stdint.h>

#include "cfdi.h"

typedef struct {
    size_t S, q, m;
    size_t n_cols;                /* NC: the regressor columns the hypotheses use */
    const int32_t *cols;          /* (NC, 2) each one's source and channel (CFDI_COL_*) */
    const int32_t *hyp_cols;      /* (H, d) each hypothesis parameter's column, -1 beyond */
    size_t n_pairs;               /* NP */
    const int32_t *pairs;         /* (NP, 2) the pairs of columns the fits' middles read */
    const int32_t *hyp_pairs;     /* (H, d, d) each pair of a hypothesis' parameters' pair */
    const cfdi_real *noise;       /* (S+1, q, m) N[l][c][a]: residual a's coefficient on
                                   * measurement c at lag l over its noise, times c's noise
                                   * standard deviation */
    const cfdi_real *steady;      /* (S+1, q, NC) what a bias' or sensor's steady column adds
                                   * to each time of a sample whose residuals are all there
                                   * (N^T of the column: a scale's varies, its entries 0) */
} cfdi_lagged_tables;

typedef struct {
    cfdi_real *psi;               /* (S+1, q, NC) the times not final, at slot t mod (S+1) */
    cfdi_real *steady;            /* (K, NP) each onset's squares of the final times from its
                                   * onset + S on */
    cfdi_real *gram;              /* (NP,) scratch */
    cfdi_real *rows;              /* (m, NC) scratch: a sample's steady regressors */
    cfdi_real *local;             /* (2S, q, d) scratch: a fit's times before its onset + S
                                   * (both the drive's scratch, lent) */
    int64_t next;                 /* the first time not final */
    int64_t newest;               /* the newest time a sample reached */
    int64_t origin;               /* the first time (slots count from it) */
    int started;
} cfdi_lagged;

#define CFDI_LAGGED_MEMORY(S, Q, NC, NP, K) \
    (CFDI_ALIGN8(sizeof(cfdi_real) * ((S) + 1u) * (Q) * (NC)) \
     + CFDI_ALIGN8(sizeof(cfdi_real) * (size_t)(K) * (NP)) + CFDI_ALIGN8(sizeof(cfdi_real) * (NP)))

/* Nothing absorbed yet, for a diagnosis over K onsets. */
void cfdi_lagged_reset(cfdi_lagged *lg, const cfdi_lagged_tables *t, size_t K);

/* Sample k (after every sample absorbed before it) with rows (m, NC): every column's steady
 * regressor at the residuals it has (zeros at the missing ones; with all_seen, every residual
 * there, only the scales' columns are read: the others are the table's); onsets (K,)
 * ascending. */
void cfdi_lagged_absorb(cfdi_lagged *lg, const cfdi_lagged_tables *t, size_t K,
                        const int64_t *onsets, int64_t k, const cfdi_real *rows, int all_seen);

/* One sample k within 2S of `onset` (onset <= k < onset + 2S) with a fit's n regressors at
 * that onset, rows (m, n), added to psi_local (2S, q, n): the times onset - S .. onset + S - 1. */
void cfdi_lagged_local(const cfdi_lagged_tables *t, int64_t onset, int64_t k,
                       const cfdi_real *rows, size_t d, cfdi_real *psi_local);

/* Hypothesis hyp's middle at onset position kb (its onset `onset`, its n of d parameters) over
 * every sample absorbed, (d, d) into out: psi_local (2S, q, n) holds its samples from the onset
 * to onset + 2S - 1 (cfdi_lagged_local; zeros to start), the rest comes from the steady sums
 * and the times not final. Entries beyond its n parameters are zero. */
void cfdi_lagged_middle(const cfdi_lagged *lg, const cfdi_lagged_tables *t, size_t kb,
                        int64_t onset, size_t hyp, size_t n, size_t d,
                        const cfdi_real *psi_local, cfdi_real *out);

#endif

/* The accepted faults' tracking at a checkpoint (track.h's cfdi_track_correction,
 * AcceptedFaultTracker.correction): the segment tested against the fit so far (numpy's
 * matrix_rank and pinv of a symmetric matrix, by Jacobi rotations), the corrections that are
 * significant, the end of tracking. */
#include <float.h>
#include <math.h>
#include <string.h>

#include "track.h"

#ifdef CFDI_FLOAT32
#define REAL_EPS FLT_EPSILON
#define PINV_RCOND (FLT_EPSILON * 8)
#else
#define REAL_EPS DBL_EPSILON
#define PINV_RCOND 1e-15 /* numpy's pinv */
#endif

/* out = A B (D, D) */
static void matmul(size_t D, const cfdi_real *A, const cfdi_real *B, cfdi_real *out)
{
    size_t i, j, k;
    for (i = 0; i < D; i++) {
        for (j = 0; j < D; j++) {
            cfdi_real sum = 0;
            for (k = 0; k < D; k++) {
                sum += A[i * D + k] * B[k * D + j];
            }
            out[i * D + j] = sum;
        }
    }
}

/* The eigenvalues (into w) and eigenvectors (columns of V) of the symmetric A (D, D), by
 * cyclic Jacobi rotations (A is overwritten). */
static void eigen(size_t D, cfdi_real *A, cfdi_real *w, cfdi_real *V)
{
    size_t i, j, k, sweep;
    for (i = 0; i < D * D; i++) {
        V[i] = (cfdi_real)(i % (D + 1) == 0);
    }
    for (sweep = 0; sweep < 64; sweep++) {
        cfdi_real off = 0, total = 0;
        for (i = 0; i < D; i++) {
            for (j = 0; j < D; j++) {
                total += A[i * D + j] * A[i * D + j];
                if (i != j) {
                    off += A[i * D + j] * A[i * D + j];
                }
            }
        }
        if (off <= total * REAL_EPS * REAL_EPS || off == 0) {
            break;
        }
        for (i = 0; i < D; i++) {
            for (j = i + 1; j < D; j++) {
                cfdi_real apq = A[i * D + j], theta, tt, c, s;
                if (apq == 0) {
                    continue;
                }
                theta = (A[j * D + j] - A[i * D + i]) / (2 * apq);
                tt = (theta >= 0 ? 1 : -1) / (CFDI_FABS(theta) + CFDI_SQRT(theta * theta + 1));
                c = 1 / CFDI_SQRT(tt * tt + 1);
                s = tt * c;
                for (k = 0; k < D; k++) { /* A = R^T A R, the columns then the rows */
                    cfdi_real aki = A[k * D + i], akj = A[k * D + j];
                    A[k * D + i] = c * aki - s * akj;
                    A[k * D + j] = s * aki + c * akj;
                }
                for (k = 0; k < D; k++) {
                    cfdi_real aik = A[i * D + k], ajk = A[j * D + k];
                    A[i * D + k] = c * aik - s * ajk;
                    A[j * D + k] = s * aik + c * ajk;
                }
                for (k = 0; k < D; k++) {
                    cfdi_real vki = V[k * D + i], vkj = V[k * D + j];
                    V[k * D + i] = c * vki - s * vkj;
                    V[k * D + j] = s * vki + c * vkj;
                }
            }
        }
    }
    for (i = 0; i < D; i++) {
        w[i] = A[i * D + i];
    }
}

/* The inverse of J (D, D) into W (LU, as numpy's inv); CFDI_ESINGULAR when it has none. */
static int inverse(size_t D, const cfdi_real *J, cfdi_real *W, cfdi_real *lu, cfdi_real *x)
{
    size_t perm[64];
    cfdi_real zero[64];
    memset(zero, 0, sizeof zero);
    return cfdi_fit_solve(D, J, zero, x, W, lu, perm);
}

/* Whether every tracked parameter's standard deviation (P: the fit's covariance) is within
 * `precise` of its noise units (tracking._precise). */
static int precise_enough(const cfdi_track *tr, const cfdi_track_tables *t,
                          const cfdi_real *P)
{
    size_t i, a, at = 0, D = tr->D;
    for (i = 0; i < tr->n; i++) {
        const cfdi_tracked *it = &tr->items[i];
        size_t np = cfdi_track_params(it->kind);
        size_t row = it->kind == CFDI_HYP_SENSOR ? t->p + (size_t)it->index : (size_t)it->index;
        cfdi_real unit[2];
        unit[0] = unit[1] = t->unit[row];
        if (it->kind == CFDI_HYP_ACTUATOR) {
            cfdi_real u_mean = tr->u_abs[it->index] / (cfdi_real)(tr->u_n > 1 ? tr->u_n : 1);
            unit[0] = u_mean > 0 ? unit[1] / u_mean : (cfdi_real)INFINITY;
        }
        for (a = 0; a < np; a++) {
            if (CFDI_SQRT(P[(at + a) * D + at + a]) > (cfdi_real)t->precise * unit[a]) {
                return 0;
            }
        }
        at += np;
    }
    return 1;
}

int cfdi_track_correction(cfdi_track *tr, const cfdi_track_tables *t, cfdi_correction *out)
{
    size_t D = tr->D, i, a, b, at = 0, n_out = 0, rank = 0;
    cfdi_real *W = tr->work, *A = W + D * D, *B = A + D * D, *V = B + D * D, *lu = V + D * D,
              *x = lu + D * D, *v = x + D, *w = v + D, *applied = w + D, big = 0, quad = 0;
    int last;
    if (tr->n == 0) {
        return 0;
    }
    tr->next_check *= 2;
    if (inverse(D, tr->J, W, lu, x) != CFDI_OK) {
        return CFDI_ESINGULAR;
    }
    /* before = W h, P_before = W M W; v = sh - sJ before; spread = sM + sJ P_before sJ */
    for (a = 0; a < D; a++) {
        cfdi_real sum = 0;
        for (b = 0; b < D; b++) {
            sum += W[a * D + b] * tr->h[b];
        }
        x[a] = sum;
    }
    for (a = 0; a < D; a++) {
        cfdi_real sum = 0;
        for (b = 0; b < D; b++) {
            sum += tr->sJ[a * D + b] * x[b];
        }
        v[a] = tr->sh[a] - sum;
    }
    matmul(D, W, tr->M, A);
    matmul(D, A, W, B);        /* P_before */
    matmul(D, tr->sJ, B, A);
    matmul(D, A, tr->sJ, B);   /* sJ P_before sJ */
    for (a = 0; a < D * D; a++) {
        B[a] += tr->sM[a];
    }
    eigen(D, B, w, V);
    for (a = 0; a < D; a++) {
        big = CFDI_FABS(w[a]) > big ? CFDI_FABS(w[a]) : big;
    }
    for (a = 0; a < D; a++) { /* numpy's matrix_rank and pinv (hermitian) */
        if (CFDI_FABS(w[a]) > big * (cfdi_real)D * (cfdi_real)REAL_EPS) {
            rank++;
        }
        if (CFDI_FABS(w[a]) > big * (cfdi_real)PINV_RCOND) {
            cfdi_real proj = 0;
            for (b = 0; b < D; b++) {
                proj += V[b * D + a] * v[b];
            }
            quad += proj * proj / w[a];
        }
    }
    if (rank > 0 && quad > t->chi2[rank]) {
        /* a new change: left to the detector, the segment dropped */
        memset(tr->sJ, 0, D * D * sizeof *tr->sJ);
        memset(tr->sM, 0, D * D * sizeof *tr->sM);
        memset(tr->sh, 0, D * sizeof *tr->sh);
        tr->contradicted += 1;
        return 0;
    }
    for (a = 0; a < D * D; a++) {
        tr->J[a] += tr->sJ[a];
        tr->M[a] += tr->sM[a];
        tr->sJ[a] = 0;
        tr->sM[a] = 0;
    }
    for (a = 0; a < D; a++) {
        tr->h[a] += tr->sh[a];
        tr->sh[a] = 0;
    }
    if (inverse(D, tr->J, W, lu, x) != CFDI_OK) {
        return CFDI_ESINGULAR;
    }
    for (a = 0; a < D; a++) { /* theta */
        cfdi_real sum = 0;
        for (b = 0; b < D; b++) {
            sum += W[a * D + b] * tr->h[b];
        }
        x[a] = sum;
    }
    matmul(D, W, tr->M, A);
    matmul(D, A, W, B);        /* P */
    last = t->precise > 0 && precise_enough(tr, t, B);
    for (a = 0; a < D; a++) {
        applied[a] = 0;
    }
    for (i = 0; i < tr->n; i++) {
        size_t np = cfdi_track_params(tr->items[i].kind);
        int any = 0;
        cfdi_real chi = 0;
        for (a = 0; a < np; a++) {
            any |= x[at + a] != 0;
        }
        if (!(last && any)) {
            cfdi_real Ps[4], d2[2], lu2[4];
            size_t perm2[2];
            for (a = 0; a < np; a++) {
                for (b = 0; b < np; b++) {
                    Ps[a * np + b] = B[(at + a) * D + at + b];
                }
            }
            if (cfdi_fit_solve(np, Ps, x + at, d2, NULL, lu2, perm2) != CFDI_OK) {
                at += np;
                continue;
            }
            for (a = 0; a < np; a++) {
                chi += x[at + a] * d2[a];
            }
            if (chi < t->chi2[np]) {
                at += np;
                continue;
            }
        }
        out[n_out].item = (int32_t)i;
        out[n_out].n = (int32_t)np;
        for (a = 0; a < np; a++) {
            applied[at + a] = x[at + a];
            out[n_out].delta[a] = x[at + a];
            out[n_out].var[a] = B[(at + a) * D + at + a];
        }
        n_out++;
        at += np;
    }
    /* The fit is now relative to the new compensation: its mean moves, its information
     * stays. */
    for (a = 0; a < D; a++) {
        cfdi_real sum = 0;
        for (b = 0; b < D; b++) {
            sum += tr->J[a * D + b] * applied[b];
        }
        A[a] = sum;
    }
    for (a = 0; a < D; a++) {
        tr->h[a] -= A[a];
    }
    if (last) {
        cfdi_track_clear(tr);
    }
    return (int)n_out;
}

/* canfdi's C core: the per-sample hot path of the monitor (see README.md in this folder).
 *
 * C99, no allocation, no global state, nothing from libc beyond <stdint.h>, <string.h>,
 * <float.h> and <math.h>. Every function works on memory its caller owns and sized; every index it derives
 * from data is checked where it is used. The numpy code in canfdi.core is the reference:
 * these functions give its numbers (see each one for how exactly).
 */
#ifndef CFDI_H
#define CFDI_H

#include <stddef.h>
#include <stdint.h>

#include <float.h>

#ifdef CFDI_FLOAT32
typedef float cfdi_real;
#define CFDI_REAL_MAX FLT_MAX
#define CFDI_FABS fabsf /* the real type's own: an M4F's FPU does float, double in software */
#define CFDI_SQRT sqrtf
#else
typedef double cfdi_real;
#define CFDI_REAL_MAX DBL_MAX
#define CFDI_FABS fabs
#define CFDI_SQRT sqrt
#endif

/* A size rounded up to a multiple of 8 (each part of a memory block a caller gives starts
 * there). */
#define CFDI_ALIGN8(n) ((((size_t)(n)) + 7u) / 8u * 8u)

/* Statuses: 0 is success; a negative value names what the caller got wrong. */
enum {
    CFDI_OK = 0,
    CFDI_EBADARG = -1,  /* a null pointer or a size of zero where one is needed */
    CFDI_ESHAPE = -2,   /* sizes that do not fit together */
    CFDI_ESINGULAR = -3 /* a matrix that has no inverse */
};

/* The residual bank as one FIR matrix (canfdi.core.residuals.ResidualBank.batch).
 *
 * x     : (rows, width) samples [z, u], row-major; NaN marks a missing value.
 * coef  : (S+1, width, m) the FIR blocks M_l^T, oldest lag first.
 * uses  : (S+1, width, m) 1 where the residual reads that entry, else 0.
 * out   : (rows - S, m) residual j at sample r + S; NaN where it reads a missing value.
 * Returns CFDI_OK, or a negative status (out untouched) when rows <= S or a size is zero.
 */
int cfdi_fir_block(const cfdi_real *x, size_t rows, size_t width, const cfdi_real *coef,
                   const uint8_t *uses, size_t S, size_t m, cfdi_real *out);

/* The one residual row of a window of S+1 rows (cfdi_fir_block with rows = S+1, the same
 * sums): a drive loop's, sample by sample, without the block form's staging buffer on the
 * stack. out: (m,). */
int cfdi_fir_row(const cfdi_real *x, size_t width, const cfdi_real *coef, const uint8_t *uses,
                 size_t S, size_t m, cfdi_real *out);

/* The two-sided Page-Hinkley detectors over a block, with change dating
 * (canfdi.core.detect.ChangePointDetector.update_block).
 *
 * k      : (n,) sample indices of the rows; x : (n, c) normalised statistics' inputs,
 *          row-major, NaN missing (the statistics hold).
 * delta, h : (c,) drifts and thresholds.
 * state  : (c, 2) (g+, g-) before the block; on return, after the rows before the first
 *          alarm row (the alarm row is left to the caller's streaming path).
 * last_zero : (c, 2) the last sample each statistic was zero after a present value; updated
 *          over the same rows.
 * g_up, g_down : (n, c) the statistics, written for rows 0..done (the alarm row included).
 * alarm  : (c,) the alarm row's signs (+1 up, -1 down, 0), zeros without an alarm.
 * done   : the rows before the first alarm row (n without one).
 * Arithmetic: the closed form numpy uses, g_k = max(g_0 + S_k, S_k - min(0, min_j S_j)) over
 * cumulative sums restarted every CFDI_PH_BLOCK rows, in the same order: the statistics are
 * numpy's bit for bit.
 */
#define CFDI_PH_BLOCK 4096
int cfdi_ph_block(const int64_t *k, const cfdi_real *x, size_t n, size_t c,
                  const cfdi_real *delta, const cfdi_real *h, cfdi_real *state,
                  int64_t *last_zero, cfdi_real *g_up, cfdi_real *g_down, int8_t *alarm,
                  size_t *done);

/* The time gate over a block (canfdi.bus.timegate.TimeGate.step frame by frame).
 *
 * state : int64 [CFDI_GATE_STATE], the gate's, updated: whether it has a reference, the
 *         reference (the drive's time), the offset, the chain of frames beyond the bound (its
 *         length, first and last raw times) and the jumps counted.
 * bound, confirm : the gate's bound (ns, > 0) and the frames that confirm a step (>= 1).
 * t     : (n_t,) raw times; rows : (n_rows,) the positions of the frames to check, in order.
 * out   : (n_t,) the checked frames' corrected times written at their rows.
 * dropped : (n_rows,) the positions among rows of the frames dropped, *n_dropped of them.
 * steps : (n_rows, 2) the clock steps followed (raw time of the first frame after it, its
 *         size), *n_steps of them.
 * done  : the frames checked: n_rows, or fewer when a time, offset or reference reached
 *         CFDI_GATE_SAFE in magnitude (beyond it int64 could wrap; the caller goes on exactly,
 *         from the state left).
 * Returns CFDI_OK, or a negative status for a null pointer, a bad bound or a row outside t. */
#define CFDI_GATE_HAS_REF 0
#define CFDI_GATE_REF 1
#define CFDI_GATE_OFFSET 2
#define CFDI_GATE_CHAIN_COUNT 3
#define CFDI_GATE_CHAIN_FIRST 4
#define CFDI_GATE_CHAIN_LAST 5
#define CFDI_GATE_JUMPS 6
#define CFDI_GATE_STATE 7
#define CFDI_GATE_SAFE ((int64_t)1 << 61)
int cfdi_gate_block(int64_t *state, int64_t bound, int64_t confirm, const int64_t *t,
                    size_t n_t, const int64_t *rows, size_t n_rows, int64_t *out,
                    int64_t *dropped, size_t *n_dropped, int64_t *steps, size_t *n_steps,
                    size_t *done);

/* The trigger and grid clocks' samples over a block
 * (canfdi.bus.clock.latest_values: the newest value of each signal at each sample instant).
 *
 * ok      : (n_ok,) ascending rows of the block's valid drive frames; slot : (n,) each row's
 *           slot; values : (n, vwidth) the decoded fields; t : (n,) the rows' times.
 * dest    : (n_slots, cols) each slot's fields' positions in a sample row, -1 beyond.
 * instants, upto : (n_samples,) the samples' instants and their last rows (non-decreasing,
 *           -1: none of the block's).
 * max_age : the oldest a value may be at an instant (ns, as a double: numpy's comparison).
 * value, time : (width,) each position's newest value and time, updated to the block's.
 * out     : (n_samples, width) written: the newest values, NaN where older than max_age.
 * Returns CFDI_OK, or a negative status (rows out of order or out of range, an upto that
 * decreases, a position outside width). */
int cfdi_latest_block(const int64_t *ok, size_t n_ok, const int16_t *slot, size_t n,
                      const double *values, size_t vwidth, const int64_t *t,
                      const int64_t *dest, size_t n_slots, size_t cols,
                      const int64_t *instants, const int64_t *upto, size_t n_samples,
                      double max_age, double *value, int64_t *time, size_t width, double *out);

/* The counter clock's state machine over a run of accepted drive frames
 * (canfdi.bus.assembler.SampleAssembler's slow path).
 *
 * state  : int64 [CFDI_CTR_STATE], the machine's, updated (see the indices below; SEEN is a
 *          bit mask of the slots seen, so at most 62 slots).
 * buffer : (width,) the pending sample's values, updated.
 * rows, slots, counters, times : (n_frames,) the frames' rows in the block, slots, alive
 *          counters and gate-checked times.
 * values : (n_values, vwidth) the block's decoded fields; dest : (n_slots, cols) each slot's
 *          fields' positions in a sample row, -1 beyond.
 * mod, dt_ns, slack : the counter's modulus, the period (ns) and the jump slack.
 * status : (n_status,) the block's statuses: duplicate, stale and jump verdicts written.
 * ks, done, gaps, samples : (2 n_frames,) and (2 n_frames, width) the samples delivered,
 *          *n_out of them (a broken one a frame closed, then the one it completed).
 * used   : the frames taken (n_frames, or fewer where a time or index reaches 2^62 in
 *          magnitude: the caller goes on from the state left).
 * Returns CFDI_OK, or a negative status for bad sizes or indices. */
#define CFDI_CTR_K 0
#define CFDI_CTR_T_REF 1
#define CFDI_CTR_SEEN 2
#define CFDI_CTR_OPEN 3
#define CFDI_CTR_LAST_COMPLETE 4
#define CFDI_CTR_LAST_DELIVERED 5
#define CFDI_CTR_LAST_GAP 6
#define CFDI_CTR_JUMP_SET 7
#define CFDI_CTR_JUMP 8
#define CFDI_CTR_COMPLETE 9
#define CFDI_CTR_BROKEN 10
#define CFDI_CTR_MISSING 11
#define CFDI_CTR_STATE 12
int cfdi_counter_run(int64_t *state, double *buffer, size_t width, const int64_t *rows,
                     const int64_t *slots, const int64_t *counters, const int64_t *times,
                     size_t n_frames, const double *values, size_t n_values, size_t vwidth,
                     const int64_t *dest, size_t n_slots, size_t cols, int64_t mod,
                     double dt_ns, double slack, int8_t *status, size_t n_status,
                     int64_t *ks, int64_t *done, int64_t *gaps, double *samples,
                     size_t *n_out, size_t *used);


/* End of stream for the counter clock (SampleAssembler.flush): a pending incomplete sample is
 * closed as broken (NaN for the slots not seen) and written to ks, done, gaps, samples ((1,),
 * (1, width)); *n_out is 1 then, else 0. */
int cfdi_counter_close(int64_t *state, const double *buffer, size_t width, const int64_t *dest,
                       size_t n_slots, size_t cols, int64_t *ks, int64_t *done, int64_t *gaps,
                       double *samples, size_t *n_out);

/* A diagnosis' least squares in information form absorbing n samples at once
 * (canfdi.methods.parity.hypotheses.information_increments, ParityDiagnoser._accumulate): every
 * hypothesis' normalised regressors at every candidate onset (block_regressors), and what they
 * add to its fit: the information phi^T phi and the vector phi^T r over the residuals present,
 * the sandwich's middle phi^T Gamma phi, the residuals' sum of squares and the equations.
 *
 * Gz : (q, m, S+1), Gu : (p, m, S+1) the bank's fault signatures; sigma : (m,) the noise the
 *         residuals were normalised by.
 * columns : (H, d, 2) each hypothesis' parameter columns: a source (CFDI_COL_*) and its
 *         channel (canfdi.methods.parity.hypotheses.regressor_columns).
 * onsets : (K,) the candidate fault onsets; k : (n,) the samples.
 * U     : (n, S+1, p) each sample's command window (NaN read as 0, an infinity as the largest
 *         finite value of its sign: numpy's nan_to_num); rn : (n, m) the normalised
 *         residuals, NaN: no equation.
 * gamma : (m, m) the residuals' long-run covariance.
 * J, meat : (H, K, d, d), h : (H, K, d), rr : (1,), n_eq : (1,): the sums added to.
 * work  : (work_len,) scratch: CFDI_INFO_WORK(m, d, S, p, H, NC) reals at least, NC the distinct
 *         columns the hypotheses use (H d bounds them; more than 64 parameters need NC 0).
 * Returns CFDI_OK, or a negative status (nothing added) for a null pointer, a zero size or a
 * column outside the bank. */
#define CFDI_INFO_WORK(m, d, S, p, H, NC) \
    ((3 * (m) + 2 * (d) + 1) * (d) + ((S) + 1) * (p) + (H) * (2 * (d) * (d) + (d)) \
     + 3 * (m) * (NC) + 2 * (NC) * (NC) + (NC) + (2 * (NC) * (NC) + (NC)) / 4 + 1)
#define CFDI_COL_NONE 0   /* beyond the hypothesis' parameters: a zero column */
#define CFDI_COL_SENSOR 1 /* sensor j's bias: Gz[j] */
#define CFDI_COL_SCALE 2  /* actuator j's eta - 1: Gu[j] times its command */
#define CFDI_COL_BIAS 3   /* actuator j's lambda: Gu[j] */
int cfdi_info_block(size_t q, size_t p, size_t m, size_t S, const cfdi_real *Gz,
                    const cfdi_real *Gu, const cfdi_real *sigma, size_t H, size_t d,
                    const int32_t *columns, size_t K, const int64_t *onsets, size_t n,
                    const int64_t *k, const cfdi_real *U, const cfdi_real *rn,
                    const cfdi_real *gamma, cfdi_real *J, cfdi_real *h, cfdi_real *meat,
                    cfdi_real *rr, int64_t *n_eq, cfdi_real *work, size_t work_len);
/* The bank's fault signatures as the regressors read them: Gz (q, m, S+1), Gu (p, m, S+1),
 * each residual's noise sigma (m,) and the residuals' long-run covariance gamma (m, m). */
typedef struct {
    size_t q, p, m, S;
    const cfdi_real *Gz, *Gu, *sigma, *gamma;
} cfdi_signatures;

/* One regressor column of sample k for a fault from `onset` on (hypotheses.row_regressors'
 * column): out[a] = sum over the window's lags s at or after the onset of G[a][s] (times the
 * command u[s][j] for a scale, nan_to_num'ed) over sigma[a], summed from the window's end as
 * cfdi_info_block sums; zeros for an onset after the sample. source, channel: CFDI_COL_* and
 * its channel (checked by the caller); U: (S+1, p) the sample's command window. */
void cfdi_column(const cfdi_signatures *g, int32_t source, int32_t channel, int64_t k,
                 int64_t onset, const cfdi_real *U, cfdi_real *out);

/* One fit solved: theta = J^-1 h and, with P not NULL, P = J^-1 (LU with partial pivoting, as
 * cfdi_info_solve); J (d, d), h (d,); lu (d, d), perm (d,) scratch. CFDI_OK or
 * CFDI_ESINGULAR. */
int cfdi_fit_solve(size_t d, const cfdi_real *J, const cfdi_real *h, cfdi_real *theta,
                   cfdi_real *P, cfdi_real *lu, size_t *perm);

/* Every fit of a diagnosis solved (canfdi.core.identify.rls_solve): for each of `count`
 * estimators, theta = J^-1 h, P = J^-1 and the cost rr - theta.h, by LU with partial
 * pivoting (LAPACK's getrf and getrs, which numpy's solve and inv call; to rounding).
 *
 * J : (count, d, d); h : (count, d); rr : (count,).
 * theta : (count, d), P : (count, d, d), cost : (count,) written.
 * lu : (d, d), perm : (d,) scratch.
 * Returns CFDI_OK, CFDI_ESINGULAR at the first J with a zero pivot (numpy's LinAlgError;
 * what is written of the others is not to be used), or CFDI_EBADARG. */
int cfdi_info_solve(size_t count, size_t d, const cfdi_real *J, const cfdi_real *h,
                    const cfdi_real *rr, cfdi_real *theta, cfdi_real *P, cfdi_real *cost,
                    cfdi_real *lu, size_t *perm);

/* A diagnosis' decision at one sample, from its fits (canfdi.methods.parity.decide: the same
 * rules, in the same order; decide.py's module text says them). */
#define CFDI_HYP_ACTUATOR 0      /* eta - 1 and lambda */
#define CFDI_HYP_ACTUATOR_BIAS 1 /* lambda alone */
#define CFDI_HYP_SENSOR 2        /* a bias */
#define CFDI_HYP_SENSORS 3       /* several sensors' biases, jointly */

#define CFDI_DECIDE_WAIT 0
#define CFDI_DECIDE_ACCEPT 1
#define CFDI_DECIDE_NAME 2
#define CFDI_DECIDE_ACCEPT_NEAR 3 /* max_samples: accepted, its near twins its candidates */
#define CFDI_DECIDE_UNEXPLAINED 4

/* The hypotheses as a decision reads them (decide.HypothesisTable), H of them, d parameters
 * at most, over p commands. */
typedef struct {
    size_t H, d, p;
    const int8_t *kind;       /* (H,) CFDI_HYP_* */
    const int32_t *index;     /* (H,) its channel (an input's for the actuator kinds) */
    const int32_t *n_params;  /* (H,) 1..d */
    const int32_t *full;      /* (H,) a bias-only actuator's full hypothesis, else -1 */
    const int64_t *name_key;  /* (H,) the order that names a group of twins */
    const uint8_t *twins;     /* (H, H) 1: proportional signatures */
    const cfdi_real *penalty; /* (H,) the cost of each hypothesis' extra parameters */
} cfdi_hypotheses;

/* The settings a decision reads (ParitySettings'). */
typedef struct {
    int64_t max_samples;
    double isolation_margin, settle_rel_std, settle_noise, max_fit_variance;
} cfdi_decide_settings;

typedef struct {
    int32_t action;           /* CFDI_DECIDE_* */
    int32_t best, kb;         /* the best hypothesis (its group's name) and its onset position */
    int32_t size_known, form_known;
    cfdi_real scale;          /* its fit's cost per degree of freedom */
} cfdi_decision;

/* The tables' entries in range for K onsets (every kind, parameter count, channel and full
 * hypothesis): CFDI_OK or CFDI_ESHAPE. cfdi_decide checks them at every call; a caller of the
 * two halves below checks them once. */
int cfdi_hypotheses_check(const cfdi_hypotheses *hy, size_t K);

/* A decision's first half (decide_reference up to the margin): each hypothesis' cheapest onset
 * (best_onset), its penalised cost (cost_h), the hypotheses ranked (order), the best group's
 * name and onset, whether the margin holds and who lies within it (near); for a bias-only
 * actuator, its full fit and that fit's cheapest onset, which the second half reads too. */
typedef struct {
    int32_t best, kb;         /* the best hypothesis (its group's name) and its onset position */
    int32_t full, full_kb;    /* a bias-only best's full hypothesis and its onset; -1: none */
    int margin_ok;
} cfdi_rank;
int cfdi_decide_rank(const cfdi_hypotheses *hy, const cfdi_decide_settings *s, size_t K,
                     const cfdi_real *cost, int64_t *best_onset, cfdi_real *cost_h,
                     int64_t *order, uint8_t *near, cfdi_rank *out);

/* One fit as a decision's second half reads it: theta (d,), P = J^-1 and the long-run
 * sandwich's middle (d, d), its cost and the no-fault cost. */
typedef struct {
    const cfdi_real *theta, *P, *meat;
    cfdi_real cost, rr;
} cfdi_fit_view;

/* A decision's second half: the best fit's settling, its form (a bias-only actuator's full fit,
 * `full`, NULL when rank->full is -1), the F test, then the action (cost: (H, K), for the
 * leftover's onset). Returns CFDI_OK or CFDI_EBADARG. */
int cfdi_decide_judge(const cfdi_hypotheses *hy, const cfdi_decide_settings *s, size_t K,
                      const cfdi_rank *rank, const cfdi_fit_view *fit,
                      const cfdi_fit_view *full, const cfdi_real *cost, int64_t n_eq,
                      const cfdi_real *u_abs, const cfdi_real *n_u, const cfdi_real *units,
                      const int32_t *leftover, int64_t since, int named, cfdi_decision *out);

/* decide.spread's noise scale of a fit: its cost per degree of freedom (n_eq - n_params, at
 * least 1), floored at the tiniest positive the real type holds. */
cfdi_real cfdi_noise_scale(cfdi_real cost, int64_t n_eq, int32_t n_params);

/* One fit's sandwich variance of parameter i, diag(P M P)[i] unscaled, (P M) first as numpy's
 * matmul associates: P, M (d, d). */
cfdi_real cfdi_sandwich(const cfdi_real *P, const cfdi_real *M, size_t d, size_t i);

/* theta : (H, K, d), P : (H, K, d, d), cost, rr : (H, K) the fits (rls_solve) and the
 *         no-fault cost; n_eq : residual rows absorbed; meat : (H, K, d, d) the long-run
 *         sandwich's middle; u_abs, n_u : (p,) the sum of |u_c| and count of known commands
 *         since the alarm; units : (H, d) the noise units (decide.unit_table); leftover :
 *         (H,) the onset position of the latest accepted fault on each hypothesis' channel,
 *         -1: none; since : samples since the alarm; named : 1 once the fault was named.
 * best_onset : (H,) each hypothesis' cheapest onset position, cost_h : (H,) its penalised cost,
 *         order : (H,) the hypotheses by cost_h (stable, NaN last), near : (H,) 1 outside the
 *         best's group within the margin; all written, with *out.
 * Returns CFDI_OK, or a negative status (nothing decided) for a null pointer, a zero size, or a
 * table entry out of range. */
int cfdi_decide(const cfdi_hypotheses *hy, const cfdi_decide_settings *s, size_t K,
                const cfdi_real *theta, const cfdi_real *P, const cfdi_real *cost,
                const cfdi_real *rr, int64_t n_eq, const cfdi_real *meat,
                const cfdi_real *u_abs, const cfdi_real *n_u, const cfdi_real *units,
                const int32_t *leftover, int64_t since, int named, int64_t *best_onset,
                cfdi_real *cost_h, int64_t *order, uint8_t *near, cfdi_decision *out);

#endif

/* canfdi's C core: the per-sample hot path of the monitor (see README.md in this folder).
 *
 * C99, no allocation, no global state, nothing from libc beyond <stdint.h>, <string.h> and
 * <math.h>. Every function works on memory its caller owns and sized; every index it derives
 * from data is checked where it is used. The numpy code in canfdi.core is the reference:
 * these functions give its numbers (see each one for how exactly).
 */
#ifndef CFDI_H
#define CFDI_H

#include <stddef.h>
#include <stdint.h>

#ifdef CFDI_FLOAT32
typedef float cfdi_real;
#else
typedef double cfdi_real;
#endif

/* Statuses: 0 is success; a negative value names what the caller got wrong. */
enum {
    CFDI_OK = 0,
    CFDI_EBADARG = -1,  /* a null pointer or a size of zero where one is needed */
    CFDI_ESHAPE = -2    /* sizes that do not fit together */
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

#endif

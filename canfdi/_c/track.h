/* The accepted faults' tracking: every compensated channel fitted again, jointly, on the
 * compensated residuals of the samples monitored since the last acceptance, its significant
 * corrections folded in at checkpoints 64, 128, 256, ... samples on
 * (canfdi.methods.parity.tracking.AcceptedFaultTracker: the same sums, tests and ending; the
 * module's text says why). The sums are added sample by sample where the Python adds 256 at
 * once: the same numbers to rounding. */
#ifndef CFDI_TRACK_H
#define CFDI_TRACK_H

#include <stddef.h>
#include <stdint.h>

#include "cfdi.h"

typedef struct {
    size_t p, n_channels;         /* the inputs, and p + q: inputs, then outputs */
    size_t max_params;            /* T: the parameters tracked at once, at most */
    const double *chi2;           /* (T + 1,) chi2_sigma(d), d = 0..T (identify.chi2_sigma) */
    const cfdi_real *ratio;       /* (p + q,) each channel's steady signature's long-run
                                   * variance over least squares' (tracking._ratio) */
    const cfdi_real *unit;        /* (p + q,) each channel's noise unit: an actuator's
                                   * lambda's, a sensor's bias' (hypotheses.noise_units) */
    double precise;               /* tracking ends where every parameter is known within this
                                   * many of its noise units (0: never) */
    int64_t first_check;          /* samples to the first checkpoint (tracking.FIRST_CHECK) */
} cfdi_track_tables;

/* A compensated channel as it is fitted. */
typedef struct {
    int32_t kind;                 /* CFDI_HYP_ACTUATOR (eta - 1, lambda), CFDI_HYP_ACTUATOR_BIAS
                                   * (lambda), CFDI_HYP_SENSOR (its bias) */
    int32_t index;                /* the input's, or the output's */
    int64_t onset;
    cfdi_real precision[4];       /* (n, n) what its acceptance knew of its parameters */
} cfdi_tracked;


/* A correction a checkpoint folds into one channel's compensation: its parameters relative to
 * the compensation (an actuator's eta - 1 and lambda, or lambda alone; a sensor's bias), with
 * their variances. */
struct cfdi_correction_s {
    int32_t item;                 /* the channel's position among those tracked */
    int32_t n;                    /* its parameters */
    cfdi_real delta[2], var[2];
};
typedef struct cfdi_correction_s cfdi_correction;
typedef struct {
    cfdi_tracked *items;          /* (T,) */
    cfdi_correction *fixes;       /* (T,) a checkpoint's corrections */
    size_t n, D;
    cfdi_real *J, *h, *M;         /* the fit so far: (D, D), (D,), (D, D) */
    cfdi_real *sJ, *sh, *sM;      /* the segment since the last checkpoint */
    cfdi_real *u_abs;             /* (p,) the commands' sizes absorbed */
    cfdi_real *work;              /* scratch */
    int64_t absorbed, next_check, u_n;
    uint64_t contradicted;        /* checkpoints whose segment contradicted the fit */
} cfdi_track;

/* The memory of a tracker of T parameters over M residuals and P inputs: its state, and its
 * scratch of CFDI_TRACK_WORK reals (the drive lends it the diagnosis' memory). */
#define CFDI_TRACK_WORK(M, T) (2u * (M) * (T) + (M) + 6u * (T) * (T) + 4u * (T))
#define CFDI_TRACK_MEMORY(M, T, P) \
    (CFDI_ALIGN8(sizeof(cfdi_tracked) * (T)) + CFDI_ALIGN8(sizeof(cfdi_correction) * (T)) \
     + CFDI_ALIGN8(sizeof(cfdi_real) * (4u * (T) * (T) + 2u * (T) + (P))))

/* The parameters of a tracked channel of this kind (1 or 2). */
size_t cfdi_track_params(int32_t kind);

/* Track nothing. */
void cfdi_track_clear(cfdi_track *tr);

/* Fit these channels (n of them, their parameters T at most: else CFDI_ESHAPE) from now on,
 * relative to the compensation as it now is, from the information of their acceptances. */
int cfdi_track_restart(cfdi_track *tr, const cfdi_track_tables *t, const cfdi_signatures *g,
                       const cfdi_tracked *items, size_t n);

/* One monitored sample k: its compensated command window U (S+1, p) and normalised residuals
 * rn (m,), NaN: no equation. */
void cfdi_track_absorb(cfdi_track *tr, const cfdi_track_tables *t, const cfdi_signatures *g,
                       int64_t k, const cfdi_real *U, const cfdi_real *rn);

/* Whether a checkpoint is reached. */
int cfdi_track_due(const cfdi_track *tr);

/* At a checkpoint: the channels whose correction is significant, into out (n of them at most),
 * now counted as folded in; none when the segment contradicts the fit so far. The tracking
 * ends (nothing tracked) at the checkpoint where every parameter is precise. Returns how many,
 * or a negative status (a fit with no solution: nothing folded, the segment dropped). */
int cfdi_track_correction(cfdi_track *tr, const cfdi_track_tables *t, cfdi_correction *out);

#endif

/* One drive's monitor, frame by frame, as canfdi's monitor runs it with the parity method:
 * decode (and E2E), the time gate, the counter clock, the residual bank and the Page-Hinkley
 * detectors (the block functions of cfdi.h and decode.h, the code the daemon's extension runs
 * over blocks), then each alarm's diagnosis: every hypothesis fitted at every candidate onset
 * (info.c), solved and decided on at every sample (decide.c); a fault named, accepted (folded
 * into the compensation, the window rebuilt, the detector restarted: the next fault is
 * diagnosed on top), refined, or the alarm unexplained; the accepted faults tracked and refined
 * between diagnoses (track.c). Each is announced as canfdi's monitor does: FDI_FAULT and
 * FDI_ESTIMATE frames (the estimates' standard deviations counting the residuals' correlation
 * lag by lag, lagged.c), and FDI_STATUS when the caller's timer asks, queued for the caller to
 * send (cfdi_drive_poll_tx); and as events the caller may read (cfdi_drive_poll_event).
 *
 * This is the loop a drive's MCU runs: `canfdi codegen` writes its tables as const data and
 * the size of its memory. No allocation, no global state: a cfdi_drive holds its state and
 * points at its tables and at one block of memory its caller owns, both checked by
 * cfdi_drive_init, which lays the block out. */
#ifndef CFDI_DRIVE_H
#define CFDI_DRIVE_H

#include <stddef.h>
#include <stdint.h>

#include "cfdi.h"
#include "decode.h"
#include "encode.h"
#include "lagged.h"
#include "track.h"

#define CFDI_N_STATUS 16
#define CFDI_MAX_FAULTS 4     /* faults one decision accepts (a joint fit's members) */
#define CFDI_MAX_COMP 8       /* compensation entries held apart; older ones are composed */
#define CFDI_EVENT_QUEUE 4    /* events a drive holds until polled */
#define CFDI_MAX_CANDIDATES 3 /* look-alike channels an event lists */

/* -- tables: generated from the config, never written to --------------------------------- */

/* The diagnosis (canfdi.methods.parity.diagnoser, ParityDiagnoser.c_tables). */
typedef struct {
    cfdi_hypotheses hyp;          /* H, d, p; kind, index, n_params, full, name_key, twins,
                                   * penalty */
    cfdi_decide_settings settings;
    int64_t min_samples;          /* samples after the alarm before a decision */
    const int32_t *columns;       /* (H, d, 2) each hypothesis' regressor columns */
    const cfdi_real *Gz, *Gu;     /* (q, m, S+1), (p, m, S+1) the bank's fault signatures */
    const cfdi_real *gamma;       /* (m, m) the residuals' long-run covariance */
    const cfdi_real *units;       /* (H, d) the noise units (decide.unit_table) */
    cfdi_real prior_precision;    /* J0 = this * I at the alarm */
    size_t onset_before;          /* onsets tried before the change point */
    size_t max_onsets;            /* onsets tried around the change point, at most */
    size_t max_earlier;           /* compensated channels' onsets tried too, at most */
    size_t lookback;              /* samples a diagnosis keeps before its alarm */
    size_t earlier_lookback;      /* with compensated channels, samples fitted before the
                                   * first onset (diagnoser.LOOKBACK) */
    cfdi_lagged_tables lagged;    /* the estimates' variances lag by lag (lagged.h) */
    cfdi_track_tables track;      /* the accepted faults' tracking (track.h) */
    double own_chi2[3];           /* chi2_sigma(d, records.OWN_FAULT_SIGMA), d = 0..2 */
    const int32_t *twin_order;    /* (H, H) each sensor hypothesis' twins by kind and index
                                   * (-1 ends the list: diagnoser._sensor_twins) */
    const cfdi_real *twin_ratio;  /* (H, H) each one's size per unit of the sensor's bias */
} cfdi_diag_tables;

/* What the drive's monitor frames carry: a message (encode.h; NULL: none sent), each role's
 * modulus (0: none) and cap (0: none), canfdi.monitor's WRAPS and CAPS. */
typedef struct {
    const cfdi_message *msg;
    double wrap[CFDI_N_ROLES], cap[CFDI_N_ROLES];
} cfdi_monitor_message;

typedef struct {
    const cfdi_bus *bus;          /* its frames' tables (decode.h) */
    int64_t gate_bound;           /* the time gate's bound (ns) and the frames confirming a step */
    int64_t gate_confirm;
    const int64_t *dest;          /* (n_slots, cols): each slot's fields' positions in a sample */
    size_t n_slots, cols;
    int64_t mod;                  /* the alive counter's modulus */
    double dt_ns, slack;          /* the control period (ns) and the counter's jump slack */
    size_t p, q;                  /* a sample: p inputs then q outputs (the clock's order) */
    const cfdi_real *coef;        /* (S+1, q+p, m) the residual bank's FIR blocks, [z, u] */
    const uint8_t *uses;          /* (S+1, q+p, m) */
    size_t S, m;
    const cfdi_real *sigma;       /* (m,) each residual's noise standard deviation */
    const cfdi_real *delta, *h;   /* (m,) Page-Hinkley drifts and thresholds (noise units) */
    /* The monitor's frames (all msg NULL: listen-only, nothing sent). */
    cfdi_monitor_message fault, estimate, status;
    double drive_index;           /* the drive's index on the bus */
    double fault_states[3];       /* FDI_FAULT's State of a detection, a naming, an acceptance */
    double kinds[3];              /* the Kind of none, an actuator, a sensor */
    double params[3];             /* FDI_ESTIMATE's Param of eta, lambda, bias */
    double std_param;             /* added for a standard deviation */
    double status_states[3];      /* FDI_STATUS's State: monitoring, diagnosing, named */
    size_t tx_frames;             /* frames the queue holds (a sample's announcements) */
    const uint8_t *valid_status;  /* (CFDI_N_STATUS,) 1: a valid frame's status */
    const cfdi_diag_tables *diag; /* the diagnosis; NULL: the loop stops at its first alarm */
} cfdi_drive_tables;

/* -- events ----------------------------------------------------------------------------- */

#define CFDI_EVENT_DETECTED 0
#define CFDI_EVENT_NAMED 1
#define CFDI_EVENT_ACCEPTED 2
#define CFDI_EVENT_UNEXPLAINED 3
#define CFDI_EVENT_REFINED 4

#define CFDI_TARGET_NONE 0
#define CFDI_TARGET_ACTUATOR 1
#define CFDI_TARGET_SENSOR 2
#define CFDI_TARGET_SENSORS 3     /* a joint fit of sensors (an unexplained alarm's candidate) */

#define CFDI_UNDECIDED_FORM 1     /* a named fault's scale not ruled out */
#define CFDI_UNDECIDED_SIZE 2     /* a named fault's size not settled */

/* A channel and its estimates (an event's, or one of its candidates). An actuator's are
 * eta and lambda (est[0], est[1]), or lambda alone (n_est 1, est[1]: a naming); a sensor's its
 * bias (est[0]). */
typedef struct {
    int16_t target, hyp;          /* CFDI_TARGET_*; the hypothesis (a joint fit's members) */
    int16_t index, n_est;         /* the channel (an input's or an output's) */
    cfdi_real est[2];
} cfdi_channel;

/* What the drive concluded at a sample (canfdi.core.records.FaultEvent). */
typedef struct {
    int32_t kind;                 /* CFDI_EVENT_* */
    cfdi_channel ch;              /* the channel and estimates (none for a detection) */
    cfdi_real var[2];             /* the estimates' variances, as est */
    int32_t has_var;              /* whether the event reports them */
    int32_t undecided;            /* a naming's CFDI_UNDECIDED_* */
    int64_t sample, timestamp_ns;
    int64_t onset;                /* the onset it dates (a detection: its change point); -1 */
    int64_t detected;             /* the alarm it follows; -1: none (a tracker's refinement) */
    int64_t accepted;             /* accepted and refined: the sample; -1 */
    uint32_t residuals;           /* a detection's residuals in alarm (bit i: residual i) */
    int32_t n_candidates;         /* channels that explain the data as well (look-alikes) */
    cfdi_channel candidates[CFDI_MAX_CANDIDATES];
} cfdi_event;

/* A frame the monitor sends. */
typedef struct {
    uint32_t id;
    uint8_t extended;             /* 1: a 29-bit ID */
    uint8_t len;                  /* payload bytes */
    uint8_t data[CFDI_MAX_PAYLOAD];
} cfdi_tx_frame;

/* -- memory ----------------------------------------------------------------------------- */

/* The bytes the drive's memory block needs, from its sizes: W = p + q, VW = the bus's value
 * width, S, M residuals, P inputs, H hypotheses, D parameters, K onsets (max_onsets +
 * max_earlier), R rows kept (lookback + S + max(2S, min_samples) + 1), Y rows of history
 * (S + onset_before + 1), NC, NP the lagged tables' columns and pairs, T the tracker's
 * parameters, X frames queued, L their longest payload. Every part starts at a multiple of 8;
 * cfdi_drive_memory_size gives the same (a test compares), CFDI_DRIVE_MEMORY_MONITOR a drive
 * without a diagnosis'. */
#define CFDI_DRIVE_MEMORY_MONITOR(W, VW, S, M, X, L) \
    (CFDI_MEM_MONITOR(W, VW, S, M) + CFDI_MEM_TX(X, L) + CFDI_MEM_CHANNELS(W))
#define CFDI_MEM_MONITOR(W, VW, S, M) \
    (CFDI_ALIGN8(8u * (VW)) + CFDI_ALIGN8(sizeof(cfdi_real) * (W)) + CFDI_ALIGN8(8u * (W)) \
     + CFDI_ALIGN8(16u * (W)) + CFDI_ALIGN8(sizeof(cfdi_real) * ((S) + 1u) * (W)) \
     + 4u * CFDI_ALIGN8(sizeof(cfdi_real) * (M)) + CFDI_ALIGN8(sizeof(cfdi_real) * 2u * (M)) \
     + CFDI_ALIGN8(16u * (M)) + CFDI_ALIGN8(M))
#define CFDI_MEM_TX(X, L) CFDI_ALIGN8((size_t)(X) * (6u + (size_t)(L)))
#define CFDI_MEM_CHANNELS(W) CFDI_ALIGN8(sizeof(cfdi_comp_channel) * (W))
/* the fits, (H, K) of (d, d) information, (d, d) sandwich middle, (d) vector and the cost,
 * which the tracking's scratch shares (it runs between diagnoses) */
#define CFDI_FITS_ONLY(H, D, K) ((size_t)(H) * (K) * (2u * (D) * (D) + (D) + 1u))
#define CFDI_MEM_FITS(M, H, D, K, T) \
    (CFDI_FITS_ONLY(H, D, K) > CFDI_TRACK_WORK(M, T) ? CFDI_FITS_ONLY(H, D, K) \
                                                     : CFDI_TRACK_WORK(M, T))
/* the scratch of a sample's sums, which an event's walk borrows */
#define CFDI_MEM_LEND(W, S, M, P, D, NC) \
    (2u * (S) * ((W) - (P)) * (D) + (M) * ((NC) > (D) ? (NC) : (D)) + 2u * (M) + (D))
#define CFDI_MEM_WORK(W, S, M, P, H, D, NC) \
    (CFDI_INFO_WORK(M, D, S, P, H, NC) > CFDI_MEM_LEND(W, S, M, P, D, NC) \
         ? CFDI_INFO_WORK(M, D, S, P, H, NC) : CFDI_MEM_LEND(W, S, M, P, D, NC))
#define CFDI_MEM_DIAG(W, S, M, P, H, D, K, R, Y, T, NC) \
    (CFDI_ALIGN8(sizeof(cfdi_real) * ((size_t)(R) + (size_t)(Y)) * (W)) \
     + CFDI_ALIGN8(sizeof(cfdi_real) * ((S) + 1u) * ((W) + (P))) \
     + CFDI_ALIGN8(sizeof(cfdi_real) * (CFDI_MEM_WORK(W, S, M, P, H, D, NC) + (D) * (D) * 3u \
                                        + (D) * 2u)) \
     + CFDI_ALIGN8(8u * (K)) + CFDI_ALIGN8(sizeof(cfdi_real) * CFDI_MEM_FITS(M, H, D, K, T)) \
     + CFDI_ALIGN8(sizeof(cfdi_real) * (2u * (P) + (H))) + CFDI_ALIGN8(8u * (D)) \
     + 2u * CFDI_ALIGN8(8u * (H)) + CFDI_ALIGN8(H) + CFDI_ALIGN8(4u * (H)))
#define CFDI_DRIVE_MEMORY(W, VW, S, M, P, H, D, K, R, Y, NC, NP, T, X, L) \
    (CFDI_MEM_MONITOR(W, VW, S, M) + CFDI_MEM_TX(X, L) + CFDI_MEM_CHANNELS(W) \
     + CFDI_MEM_DIAG(W, S, M, P, H, D, K, R, Y, T, NC) \
     + CFDI_LAGGED_MEMORY(S, (W) - (P), NC, NP, K) + CFDI_TRACK_MEMORY(M, T, P))

/* The compensation: the accepted faults folded in, oldest first (canfdi.core.records'). */
typedef struct {
    int32_t channel;              /* an input j (j) or an output j (p + j) */
    int64_t onset;
    cfdi_real eta, lam, bias;
} cfdi_comp_entry;

/* One channel's compensation as the next decisions read it (records.fault_onset,
 * latest_fault, the latest entry's variances and what it held fixed). */
typedef struct {
    int32_t has;                  /* compensated */
    int32_t fixed_eta;            /* the latest entry held eta at 1 (a bias accepted alone) */
    int64_t first_onset;          /* its oldest entry's onset (the tracker fits from there) */
    int64_t fault_onset;          /* its latest fault's (not a correction's) */
    cfdi_real eta, lam, bias;     /* its latest fault with its corrections, composed */
    cfdi_real base_eta, base_lam, base_bias; /* entries composed when the list was full */
    cfdi_real var[2];             /* the latest entry's variances (eta, lambda; or the bias) */
    int32_t has_var[2];
} cfdi_comp_channel;

#define CFDI_MAX_CHANNELS 32      /* p + q at most */

/* -- the drive ------------------------------------------------------------------------- */

typedef struct {
    const cfdi_drive_tables *t;
    /* the memory block's parts (laid out by cfdi_drive_init) */
    double *values, *buffer, *samples;
    cfdi_real *row_raw;
    cfdi_real *ring, *r, *ph, *g_up, *g_down, *r_raw;
    int64_t *last_zero;
    int8_t *alarm;
    uint8_t *tx;
    cfdi_real *recent, *history, *window, *U, *work, *fit_scratch;
    size_t work_len;              /* reals of work */
    int64_t *onsets;
    cfdi_real *J, *meat, *hc; /* (H, K, d, d) twice; (H, K, d + 1): h then the cost */
    cfdi_real *u_abs, *n_u, *cost_h;
    size_t *perm;
    int64_t *best_onset, *order;
    uint8_t *near;
    int32_t *leftover;
    cfdi_comp_channel *chan;      /* (p + q,) each channel's compensation */
    cfdi_lagged lagged;
    cfdi_track track;
    /* the frame path */
    int64_t gate[CFDI_GATE_STATE];
    int64_t ctr[CFDI_CTR_STATE];
    int64_t clock_steps;
    int64_t last_k;               /* the latest sample the bank took (-1: none) */
    int64_t last_t;               /* its time */
    uint64_t status_count[CFDI_N_STATUS];
    uint64_t samples_taken;       /* samples delivered by the clock */
    uint64_t detections;
    /* the queues */
    size_t tx_head, tx_count, tx_stride;
    uint64_t tx_dropped;          /* frames the queue had no room for */
    uint64_t counters[3];         /* FDI_FAULT's, FDI_ESTIMATE's, FDI_STATUS's E2E counters */
    cfdi_event events[CFDI_EVENT_QUEUE];
    size_t ev_head, ev_count;
    uint64_t events_dropped;
    /* the recent samples, raw (a ring: rows held, next slot, overwritten since a clear, the
     * newest's sample, the first one offered to a diagnosis), and the history of the latest
     * consecutive ones (for the window rebuilt after an acceptance) */
    size_t rec_rows, rec_count, rec_next;
    int rec_wrapped, rec_frozen;
    int64_t rec_last_k, rec_offer_k;
    int64_t win_k;                /* the sample whose window d->window holds (-1: none) */
    size_t hist_rows, hist_count, hist_next;
    int64_t hist_last_k;
    /* the compensation */
    cfdi_comp_entry comp[CFDI_MAX_COMP];
    size_t n_comp;
    uint64_t comp_composed;       /* entries composed into a channel's base (the list full) */
    /* the detector and the diagnosis under way */
    int alarmed;                  /* 1 from an alarm to its decision */
    int64_t alarm_k, alarm_t, alarm_onset, restart_k;
    int named;
    size_t n_onsets, n_earlier;
    int64_t cursor;               /* the next sample to absorb (behind: catching up) */
    int64_t diag_start;           /* the first sample the diagnosis absorbs */
    size_t share;                 /* samples absorbed a frame while catching up */
    int64_t freeze_k;             /* the recent ring takes no sample from here on */
    cfdi_real rr;                 /* the no-fault cost and the equations absorbed */
    int64_t n_eq;
    uint64_t singular;            /* samples whose fits had no solution (waited over) */
} cfdi_drive;

/* The bytes of memory a drive of these tables needs (0: tables that do not check). */
size_t cfdi_drive_memory_size(const cfdi_drive_tables *t);

/* Check the tables, lay the caller's memory block (`bytes` long, 8-byte aligned) out and reset
 * the drive: CFDI_OK, or a negative status (a table that does not check, too little memory). */
int cfdi_drive_init(cfdi_drive *d, const cfdi_drive_tables *t, void *memory, size_t bytes);

/* One received frame (its ID, payload length, flags CFDI_FLAG_*, payload of `len` bytes,
 * 0..64, and arrival time in ns): its status code (>= 0, decode.h's CFDI_ST_*), or a negative
 * status (a bad argument; nothing counted). */
int cfdi_drive_on_frame(cfdi_drive *d, uint32_t id, uint8_t len, uint8_t flags,
                        const uint8_t *data, int64_t t_ns);

/* End of stream: a pending incomplete sample is closed as broken and taken. */
int cfdi_drive_finish(cfdi_drive *d);

/* The heartbeat: an FDI_STATUS frame queued (the drive's state, the channels compensated,
 * samples, invalid frames; canfdi.monitor.Monitor.status_frames). Call it from a timer (canfdi's
 * service: every bus.status_period seconds). CFDI_OK, or a negative status. */
int cfdi_drive_status(cfdi_drive *d);

/* The oldest frame the monitor has to send, taken off its queue into *out: 1, or 0 when there
 * is none (a negative status for a null pointer). Call it after each frame and after
 * cfdi_drive_status, and send what it gives (a listen-only drive's tables make none). */
int cfdi_drive_poll_tx(cfdi_drive *d, cfdi_tx_frame *out);

/* The oldest event, taken off its queue into *out: 1, or 0 when there is none. Events not
 * polled are dropped once CFDI_EVENT_QUEUE wait (counted: events_dropped). */
int cfdi_drive_poll_event(cfdi_drive *d, cfdi_event *out);

/* The drive's state: 0 monitoring, 1 diagnosing, 2 named (FDI_STATUS's). */
int cfdi_drive_state(const cfdi_drive *d);

/* The channels compensated now (FDI_STATUS's ActiveFaults before its cap). */
int cfdi_drive_active_faults(const cfdi_drive *d);

#endif

/* One drive's monitor, frame by frame: decode (and E2E), the time gate, the counter clock,
 * the residual bank and the Page-Hinkley detectors, composed from the block functions of
 * cfdi.h and decode.h (the same code the daemon's extension runs over blocks).
 *
 * This is the loop a drive's MCU runs (`canfdi codegen` writes its tables as const data and
 * sizes its memory). Its first alarm starts a diagnosis (with tables' diag): every hypothesis
 * fitted at every candidate onset from the change point on (info.c), solved and decided on
 * at every sample (decide.c), as the Python diagnoser does, up to its first decision: a
 * fault named, accepted, or the alarm unexplained. Each is announced as the Python monitor
 * does, an FDI_FAULT frame queued for the caller to send (cfdi_drive_poll_tx). What follows an
 * acceptance (compensation, the window rebuilt, the detector restarted for the next fault, the
 * accepted faults' tracking) and FDI_ESTIMATE are still the gateway's (issue 43); frames and
 * samples go on being counted.
 *
 * No allocation, no global state: a cfdi_drive holds its state and points at its tables and
 * at memory its caller owns, both checked once by cfdi_drive_init. */
#ifndef CFDI_DRIVE_H
#define CFDI_DRIVE_H

#include <stddef.h>
#include <stdint.h>

#include "cfdi.h"
#include "decode.h"
#include "encode.h"

#define CFDI_N_STATUS 16
#define CFDI_TX_QUEUE 4           /* frames to send a drive holds until polled */

#define CFDI_MAX_FAULTS 4          /* faults one decision accepts (a joint fit's members) */

/* A diagnosis as the drive runs it (canfdi.methods.parity.diagnoser, up to its first
 * decision): the hypotheses and settings a decision reads (cfdi.h's cfdi_decide), and what
 * their fits are made of (cfdi_info_block's tables). */
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
    size_t max_onsets;            /* K: onsets tried at most */
    size_t lookback;              /* samples kept before the alarm (their windows) */
} cfdi_diag_tables;

/* The memory a diagnosis works in (sizes from its tables; H, K = max_onsets, d, m, S). */
typedef struct {
    cfdi_real *recent;            /* (lookback + S + 1, q + p) the latest samples, a ring */
    cfdi_real *window;            /* (S + 1, q + p) one kept sample's window */
    cfdi_real *U;                 /* (S + 1, p) its commands */
    cfdi_real *rn;                /* (m,) its residuals, normalised */
    int64_t *onsets;              /* (K,) */
    cfdi_real *J, *meat, *P;      /* (H, K, d, d) */
    cfdi_real *h, *theta;         /* (H, K, d) */
    cfdi_real *rr, *cost;         /* (H, K) */
    cfdi_real *lu;                /* (d, d) */
    size_t *perm;                 /* (d,) */
    cfdi_real *work;              /* (CFDI_INFO_WORK(m, d)) */
    cfdi_real *u_abs, *n_u;       /* (p,) */
    int64_t *best_onset, *order;  /* (H,) */
    cfdi_real *cost_h;            /* (H,) */
    uint8_t *near;                /* (H,) */
    int32_t *leftover;            /* (H,) */
} cfdi_diag_memory;

/* A decision the diagnosis made: a fault named or accepted (on an actuator, kind 1, or a
 * sensor, kind 2: FDI_FAULT's), or the alarm left unexplained (kind 0). */
#define CFDI_EVENT_NAMED 1
#define CFDI_EVENT_ACCEPTED 2
#define CFDI_EVENT_UNEXPLAINED 3
typedef struct {
    int32_t event;                /* CFDI_EVENT_* */
    int32_t target;               /* 1 actuator, 2 sensor, 0 none */
    int32_t index;                /* the channel (an input's or an output's) */
    int64_t sample, onset;        /* when it was decided, and the onset it dates */
    cfdi_real value;              /* an actuator's lambda, a sensor's bias */
    cfdi_real eta;                /* an accepted actuator's eta (1: a bias alone); NaN: none
                                   * (a sensor; a naming, which gives the offset alone) */
} cfdi_event;

/* A frame the monitor sends. */
typedef struct {
    uint32_t id;
    uint8_t extended;             /* 1: a 29-bit ID */
    uint8_t len;                  /* payload bytes */
    uint8_t data[CFDI_MAX_PAYLOAD];
} cfdi_tx_frame;

/* What a drive's monitor is made of: generated from its config, never written to. */
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
    const cfdi_message *fault;    /* FDI_FAULT (encode.h); NULL: listen-only, nothing sent */
    double fault_roles[CFDI_N_ROLES]; /* a detection's FDI_FAULT values by role (the sample's
                                       * its own): kind none, state detected, the drive */
    double fault_states[3];       /* FDI_FAULT's State of a detection, a naming, an acceptance */
    double fault_kinds[3];        /* its Kind of none, an actuator, a sensor */
    const cfdi_diag_tables *diag; /* the diagnosis; NULL: the loop stops at its alarm */
} cfdi_drive_tables;

/* The memory a drive works in, its caller's (sizes: cfdi_tables.h's CFDI_GEN_*). */
typedef struct {
    double *values;               /* (bus->width,) one frame's decoded fields */
    double *buffer;               /* (p+q,) the clock's pending sample */
    double *samples;              /* (2, p+q) the samples one frame delivers */
    cfdi_real *ring;              /* (S+1, q+p) the bank's window, oldest first */
    cfdi_real *r;                 /* (m,) the latest residuals, normalised */
    cfdi_real *ph;                /* (m, 2) the statistics g+, g- */
    int64_t *last_zero;           /* (m, 2) */
    cfdi_real *g_up, *g_down;     /* (m,) */
    int8_t *alarm;                /* (m,) the alarm's signs */
    cfdi_diag_memory diag;        /* with tables' diag: the diagnosis' */
} cfdi_drive_memory;

typedef struct {
    const cfdi_drive_tables *t;
    cfdi_drive_memory mem;
    int64_t gate[CFDI_GATE_STATE];
    int64_t ctr[CFDI_CTR_STATE];
    int64_t clock_steps;
    int64_t last_k;               /* the latest sample the bank took (-1: none) */
    uint64_t status_count[CFDI_N_STATUS];
    uint64_t samples;             /* samples delivered by the clock */
    int alarmed;                  /* 1 once a detector alarmed */
    int64_t alarm_k;              /* the alarm's sample and the change point it dates */
    int64_t alarm_onset;
    cfdi_tx_frame tx[CFDI_TX_QUEUE]; /* frames to send, oldest at tx_head */
    size_t tx_head, tx_count;
    uint64_t tx_dropped;          /* frames the queue had no room for */
    uint64_t fault_counter;       /* FDI_FAULT's E2E alive counter */
    /* the recent ring (RecentWindows): rows held, the next slot, overwritten since a clear,
     * the newest row's sample */
    size_t rec_count, rec_next;
    int rec_wrapped;
    int64_t rec_last_k;
    /* the diagnosis under way */
    int diagnosing;               /* 1 from the alarm to its decision */
    int decided;                  /* 1 once it decided (the loop diagnoses one fault so far) */
    int named;
    size_t n_onsets;
    int64_t catch_k;              /* the next kept sample to absorb (to alarm_k) */
    size_t catch_share;           /* how many a sample */
    cfdi_real rr;                 /* the no-fault cost and the equations absorbed */
    int64_t n_eq;
    uint64_t singular;            /* samples whose fits had no solution (waited over) */
    cfdi_event events[1 + CFDI_MAX_FAULTS]; /* what it decided: named, then accepted ones */
    size_t n_events;
} cfdi_drive;

/* Check the tables and the memory against each other and reset the drive: CFDI_OK, or a
 * negative status (nothing usable). */
int cfdi_drive_init(cfdi_drive *d, const cfdi_drive_tables *t, const cfdi_drive_memory *mem);

/* One received frame (its ID, payload length, flags CFDI_FLAG_*, payload of `len` bytes,
 * 0..64, and arrival time in ns): its status code (>= 0, decode.h's CFDI_ST_*), or a negative
 * status (a bad argument; nothing counted). */
int cfdi_drive_on_frame(cfdi_drive *d, uint32_t id, uint8_t len, uint8_t flags,
                        const uint8_t *data, int64_t t_ns);

/* End of stream: a pending incomplete sample is closed as broken and taken. */
int cfdi_drive_finish(cfdi_drive *d);

/* The oldest frame the monitor has to send, taken off its queue into *out: 1, or 0 when there
 * is none (a negative status for a null pointer). Call it after each frame, and send what it
 * gives on the bus (a listen-only drive's tables make none). */
int cfdi_drive_poll_tx(cfdi_drive *d, cfdi_tx_frame *out);

#endif

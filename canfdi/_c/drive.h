/* One drive's monitor, frame by frame: decode (and E2E), the time gate, the counter clock,
 * the residual bank and the Page-Hinkley detectors, composed from the block functions of
 * cfdi.h and decode.h (the same code the daemon's extension runs over blocks).
 *
 * This is the loop a drive's MCU runs (`canfdi codegen` writes its tables as const data and
 * sizes its memory). It stops detecting at the first alarm, which it announces as the Python
 * monitor does: an FDI_FAULT frame (state detected, the alarm's sample), queued for the caller
 * to send (cfdi_drive_poll_tx). What follows an alarm (the diagnosis: hypotheses, least
 * squares, acceptance, compensation and reset) is the diagnoser's, still in Python (issue
 * 43); frames and samples go on being counted.
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
} cfdi_drive_tables;

/* The memory a drive works in, its caller's (sizes from the tables; cfdi_drive_memory_ok). */
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

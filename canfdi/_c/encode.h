/* The monitor's own messages encoded from compiled tables: canfdi.bus.codec.MessageLayout.encode
 * of physical values (then the message's E2E protection, e2e.h), for messages without
 * multiplexing and with integer, 32- or 64-bit float signals.
 *
 * Tables, not logic: canfdi.bus.ctables.message_tables builds each row from the monitor DBC's
 * compiled layout and `canfdi codegen` writes them as const data. */
#ifndef CFDI_ENCODE_H
#define CFDI_ENCODE_H

#include <stddef.h>
#include <stdint.h>

#include "cfdi.h"

/* One signal: int64 [CFDI_ENC_INTS] and double [CFDI_ENC_REALS]. */
#define CFDI_ENC_START 0   /* DBC start bit (Intel: LSB; Motorola: MSB, sawtooth) */
#define CFDI_ENC_LENGTH 1  /* bits: 1..64, a float 32 or 64 */
#define CFDI_ENC_FLAGS 2   /* decode.h's CFDI_SIGF_BIG, CFDI_SIGF_SIGNED, CFDI_SIGF_FLOAT */
#define CFDI_ENC_ROLE 3    /* what the monitor writes there (CFDI_ROLE_*) */
#define CFDI_ENC_INTS 4

#define CFDI_ENC_SCALE 0   /* raw = (value - offset) / scale, in double */
#define CFDI_ENC_OFFSET 1
#define CFDI_ENC_LO 2      /* the physical range: a value beyond is clipped to it (an integer */
#define CFDI_ENC_HI 3      /*   signal's NaN reads 0 first, its infinities the largest double) */
#define CFDI_ENC_RAW_LO 4  /* an integer's raw range, as doubles at or inside it: the rounded */
#define CFDI_ENC_RAW_HI 5  /*   raw value is clipped to it */
#define CFDI_ENC_REALS 6

/* What a signal of a monitor message carries (canfdi.monitor's FDI_FAULT, FDI_ESTIMATE and
 * FDI_STATUS values, canfdi.monitor.MONITOR_ROLES). */
#define CFDI_ROLE_NONE 0    /* nothing: raw 0 (the E2E fields, written by the protection) */
#define CFDI_ROLE_KIND 1    /* the faulty channel's kind (none, actuator, sensor) */
#define CFDI_ROLE_STATE 2   /* detected, named, accepted; FDI_STATUS: the drive's state */
#define CFDI_ROLE_DRIVE 3   /* the drive's index on the bus */
#define CFDI_ROLE_INDEX 4   /* the channel's index */
#define CFDI_ROLE_SAMPLE 5  /* the sample, modulo 2^32; FDI_STATUS: the samples, modulo 2^21 */
#define CFDI_ROLE_PARAM 6   /* FDI_ESTIMATE: eta, lambda, bias, or their standard deviations */
#define CFDI_ROLE_VALUE 7   /* FDI_ESTIMATE: the estimate */
#define CFDI_ROLE_ACTIVE 8  /* FDI_STATUS: the channels compensated */
#define CFDI_ROLE_INVALID 9 /* FDI_STATUS: the invalid frames, modulo 2^16 */
#define CFDI_N_ROLES 10

/* One message the monitor sends. */
typedef struct {
    uint32_t id;
    uint8_t extended;          /* 1: a 29-bit ID */
    uint8_t length;            /* payload bytes, 1..64 */
    const int32_t *e2e_spec;   /* its E2E profile (e2e.h) */
    const uint8_t *e2e_bytes;
    const int64_t *sig_int;    /* (n_signals, CFDI_ENC_INTS) */
    const double *sig_real;    /* (n_signals, CFDI_ENC_REALS) */
    size_t n_signals;
} cfdi_message;

/* CFDI_OK when every signal fits the message (its bits inside the payload, a float 32 or 64
 * bits, a known role) and the E2E profile is well formed for its length, else a negative
 * status. cfdi_encode checks this first. */
int cfdi_message_check(const cfdi_message *msg);

/* The payload (msg->length bytes) of the message with each signal's physical value from
 * by_role[its role] (CFDI_N_ROLES values; a signal of role CFDI_ROLE_NONE is raw 0), before
 * the E2E protection. CFDI_OK, or a negative status (payload untouched). */
int cfdi_encode(const cfdi_message *msg, const double *by_role, uint8_t *payload);

#endif

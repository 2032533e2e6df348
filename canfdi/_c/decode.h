/* A drive's frames decoded from compiled tables (canfdi.bus.dbc.BusMap.decode_frames).
 *
 * Tables, not logic: every number below is one row of a flat array that Python builds from
 * the drive's DBC and config (canfdi.bus.ctables, the one place in Python that knows this
 * layout) and that `canfdi codegen` writes as const data. The indices here and there are
 * the same; a test compares them. */
#ifndef CFDI_DECODE_H
#define CFDI_DECODE_H

#include <stddef.h>
#include <stdint.h>

#include "cfdi.h"

/* Frame flags (canfdi.bus.frames.FLAG_*) and statuses (STATUS_NAMES' codes). */
#define CFDI_FLAG_EXTENDED 1
#define CFDI_FLAG_REMOTE 2
#define CFDI_FLAG_ERROR 4
#define CFDI_FLAG_FD 8
enum {
    CFDI_ST_OK = 0, CFDI_ST_MONITOR = 1, CFDI_ST_UNUSED = 2, CFDI_ST_UNKNOWN_ID = 3,
    CFDI_ST_EXTENDED = 4, CFDI_ST_REMOTE = 5, CFDI_ST_ERROR = 6, CFDI_ST_FD = 7,
    CFDI_ST_DLC = 8, CFDI_ST_CRC = 9, CFDI_ST_DUPLICATE = 10, CFDI_ST_STALE = 11,
    CFDI_ST_JUMP = 12, CFDI_ST_TIME_JUMP = 13, CFDI_ST_IMPLAUSIBLE = 14, CFDI_ST_SATURATED = 15
};

/* One known message (an entry): int64 [CFDI_ENTRY_INTS]. Entries 0 .. n_slots - 1 are the
 * drive's slots (entry = slot), the others known messages that are no slot. */
#define CFDI_ENTRY_KIND 0     /* the status of a frame that passes: ok, monitor or unused */
#define CFDI_ENTRY_LENGTH 1   /* payload bytes, 0..64 */
#define CFDI_ENTRY_FD 2       /* 1: a CAN FD frame */
#define CFDI_ENTRY_PROFILE 3  /* its E2E profile: a row of the profile tables */
#define CFDI_ENTRY_SIG_AT 4   /* a slot's compiled signals: rows SIG_AT .. SIG_AT + SIG_COUNT */
#define CFDI_ENTRY_SIG_COUNT 5
#define CFDI_ENTRY_COLUMNS 6  /* the values a slot gives (its model fields) */
#define CFDI_ENTRY_CHECKED 7  /* 1: some field has a plausible range */
#define CFDI_ENTRY_INTS 8

/* One compiled signal of a slot, multiplexers before what they select: int64
 * [CFDI_SIG_INTS] and double [CFDI_SIG_REALS]. */
#define CFDI_SIG_START 0      /* DBC start bit (Intel: LSB; Motorola: MSB, sawtooth) */
#define CFDI_SIG_LENGTH 1     /* bits, 1..64 (a float: 16, 32 or 64) */
#define CFDI_SIG_FLAGS 2      /* CFDI_SIGF_* */
#define CFDI_SIG_CONV 3       /* CFDI_CONV_* */
#define CFDI_SIG_ISCALE 4     /* the integer scale and offset of CFDI_CONV_INTEGER(_FLOAT) */
#define CFDI_SIG_IOFFSET 5
#define CFDI_SIG_PARENT 6     /* the multiplexer selecting it (a row of this slot), -1 none */
#define CFDI_SIG_IDS_AT 7     /* the multiplexer values selecting it: ids rows */
#define CFDI_SIG_IDS_COUNT 8
#define CFDI_SIG_NUMBER 9     /* a multiplexer's value kind: CFDI_NUM_* */
#define CFDI_SIG_COLUMN 10    /* its value's column, -1 for a multiplexer the model does not use */
#define CFDI_SIG_INTS 11

#define CFDI_SIGF_BIG 1       /* Motorola byte order */
#define CFDI_SIGF_SIGNED 2
#define CFDI_SIGF_FLOAT 4
#define CFDI_SIGF_NEVER 8     /* multiplexed by nothing that ever selects it */
#define CFDI_SIGF_MUX 16      /* a multiplexer */

#define CFDI_CONV_IDENTITY 0  /* physical = raw */
#define CFDI_CONV_INTEGER 1   /* physical = raw * iscale + ioffset, exact in int64 */
#define CFDI_CONV_INTEGER_FLOAT 2 /* physical = (raw * iscale, exact) + offset */
#define CFDI_CONV_LINEAR 3    /* physical = raw * scale (+ offset when not 0), in double */

#define CFDI_NUM_INT 0        /* a multiplexer's value: int64 */
#define CFDI_NUM_UINT 1       /* uint64 (an unsigned 64-bit multiplexer) */
#define CFDI_NUM_REAL 2       /* double, trunc(raw * scale + offset) */

#define CFDI_SIG_SCALE 0
#define CFDI_SIG_OFFSET 1
#define CFDI_SIG_LOW 2        /* the plausible range of a column (-inf, inf: none) */
#define CFDI_SIG_HIGH 3
#define CFDI_SIG_CLIP_LOW 4   /* at or beyond either, the value is saturated */
#define CFDI_SIG_CLIP_HIGH 5
#define CFDI_SIG_REALS 6

/* The most compiled signals a slot may have (a bit each of a uint64_t on the stack). */
#define CFDI_SLOT_SIGNALS 64
#define CFDI_MAX_PAYLOAD 64

/* A drive's tables. Every array is the caller's; sizes in rows. */
typedef struct {
    const int64_t *std_id;     /* (n_std,) the 11-bit IDs known, ascending */
    const int32_t *std_entry;  /* (n_std,) their entries */
    size_t n_std;
    const int64_t *ext_id;     /* (n_ext,) the 29-bit IDs known, ascending */
    const int32_t *ext_entry;  /* (n_ext,) their entries */
    size_t n_ext;
    const int64_t *entry;      /* (n_entries, CFDI_ENTRY_INTS) */
    size_t n_entries, n_slots;
    const int32_t *e2e_spec;   /* (n_profiles, CFDI_E2E_INTS), canfdi/_c/e2e.h */
    const uint8_t *e2e_bytes;  /* (n_profiles, CFDI_E2E_BYTES) */
    size_t n_profiles;
    const int64_t *sig_int;    /* (n_signals, CFDI_SIG_INTS) */
    const double *sig_real;    /* (n_signals, CFDI_SIG_REALS) */
    size_t n_signals;
    const int64_t *ids_int;    /* (n_ids,) multiplexer values (uint64 ones as their bits) */
    const double *ids_real;    /* (n_ids,) the same as doubles */
    size_t n_ids;
    size_t width;              /* the values' columns: the most a slot gives */
} cfdi_bus;

/* Every index of the tables in range, every size within its bound: CFDI_OK, or a negative
 * status. cfdi_decode_block checks this first. */
int cfdi_bus_check(const cfdi_bus *bus);

/* Check and decode n frames (BusMap.decode_frames).
 *
 * id, dlc, flags : (n,) the frames' IDs, payload lengths (bytes) and flags.
 * data     : (n, 8) the first 8 payload bytes, zero-padded.
 * long_row : (n,) for a frame of over 8 bytes the row of `longdata` with its whole payload,
 *            -1 (then bytes 8.. read as zero); may be NULL when n_long is 0.
 * longdata : (n_long, 64) whole payloads, zero-padded.
 * status   : (n,) int8 written: STATUS_NAMES' codes.
 * slot     : (n,) int16 written: the slot of the frame's message, else -1.
 * values   : (n, width) written: a slot's field values of an "ok" frame, NaN elsewhere.
 * counters : (n,) written: the E2E alive counter of an "ok" frame, -1 elsewhere.
 * Returns CFDI_OK, or a negative status (nothing written) for malformed tables or sizes. */
int cfdi_decode_block(const cfdi_bus *bus, size_t n, const uint32_t *id, const uint8_t *dlc,
                      const uint8_t *flags, const uint8_t *data, const int32_t *long_row,
                      const uint8_t *longdata, size_t n_long, int8_t *status, int16_t *slot,
                      double *values, int64_t *counters);

/* cfdi_decode_block for tables the caller has checked once with cfdi_bus_check (and never
 * changes): a drive loop that decodes frame by frame checks its tables at init, not per frame
 * (drive.c). The same answers. */
int cfdi_decode_checked(const cfdi_bus *bus, size_t n, const uint32_t *id, const uint8_t *dlc,
                        const uint8_t *flags, const uint8_t *data, const int32_t *long_row,
                        const uint8_t *longdata, size_t n_long, int8_t *status, int16_t *slot,
                        double *values, int64_t *counters);

#endif

/* The runner of a generated project (`canfdi codegen`): reads a candump -L log (can-utils'
 * format, as python-can reads it) or a Vector .asc, feeds every frame to the drive's monitor
 * (drive.h), with its heartbeat every bus.status_period of the log's time, and prints what it
 * found as JSON in the form `canfdi replay --json` gives it (faults, named, unexplained,
 * refined, detections, samples, frames), then the frames the monitor sent. The same file runs
 * on the host (cfdi_io_host.c) and on the MCU through semihosting (cfdi_io_semihost.c); it
 * parses and formats numbers itself, so the MCU's image needs nothing of the C library's I/O
 * and never allocates.
 *
 * A harness, not the core, and one that keeps nothing of what it prints: it streams the frames
 * sent as they go, then runs the log again for each list of events that has any, streaming
 * that list (the drive is the same every time: the same frames give the same events). */
#include <float.h>
#include <stdint.h>
#include <string.h>

#include "cfdi_io.h"
#include "cfdi_tables.h"
#include "drive.h"

#define LINE 320

static int hex_digit(char c)
{
    if (c >= '0' && c <= '9') return c - '0';
    if (c >= 'a' && c <= 'f') return c - 'a' + 10;
    if (c >= 'A' && c <= 'F') return c - 'A' + 10;
    return -1;
}

/* A time "(seconds)" as python-can reads it, float(text), times 1e9 truncated to int64 as
 * canfdi converts it (numpy's astype). Digits only, a point and at most 22 decimals, below
 * 2^53 units of the last decimal (a microsecond candump reaches that in 285 years): then the
 * decimal's double is the quotient of two exact doubles, correctly rounded as float() is.
 * 1 read (*end after it), 0 not such a time. */
static int parse_time(const char *p, const char **end, int64_t *t_ns)
{
    static const double tens[23] = {1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10,
                                    1e11, 1e12, 1e13, 1e14, 1e15, 1e16, 1e17, 1e18, 1e19,
                                    1e20, 1e21, 1e22};
    uint64_t n = 0;
    int decimals = -1, digits = 0, negative = 0;
    double seconds;
    if (*p == '-' || *p == '+') negative = *p++ == '-';
    for (;; p++) {
        if (*p == '.' && decimals < 0) {
            decimals = 0;
            continue;
        }
        if (*p < '0' || *p > '9') break;
        n = n * 10 + (uint64_t)(*p - '0');
        digits++;
        if (decimals >= 0) decimals++;
        if (n >= ((uint64_t)1 << 53) || decimals > 22) return 0;
    }
    if (digits == 0) return 0;
    seconds = (double)n / tens[decimals < 0 ? 0 : decimals] * 1e9;
    seconds = negative ? -seconds : seconds;
    *t_ns = (int64_t)seconds; /* |seconds| < 2^53 * 1e9 < 2^63 */
    *end = p;
    return 1;
}

/* An unsigned number of base 16 or 10 from p (digits only, below 2^32): 1 read (*end after
 * it), 0 not. */
static int parse_uint(const char *p, int base, const char **end, uint32_t *value)
{
    uint64_t v = 0;
    const char *start = p;
    for (;; p++) {
        int d = hex_digit(*p);
        if (d < 0 || d >= base) break;
        v = v * (uint64_t)base + (uint64_t)d;
        if (v > 0xFFFFFFFFULL) return 0;
    }
    if (p == start) return 0;
    *end = p;
    *value = (uint32_t)v;
    return 1;
}

static const char *skip_blank(const char *p)
{
    while (*p == ' ' || *p == '\t') p++;
    return p;
}

/* One candump -L line: "(seconds) interface ID#DATA [R|T]", ID##F DATA for CAN FD, ID#R[n]
 * for a remote request. 1 parsed, 0 blank, -1 malformed. */
static int parse_line(const char *line, uint32_t *id, uint8_t *len, uint8_t *flags,
                      uint8_t *data, int64_t *t_ns)
{
    const char *p = line, *end, *frame, *hash;
    uint32_t raw;
    size_t n = 0;
    p = skip_blank(p);
    if (*p == '\0' || *p == '\n' || *p == '\r') return 0;
    if (*p != '(' || !parse_time(p + 1, &end, t_ns) || *end != ')') return -1;
    p = end + 1;
    while (*p == ' ') p++;
    while (*p && *p != ' ') p++; /* the interface */
    while (*p == ' ') p++;
    frame = p;
    hash = strchr(frame, '#');
    if (!hash || hash - frame > 8 || !parse_uint(frame, 16, &end, &raw) || end != hash) return -1;
    *flags = hash - frame > 3 ? CFDI_FLAG_EXTENDED : 0;
    if ((raw & 0x20000000UL) && (raw & 0x80UL)) { /* CAN_ERR_FLAG and CAN_ERR_BUSERROR */
        *id = 0;
        *flags = CFDI_FLAG_ERROR;
        *len = 0;
        return 1;
    }
    *id = raw & 0x1FFFFFFFUL;
    p = hash + 1;
    if (*p == '#') {
        *flags |= CFDI_FLAG_FD;
        if (hex_digit(p[1]) < 0) return -1;
        p += 2;
    }
    if (*p == 'R' || *p == 'r') {
        *flags |= CFDI_FLAG_REMOTE;
        *len = 0;
        for (p++; *p >= '0' && *p <= '9'; p++) {
            if (*len > 6) return -1;
            *len = (uint8_t)(*len * 10 + (*p - '0'));
        }
        return 1;
    }
    while (hex_digit(p[0]) >= 0 && hex_digit(p[1]) >= 0) {
        if (n == CFDI_MAX_PAYLOAD) return -1;
        data[n++] = (uint8_t)(hex_digit(p[0]) * 16 + hex_digit(p[1]));
        p += 2;
    }
    if (*p != '\0' && *p != ' ' && *p != '\n' && *p != '\r') return -1;
    *len = (uint8_t)n;
    return 1;
}

/* python-can's dlc2len: a CAN FD DLC's payload length */
static uint8_t dlc_length(uint32_t dlc)
{
    static const uint8_t fd[7] = {12, 16, 20, 24, 32, 48, 64};
    return dlc <= 8 ? (uint8_t)dlc : dlc <= 15 ? fd[dlc - 9] : 64;
}

/* The ASC token at p (up to a blank or the end) and where the next one starts. */
static const char *asc_token(const char *p, const char **next)
{
    const char *end = p;
    while (*end && *end != ' ' && *end != '\t' && *end != '\n' && *end != '\r') end++;
    *next = skip_blank(end);
    return end;
}

/* Up to `want` bytes in the log's base from p into data (the rest zeros), as python-can's
 * _process_data_string takes them: the next `want` tokens, each a byte; the frame as long as
 * the line has tokens. A line cut short (`cut`: longer than the runner's buffer) must hold
 * all of them. The count, or -1. */
static int asc_bytes(const char *p, int base, size_t want, int cut, uint8_t *data)
{
    const char *end;
    uint32_t value;
    size_t n = 0;
    while (n < want && *p != '\0' && *p != '\r') {
        if (!parse_uint(p, base, &end, &value) || value > 255
            || (*end != '\0' && *end != ' ' && *end != '\t' && *end != '\r')) {
            return -1;
        }
        data[n++] = (uint8_t)value;
        p = skip_blank(end);
    }
    if (cut && n < want) return -1;
    memset(data + n, 0, CFDI_MAX_PAYLOAD - n);
    return (int)n;
}

/* An ASC CAN FD line after "CANFD", as python-can's _process_fd_can_frame reads it: channel,
 * direction, "ErrorFrame" or the ID (x: extended), a symbolic name unless the next token is a
 * number, BRS, ESI, the DLC (in the log's base), the data length (decimal: 0 for a remote
 * request, whose length is then its DLC) and up to that many bytes (asc_bytes). 1 parsed, -1
 * malformed. */
static int parse_asc_fd(const char *p, int base, int cut, uint32_t *id, uint8_t *len,
                        uint8_t *flags, uint8_t *data)
{
    const char *end, *next, *brs;
    uint32_t value, dlc, length;
    int n;
    if (!parse_uint(p, 10, &end, &value) || (*end != ' ' && *end != '\t')) return -1;
    p = skip_blank(end);
    if (strncmp(p, "Rx", 2) != 0 && strncmp(p, "Tx", 2) != 0) return -1;
    p = skip_blank(p + 2);
    *flags = CFDI_FLAG_FD;
    if (strncmp(p, "ErrorFrame", 10) == 0 || strncmp(p, "errorframe", 10) == 0) {
        *id = 0;
        *flags |= CFDI_FLAG_ERROR;
        *len = 0;
        return 1;
    }
    if (!parse_uint(p, base, &end, &value)) return -1;
    if (*end == 'x' || *end == 'X') {
        *flags |= CFDI_FLAG_EXTENDED;
        end++;
    }
    if (*end != ' ' && *end != '\t') return -1;
    *id = value;
    p = skip_blank(end);
    brs = p;
    end = asc_token(p, &next);
    while (brs < end && *brs >= '0' && *brs <= '9') brs++;
    if (brs != end || end == p) p = next; /* a symbolic name, not the BRS bit */
    end = asc_token(p, &p); /* BRS */
    end = asc_token(p, &p); /* ESI */
    if (!parse_uint(p, base, &end, &dlc) || (*end != ' ' && *end != '\t')) return -1;
    p = skip_blank(end);
    if (!parse_uint(p, 10, &end, &length) || (*end && *end != ' ' && *end != '\t'
                                              && *end != '\n' && *end != '\r')) {
        return -1;
    }
    p = skip_blank(end);
    if (length == 0) {
        if (dlc > CFDI_MAX_PAYLOAD) return -1;
        *flags |= CFDI_FLAG_REMOTE;
        *len = (uint8_t)dlc;
        return 1;
    }
    if (length > CFDI_MAX_PAYLOAD) return -1;
    n = asc_bytes(p, base, length, cut, data);
    if (n < 0) return -1;
    *len = (uint8_t)n;
    return 1;
}

/* Whether p starts a word (letters, digits, _), blanks, then Tx or Rx, in any case: the frame
 * lines python-can's ASC_MESSAGE_REGEX takes ("1  Statistic: ...", "1  J1939TP ..." are not). */
static int asc_word_then_direction(const char *p)
{
    const char *q = p;
    while ((*q >= '0' && *q <= '9') || (*q >= 'a' && *q <= 'z') || (*q >= 'A' && *q <= 'Z')
           || *q == '_') {
        q++;
    }
    if (q == p || (*q != ' ' && *q != '\t')) return 0;
    q = skip_blank(q);
    return (q[0] == 'T' || q[0] == 't' || q[0] == 'R' || q[0] == 'r')
           && (q[1] == 'x' || q[1] == 'X');
}

/* One line of a Vector ASC log, as python-can's ASCReader takes it: "<seconds> <channel> <ID>[x]
 * Rx|Tx d <DLC> <bytes>", "... r [DLC]" for a remote request, "<seconds> <channel>
 * ErrorFrame"; a CAN FD frame "<seconds> CANFD <channel> Rx|Tx <ID>[x] [<name>] <BRS> <ESI>
 * <DLC> <data length> <bytes>" (parse_asc_fd); the header's "base hex|dec" sets *base. Every
 * other line (the header, comments, events, statistics, J1939 transport) is no frame, as it is
 * to python-can. A data frame is as long as the bytes it lists, up to its DLC's length (8 at
 * most in classic CAN), as python-can reads it. `cut`: the line is longer than the runner's
 * buffer, and what it needs must lie in the part read. 1 parsed, 0 no frame, -1 malformed. */
static int parse_asc_line(const char *line, int *base, int cut, uint32_t *id, uint8_t *len,
                          uint8_t *flags, uint8_t *data, int64_t *t_ns)
{
    const char *p = skip_blank(line), *end;
    uint32_t value, dlc;
    int n;
    if (strncmp(p, "base ", 5) == 0) {
        p = skip_blank(p + 5);
        *base = strncmp(p, "dec", 3) == 0 ? 10 : 16;
        return 0;
    }
    if (!parse_time(p, &end, t_ns) || (*end != ' ' && *end != '\t')) return 0;
    p = skip_blank(end);
    if (strncmp(p, "CANFD", 5) == 0 && (p[5] == ' ' || p[5] == '\t')) {
        return parse_asc_fd(skip_blank(p + 5), *base, cut, id, len, flags, data);
    }
    if (*p < '0' || *p > '9') return 0; /* "Start of measurement", statistics, J1939 ... */
    while (*p >= '0' && *p <= '9') p++; /* the channel */
    p = skip_blank(p);
    *flags = 0;
    if (strncmp(p, "ErrorFrame", 10) == 0 || strncmp(p, "errorframe", 10) == 0) {
        *id = 0;
        *flags = CFDI_FLAG_ERROR;
        *len = 0;
        return 1;
    }
    if (!asc_word_then_direction(p)) return 0;
    if (!parse_uint(p, *base, &end, &value)) return -1;
    if (*end == 'x' || *end == 'X') {
        *flags |= CFDI_FLAG_EXTENDED;
        end++;
    }
    *id = value;
    p = skip_blank(end);
    if (strncmp(p, "Rx", 2) != 0 && strncmp(p, "Tx", 2) != 0) return -1;
    p = skip_blank(p + 2);
    if (*p == 'r' || *p == 'R') {
        *flags |= CFDI_FLAG_REMOTE;
        *len = 0;
        p = skip_blank(p + 1);
        if (parse_uint(p, 10, &end, &dlc) && (*end == '\0' || *end == ' ')) {
            if (!parse_uint(p, *base, &end, &dlc) || dlc > 64) return -1;
            *len = (uint8_t)dlc;
        }
        return 1;
    }
    if (*p != 'd' && *p != 'D') return -1;
    p = skip_blank(p + 1);
    if (!parse_uint(p, *base, &end, &dlc)) return -1;
    n = asc_bytes(skip_blank(end), *base, dlc_length(dlc) < 8 ? dlc_length(dlc) : 8, cut, data);
    if (n < 0) return -1;
    *len = (uint8_t)n;
    return 1;
}

/* Text out: strings, integers and reals, all the JSON here needs. */
static void out_u64(uint64_t v)
{
    char buf[24], *p = buf + sizeof buf - 1;
    *p = '\0';
    do {
        *--p = (char)('0' + v % 10);
        v /= 10;
    } while (v);
    cfdi_io_out(p);
}

static void out_i64(int64_t v)
{
    if (v < 0) {
        cfdi_io_out("-");
        out_u64((uint64_t)(-(v + 1)) + 1);
    } else {
        out_u64((uint64_t)v);
    }
}

/* Bytes as lower-case hex, two digits each (canfdi's logs' spelling of a payload). */
static void out_hex(const uint8_t *data, size_t n)
{
    static const char digits[] = "0123456789abcdef";
    char pair[3];
    size_t i;
    pair[2] = '\0';
    for (i = 0; i < n; i++) {
        pair[0] = digits[data[i] >> 4];
        pair[1] = digits[data[i] & 15];
        cfdi_io_out(pair);
    }
}

/* A real to 16 significant digits in exponent form (null for NaN or an infinity: JSON has
 * neither): what the estimates need, compared to 1e-6. */
static void out_real(double v)
{
    char buf[40];
    size_t n = 0;
    int e10, i;
    double mant;
    if (v != v || v > DBL_MAX || v < -DBL_MAX) {
        cfdi_io_out("null");
        return;
    }
    if (v < 0) {
        buf[n++] = '-';
        v = -v;
    }
    if (v == 0) {
        cfdi_io_out(n ? "-0.0" : "0.0");
        return;
    }
    /* (by tens, not log10 and pow: the MCU's image keeps no libm for output; a few hundred
     * roundings at most, far below the digits compared) */
    e10 = 0;
    mant = v;
    while (mant >= 10.0) {
        mant /= 10.0;
        e10 += 1;
    }
    while (mant < 1.0) {
        mant *= 10.0;
        e10 -= 1;
    }
    for (i = 0; i < 16; i++) {
        int digit = (int)mant;
        digit = digit > 9 ? 9 : digit < 0 ? 0 : digit;
        buf[n++] = (char)('0' + digit);
        if (i == 0) {
            buf[n++] = '.';
        }
        mant = (mant - digit) * 10.0;
    }
    buf[n++] = 'e';
    buf[n] = '\0';
    cfdi_io_out(buf);
    out_i64(e10);
}

static void out_name(const char *name)
{
    cfdi_io_out("\"");
    cfdi_io_out(name);
    cfdi_io_out("\"");
}

/* The log's lines one by one, from chunks. A line longer than the buffer sets *overlong and
 * is returned up to its last blank in the buffer (whole tokens): an ASC line's trailing
 * fields (lengths, bit counts) may lie past what the frame needs. 1 a line, 0 the end, -1 a
 * read error. */
typedef struct {
    long handle;
    char chunk[256];
    size_t at, have;
    int eof;
} lines_t;

static int next_line(lines_t *in, char *line, size_t size, int *overlong)
{
    size_t n = 0;
    int newline = 0;
    *overlong = 0;
    for (;;) {
        char c;
        if (in->at == in->have) {
            long got;
            if (in->eof) break;
            got = cfdi_io_read(in->handle, in->chunk, sizeof in->chunk);
            if (got < 0) return -1;
            if (got == 0) {
                in->eof = 1;
                break;
            }
            in->at = 0;
            in->have = (size_t)got;
        }
        c = in->chunk[in->at++];
        if (c == '\n') {
            newline = 1;
            break;
        }
        if (n + 1 < size) {
            line[n++] = c;
        } else {
            *overlong = 1;
        }
    }
    if (*overlong) {
        while (n > 0 && line[n - 1] != ' ' && line[n - 1] != '\t') n--;
    }
    line[n] = '\0';
    return n > 0 || *overlong || newline ? 1 : 0;
}

/* -- the events the JSON lists ---------------------------------------------------------- */

/* What a list's entries read of the events before them: the latest detection's sample and
 * time, and the latest naming and the detection it followed. */
typedef struct {
    int64_t detected, detected_ns, named, named_of;
    uint64_t counts[5];           /* events by kind (CFDI_EVENT_*) */
} run_events;

static const char *channel_name(int target, int index)
{
    return target == CFDI_TARGET_ACTUATOR ? cfdi_input_names[index] : cfdi_output_names[index];
}

static const char *target_name(int target)
{
    return target == CFDI_TARGET_ACTUATOR ? "actuator" : target == CFDI_TARGET_SENSOR
                                                         ? "sensor" : "sensors";
}

/* A channel's estimates as the replay names them: an actuator's eta and lambda (or lambda
 * alone), a sensor's bias, a joint fit's members by name. */
static void out_estimates(const cfdi_channel *c, const cfdi_real *values)
{
    const cfdi_diag_tables *g = cfdi_drive_tables_gen.diag;
    int i;
    cfdi_io_out("{");
    if (c->target == CFDI_TARGET_SENSOR) {
        cfdi_io_out("\"bias\": ");
        out_real((double)values[0]);
    } else if (c->target == CFDI_TARGET_ACTUATOR && c->n_est == 2) {
        cfdi_io_out("\"eta\": ");
        out_real((double)values[0]);
        cfdi_io_out(", \"lambda\": ");
        out_real((double)values[1]);
    } else if (c->target == CFDI_TARGET_ACTUATOR) {
        cfdi_io_out("\"lambda\": ");
        out_real((double)values[1]);
    } else if (g != NULL && c->hyp >= 0) {
        for (i = 0; i < c->n_est; i++) {
            int32_t member = g->columns[((size_t)c->hyp * g->hyp.d + (size_t)i) * 2 + 1];
            cfdi_io_out(i ? ", " : "");
            out_name(cfdi_output_names[member]);
            cfdi_io_out(": ");
            out_real((double)values[i]);
        }
    }
    cfdi_io_out("}");
}

static void out_candidates(const cfdi_event *ev)
{
    const cfdi_diag_tables *g = cfdi_drive_tables_gen.diag;
    int i;
    cfdi_io_out("[");
    for (i = 0; i < ev->n_candidates; i++) {
        const cfdi_channel *c = &ev->candidates[i];
        cfdi_io_out(i ? ", {\"target\": " : "{\"target\": ");
        out_name(target_name(c->target));
        cfdi_io_out(", \"index\": ");
        out_i64(c->index);
        cfdi_io_out(", \"name\": ");
        if (c->target == CFDI_TARGET_SENSORS && g != NULL && c->hyp >= 0) {
            int32_t k;
            cfdi_io_out("\"");
            for (k = 0; k < g->hyp.n_params[c->hyp]; k++) {
                int32_t member = g->columns[((size_t)c->hyp * g->hyp.d + (size_t)k) * 2 + 1];
                cfdi_io_out(k ? "+" : "");
                cfdi_io_out(cfdi_output_names[member]);
            }
            cfdi_io_out("\"");
        } else {
            out_name(channel_name(c->target, c->index));
        }
        cfdi_io_out(", \"estimates\": ");
        out_estimates(c, c->est);
        cfdi_io_out("}");
    }
    cfdi_io_out("]");
}

static void out_maybe(int64_t v)
{
    if (v < 0) {
        cfdi_io_out("null");
    } else {
        out_i64(v);
    }
}

/* One listed event in its list's form (canfdi.monitor.summary_json). */
static void out_listed(const cfdi_event *ev, const run_events *rs, int first)
{
    cfdi_io_out(first ? "{" : ", {");
    if (ev->kind == CFDI_EVENT_UNEXPLAINED) {
        cfdi_io_out("\"kind\": \"unexplained\", \"sample\": ");
        out_i64(ev->sample);
        cfdi_io_out(", \"timestamp_ns\": ");
        out_i64(ev->timestamp_ns);
        cfdi_io_out(", \"target\": null, \"index\": null, \"name\": null, \"estimates\": {}, "
                    "\"variances\": {}, \"onset_sample\": null, \"detected_sample\": ");
        out_maybe(ev->detected);
        cfdi_io_out(", \"accepted_sample\": null, \"candidates\": ");
        out_candidates(ev);
        cfdi_io_out(", \"residuals\": [], \"drive\": ");
        out_name(cfdi_drive_name);
        cfdi_io_out(", \"undecided\": []}");
        return;
    }
    cfdi_io_out("\"kind\": ");
    out_name(target_name(ev->ch.target));
    cfdi_io_out(", \"index\": ");
    out_i64(ev->ch.index);
    cfdi_io_out(", \"name\": ");
    out_name(channel_name(ev->ch.target, ev->ch.index));
    cfdi_io_out(", \"drive\": ");
    out_name(cfdi_drive_name);
    if (ev->kind == CFDI_EVENT_NAMED) {
        cfdi_io_out(", \"sample\": ");
        out_i64(ev->sample);
    }
    cfdi_io_out(", \"onset_sample\": ");
    out_maybe(ev->onset);
    cfdi_io_out(", \"detected_sample\": ");
    out_maybe(ev->detected);
    if (ev->kind == CFDI_EVENT_ACCEPTED) {
        cfdi_io_out(", \"named_sample\": ");
        out_i64(rs->named_of == ev->detected && ev->detected >= 0 ? rs->named : ev->sample);
    }
    if (ev->kind != CFDI_EVENT_NAMED) {
        cfdi_io_out(", \"accepted_sample\": ");
        out_maybe(ev->accepted);
    }
    if (ev->kind == CFDI_EVENT_ACCEPTED) {
        cfdi_io_out(", \"detected_time\": ");
        if (rs->detected == ev->detected) {
            out_real((double)rs->detected_ns / 1e9);
        } else {
            cfdi_io_out("null");
        }
    }
    cfdi_io_out(", \"estimate\": ");
    out_estimates(&ev->ch, ev->ch.est);
    if (ev->kind != CFDI_EVENT_REFINED) {
        cfdi_io_out(", \"variance\": ");
        if (ev->has_var) {
            out_estimates(&ev->ch, ev->var);
        } else {
            cfdi_io_out("{}");
        }
    }
    if (ev->kind == CFDI_EVENT_NAMED) {
        cfdi_io_out(", \"undecided\": [");
        cfdi_io_out((ev->undecided & CFDI_UNDECIDED_FORM) ? "\"form\"" : "");
        cfdi_io_out((ev->undecided & CFDI_UNDECIDED_FORM) && (ev->undecided & CFDI_UNDECIDED_SIZE)
                    ? ", " : "");
        cfdi_io_out((ev->undecided & CFDI_UNDECIDED_SIZE) ? "\"size\"" : "");
        cfdi_io_out("]");
    }
    if (ev->kind != CFDI_EVENT_REFINED) {
        cfdi_io_out(", \"candidates\": ");
        out_candidates(ev);
    }
    cfdi_io_out("}");
}

static void out_sent(const cfdi_tx_frame *f, uint64_t n)
{
    cfdi_io_out(n ? ", {\"id\": " : "{\"id\": ");
    out_u64(f->id);
    cfdi_io_out(f->extended ? ", \"extended\": true" : ", \"extended\": false");
    cfdi_io_out(", \"data\": \"");
    out_hex(f->data, f->len);
    cfdi_io_out("\"}");
}

/* What a run over the log counts. */
typedef struct {
    uint64_t lines, malformed, sent;
#ifdef CFDI_TICK_INSNS
    uint64_t ticks, monitor_ticks, monitor_samples, tracked_ticks, tracked_samples;
    uint32_t worst, alarm_tick, diag_worst;
#endif
} run_counts;

/* One event polled: the bookkeeping lists read, and printed when it is of `list`'s kind. */
static void take_event(const cfdi_event *ev, run_events *rs, int32_t list, int *first)
{
    rs->counts[ev->kind] += 1;
    if (ev->kind == list) {
        out_listed(ev, rs, *first);
        *first = 0;
    }
    if (ev->kind == CFDI_EVENT_DETECTED) {
        rs->detected = ev->sample;
        rs->detected_ns = ev->timestamp_ns;
    } else if (ev->kind == CFDI_EVENT_NAMED) {
        rs->named = ev->sample;
        rs->named_of = ev->detected;
    }
}

/* The log through the drive, from the start: the heartbeat every status period of the log's
 * time; the frames sent printed (list < 0) or the events of kind `list`. 0, or 1 (said why). */
static int run_log(cfdi_drive *drive, void *memory, size_t bytes, const char *path, int asc,
                   int32_t list, run_events *rs, run_counts *n)
{
    static lines_t in;
    static char line[LINE];
    uint8_t data[CFDI_MAX_PAYLOAD];
    cfdi_tx_frame out;
    cfdi_event ev;
    int rc, got, overlong, base = 16, beat_set = 0, first = 1;
    int64_t next_beat = 0;
#ifdef CFDI_TICK_INSNS
    uint32_t tick;
    uint64_t samples_before;
    int was_alarmed, was_tracking;
#endif
    memset(rs, 0, sizeof *rs);
    memset(n, 0, sizeof *n);
    rs->detected = rs->named_of = -1;
    if (cfdi_drive_init(drive, &cfdi_drive_tables_gen, memory, bytes) != CFDI_OK) {
        cfdi_io_err("cfdi_run: the generated tables do not check\n");
        return 1;
    }
    memset(&in, 0, sizeof in);
    in.handle = cfdi_io_open(path);
    if (in.handle < 0) {
        cfdi_io_err("cfdi_run: cannot open the log\n");
        return 1;
    }
    while ((got = next_line(&in, line, sizeof line, &overlong)) > 0) {
        uint32_t id = 0;
        uint8_t len = 0, flags = 0;
        int64_t t_ns = 0;
        n->lines++;
        /* (a candump line has no trailing fields: one cut short is malformed) */
        rc = overlong && (!asc || line[0] == '\0') ? -1
             : asc ? parse_asc_line(line, &base, overlong, &id, &len, &flags, data, &t_ns)
                   : parse_line(line, &id, &len, &flags, data, &t_ns);
        if (rc < 0) {
            n->malformed++;
            continue;
        }
        if (rc == 0) continue;
        /* The heartbeat: before the first frame at or after a status period past the first
         * frame's time, then past the last one due. */
        if (!beat_set) {
            next_beat = t_ns + CFDI_GEN_STATUS_PERIOD_NS;
            beat_set = 1;
        } else if (t_ns >= next_beat) {
            cfdi_drive_status(drive);
            next_beat += CFDI_GEN_STATUS_PERIOD_NS
                         * ((t_ns - next_beat) / CFDI_GEN_STATUS_PERIOD_NS + 1);
        }
#ifdef CFDI_TICK_INSNS
        was_alarmed = drive->alarmed;
        was_tracking = drive->track.n > 0;
        samples_before = drive->samples_taken;
        tick = cfdi_io_ticks();
        rc = cfdi_drive_on_frame(drive, id, len, flags, data, t_ns);
        tick = (cfdi_io_ticks() - tick) & 0xFFFFFFu;
        n->ticks += tick;
        n->worst = tick > n->worst ? tick : n->worst;
        if (!was_alarmed && drive->alarmed) {
            n->alarm_tick = tick > n->alarm_tick ? tick : n->alarm_tick;
        } else if (was_alarmed) {
            n->diag_worst = tick > n->diag_worst ? tick : n->diag_worst;
        } else if (drive->detections == 0) {
            n->monitor_ticks += tick;
            n->monitor_samples = drive->samples_taken;
        } else if (was_tracking) {
            n->tracked_ticks += tick;
            n->tracked_samples += drive->samples_taken - samples_before;
        }
#else
        rc = cfdi_drive_on_frame(drive, id, len, flags, data, t_ns);
#endif
        if (rc < 0) {
            cfdi_io_err("cfdi_run: the drive refused a frame\n");
            cfdi_io_close(in.handle);
            return 1;
        }
        while (cfdi_drive_poll_event(drive, &ev) == 1) {
            take_event(&ev, rs, list, &first);
        }
        /* What the monitor sends, as the MCU would after each frame (here: printed). */
        while (cfdi_drive_poll_tx(drive, &out) == 1) {
            if (list < 0) {
                out_sent(&out, n->sent);
            }
            n->sent++;
        }
    }
    cfdi_io_close(in.handle);
    if (got < 0 || cfdi_drive_finish(drive) < 0) {
        cfdi_io_err(got < 0 ? "cfdi_run: reading the log failed\n"
                            : "cfdi_run: finishing failed\n");
        return 1;
    }
    while (cfdi_drive_poll_event(drive, &ev) == 1) {
        take_event(&ev, rs, list, &first);
    }
    while (cfdi_drive_poll_tx(drive, &out) == 1) {
        if (list < 0) {
            out_sent(&out, n->sent);
        }
        n->sent++;
    }
    return 0;
}

int cfdi_run_main(void)
{
    static uint64_t memory[(CFDI_GEN_MEMORY + 7) / 8];
    static cfdi_drive drive;
    static const char *const lists[] = {"faults", "named", "unexplained", "refined"};
    static const int32_t kinds[] = {CFDI_EVENT_ACCEPTED, CFDI_EVENT_NAMED,
                                    CFDI_EVENT_UNEXPLAINED, CFDI_EVENT_REFINED};
    run_events rs, again;
    run_counts n, n_again;
    uint64_t valid = 0, invalid = 0;
    char *argv[4];
    int argc = 0, first, asc, len;
    long in_handle;
    size_t i;
    if (cfdi_io_args(&argc, argv, 4) != 0 || argc != 2) {
        cfdi_io_err("usage: cfdi_run LOG (a candump -L .log, or a Vector .asc)\n");
        return 2;
    }
    len = (int)strlen(argv[1]);
    asc = len >= 4 && memcmp(argv[1] + len - 4, ".asc", 4) == 0;
    in_handle = cfdi_io_open(argv[1]); /* (an error before any output: no half a JSON) */
    if (in_handle < 0) {
        cfdi_io_err("cfdi_run: cannot open the log\n");
        return 2;
    }
    cfdi_io_close(in_handle);
    cfdi_io_out("{\"sent\": [");
    if (run_log(&drive, memory, sizeof memory, argv[1], asc, -1, &rs, &n) != 0) {
        return 1;
    }
    cfdi_io_out("], \"drive\": ");
    out_name(cfdi_drive_name);
    for (i = 0; i < 4; i++) {
        cfdi_io_out(", ");
        out_name(lists[i]);
        cfdi_io_out(": [");
        if (rs.counts[kinds[i]] > 0
            && run_log(&drive, memory, sizeof memory, argv[1], asc, kinds[i], &again,
                       &n_again) != 0) {
            return 1;
        }
        cfdi_io_out("]");
    }
    for (i = 0; i < CFDI_N_STATUS; i++) {
        if (cfdi_drive_tables_gen.valid_status[i]) valid += drive.status_count[i];
        else invalid += drive.status_count[i];
    }
    cfdi_io_out(", \"mismatches\": [], \"quiet\": [], \"detections\": ");
    out_u64(rs.counts[CFDI_EVENT_DETECTED]);
    cfdi_io_out(", \"samples\": ");
    out_u64(drive.samples_taken);
    cfdi_io_out(", \"frames\": {\"received\": ");
    out_u64(valid + invalid);
    cfdi_io_out(", \"valid\": ");
    out_u64(valid);
    cfdi_io_out(", \"invalid\": ");
    out_u64(invalid);
    cfdi_io_out(", \"invalid_by_reason\": {");
    for (i = 0, first = 1; i < CFDI_N_STATUS; i++) {
        if (!cfdi_drive_tables_gen.valid_status[i]) {
            cfdi_io_out(first ? "" : ", ");
            out_name(cfdi_status_names[i]);
            cfdi_io_out(": ");
            out_u64(drive.status_count[i]);
            first = 0;
        }
    }
    cfdi_io_out("}, \"samples_complete\": ");
    out_i64(drive.ctr[CFDI_CTR_COMPLETE]);
    cfdi_io_out(", \"samples_broken\": ");
    out_i64(drive.ctr[CFDI_CTR_BROKEN]);
    cfdi_io_out(", \"samples_missing\": ");
    out_i64(drive.ctr[CFDI_CTR_MISSING]);
    cfdi_io_out(", \"clock_steps\": ");
    out_i64(drive.clock_steps);
    cfdi_io_out("}, \"residuals\": [");
    for (i = 0; i < CFDI_GEN_M; i++) {
        cfdi_io_out(i ? ", " : "");
        out_name(cfdi_residual_names[i]);
    }
    cfdi_io_out("], \"frames_sent\": ");
    out_u64(n.sent);
    cfdi_io_out(", \"frames_not_sent\": ");
    out_u64(drive.tx_dropped);
    cfdi_io_out(", \"events_not_listed\": ");
    out_u64(drive.events_dropped);
    cfdi_io_out(", \"lines\": ");
    out_u64(n.lines);
    cfdi_io_out(", \"malformed_lines\": ");
    out_u64(n.malformed);
    cfdi_io_out(", \"memory\": ");
    out_u64(cfdi_drive_memory_size(&cfdi_drive_tables_gen));
#ifdef CFDI_TICK_INSNS
    /* instructions in the drive loop over the first run (ticks of CFDI_TICK_INSNS instructions
     * each: qemu's -icount): per sample on average, while monitoring before the first alarm,
     * while monitoring with accepted faults tracked; the costliest frame that raised an alarm
     * (the diagnosis started: a share of the kept samples fitted), of a diagnosis after it,
     * and of all */
    cfdi_io_out(", \"instructions\": {\"per_sample\": ");
    out_u64(drive.samples_taken ? n.ticks * CFDI_TICK_INSNS / drive.samples_taken : 0);
    cfdi_io_out(", \"per_monitored_sample\": ");
    out_u64(n.monitor_samples ? n.monitor_ticks * CFDI_TICK_INSNS / n.monitor_samples : 0);
    cfdi_io_out(", \"per_tracked_sample\": ");
    out_u64(n.tracked_samples ? n.tracked_ticks * CFDI_TICK_INSNS / n.tracked_samples : 0);
    cfdi_io_out(", \"alarm_frame\": ");
    out_u64((uint64_t)n.alarm_tick * CFDI_TICK_INSNS);
    cfdi_io_out(", \"worst_diagnosed_frame\": ");
    out_u64((uint64_t)n.diag_worst * CFDI_TICK_INSNS);
    cfdi_io_out(", \"worst_frame\": ");
    out_u64((uint64_t)n.worst * CFDI_TICK_INSNS);
    cfdi_io_out(", \"resolution\": ");
    out_u64(CFDI_TICK_INSNS);
    cfdi_io_out("}");
#endif
    cfdi_io_out("}\n");
    return 0;
}

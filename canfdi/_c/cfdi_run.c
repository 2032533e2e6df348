/* The runner of a generated project (`canfdi codegen`): reads a candump -L log (can-utils'
 * format, as python-can reads it), feeds every frame to the drive's monitor (drive.h) and
 * prints what it found as JSON, in the form `canfdi replay --json` gives it (detections,
 * samples, frames). The same file runs on the host (cfdi_io_host.c) and on the MCU through
 * semihosting (cfdi_io_semihost.c); it parses and formats numbers itself, so the MCU's image
 * needs nothing of the C library's I/O and never allocates.
 *
 * A harness, not the core. */
#include <float.h>
#include <stdint.h>
#include <string.h>

#include "cfdi_io.h"
#include "cfdi_tables.h"
#include "drive.h"

#define LINE 512
#define SENT_KEPT 8 /* the frames sent that the JSON lists (all are counted) */

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

/* An ASC CAN FD line after "CANFD", as python-can's _process_fd_can_frame reads it: channel,
 * direction, "ErrorFrame" or the ID (x: extended), a symbolic name unless the next token is a
 * number, BRS, ESI, the DLC (in the log's base), the data length (decimal: 0 for a remote
 * request, whose length is then its DLC; else the frame's length, whatever the DLC says) and
 * that many bytes. 1 parsed, -1 malformed. */
static int parse_asc_fd(const char *p, int base, uint32_t *id, uint8_t *len, uint8_t *flags,
                        uint8_t *data)
{
    const char *end, *next, *brs;
    uint32_t value, dlc, length;
    size_t n = 0;
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
    *len = (uint8_t)length;
    while (n < length && parse_uint(p, base, &end, &value)) {
        if (value > 255) return -1;
        data[n++] = (uint8_t)value;
        p = skip_blank(end);
    }
    for (; n < CFDI_MAX_PAYLOAD; n++) data[n] = 0;
    return 1;
}

/* One line of a Vector ASC log, as python-can's ASCReader takes it: "<seconds> <channel> <ID>[x]
 * Rx|Tx d <DLC> <bytes>", "... r [DLC]" for a remote request, "<seconds> <channel>
 * ErrorFrame"; a CAN FD frame "<seconds> CANFD <channel> Rx|Tx <ID>[x] [<name>] <BRS> <ESI>
 * <DLC> <data length> <bytes>" (parse_asc_fd); the header's "base hex|dec" sets *base. Every
 * other line (the header, comments, events, statistics) is no frame, as it is to python-can.
 * 1 parsed, 0 no frame, -1 malformed. */
static int parse_asc_line(const char *line, int *base, uint32_t *id, uint8_t *len,
                          uint8_t *flags, uint8_t *data, int64_t *t_ns)
{
    const char *p = skip_blank(line), *end;
    uint32_t value, dlc;
    size_t n = 0;
    if (strncmp(p, "base ", 5) == 0) {
        p = skip_blank(p + 5);
        *base = strncmp(p, "dec", 3) == 0 ? 10 : 16;
        return 0;
    }
    if (!parse_time(p, &end, t_ns) || (*end != ' ' && *end != '\t')) return 0;
    p = skip_blank(end);
    if (strncmp(p, "CANFD", 5) == 0 && (p[5] == ' ' || p[5] == '\t')) {
        return parse_asc_fd(skip_blank(p + 5), *base, id, len, flags, data);
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
    *len = dlc_length(dlc);
    p = skip_blank(end);
    while (n < (*len < 8 ? *len : 8) && parse_uint(p, *base, &end, &value)) {
        if (value > 255) return -1;
        data[n++] = (uint8_t)value;
        p = skip_blank(end);
    }
    for (; n < CFDI_MAX_PAYLOAD; n++) data[n] = 0;
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

/* The log's lines one by one, from chunks: a line longer than the buffer is skipped whole
 * (returned as "" with *overlong set). 1 a line, 0 the end, -1 a read error. */
typedef struct {
    long handle;
    char chunk[1024];
    size_t at, have;
    int eof;
} lines_t;

static int next_line(lines_t *in, char *line, size_t size, int *overlong)
{
    size_t n = 0;
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
            line[*overlong ? 0 : n] = '\0';
            return 1;
        }
        if (n + 1 < size) {
            line[n++] = c;
        } else {
            *overlong = 1;
        }
    }
    line[*overlong ? 0 : n] = '\0';
    return n > 0 || *overlong ? 1 : 0;
}

/* A diagnosis' decision as `canfdi replay --json` lists its events: kind, sample, the
 * channel (target, index, name), the onset and the estimates. */
static void out_event(const cfdi_event *e, int first)
{
    static const char *const kinds[] = {"", "named", "accepted", "unexplained"};
    cfdi_io_out(first ? "{\"kind\": " : ", {\"kind\": ");
    out_name(kinds[e->event]);
    cfdi_io_out(", \"sample\": ");
    out_i64(e->sample);
    if (e->target != 0) {
        cfdi_io_out(e->target == 1 ? ", \"target\": \"actuator\", \"index\": "
                                   : ", \"target\": \"sensor\", \"index\": ");
        out_i64(e->index);
        cfdi_io_out(", \"name\": ");
        out_name(e->target == 1 ? cfdi_input_names[e->index] : cfdi_output_names[e->index]);
        cfdi_io_out(", \"onset_sample\": ");
        out_i64(e->onset);
        cfdi_io_out(", \"estimates\": {");
        if (e->target == 2) {
            cfdi_io_out("\"bias\": ");
        } else if (e->eta == e->eta) {
            cfdi_io_out("\"eta\": ");
            out_real((double)e->eta);
            cfdi_io_out(", \"lambda\": ");
        } else {
            cfdi_io_out("\"lambda\": ");
        }
        out_real((double)e->value);
        cfdi_io_out("}");
    }
    cfdi_io_out("}");
}

int cfdi_run_main(void)
{
    static double values[CFDI_GEN_VWIDTH], buffer[CFDI_GEN_WIDTH], samples[2 * CFDI_GEN_WIDTH];
    static cfdi_real ring[(CFDI_GEN_S + 1) * CFDI_GEN_WIDTH], r[CFDI_GEN_M], ph[2 * CFDI_GEN_M];
    static cfdi_real g_up[CFDI_GEN_M], g_down[CFDI_GEN_M];
    static int64_t last_zero[2 * CFDI_GEN_M];
    static int8_t alarm[CFDI_GEN_M];
    /* the diagnosis' */
    static cfdi_real recent[(CFDI_GEN_LOOKBACK + CFDI_GEN_S + 1) * CFDI_GEN_WIDTH];
    static cfdi_real window[(CFDI_GEN_S + 1) * CFDI_GEN_WIDTH], U[(CFDI_GEN_S + 1) * CFDI_GEN_P];
    static cfdi_real rn[CFDI_GEN_M], work[CFDI_INFO_WORK(CFDI_GEN_M, CFDI_GEN_D)];
    static int64_t onsets[CFDI_GEN_K], best_onset[CFDI_GEN_H], order[CFDI_GEN_H];
    static cfdi_real J[CFDI_GEN_H * CFDI_GEN_K * CFDI_GEN_D * CFDI_GEN_D];
    static cfdi_real meat[CFDI_GEN_H * CFDI_GEN_K * CFDI_GEN_D * CFDI_GEN_D];
    static cfdi_real P[CFDI_GEN_H * CFDI_GEN_K * CFDI_GEN_D * CFDI_GEN_D];
    static cfdi_real h[CFDI_GEN_H * CFDI_GEN_K * CFDI_GEN_D];
    static cfdi_real theta[CFDI_GEN_H * CFDI_GEN_K * CFDI_GEN_D];
    static cfdi_real rr[CFDI_GEN_H * CFDI_GEN_K], cost[CFDI_GEN_H * CFDI_GEN_K];
    static cfdi_real lu[CFDI_GEN_D * CFDI_GEN_D], u_abs[CFDI_GEN_P], n_u[CFDI_GEN_P];
    static cfdi_real cost_h[CFDI_GEN_H];
    static size_t perm[CFDI_GEN_D];
    static uint8_t near[CFDI_GEN_H];
    static int32_t leftover[CFDI_GEN_H];
    static cfdi_drive drive;
    static lines_t in;
    static char line[LINE];
    const cfdi_drive_memory mem = {values, buffer, samples, ring, r, ph, last_zero, g_up,
                                   g_down, alarm,
                                   {recent, window, U, rn, onsets, J, meat, P, h, theta, rr,
                                    cost, lu, perm, work, u_abs, n_u, best_onset, order,
                                    cost_h, near, leftover}};
    uint8_t data[CFDI_MAX_PAYLOAD];
    uint64_t lines = 0, malformed = 0, valid = 0, invalid = 0;
#ifdef CFDI_TICK_INSNS
    uint32_t tick, worst = 0, alarm_tick = 0, diag_worst = 0;
    uint64_t ticks = 0, monitor_ticks = 0, monitor_samples = 0;
    int was_alarmed, was_diagnosing;
#endif
    static cfdi_tx_frame sent[SENT_KEPT];
    cfdi_tx_frame out;
    uint64_t n_sent = 0;
    char *argv[4];
    int argc = 0, rc, first, overlong, got, asc, base = 16;
    size_t i;
    if (cfdi_io_args(&argc, argv, 4) != 0 || argc != 2) {
        cfdi_io_err("usage: cfdi_run LOG (a candump -L .log, or a Vector .asc)\n");
        return 2;
    }
    rc = cfdi_drive_init(&drive, &cfdi_drive_tables_gen, &mem);
    if (rc != CFDI_OK) {
        cfdi_io_err("cfdi_run: the generated tables do not check\n");
        return 1;
    }
    got = (int)strlen(argv[1]);
    asc = got >= 4 && strcmp(argv[1] + got - 4, ".asc") == 0;
    in.handle = cfdi_io_open(argv[1]);
    if (in.handle < 0) {
        cfdi_io_err("cfdi_run: cannot open the log\n");
        return 1;
    }
    while ((got = next_line(&in, line, sizeof line, &overlong)) > 0) {
        uint32_t id = 0;
        uint8_t len = 0, flags = 0;
        int64_t t_ns = 0;
        lines++;
        rc = overlong ? -1
             : asc ? parse_asc_line(line, &base, &id, &len, &flags, data, &t_ns)
                   : parse_line(line, &id, &len, &flags, data, &t_ns);
        if (rc < 0) {
            malformed++;
            continue;
        }
        if (rc == 0) continue;
#ifdef CFDI_TICK_INSNS
        was_alarmed = drive.alarmed;
        was_diagnosing = drive.diagnosing;
        tick = cfdi_io_ticks();
        rc = cfdi_drive_on_frame(&drive, id, len, flags, data, t_ns);
        tick = (cfdi_io_ticks() - tick) & 0xFFFFFFu;
        ticks += tick;
        worst = tick > worst ? tick : worst;
        if (!was_alarmed && drive.alarmed) {
            alarm_tick = tick;
        } else if (was_diagnosing) {
            diag_worst = tick > diag_worst ? tick : diag_worst;
        }
        if (!was_alarmed && !drive.alarmed) {
            monitor_ticks += tick;
            monitor_samples = drive.samples;
        }
#else
        rc = cfdi_drive_on_frame(&drive, id, len, flags, data, t_ns);
#endif
        if (rc < 0) {
            cfdi_io_err("cfdi_run: the drive refused a frame\n");
            cfdi_io_close(in.handle);
            return 1;
        }
        /* What the monitor sends, as the MCU would after each frame (here: printed). */
        while (cfdi_drive_poll_tx(&drive, &out) == 1) {
            if (n_sent < SENT_KEPT) {
                sent[n_sent] = out;
            }
            n_sent++;
        }
    }
    cfdi_io_close(in.handle);
    if (got < 0 || cfdi_drive_finish(&drive) < 0) {
        cfdi_io_err(got < 0 ? "cfdi_run: reading the log failed\n"
                            : "cfdi_run: finishing failed\n");
        return 1;
    }
    for (i = 0; i < CFDI_N_STATUS; i++) {
        if (cfdi_status_valid[i]) valid += drive.status_count[i];
        else invalid += drive.status_count[i];
    }
    cfdi_io_out("{\"drive\": ");
    out_name(cfdi_drive_name);
    cfdi_io_out(", \"detections\": [");
    if (drive.alarmed) {
        cfdi_io_out("{\"sample\": ");
        out_i64(drive.alarm_k);
        cfdi_io_out(", \"onset_sample\": ");
        out_i64(drive.alarm_onset);
        cfdi_io_out(", \"residuals\": [");
        for (i = 0, first = 1; i < CFDI_GEN_M; i++) {
            if (alarm[i] != 0) {
                cfdi_io_out(first ? "" : ", ");
                out_name(cfdi_residual_names[i]);
                first = 0;
            }
        }
        cfdi_io_out("]}");
    }
    cfdi_io_out("], \"faults\": [");
    for (i = 0; i < drive.n_events; i++) {
        out_event(&drive.events[i], i == 0);
    }
    cfdi_io_out("], \"samples\": ");
    out_u64(drive.samples);
    cfdi_io_out(", \"frames\": {\"received\": ");
    out_u64(valid + invalid);
    cfdi_io_out(", \"valid\": ");
    out_u64(valid);
    cfdi_io_out(", \"invalid\": ");
    out_u64(invalid);
    cfdi_io_out(", \"invalid_by_reason\": {");
    for (i = 0, first = 1; i < CFDI_N_STATUS; i++) {
        if (!cfdi_status_valid[i]) {
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
    cfdi_io_out("], \"sent\": [");
    for (i = 0; i < n_sent && i < SENT_KEPT; i++) {
        cfdi_io_out(i ? ", {\"id\": " : "{\"id\": ");
        out_u64(sent[i].id);
        cfdi_io_out(sent[i].extended ? ", \"extended\": true" : ", \"extended\": false");
        cfdi_io_out(", \"data\": \"");
        out_hex(sent[i].data, sent[i].len);
        cfdi_io_out("\"}");
    }
    cfdi_io_out("], \"frames_sent\": ");
    out_u64(n_sent);
    cfdi_io_out(", \"frames_not_sent\": ");
    out_u64(drive.tx_dropped);
    cfdi_io_out(", \"lines\": ");
    out_u64(lines);
    cfdi_io_out(", \"malformed_lines\": ");
    out_u64(malformed);
#ifdef CFDI_TICK_INSNS
    /* instructions in the drive loop (ticks of CFDI_TICK_INSNS instructions each: qemu's
     * -icount): per sample on average, and while monitoring (before the alarm); in the frame
     * that raised the alarm (the diagnosis started: the kept samples fitted), in the costliest
     * frame of the diagnosis after it, and in the costliest of all */
    cfdi_io_out(", \"instructions\": {\"per_sample\": ");
    out_u64(drive.samples ? ticks * CFDI_TICK_INSNS / drive.samples : 0);
    cfdi_io_out(", \"per_monitored_sample\": ");
    out_u64(monitor_samples ? monitor_ticks * CFDI_TICK_INSNS / monitor_samples : 0);
    cfdi_io_out(", \"alarm_frame\": ");
    out_u64((uint64_t)alarm_tick * CFDI_TICK_INSNS);
    cfdi_io_out(", \"worst_diagnosed_frame\": ");
    out_u64((uint64_t)diag_worst * CFDI_TICK_INSNS);
    cfdi_io_out(", \"worst_frame\": ");
    out_u64((uint64_t)worst * CFDI_TICK_INSNS);
    cfdi_io_out(", \"resolution\": ");
    out_u64(CFDI_TICK_INSNS);
    cfdi_io_out("}");
#endif
    cfdi_io_out("}\n");
    return 0;
}

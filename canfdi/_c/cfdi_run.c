/* The runner of a generated project (`canfdi codegen`): reads a candump -L log (can-utils'
 * format, as python-can reads it), feeds every frame to the drive's monitor (drive.h) and
 * prints what it found as JSON, in the form `canfdi replay --json` gives it (detections,
 * samples, frames). The same file runs on the host and, through semihosting, on the MCU.
 *
 * Not the core: this is the harness around it, so it may use <stdio.h> and <stdlib.h>. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "cfdi_tables.h"
#include "drive.h"

#define LINE 512

static int hex_digit(char c)
{
    if (c >= '0' && c <= '9') return c - '0';
    if (c >= 'a' && c <= 'f') return c - 'a' + 10;
    if (c >= 'A' && c <= 'F') return c - 'A' + 10;
    return -1;
}

/* One candump -L line: "(seconds) interface ID#DATA [R|T]", ID##F DATA for CAN FD, ID#R[n]
 * for a remote request. 1 parsed, 0 blank, -1 malformed. */
static int parse_line(char *line, uint32_t *id, uint8_t *len, uint8_t *flags, uint8_t *data,
                      int64_t *t_ns)
{
    char *p = line, *end, *frame, *hash;
    double seconds;
    unsigned long long raw;
    size_t digits, n = 0;
    while (*p == ' ' || *p == '\t') p++;
    if (*p == '\0' || *p == '\n' || *p == '\r') return 0;
    if (*p != '(') return -1;
    seconds = strtod(p + 1, &end);
    if (end == p + 1 || *end != ')') return -1;
    /* python-can: float seconds; canfdi: (seconds * 1e9) truncated to int64, and what int64
     * cannot hold (or NaN) is INT64_MIN, as numpy's conversion gives it on x86 */
    seconds *= 1e9;
    *t_ns = (seconds >= -9.223372036854775808e18 && seconds < 9.223372036854775808e18)
            ? (int64_t)seconds : INT64_MIN;
    p = end + 1;
    while (*p == ' ') p++;
    while (*p && *p != ' ') p++; /* the interface */
    while (*p == ' ') p++;
    frame = p;
    hash = strchr(frame, '#');
    if (!hash) return -1;
    digits = (size_t)(hash - frame);
    if (digits == 0 || digits > 8) return -1;
    raw = strtoull(frame, &end, 16);
    if (end != hash) return -1;
    *flags = digits > 3 ? CFDI_FLAG_EXTENDED : 0;
    if ((raw & 0x20000000ULL) && (raw & 0x80ULL)) { /* CAN_ERR_FLAG and CAN_ERR_BUSERROR */
        *id = 0;
        *flags = CFDI_FLAG_ERROR;
        *len = 0;
        return 1;
    }
    *id = (uint32_t)(raw & 0x1FFFFFFFULL);
    p = hash + 1;
    if (*p == '#') {
        *flags |= CFDI_FLAG_FD;
        if (hex_digit(p[1]) < 0) return -1;
        p += 2;
    }
    if (*p == 'R' || *p == 'r') {
        *flags |= CFDI_FLAG_REMOTE;
        *len = (uint8_t)(p[1] >= '0' && p[1] <= '9' ? atoi(p + 1) : 0);
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

static void print_names(const char *const *names, size_t n)
{
    size_t i;
    for (i = 0; i < n; i++) {
        printf("%s\"%s\"", i ? ", " : "", names[i]);
    }
}

int main(int argc, char **argv)
{
    static double values[CFDI_GEN_VWIDTH], buffer[CFDI_GEN_WIDTH], samples[2 * CFDI_GEN_WIDTH];
    static cfdi_real ring[(CFDI_GEN_S + 1) * CFDI_GEN_WIDTH], r[CFDI_GEN_M], ph[2 * CFDI_GEN_M];
    static cfdi_real g_up[CFDI_GEN_M], g_down[CFDI_GEN_M];
    static int64_t last_zero[2 * CFDI_GEN_M];
    static int8_t alarm[CFDI_GEN_M];
    static cfdi_drive drive;
    const cfdi_drive_memory mem = {values, buffer, samples, ring, r, ph, last_zero, g_up,
                                   g_down, alarm};
    char line[LINE];
    uint8_t data[CFDI_MAX_PAYLOAD];
    uint64_t lines = 0, malformed = 0, valid = 0, invalid = 0;
    size_t i;
    int rc, first;
    FILE *log;
    if (argc != 2) {
        fprintf(stderr, "usage: %s LOG (a candump -L log)\n", argc ? argv[0] : "cfdi_run");
        return 2;
    }
    rc = cfdi_drive_init(&drive, &cfdi_drive_tables_gen, &mem);
    if (rc != CFDI_OK) {
        fprintf(stderr, "cfdi_run: the generated tables do not check (%d)\n", rc);
        return 1;
    }
    log = fopen(argv[1], "r");
    if (!log) {
        fprintf(stderr, "cfdi_run: %s: cannot open\n", argv[1]);
        return 1;
    }
    while (fgets(line, sizeof line, log)) {
        uint32_t id = 0;
        uint8_t len = 0, flags = 0;
        int64_t t_ns = 0;
        lines++;
        if (!strchr(line, '\n') && !feof(log)) { /* longer than any candump line: skip it */
            int c;
            while ((c = fgetc(log)) != EOF && c != '\n') {}
            malformed++;
            continue;
        }
        rc = parse_line(line, &id, &len, &flags, data, &t_ns);
        if (rc < 0) {
            malformed++;
            continue;
        }
        if (rc == 0) continue;
        rc = cfdi_drive_on_frame(&drive, id, len, flags, data, t_ns);
        if (rc < 0) {
            fprintf(stderr, "cfdi_run: %s line %llu: the drive refused the frame (%d)\n",
                    argv[1], (unsigned long long)lines, rc);
            fclose(log);
            return 1;
        }
    }
    fclose(log);
    rc = cfdi_drive_finish(&drive);
    if (rc < 0) {
        fprintf(stderr, "cfdi_run: finishing failed (%d)\n", rc);
        return 1;
    }
    for (i = 0; i < CFDI_N_STATUS; i++) {
        if (cfdi_status_valid[i]) valid += drive.status_count[i];
        else invalid += drive.status_count[i];
    }
    printf("{\"drive\": \"%s\", \"detections\": [", cfdi_drive_name);
    if (drive.alarmed) {
        printf("{\"sample\": %lld, \"onset_sample\": %lld, \"residuals\": [",
               (long long)drive.alarm_k, (long long)drive.alarm_onset);
        for (i = 0, first = 1; i < CFDI_GEN_M; i++) {
            if (alarm[i] != 0) {
                printf("%s\"%s\"", first ? "" : ", ", cfdi_residual_names[i]);
                first = 0;
            }
        }
        printf("]}");
    }
    printf("], \"samples\": %llu, \"frames\": {\"received\": %llu, \"valid\": %llu, "
           "\"invalid\": %llu, \"invalid_by_reason\": {",
           (unsigned long long)drive.samples, (unsigned long long)(valid + invalid),
           (unsigned long long)valid, (unsigned long long)invalid);
    for (i = 0, first = 1; i < CFDI_N_STATUS; i++) {
        if (!cfdi_status_valid[i]) {
            printf("%s\"%s\": %llu", first ? "" : ", ", cfdi_status_names[i],
                   (unsigned long long)drive.status_count[i]);
            first = 0;
        }
    }
    printf("}, \"samples_complete\": %lld, \"samples_broken\": %lld, \"samples_missing\": %lld, "
           "\"clock_steps\": %lld}, \"residuals\": [",
           (long long)drive.ctr[CFDI_CTR_COMPLETE], (long long)drive.ctr[CFDI_CTR_BROKEN],
           (long long)drive.ctr[CFDI_CTR_MISSING], (long long)drive.clock_steps);
    print_names(cfdi_residual_names, CFDI_GEN_M);
    printf("], \"lines\": %llu, \"malformed_lines\": %llu}\n", (unsigned long long)lines,
           (unsigned long long)malformed);
    return 0;
}

/* cfdi_io.h on an MCU through Arm semihosting (the debugger's or qemu's
 * -semihosting-config enable=on): files and the console of the host, no C library I/O. */
#include <stdint.h>
#include <string.h>

#include "cfdi_io.h"

enum { SYS_OPEN = 0x01, SYS_CLOSE = 0x02, SYS_WRITE0 = 0x04, SYS_WRITE = 0x05,
       SYS_READ = 0x06, SYS_GET_CMDLINE = 0x15 };

#define SYST_CSR (*(volatile uint32_t *)0xE000E010u)
#define SYST_RVR (*(volatile uint32_t *)0xE000E014u)
#define SYST_CVR (*(volatile uint32_t *)0xE000E018u)

static long semihost(long op, void *arg)
{
    register long r0 __asm__("r0") = op;
    register void *r1 __asm__("r1") = arg;
    __asm__ volatile("bkpt 0xAB" : "+r"(r0) : "r"(r1) : "memory");
    return r0;
}

uint32_t cfdi_io_ticks(void)
{
    return 0xFFFFFFu - (SYST_CVR & 0xFFFFFFu); /* SysTick counts down */
}

int cfdi_io_args(int *argc, char **argv, int max)
{
    static char line[256];
    uintptr_t block[2];
    char *p = line;
    int n = 0;
    SYST_RVR = 0xFFFFFFu; /* SysTick free-running on the CPU clock (cfdi_io_ticks) */
    SYST_CVR = 0;
    SYST_CSR = 5u;
    block[0] = (uintptr_t)line;
    block[1] = sizeof line - 1;
    if (semihost(SYS_GET_CMDLINE, block) != 0) {
        *argc = 0;
        return -1;
    }
    line[block[1] < sizeof line ? block[1] : sizeof line - 1] = '\0';
    while (*p && n < max) {
        while (*p == ' ') *p++ = '\0';
        if (!*p) break;
        argv[n++] = p;
        while (*p && *p != ' ') p++;
    }
    *argc = n;
    return 0;
}

long cfdi_io_open(const char *path)
{
    uintptr_t block[3];
    block[0] = (uintptr_t)path;
    block[1] = 1; /* "rb" */
    block[2] = strlen(path);
    return semihost(SYS_OPEN, block);
}

long cfdi_io_read(long handle, char *buf, size_t n)
{
    uintptr_t block[3];
    long left;
    block[0] = (uintptr_t)handle;
    block[1] = (uintptr_t)buf;
    block[2] = n;
    left = semihost(SYS_READ, block); /* the bytes NOT read */
    return left < 0 || (size_t)left > n ? -1 : (long)(n - (size_t)left);
}

void cfdi_io_close(long handle)
{
    uintptr_t block[1];
    block[0] = (uintptr_t)handle;
    semihost(SYS_CLOSE, block);
}

void cfdi_io_out(const char *text)
{
    semihost(SYS_WRITE0, (void *)text);
}

void cfdi_io_err(const char *text)
{
    /* the host's stderr: ":tt" opened for appending (the semihosting spec's mode 8) */
    static long handle = -1;
    uintptr_t block[3];
    if (handle < 0) {
        block[0] = (uintptr_t)":tt";
        block[1] = 8;
        block[2] = 3;
        handle = semihost(SYS_OPEN, block);
    }
    if (handle < 0) {
        semihost(SYS_WRITE0, (void *)text); /* (no stderr: the console) */
        return;
    }
    block[0] = (uintptr_t)handle;
    block[1] = (uintptr_t)text;
    block[2] = strlen(text);
    semihost(SYS_WRITE, block);
}

int cfdi_run_main(void);

int main(void)
{
    return cfdi_run_main();
}

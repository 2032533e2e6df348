/* Reset and vector table of the Cortex-M4F image (`make cortex-m4f` of a generated project;
 * qemu's mps2-an386 board): the FPU enabled, .data copied, .bss cleared, the free RAM painted,
 * main run, the stack it used (the deepest word no longer paint) said on stderr, its status
 * handed to the host through semihosting. A fault ends the run with status 3. Not the core. */
#include <stdint.h>
#include <string.h>

#include "cfdi_io.h"

#define PAINT 0xC5FD1C5Fu

extern uint32_t __data_load[], __data_start[], __data_end[], __bss_start[], __bss_end[],
    __stack_top[];
int main(void);

static void semihost_exit(int status)
{
    /* SYS_EXIT_EXTENDED: ADP_Stopped_ApplicationExit with the status */
    static uint32_t block[2];
    register uint32_t r0 __asm__("r0") = 0x20;
    register uint32_t *r1 __asm__("r1") = block;
    block[0] = 0x20026;
    block[1] = (uint32_t)status;
    __asm__ volatile("bkpt 0xAB" : "+r"(r0) : "r"(r1) : "memory");
    for (;;) {
    }
}

/* The free RAM below this frame painted, that stack_used finds what main's calls wrote. */
static void paint(void)
{
    uint32_t *w, *sp;
    __asm__ volatile("mov %0, sp" : "=r"(sp));
    for (w = __bss_end; w + 16 < sp; w++) {
        *w = PAINT;
    }
}

/* Says on stderr how deep the stack went (from its top to the lowest word not paint), and
 * passes main's status on. */
static int stack_used(int status)
{
    char text[48] = "stack used ", digits[12];
    const uint32_t *w = __bss_end;
    uint32_t used;
    size_t n = 0, at = strlen(text);
    while (w < __stack_top && *w == PAINT) {
        w++;
    }
    used = (uint32_t)((const char *)__stack_top - (const char *)w);
    do {
        digits[n++] = (char)('0' + used % 10);
        used /= 10;
    } while (used > 0 && n < sizeof digits);
    while (n > 0) {
        text[at++] = digits[--n];
    }
    memcpy(text + at, " bytes (measured)\n", 19);
    cfdi_io_err(text);
    return status;
}

void cfdi_reset(void)
{
    volatile uint32_t *cpacr = (volatile uint32_t *)0xE000ED88u;
    *cpacr |= 0xFu << 20; /* CP10, CP11: full access to the FPU */
    __asm__ volatile("dsb\n\tisb" ::: "memory");
    memcpy(__data_start, __data_load, (size_t)((char *)__data_end - (char *)__data_start));
    memset(__bss_start, 0, (size_t)((char *)__bss_end - (char *)__bss_start));
    paint();
    semihost_exit(stack_used(main()));
}

void cfdi_fault(void)
{
    semihost_exit(3);
}

__attribute__((section(".vectors"), used)) static void (*const vectors[16])(void) = {
    (void (*)(void))(uintptr_t)__stack_top, cfdi_reset, cfdi_fault, cfdi_fault, cfdi_fault,
    cfdi_fault, cfdi_fault, 0, 0, 0, 0, cfdi_fault, cfdi_fault, 0, cfdi_fault, cfdi_fault,
};

/* The runner's input and output (cfdi_run.c): a file read in chunks, text written, the
 * command line. Two sides: cfdi_io_host.c (the C library's stdio, on a host) and
 * cfdi_io_semihost.c (Arm semihosting, on an MCU under a debugger or qemu: no C library
 * I/O, so no allocation). A harness, not the core. */
#ifndef CFDI_IO_H
#define CFDI_IO_H

#include <stddef.h>
#include <stdint.h>

/* The program's arguments: *argc of them into argv (at most max), 0 or a negative status. */
int cfdi_io_args(int *argc, char **argv, int max);
/* Open a file to read: a handle >= 0, or negative. */
long cfdi_io_open(const char *path);
/* Read up to n bytes: the count read (0 at the end), or negative. */
long cfdi_io_read(long handle, char *buf, size_t n);
void cfdi_io_close(long handle);
/* Write text to the standard output (out) or error (err). */
void cfdi_io_out(const char *text);
void cfdi_io_err(const char *text);
/* A free-running tick count, 24 bits (the MCU's SysTick at its CPU clock; 0 on a host): the
 * runner's instruction count under qemu -icount (built with CFDI_TICK_INSNS). */
uint32_t cfdi_io_ticks(void);

#endif

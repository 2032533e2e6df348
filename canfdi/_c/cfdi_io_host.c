/* cfdi_io.h on a host: the C library's stdio. */
#include <stdio.h>

#include "cfdi_io.h"

#define HANDLES 4
static FILE *files[HANDLES]; /* the runner's open files (a harness, not the core) */
static int host_argc;
static char **host_argv;

int cfdi_io_args(int *argc, char **argv, int max)
{
    int i;
    for (i = 0; i < host_argc && i < max; i++) {
        argv[i] = host_argv[i];
    }
    *argc = i;
    return 0;
}

long cfdi_io_open(const char *path)
{
    long h;
    for (h = 0; h < HANDLES; h++) {
        if (!files[h]) {
            files[h] = fopen(path, "rb");
            return files[h] ? h : -1;
        }
    }
    return -1;
}

long cfdi_io_read(long handle, char *buf, size_t n)
{
    size_t got;
    if (handle < 0 || handle >= HANDLES || !files[handle]) return -1;
    got = fread(buf, 1, n, files[handle]);
    return ferror(files[handle]) ? -1 : (long)got;
}

void cfdi_io_close(long handle)
{
    if (handle >= 0 && handle < HANDLES && files[handle]) {
        fclose(files[handle]);
        files[handle] = NULL;
    }
}

void cfdi_io_out(const char *text)
{
    fputs(text, stdout);
}

void cfdi_io_err(const char *text)
{
    fputs(text, stderr);
}

uint32_t cfdi_io_ticks(void)
{
    return 0;
}

int cfdi_run_main(void);

int main(int argc, char **argv)
{
    host_argc = argc;
    host_argv = argv;
    return cfdi_run_main();
}

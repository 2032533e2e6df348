/* The binary stdin/stdout plumbing the C test drivers of this folder share (e2e_main.c,
 * encode_main.c): a driver may use stdio and malloc; the core it tests may not. A short read
 * or a failed allocation ends the driver with a status of its own (3, 4), which the Python
 * side reports. */
#ifndef DRIVER_IO_H
#define DRIVER_IO_H

#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>

static void put(int64_t v)
{
    fwrite(&v, sizeof v, 1, stdout);
}

/* 1 when count items were read, 0 at a clean end of the input; exits on a partial read. */
static int read_exact(void *p, size_t size, size_t count, int may_end)
{
    size_t got = fread(p, size, count, stdin);
    if (got == count) {
        return 1;
    }
    if (may_end && got == 0 && feof(stdin)) {
        return 0;
    }
    exit(3);
}

/* size bytes (at least 1) from the heap, exactly: a read one past them is caught by ASan. */
static void *must_alloc(size_t size)
{
    void *p = malloc(size > 0 ? size : 1);
    if (p == NULL) {
        exit(4);
    }
    return p;
}

#endif

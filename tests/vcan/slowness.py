"""How much slower than the machine that started it the vcan tests' machine runs Python.

A few vcan tests bound a time that the product promises on real hardware (SIGTERM ends `canfdi
run` within a second). Inside `deploy/vcan-harness`'s qemu, on a software CPU, every
instruction costs several times more, and so does that second. The harness times a Python loop
on the host before it boots (``VCAN_HARNESS_HOST_CPU_S``); here the same loop is timed again, and
the ratio scales those bounds. On the host itself, or without that variable, the factor is 1.
"""

from __future__ import annotations

import functools
import os
import time

__all__ = ["slowness"]


def _seconds() -> float:
    """The best of three times of the loop deploy/vcan-harness times on the host."""
    best = float("inf")
    for _ in range(3):
        start = time.perf_counter()
        sum(i * i for i in range(2_000_000))
        best = min(best, time.perf_counter() - start)
    return best


@functools.cache
def slowness() -> float:
    """This machine's time for the loop over the host's (at least 1.0)."""
    host = os.environ.get("VCAN_HARNESS_HOST_CPU_S")
    if not host:
        return 1.0
    return max(1.0, _seconds() / float(host))

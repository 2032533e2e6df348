"""Waiting for `canfdi run` to have read what the bus carried, before it is stopped."""

from __future__ import annotations

import time
from pathlib import Path

from canfdi.io.reader import read_frames
from tests.vcan.slowness import slowness

__all__ = ["drain"]


def drain(log: Path, expected: int | None = None, timeout: float = 600.0) -> int:
    """Wait until the monitor's log holds ``expected`` received frames (None: any number), or
    until the received frames in it have not grown for a while (at least 2 s; its own
    FDI_STATUS goes on each second): a slow machine (the harness's software CPU) leaves it
    seconds behind the bus after a diagnosis, and SIGTERM closes the bus before the frames
    still in its socket are read. Returns the count reached."""
    quiet = max(2.0, 3.0 * slowness())
    count, start = received(log), time.monotonic()
    since = start
    while ((expected is None or count < expected) and time.monotonic() - since < quiet
           and time.monotonic() - start < timeout):
        time.sleep(1.0)
        now = received(log)
        if now != count:
            count, since = now, time.monotonic()
    return count


def received(log: Path) -> int:
    """Frames the log holds so far that the monitor received (it flushes each second)."""
    return read_frames(log).received().size if log.exists() else 0

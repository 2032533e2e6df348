"""candump as the vcan tests' outside witness: a large socket receive buffer, so that it does
not drop frames itself when the harness's software CPU lets it fall behind, and the kernel's
count of the frames it dropped all the same, so that a test can tell a witness with a hole
from a monitor with one (issue 40)."""

from __future__ import annotations

import time
from pathlib import Path

__all__ = ["CANDUMP_BUFFER", "candump_command", "caught_up", "dropped", "frames"]

CANDUMP_BUFFER = 8 << 20  # bytes of candump's socket receive buffer: ~100 s of these buses


def candump_command(interface: str = "vcan0") -> list[str]:
    """`candump -L` with a forced receive buffer (``-r``) and the drop count (``-d``: a
    ``DROPCOUNT`` line in its output whenever the kernel dropped frames on its socket)."""
    return ["candump", "-L", "-d", "-r", str(CANDUMP_BUFFER), interface]


def frames(path: Path) -> list[tuple[float, int, str]]:
    """(kernel time, ID, data as candump wrote it: hex, or "R" for an RTR) of each frame of a
    `candump -L` log; a DROPCOUNT line, or a last line still being written, is none."""
    out = []
    for line in path.read_text().splitlines():
        parts = line.split()
        if len(parts) != 3 or "#" not in parts[2]:
            continue
        frame_id, _, data = parts[2].partition("#")
        out.append((float(parts[0].strip("()")), int(frame_id, 16), data))
    return out


def dropped(path: Path) -> int:
    """Frames the kernel dropped on candump's socket: the last DROPCOUNT total of its log."""
    totals = [int(line.rsplit("total drops ", 1)[1].rstrip(")"))
              for line in path.read_text().splitlines()
              if line.startswith("DROPCOUNT") and "total drops " in line]
    return max(totals, default=0)


def caught_up(path: Path, quiet: float = 3.0, limit: float = 300.0) -> None:
    """Wait until candump has read what its socket holds, before it is stopped: with a buffer
    this large a witness that fell behind would otherwise be stopped with frames still queued,
    unread and uncounted. Its log (block-buffered: it grows 4 KiB, about a hundred frames, at a
    time while candump reads, and candump is C: hundreds of frames a second even on the
    harness's software CPU) must not have grown for ``quiet`` seconds; at most ``limit``
    seconds. (Scaled by the harness's slowness, 15 there, the wait cost 9 minutes a suite.)"""
    deadline = time.monotonic() + limit
    size, still_since = -1, time.monotonic()
    while time.monotonic() < deadline:
        now = path.stat().st_size
        if now != size:
            size, still_since = now, time.monotonic()
        elif time.monotonic() - still_since >= quiet:
            return
        time.sleep(0.2)

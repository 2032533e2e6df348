"""candump as the vcan tests' outside witness: a large socket receive buffer, so that it does
not drop frames itself when the harness's software CPU lets it fall behind, and the kernel's
count of the frames it dropped all the same, so that a test can tell a witness with a hole
from a monitor with one (issue 40)."""

from __future__ import annotations

from pathlib import Path

__all__ = ["CANDUMP_BUFFER", "candump_command", "dropped"]

CANDUMP_BUFFER = 8 << 20  # bytes of candump's socket receive buffer: ~100 s of these buses


def candump_command(interface: str = "vcan0") -> list[str]:
    """`candump -L` with a forced receive buffer (``-r``) and the drop count (``-d``: a
    ``DROPCOUNT`` line in its output whenever the kernel dropped frames on its socket)."""
    return ["candump", "-L", "-d", "-r", str(CANDUMP_BUFFER), interface]


def dropped(path: Path) -> int:
    """Frames the kernel dropped on candump's socket: the last DROPCOUNT total of its log."""
    totals = [int(line.rsplit("total drops ", 1)[1].rstrip(")"))
              for line in path.read_text().splitlines()
              if line.startswith("DROPCOUNT") and "total drops " in line]
    return max(totals, default=0)

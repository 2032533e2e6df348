"""How long `canfdi run`'s logs are kept: `recording.keep_days` and `recording.keep_mib`.

A daemon records for months; its disk does not grow with it. The files concerned are those
`canfdi run` names itself in its log directory: ``<config name>-YYYYMMDD-HHMMSS.mcap`` and their
rotated segments (``...-0001.mcap``...). Nothing else in the directory is touched, and neither
is the segment being written. `expired` is the rule (pure); `prune_logs` applies it to a
directory.

The rule: every segment last written more than ``keep_days`` ago goes; then, while what is
left weighs more than ``keep_mib``, the oldest segment goes (oldest by modification time, ties
by name). A log whose first segments went is still read whole from what is left
(canfdi.io.segments.log_segments).
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

__all__ = ["LogFile", "expired", "prune_logs", "run_log_files"]

_DAY_S = 86_400.0


@dataclass(frozen=True)
class LogFile:
    """One segment file: its path, modification time (s since the epoch) and size (bytes)."""

    path: Path
    mtime: float
    size: int


def expired(files: Sequence[LogFile], now: float, keep_days: float | None,
            keep_bytes: int | None, current: Iterable[Path] = ()) -> list[LogFile]:
    """The files the retention rule removes, oldest first.

    Parameters
    ----------
    files : sequence of LogFile
        The run's log files.
    now : float
        The time now (s since the epoch).
    keep_days, keep_bytes : float or None, int or None
        The bounds (None: no bound of that kind).
    current : iterable of Path
        Files never removed (the segment being written), by name: ``files`` are of one
        directory.

    Examples
    --------
    >>> old, new = LogFile(Path("a.mcap"), 0.0, 10), LogFile(Path("b.mcap"), 9e5, 10)
    >>> [f.path.name for f in expired([new, old], now=1e6, keep_days=5, keep_bytes=None)]
    ['a.mcap']
    >>> [f.path.name for f in expired([new, old], now=1e6, keep_days=None, keep_bytes=15)]
    ['a.mcap']
    >>> gone = expired([new, old], now=1e6, keep_days=None, keep_bytes=15,
    ...                current=[Path("a.mcap")])
    >>> [f.path.name for f in gone]  # the file being written stays, whatever its age
    ['b.mcap']
    """
    keep = {p.name for p in current}
    candidates = sorted((f for f in files if f.path.name not in keep),
                        key=lambda f: (f.mtime, f.path.name))
    gone: list[LogFile] = []
    if keep_days is not None:
        limit = now - keep_days * _DAY_S
        gone = [f for f in candidates if f.mtime < limit]
    if keep_bytes is not None:
        left = sum(f.size for f in files) - sum(f.size for f in gone)
        for f in candidates[len(gone):]:
            if left <= keep_bytes:
                break
            gone.append(f)
            left -= f.size
    return gone


def run_log_files(directory: Path, name: str) -> list[LogFile]:
    """The segments of the logs `canfdi run` wrote for the config ``name`` in ``directory``
    (those it names itself); [] when the directory does not exist."""
    pattern = re.compile(re.escape(name) + r"-\d{8}-\d{6}(-\d{4,})?\.mcap\Z")
    found = []
    try:
        entries = list(os.scandir(directory))
    except FileNotFoundError:
        return []
    for entry in entries:
        if pattern.match(entry.name) and entry.is_file(follow_symlinks=False):
            info = entry.stat(follow_symlinks=False)
            found.append(LogFile(Path(entry.path), info.st_mtime, info.st_size))
    return found


def prune_logs(directory: Path, name: str, now: float, keep_days: float | None,
               keep_bytes: int | None, current: Iterable[Path] = ()) -> list[LogFile]:
    """Remove the run's expired log files from ``directory``; those removed (a file that
    vanished meanwhile is not counted; any other OSError propagates)."""
    removed = []
    for f in expired(run_log_files(directory, name), now, keep_days, keep_bytes, current):
        try:
            f.path.unlink()
        except FileNotFoundError:
            continue
        removed.append(f)
    return removed

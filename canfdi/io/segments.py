"""The files of a rotated log: segment names and `log_segments`.

A log recorded under ``run.mcap`` with rotation continues in ``run-0001.mcap``,
``run-0002.mcap``... next to it (canfdi.io.writer); `log_segments` lists the family in
recording order, and the readers read it whole.
"""

from __future__ import annotations

import re
from pathlib import Path

__all__ = ["log_segments", "numbered_segments", "segment_path"]


def segment_path(path: Path, index: int) -> Path:
    """The file of segment ``index`` of the log ``path`` (0: ``path`` itself)."""
    if index == 0:
        return path
    return path.with_name(f"{path.stem}-{index:04d}{path.suffix}")


def numbered_segments(path: Path) -> list[tuple[int, Path]]:
    """(number, file) of the existing segments after the first, ordered by number."""
    pattern = re.compile(re.escape(path.stem) + r"-(\d{4,})" + re.escape(path.suffix) + r"\Z")
    found = []
    try:
        entries = list(path.parent.iterdir())
    except FileNotFoundError:
        return []
    for entry in entries:
        match = pattern.match(entry.name)
        if match and int(match.group(1)) > 0:
            found.append((int(match.group(1)), entry))
    found.sort()
    return found


def log_segments(path: str | Path) -> list[Path]:
    """The files of a (possibly rotated) log, in recording order.

    Parameters
    ----------
    path : str or Path
        The name the log was recorded under (the first segment).

    Returns
    -------
    list of Path
        ``path`` if it exists, then ``<stem>-0001<suffix>``, ``<stem>-0002<suffix>``... that
        exist, ordered by number.
    """
    path = Path(path)
    head = [path] if path.exists() else []
    return head + [p for _, p in numbered_segments(path)]

"""Read one MCAP log file in file order: its messages (`read_log`) and its run-level metadata
(`read_metadata`); `log_files` names the files of a log to read.

Every read goes through canfdi.io.scan's `McapFile`, which checks each chunk's CRC, skips what
is damaged and resynchronises after it: a damaged log reads what is left of it, never raises
for the damage, and records what it lost in the canfdi.io.damage `Damage` given as
``damage=``.
"""

from __future__ import annotations

import errno
import logging
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

from canfdi.io.damage import Damage
from canfdi.io.scan import OP_CHUNK, OP_METADATA, McapFile
from canfdi.io.schemas import METADATA_NAME
from canfdi.io.segments import log_segments

__all__ = ["LogReader", "log_files", "read_log", "read_metadata"]

# The reader's logger, by the module its readers are imported from.
logger = logging.getLogger("canfdi.io.reader")


class LogReader:
    """Messages of one MCAP file in file order: an iterator of (topic, log_time ns, message).

    Walks the file with canfdi.io.scan's `McapFile` (no summary needed, no sorting), so it
    reads a file cut short by a killed writer as well as a complete one, up to its last sound
    record, and a damaged one around its damage (skipped, and recorded in ``damage``), without
    raising for either. After iteration, `messages_read`, `complete` and `truncated` describe
    what was found. Use `read_log` to make one.

    Parameters
    ----------
    path : str or Path
        The MCAP file.
    topics : iterable of str, optional
        Only these topics (all when None).
    damage : Damage, optional
        Where what is skipped is recorded (`damage`: a private one when None).

    Raises
    ------
    canfdi.io.scan.NotMcap
        While iterating, if the file is not an MCAP file.
    """

    def __init__(self, path: str | Path, topics: Iterable[str] | None = None,
                 damage: Damage | None = None) -> None:
        self.path = Path(path)
        self._topics = frozenset(topics) if topics is not None else None
        self.damage = damage if damage is not None else Damage()
        self.messages_read = 0
        self.complete = False
        self.truncated = False
        self._iterator = self._iterate()

    def __iter__(self) -> Iterator[tuple[str, int, dict[str, Any]]]:
        return self

    def __next__(self) -> tuple[str, int, dict[str, Any]]:
        return next(self._iterator)

    def close(self) -> None:
        """Stop early and close the file."""
        self._iterator.close()

    def _iterate(self) -> Iterator[tuple[str, int, dict[str, Any]]]:
        with McapFile(self.path, self.damage) as file:
            for item in file.messages(self._topics):
                self.messages_read += 1
                yield item
            self.complete, self.truncated = file.complete, file.truncated
        if self.truncated:
            logger.info("%s ends early (killed writer?): read %d messages up to the last "
                        "complete record", self.path, self.messages_read)


def read_log(path: str | Path, topics: Iterable[str] | None = None,
             damage: Damage | None = None) -> LogReader:
    """Read back one log file's messages, tolerating a truncated end and damage.

    Parameters
    ----------
    path : str or Path
        One MCAP file (for a rotated log, read each of `log_segments` in turn).
    topics : iterable of str, optional
        Only these topics (all when None).
    damage : Damage, optional
        Where what a damaged file lost is recorded.

    Returns
    -------
    LogReader
        An iterator of ``(topic, log_time_ns, message)`` in file order; its ``messages_read``,
        ``complete`` and ``truncated`` attributes tell what was found once it is exhausted.
    """
    return LogReader(path, topics, damage)


def read_metadata(path: str | Path, damage: Damage | None = None) -> dict[str, str]:
    """The run-level metadata (records named ``"canfdi"``) of one log file.

    Walks the file's records and stops at the first chunk after the metadata, where the
    recorder puts it; a truncated or damaged file is fine (a metadata record lost to damage is
    not there).

    Parameters
    ----------
    path : str or Path
        One MCAP file.
    damage : Damage, optional
        Where damage met on the way is recorded.

    Returns
    -------
    dict of str to str
        The metadata (merged in file order if there are several records); empty if none.

    Raises
    ------
    canfdi.io.scan.NotMcap
        The file is not an MCAP file.
    """
    found: dict[str, str] = {}
    seen = False
    with McapFile(path, damage) as file:
        # inflate=False: the message data is not needed, so chunks are not decompressed.
        for op, start, stop, _ in file.records(inflate=False):
            if op == OP_METADATA:
                name, values = file.fields(op, start, stop)
                if name == METADATA_NAME:
                    found.update(values)
                    seen = True
            elif seen and op == OP_CHUNK:
                break
    return found


def log_files(path: str | Path, segments: bool = True) -> list[Path]:
    """The segment files to read: ``path`` alone or its whole family (`log_segments`);
    FileNotFoundError if none exists."""
    if not segments:
        if not Path(path).exists():
            raise FileNotFoundError(errno.ENOENT, "no such log", str(path))
        return [Path(path)]
    segments_found = log_segments(path)
    if not segments_found:
        raise FileNotFoundError(errno.ENOENT, "no such log", str(path))
    return segments_found

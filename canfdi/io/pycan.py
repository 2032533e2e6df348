"""python-can's log readers and writers as FrameBlock readers and writers, gzip included.

Every format python-can reads and writes (``.asc``, ``.blf``, ``.log``, ``.trc``, ``.csv``,
``.db``, ``.mf4``) comes through its own reader and writer classes: `read_blocks` turns the
messages of a log into FrameBlocks (canfdi.bus.frames), `write_blocks` writes FrameBlocks as
messages. A name ending in ``.gz`` (``run.asc.gz``) is the log of the suffix before it,
gzip-compressed: it is opened with `gzip.open` and handed to the same class, as python-can's
`can.LogReader` and `can.Logger` do, for any name (python-can's own dispatch only takes names
with exactly two suffixes). canfdi.io.formats registers these formats by suffix.
`messages_block` and `block_messages` are the two conversions, messages to a block and back,
that the python-can plugin for canfdi's MCAP (canfdi.io.pycan_mcap) uses too.

Directions: python-can's ``Message.is_rx`` is kept in the blocks' status column, `RX` or `TX`
(a frame the logging node sent). Written frames are Tx when their status is `TX` or
canfdi.bus.frames' ``SENT`` (the monitor's own), Rx otherwise.

ASC is written as CANalyzer writes it (`asc_writer_class`): the header's date is the
measurement start (the first frame's time, to the millisecond), in English whatever the
locale, and the frames' times count from it, so that python-can's ASCReader with
``relative_timestamp=False`` gives back every frame's absolute time to the microsecond.
"""

from __future__ import annotations

import functools
import gzip
import io
import time
from collections.abc import Iterable, Iterator, Sequence
from datetime import datetime
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from canfdi.bus.frames import FLAG_ERROR, FLAG_EXTENDED, FLAG_FD, FLAG_REMOTE, SENT, FrameBlock

__all__ = ["ASC_VERSION", "RX", "TX", "Written", "asc_date", "asc_writer_class",
           "block_messages", "messages_block", "read_blocks", "write_blocks"]

RX = "rx"
"""Status of a frame a python-can log marks received (or does not mark: python-can's default)."""
TX = "tx"
"""Status of a frame a python-can log marks transmitted by the node that logged it."""

_FLAGS = {"remote": FLAG_REMOTE, "error": FLAG_ERROR, "fd": FLAG_FD}
# Formats whose times write_blocks rounds to their resolution from the integer nanoseconds
# (ASC: whole microseconds, read back exactly; see asc_writer_class).
_RESOLUTION_NS = {".asc": 1000}


class Written(NamedTuple):
    """What a writer did: ``frames`` written, ``skipped`` frames of a kind the format cannot
    hold (remote, error or CAN FD frames in a format without them)."""

    frames: int
    skipped: int


def _reader_class(suffix: str) -> type:
    from can.io.player import MESSAGE_READERS

    return MESSAGE_READERS[suffix]


def _writer_class(suffix: str) -> type:
    if suffix == ".asc":
        return asc_writer_class()
    from can.io.logger import MESSAGE_WRITERS

    return MESSAGE_WRITERS[suffix]


def _is_text(cls: type) -> bool:
    from can.io.generic import TextIOMessageReader, TextIOMessageWriter

    return issubclass(cls, TextIOMessageReader | TextIOMessageWriter)


def _open_reader(path: Path, suffix: str, compressed: bool) -> Any:
    if not compressed:
        import can

        return can.LogReader(str(path))
    cls = _reader_class(suffix)
    return cls(gzip.open(path, "rt" if _is_text(cls) else "rb"))


def _open_writer(path: Path, suffix: str, compressed: bool) -> Any:
    cls = _writer_class(suffix)
    if not compressed:
        return cls(str(path))
    return cls(gzip.open(path, "wt" if _is_text(cls) else "wb"))


def messages_block(messages: Sequence[Any]) -> FrameBlock:
    """python-can Messages as one FrameBlock whose status column says their direction.

    Parameters
    ----------
    messages : sequence of can.Message
        The frames, in order; a message without a timestamp gets 0.

    Returns
    -------
    FrameBlock
        With status `RX` for ``is_rx`` messages, `TX` for the others.
    """
    block = FrameBlock.from_messages(messages, now=0.0)
    rx = np.fromiter((m.is_rx for m in messages), dtype=bool, count=len(messages))
    return FrameBlock(block.t_ns, block.id, block.dlc, block.flags, block.data,
                      status=np.where(rx, RX, TX), long=block.long)


def block_messages(block: FrameBlock, channel: Any = None, resolution_ns: int = 1
                   ) -> Iterator[Any]:
    """The frames of a block as python-can Messages, in order.

    Parameters
    ----------
    block : FrameBlock
        The frames.
    channel : optional
        Every message's ``channel`` (a FrameBlock holds none).
    resolution_ns : int
        Round the times to this many nanoseconds first (1000 for a log written in whole
        microseconds: rounded once, from the integer nanoseconds, since float seconds near
        1.8e9 s are only good to about 0.2 us).

    Yields
    ------
    can.Message
        With the frame's time in seconds (``t_ns / 1e9``), identifier, flags, DLC (a remote
        frame's: the length it requests, with no data) and payload; ``is_rx`` False for the
        statuses `TX` and ``"sent"`` (the monitor's own), True otherwise (or with no status).
    """
    import can

    if block.status is None:
        rx = [True] * block.size
    else:
        rx = ((block.status != SENT) & (block.status != TX)).tolist()
    t_ns = block.t_ns
    if resolution_ns > 1:
        t_ns = (t_ns + resolution_ns // 2) // resolution_ns * resolution_ns
    for t, frame_id, dlc, data, flag, is_rx in zip(
            t_ns.tolist(), block.id.tolist(), block.dlc.tolist(), block.payloads(),
            block.flags.tolist(), rx, strict=True):
        yield can.Message(
            timestamp=t / 1e9, arbitration_id=frame_id, is_extended_id=bool(flag & FLAG_EXTENDED),
            is_remote_frame=bool(flag & FLAG_REMOTE), is_error_frame=bool(flag & FLAG_ERROR),
            is_fd=bool(flag & FLAG_FD), is_rx=is_rx, dlc=dlc, data=data, channel=channel,
            check=False)


def read_blocks(path: Path, suffix: str, compressed: bool = False,
                frames_per_block: int = 65536, damage: Any = None) -> Iterator[FrameBlock]:
    """The frames of a python-can log in blocks of ``frames_per_block``, in log order.

    Parameters
    ----------
    path : Path
        The log.
    suffix : str
        The python-can suffix that says its format (``".asc"``...), ``.gz`` removed.
    compressed : bool
        The file is gzip-compressed.
    frames_per_block : int
        Frames per block (the last one may hold fewer).
    damage : canfdi.io.damage.Damage, optional
        Where a log shorter than its own header says is recorded (a BLF's header holds its
        file size and object count: a cut copy reads to its cut without an error otherwise).

    Yields
    ------
    FrameBlock
        Frames with status `RX` or `TX`; timestamps as the reader gives them (an ``.asc``
        log's from its start: python-can reads them relative).

    Raises
    ------
    Whatever python-can's reader raises for a file it cannot parse (canfdi.io.formats turns
    it into one LogReadError).
    """
    with _open_reader(path, suffix, compressed) as reader:
        pending: list[Any] = []
        frames = 0
        for message in reader:
            pending.append(message)
            frames += 1
            if len(pending) >= frames_per_block:
                yield messages_block(pending)
                pending = []
        if pending:
            yield messages_block(pending)
        announced = int(getattr(reader, "file_size", 0) or 0) if suffix == ".blf" else 0
        size = path.stat().st_size if damage is not None and announced else 0
        if damage is not None and not compressed and announced > size:
            objects = int(getattr(reader, "object_count", 0) or 0)
            damage.file(path, size).notes.append(
                f"cut short: {size:,} of the {announced:,} bytes its header announces "
                f"({objects:,} objects); {frames:,} frames read")


def write_blocks(path: Path, suffix: str, blocks: Iterable[FrameBlock], compressed: bool = False,
                 holds: frozenset[str] = frozenset(_FLAGS)) -> Written:
    """Write FrameBlocks to a python-can log (the file is replaced).

    Parameters
    ----------
    path : Path
        The log to write.
    suffix : str
        The python-can suffix of its format, ``.gz`` removed.
    blocks : iterable of FrameBlock
        The frames, in order; statuses `TX` and ``"sent"`` are written as Tx, others (or no
        status) as Rx.
    compressed : bool
        Write it gzip-compressed.
    holds : frozenset of {"remote", "error", "fd"}
        The frame kinds the format can hold; frames of another kind are skipped and counted
        (python-can's TRC writer would drop them with a warning each).

    Returns
    -------
    Written
        Frames written and skipped.
    """
    not_held = 0
    for kind, flag in _FLAGS.items():
        if kind not in holds:
            not_held |= flag
    if suffix == ".db":  # python-can's SQLite writer appends to an existing table
        path.unlink(missing_ok=True)
    resolution_ns = _RESOLUTION_NS.get(suffix, 1)
    written = skipped = 0
    with _open_writer(path, suffix, compressed) as writer:
        for block in blocks:
            if not_held:
                keep = (block.flags & not_held) == 0
                if not keep.all():
                    skipped += int((~keep).sum())
                    block = block.select(keep)
            for message in block_messages(block, 0, resolution_ns):
                writer.on_message_received(message)
            written += block.size
        _drain(writer)
    return Written(written, skipped)


def _drain(writer: Any) -> None:
    """Wait until a threaded writer (python-can's SQLite writer) has taken every queued
    message: its thread ends at the first batch it writes after stop(), and messages still
    queued then are lost (more than its 500-message batch, typically)."""
    queued = getattr(writer, "buffer", None)
    thread = getattr(writer, "_writer_thread", None)
    if queued is None or thread is None:
        return
    while not queued.empty() and thread.is_alive():
        time.sleep(0.005)


# ------------------------------------------------------------------------------------------
# ASC as CANalyzer writes it
# ------------------------------------------------------------------------------------------

ASC_VERSION = "9.0.0"
"""The CANalyzer version the ``// version`` line names: that of the line layouts python-can's
ASCWriter writes (remote frames with their DLC, new in 8.5; CAN FD events), which readers of
ASC choose their parser by; python-can's own test logs carry it."""

_WEEKDAYS = ("Mon", "Tue", "Wed", "Thu", "Fri", "Sat", "Sun")
_MONTHS = ("Jan", "Feb", "Mar", "Apr", "May", "Jun", "Jul", "Aug", "Sep", "Oct", "Nov", "Dec")


def asc_date(start_us: int) -> str:
    """The date of an ASC header (``date`` and ``Begin Triggerblock``) as CANalyzer writes it.

    ``<weekday> <month> <day> <hh:mm:ss.mmm> <am|pm> <year>`` in local time, 12-hour clock
    (12 for noon and midnight), milliseconds in three digits, English names whatever the
    process locale, e.g. ``Thu Nov 5 01:02:03.011 pm 2026``.

    Parameters
    ----------
    start_us : int
        The instant, microseconds since the epoch; written to the millisecond (cut, not
        rounded: a start is never after the frames that follow it).

    Returns
    -------
    str

    Examples
    --------
    >>> import datetime
    >>> t = datetime.datetime(2026, 11, 5, 13, 2, 3, 11559).timestamp()
    >>> asc_date(round(t * 1e6))
    'Thu Nov 5 01:02:03.011 pm 2026'
    """
    local = datetime.fromtimestamp(start_us // 1_000_000)
    millis = start_us // 1000 % 1000
    hour = local.hour % 12 or 12
    noon = "am" if local.hour < 12 else "pm"
    return (f"{_WEEKDAYS[local.weekday()]} {_MONTHS[local.month - 1]} {local.day} "
            f"{hour:02d}:{local.minute:02d}:{local.second:02d}.{millis:03d} {noon} {local.year}")


@functools.cache
def asc_writer_class() -> type:
    """python-can's ASCWriter with the header CANalyzer writes (built at the first call, so
    that python-can is imported only when a log is written).

    The header waits for the first frame, whose time, cut to the millisecond, is the
    measurement start::

        date <start>
        base hex  timestamps absolute
        internal events logged
        // version 9.0.0
        Begin Triggerblock <start>
           0.000000 Start of measurement
           0.000559 1  104             Rx   d 8 ...
        End TriggerBlock

    with ``<start>`` as `asc_date` writes it and every time after it relative to it, to the
    microsecond. A frame earlier than the start of its trigger block (logs are not always in
    time order) opens a new trigger block that starts before it. A writer that got no frame
    writes the header with the time it is stopped.
    """
    from can.io.asc import ASCWriter
    from can.io.generic import TextIOMessageWriter

    class CanalyzerASCWriter(ASCWriter):
        """python-can's ASCWriter, its header as CANalyzer writes it (see asc_writer_class)."""

        def __init__(self, file: Any, channel: int = 1, **kwargs: Any) -> None:
            # python-can's writer writes its header, with the time of writing, at once: into
            # a scratch buffer; the header goes into the file with the first frame.
            super().__init__(io.StringIO(), channel=channel, **kwargs)
            TextIOMessageWriter.__init__(self, file, mode="w", **kwargs)
            self._start_us = 0

        def _begin(self, start_us: int) -> None:
            date = asc_date(start_us)
            if self.header_written:
                self.file.write("End TriggerBlock\n")
            else:
                self.file.write(f"date {date}\nbase hex  timestamps absolute\n"
                                f"internal events logged\n// version {ASC_VERSION}\n")
                self.header_written = True
            self.file.write(f"Begin Triggerblock {date}\n")
            self._start_us = start_us
            self.started = start_us / 1e6

        def log_event(self, message: str, timestamp: float | None = None) -> None:
            if not message:
                return
            if timestamp is None:
                timestamp = self.last_timestamp if self.header_written else time.time()
            us = round(timestamp * 1e6)
            if not self.header_written:
                self._begin(us // 1000 * 1000)
                self.file.write(self.FORMAT_EVENT.format(timestamp=0.0,
                                                         message="Start of measurement"))
            elif us < self._start_us:
                self._begin(us // 1000 * 1000)
            self.last_timestamp = timestamp
            self.file.write(self.FORMAT_EVENT.format(timestamp=(us - self._start_us) / 1e6,
                                                     message=message))

        def stop(self) -> None:
            if not self.file.closed and not self.header_written:
                self._begin(int(time.time() * 1e3) * 1000)
            super().stop()

    return CanalyzerASCWriter

"""canfdi's MCAP logs in python-can: the reader and writer its plug-in entry points name.

python-can finds log formats by suffix, and takes more from the entry-point groups
``can.io.message_reader`` and ``can.io.message_writer``; canfdi registers `McapReader` and
`McapWriter` there for ``.mcap`` (pyproject.toml), so that ``can.LogReader("run.mcap")``,
``can.Logger("run.mcap")``, ``python -m can.logconvert``, ``python -m can.player`` and every
other python-can tool read and write canfdi's logs. canfdi's own code reads its MCAP through
canfdi.io.reader (canfdi.io.formats keeps ``.mcap`` as canfdi's format), not through here.

Both go through the FrameBlock conversions of canfdi.io.pycan, as canfdi's other python-can
formats do: a frame the monitor sent (status ``"sent"``) or a python-can log marks transmitted
(status ``"tx"``) is a message with ``is_rx=False``; a message with ``is_rx=False`` is written
with status ``"tx"``, as ``canfdi export`` writes a python-can log's Tx frames into MCAP (so
that ``canfdi replay`` keeps them: the logging node sent them on the bus the monitor hears),
and the others with ``"rx"``.

What a canfdi MCAP frame does not hold: the channel (messages get the reader's ``channel``
argument, None by default) and CAN FD's bit-rate-switch and error-state bits; a message's DLC
is recorded as its payload's length (a remote frame's: the length it requests), as canfdi
reads every python-can log. Times are integer nanoseconds, which python-can's float seconds
carry to about 0.2 us.
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from can.io.generic import MessageReader, SizedMessageWriter
from can.message import Message

from canfdi.io.pycan import block_messages, messages_block
from canfdi.io.segments import log_segments

__all__ = ["McapReader", "McapWriter"]


def _path_of(file: Any, what: str) -> Path:
    if not isinstance(file, str | os.PathLike):
        raise TypeError(f"{what} takes a file name, not {type(file).__name__}: a canfdi log "
                        "is a family of files (rotated segments)")
    return Path(file)


class McapReader(MessageReader):
    """The raw frames of a canfdi MCAP log as python-can Messages, in recording order.

    Every frame of the log (valid or not, the monitor's own included) of every rotated
    segment (``run.mcap``, ``run-0001.mcap``...), read by canfdi.io.reader's fast frame
    reader; a log cut short by a killed process is read up to its last complete block.

    Parameters
    ----------
    file : str or os.PathLike
        The log (its first segment).
    channel : optional
        Every message's ``channel`` (``can.LogReader("run.mcap", channel="can0")``): a canfdi
        log does not record the bus it was on. Default None.
    **kwargs
        Ignored (python-can's tools pass their own options to every reader).

    Raises
    ------
    FileNotFoundError
        No segment of the log exists.
    ValueError
        An MCAP file that canfdi did not write (no channel of its topics): its topics are
        named, where reading would give no frame.
    TypeError
        ``file`` is a file object: the reader needs names, to find the segments.

    Notes
    -----
    ``is_rx`` is False for the frames the monitor sent (status ``"sent"``) and those a
    converted python-can log marked transmitted (``"tx"``), True for the others.

    Examples
    --------
    >>> import pathlib, tempfile, can
    >>> tmp = tempfile.TemporaryDirectory()
    >>> path = pathlib.Path(tmp.name) / "run.mcap"
    >>> with McapWriter(path) as writer:
    ...     writer(can.Message(timestamp=1.5, arbitration_id=0x104, data=b"\\x01\\x02"))
    ...     writer(can.Message(timestamp=1.75, arbitration_id=0x300, is_rx=False))
    >>> with McapReader(path) as reader:  # can.LogReader(path) once canfdi is installed
    ...     [(m.timestamp, hex(m.arbitration_id), bytes(m.data), m.is_rx) for m in reader]
    [(1.5, '0x104', b'\\x01\\x02', True), (1.75, '0x300', b'', False)]
    >>> tmp.cleanup()
    """

    def __init__(self, file: Any, channel: Any = None, **kwargs: Any) -> None:
        self.path = _path_of(file, "McapReader")
        segments = log_segments(self.path)
        if not segments:
            raise FileNotFoundError(2, "no such log", str(self.path))
        foreign = _foreign_topics(segments[0])
        if foreign is not None:
            shown = ", ".join(foreign[:5]) + (", ..." if len(foreign) > 5 else "")
            raise ValueError(f"{self.path}: an MCAP file canfdi did not write (its topics: "
                             f"{shown or 'none'}): python-can reads CAN frames from a canfdi "
                             "log's /can/frames only")
        self.channel = channel
        self._iterators: list[Iterator[Message]] = []

    def __iter__(self) -> Iterator[Message]:
        iterator = self._messages()
        self._iterators.append(iterator)
        return iterator

    def _messages(self) -> Iterator[Message]:
        from canfdi.io.reader import mcap_frame_blocks

        blocks = mcap_frame_blocks(self.path, received=False)
        try:
            for block in blocks:
                yield from block_messages(block, self.channel)
        finally:
            blocks.close()  # ends the read-ahead thread of a reader left early

    def stop(self) -> None:
        """Stop reading: the iterations under way end (their files and thread are closed)."""
        for iterator in self._iterators:
            iterator.close()  # type: ignore[attr-defined]
        self._iterators.clear()


def _foreign_topics(path: Path) -> list[str] | None:
    """The topics of an MCAP file none of whose channels is canfdi's (``/can/...`` or
    ``/canfdi/...``), sorted; None for a canfdi log, or a file whose channels are not known
    (damaged before its first channel: the reader then says what it lost)."""
    from canfdi.io.scan import McapFile, NotMcap
    from canfdi.io.schemas import TOPIC_FRAMES

    try:
        with McapFile(path) as f:
            if not f.channels:  # no intact summary: the first chunks define them
                for _ in f.messages([TOPIC_FRAMES]):
                    return None
            topics = sorted(set(f.channels.values()))
    except (NotMcap, OSError):
        return None  # the reader's own errors say it
    if not topics or any(t.startswith(("/can/", "/canfdi/")) for t in topics):
        return None
    return topics


class McapWriter(SizedMessageWriter):
    """Write python-can Messages into a canfdi MCAP log (frames only), through McapRecorder.

    The log is what canfdi records: ``/can/frames`` blocks that canfdi.io.reader, ``canfdi
    replay``, ``export`` and `McapReader` read, crash-safe as McapRecorder makes it. Messages
    are gathered into blocks of up to `BLOCK` frames or `BLOCK_SECONDS` of wall-clock time
    (checked as messages arrive) before they go to the recorder, which ends an MCAP chunk
    every second: a killed process loses about the last 1.5 s.

    Parameters
    ----------
    file : str or os.PathLike
        The log to write (replaced; stale rotated segments of that name are removed).
    metadata : dict of str to str, optional
        A ``"canfdi"`` metadata record for the log (canfdi.io.writer).
    rotate_bytes, rotate_seconds : optional
        Rotate into ``<stem>-0001.mcap``... (McapRecorder's options of the same names).
    append : bool
        Must be False: an MCAP log is not appended to.
    **kwargs
        Ignored (python-can's tools pass their own options to every writer).

    Raises
    ------
    ValueError
        ``append=True``.
    TypeError
        ``file`` is a file object.
    OSError
        The log cannot be created; at `stop`, the last write error of the recorder (a full
        disk), so that no loss goes unsaid.

    Notes
    -----
    Statuses: ``"rx"`` for a message with ``is_rx`` True, ``"tx"`` for the others (the
    statuses ``canfdi export`` gives a python-can log's frames). A message without a
    timestamp is recorded at 0.

    Examples
    --------
    >>> import pathlib, tempfile, can
    >>> from canfdi.io.reader import read_frames
    >>> tmp = tempfile.TemporaryDirectory()
    >>> path = pathlib.Path(tmp.name) / "run.mcap"
    >>> with McapWriter(path) as writer:  # can.Logger(path) once canfdi is installed
    ...     writer(can.Message(timestamp=2.0, arbitration_id=0x1ABCDEF, data=b"\\xff"))
    >>> frames = read_frames(path)
    >>> int(frames.t_ns[0]), hex(int(frames.id[0])), frames.status.tolist()
    (2000000000, '0x1abcdef', ['rx'])
    >>> tmp.cleanup()
    """

    BLOCK = 4096
    """Most messages gathered before they go to the recorder."""
    BLOCK_SECONDS = 0.5
    """Most seconds (wall clock) a message waits in the writer before it goes to the
    recorder."""

    def __init__(self, file: Any, metadata: dict[str, str] | None = None,
                 rotate_bytes: int | None = None, rotate_seconds: float | None = None,
                 append: bool = False, **kwargs: Any) -> None:
        if append:
            raise ValueError("McapWriter cannot append to an existing MCAP log")
        from canfdi.io.writer import McapRecorder

        self.path = _path_of(file, "McapWriter")
        self._recorder = McapRecorder(self.path, metadata=metadata, rotate_bytes=rotate_bytes,
                                      rotate_seconds=rotate_seconds)
        self._pending: list[Message] = []
        self._due = 0.0

    def on_message_received(self, msg: Message) -> None:
        """Record one message (gathered into a block first)."""
        pending = self._pending
        if not pending:
            self._due = time.monotonic() + self.BLOCK_SECONDS
        pending.append(msg)
        if len(pending) >= self.BLOCK or time.monotonic() >= self._due:
            self._write_pending()

    def _write_pending(self) -> None:
        if self._pending:
            self._recorder.write_frames(messages_block(self._pending))
            self._pending = []

    def file_size(self) -> int:
        """Bytes written to the log's files so far (compressed; the open chunk not yet)."""
        return self._recorder.bytes_written

    def stop(self) -> None:
        """Write what is gathered, finish the log (summary, footer) and close it. Raises the
        recorder's last write error, if there was one."""
        if self._recorder.closed:
            return
        try:
            self._write_pending()
        finally:
            self._recorder.close()
        if self._recorder.last_error is not None:
            raise self._recorder.last_error

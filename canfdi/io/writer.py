"""`McapRecorder`: write a monitor run into MCAP, crash-safely, with rotation and disk-full
tolerance.

The recorder is a composition: a `Channel` per topic (canfdi.io.channels: a buffer and an
encoder; ``/can/frames``, every row topic of canfdi.io.rowtopics, and one per single-message
topic), a `SegmentedFile` (canfdi.io.segmented: the files, timed flushes, rotation, disk
full), and the live tap, which sees every message. Its methods for canfdi's own topics are
canfdi.io.topicwrites'. The topics and schemas are canfdi.io.schemas'; canfdi.io.reader reads
the files back.

Buffering and crash safety
--------------------------
Frames, samples and residual rows are appended to their channel's buffer (0.2 to 2 us a row,
no JSON) and written as messages when a buffer holds ``block_frames``, ``block_samples`` or
``block_residuals`` rows, on every timed flush, on `McapRecorder.flush` and on
`McapRecorder.close`. Whenever ``flush_interval`` seconds (on the injected clock) have passed
since the last flush, the recorder writes every buffer out and ends the file's open chunks:
the check is a single comparison inside every write or append (no thread, no lock), and
`McapRecorder.flush` forces it. A killed process loses only the rows still buffered and the
messages of the chunks still open: about the last ``flush_interval`` seconds, as long as the
caller writes at least that often (the monitor's frames and status messages do; an idle caller
should call `McapRecorder.flush`). `read_log` reads such a file up to its last complete
record, so a block is read back whole or not at all. Rotation and write errors are the
`SegmentedFile`'s (see canfdi.io.segmented): no OSError reaches the caller of a write method,
and rows still buffered when recording resumes are not lost.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from operator import is_
from pathlib import Path
from types import TracebackType
from typing import IO, Any, Self

import numpy as np
from numpy.typing import ArrayLike

from canfdi.bus.frames import FrameBlock
from canfdi.io.blocks import encode_message, stamp
from canfdi.io.channels import (
    Channel,
    FrameBlockEncoder,
    MessageBuffer,
    MessageEncoder,
    row_channel,
    schema_bytes,
)
from canfdi.io.framebuffer import FrameBuffer
from canfdi.io.loghandler import McapLogHandler
from canfdi.io.mcapwrite import Messages
from canfdi.io.rowencodings import DEFAULT_ROW_ENCODING
from canfdi.io.rowtopics import ROW_LAYOUTS
from canfdi.io.schemas import TOPIC_FRAMES, TOPIC_RESIDUALS, TOPIC_SAMPLES
from canfdi.io.segmented import (
    DEFAULT_CHUNK_SIZE,
    RETRY_INTERVAL,
    Schema,
    SegmentedFile,
    open_file,
)
from canfdi.io.topicwrites import TopicWrites

__all__ = ["DEFAULT_BLOCK_ROWS", "RETRY_INTERVAL", "McapLogHandler", "McapRecorder", "Tap"]

DEFAULT_BLOCK_ROWS = 1024
"""Rows of a row topic buffered before they are written (``block_samples``,
``block_residuals``, and every other row topic's)."""

Tap = Callable[[str, Schema, int, bytes], None]
"""Sees every message the recorder writes: ``(topic, schema (its name, data and encodings),
log_time_ns, message bytes)`` (a live Foxglove server, say)."""


class _TappedFile:
    """Where the channels' messages go: the tap, then the file, each topic's log times never
    going back.

    A topic's messages are written in the order they happened to the monitor, but their own
    times need not follow it: `canfdi run` stamps the frames it sends with the wall clock's
    now, ahead of the received frames still queued; a drive's clock may step back. MCAP's
    readers order by log time (mcap's and Foxglove's always, canfdi's for a file killed before
    its summary), so a message stamped earlier than the one before it on its topic is logged at
    that one's time: every reader then reads each topic in the order it was written. The
    message keeps its own time in its fields (``timestamp``, a frame's ``t_ns``).
    """

    __slots__ = ("_last", "file", "tap")

    def __init__(self, file: SegmentedFile, tap: Tap | None) -> None:
        self.file = file
        self.tap = tap
        self._last: dict[str, int] = {}  # topic -> its latest log time

    def message(self, topic: str, schema: Schema, timestamp_ns: int, data: bytes, rows: int,
                now: float) -> None:
        timestamp_ns = max(timestamp_ns, self._last.get(topic, timestamp_ns))
        self._last[topic] = timestamp_ns
        if self.tap is not None:
            self.tap(topic, schema, timestamp_ns, data)
        self.file.add_message(topic, schema, timestamp_ns, data, rows, now)

    def row_messages(self, topic: str, schema: Schema, t_ns: np.ndarray, data: Messages,
                     now: float) -> None:
        if len(t_ns):
            floor = self._last.get(topic, int(t_ns[0]))
            if t_ns[0] < floor or np.any(t_ns[1:] < t_ns[:-1]):
                t_ns = np.maximum.accumulate(np.maximum(t_ns, floor))
            self._last[topic] = int(t_ns[-1])
        if self.tap is not None:
            tap = self.tap
            for t, d in zip(t_ns.tolist(), data, strict=True):
                tap(topic, schema, t, d if isinstance(d, bytes) else d.tobytes())
        self.file.add_row_messages(topic, schema, t_ns, data, now)


class McapRecorder(TopicWrites):
    """Record a monitor run into MCAP, crash-safely, with rotation and disk-full tolerance.

    Parameters
    ----------
    path : str or Path or None
        The log file (the first segment); its directory must exist. None: no file, the
        messages go to ``tap`` only (a live view without a log).
    metadata : dict of str to str, optional
        Run-level information stored in a metadata record named ``"canfdi"`` at the head of
        every segment (e.g. ``config_yaml``, ``design_json``, ``truth_json``, ``version``).
    flush_interval : float
        Seconds between timed flushes (buffers written, chunk ended): the most a killed process
        loses (see the module docstring).
    rotate_bytes : int, optional
        Start a new segment once the current file holds this many bytes.
    rotate_seconds : float, optional
        Start a new segment once the current one has been open this long.
    clock : callable
        Monotonic seconds; injected by tests to place chunk ends and rotations exactly.
    opener : callable
        Opens a segment file for binary writing; injected by tests to simulate a full disk.
    chunk_size : int
        Uncompressed bytes after which the writer ends a chunk on its own.
    block_frames : int
        Frames of a full ``/can/frames`` block: a buffer holding that many is written as one
        message at once.
    block_samples, block_residuals : int
        Samples or residual rows buffered before they are written (one message per row: the
        buffer lets them be formatted together).
    tap : callable, optional
        Called with every message written (`Tap`), whether or not a file takes it.
    row_encoding : str
        How the row topics' rows become messages: a name of canfdi.io.rowencodings'
        `ROW_ENCODINGS` (``"cdr"``, ROS 2 messages; ``"json"``, JSON ones).

    Raises
    ------
    OSError
        When the first segment cannot be opened for a reason a full disk does not explain
        (missing directory, permissions). Later errors are reported, never raised.

    Notes
    -----
    Use as a context manager, or call `close`. Not thread-safe: one writer thread.

    Examples
    --------
    >>> seen = []
    >>> with McapRecorder(None, tap=lambda topic, schema, t, data: seen.append(topic)) as rec:
    ...     rec.write_frame(1_000, 0x123, b"\\x01", "ok")
    ...     rec.write_status(2_000, "running", 0, {"ok": 1}, 0)
    >>> seen
    ['/canfdi/status', '/can/frames']
    """

    def __init__(
        self,
        path: str | Path | None,
        *,
        metadata: dict[str, str] | None = None,
        flush_interval: float = 1.0,
        rotate_bytes: int | None = None,
        rotate_seconds: float | None = None,
        clock: Callable[[], float] = time.monotonic,
        opener: Callable[[Path], IO[bytes]] = open_file,
        chunk_size: int = DEFAULT_CHUNK_SIZE,
        block_frames: int = 4096,
        block_samples: int = DEFAULT_BLOCK_ROWS,
        block_residuals: int = DEFAULT_BLOCK_ROWS,
        tap: Tap | None = None,
        row_encoding: str = DEFAULT_ROW_ENCODING,
    ) -> None:
        if flush_interval <= 0:
            raise ValueError(f"flush_interval must be > 0, got {flush_interval}")
        if rotate_bytes is not None and rotate_bytes <= 0:
            raise ValueError(f"rotate_bytes must be > 0, got {rotate_bytes}")
        if rotate_seconds is not None and rotate_seconds <= 0:
            raise ValueError(f"rotate_seconds must be > 0, got {rotate_seconds}")
        for name, value in (
            ("block_frames", block_frames),
            ("block_samples", block_samples),
            ("block_residuals", block_residuals),
        ):
            if value < 1:
                raise ValueError(f"{name} must be >= 1, got {value}")
        if metadata is not None:
            bad = [
                k for k, v in metadata.items() if not isinstance(k, str) or not isinstance(v, str)
            ]
            if bad:
                raise TypeError(f"metadata keys and values must be strings: {bad}")
        self._clock = clock
        self._file = SegmentedFile(
            Path(path) if path is not None else None, metadata=metadata,
            flush_interval=flush_interval, rotate_bytes=rotate_bytes,
            rotate_seconds=rotate_seconds, opener=opener, chunk_size=chunk_size,
            separate=(TOPIC_FRAMES,))
        self._out = _TappedFile(self._file, tap)
        # The status table of the frames starts anew when full: the frames it describes go
        # out first.
        self._frame_buffer = FrameBuffer(
            block_frames,
            make_room=lambda: self._frames.emit(self._out, self._clock(), full_only=False))
        self._frames = Channel(TOPIC_FRAMES, self._frame_buffer, FrameBlockEncoder(),
                               block_frames)
        limits = {TOPIC_SAMPLES: block_samples, TOPIC_RESIDUALS: block_residuals}
        self._rows = {topic: row_channel(layout, limits.get(topic, DEFAULT_BLOCK_ROWS),
                                         row_encoding)
                      for topic, layout in ROW_LAYOUTS.items()}
        # Buffered channels, in the order they are written out.
        self._buffered = [self._frames, *self._rows.values()]
        self._messages: dict[str, Channel] = {}
        self._file.start(clock())

    # -- context manager -------------------------------------------------------------------

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    # -- properties ------------------------------------------------------------------------

    @property
    def paths(self) -> list[Path]:
        """Segment files started so far, in order (an abandoned segment stays listed)."""
        return self._file.paths

    @property
    def segments(self) -> int:
        """The number of segment files started so far (``len(paths)``, without building
        them)."""
        return self._file.segments

    @property
    def messages_written(self) -> int:
        """Rows (frames, samples, residual rows) and single messages (estimates, events, status,
        `write`) handed to a segment and not known to be lost. Rows still buffered in the
        recorder are not counted yet (`buffered`)."""
        return self._file.messages_written

    @property
    def messages_dropped(self) -> int:
        """Rows and messages lost to write errors: refused while failing, in an unflushed
        chunk, or still buffered at `close` while failing."""
        return self._file.messages_dropped

    @property
    def buffered(self) -> int:
        """Frames, samples and residual rows waiting in the recorder's buffers."""
        return sum(channel.buffer.count for channel in self._buffered)

    @property
    def bytes_written(self) -> int:
        """Bytes handed to the segment files (compressed chunks, indexes, summaries)."""
        return self._file.bytes_written

    @property
    def write_errors(self) -> int:
        """Number of OSErrors met (each failed write, flush, rotation or retry counts once)."""
        return self._file.write_errors

    @property
    def last_error(self) -> OSError | None:
        """The most recent OSError, or None if there never was one."""
        return self._file.last_error

    @property
    def failing(self) -> bool:
        """True while messages are being dropped (no segment open after a write error)."""
        return self._file.failing

    @property
    def closed(self) -> bool:
        """True once `close` has been called."""
        return self._file.closed

    # -- writing ---------------------------------------------------------------------------

    def write(self, topic: str, timestamp_ns: int, message: Mapping[str, Any]) -> None:
        """Record one message, unbuffered.

        Parameters
        ----------
        topic : str
            Any topic: one of `TOPICS` (the message must then have that topic's shape) or
            another one (registered with a generic object schema).
        timestamp_ns : int
            Log time, integer nanoseconds since the epoch.
        message : mapping
            JSON-serialisable; numpy values are converted. A ``"timestamp"`` field is added
            from ``timestamp_ns`` when the message has none (the caller's mapping is not
            modified).

        Raises
        ------
        ValueError
            After `close`.
        TypeError
            If the message cannot be expressed in JSON (a programming error, not an I/O one).
        """
        if "timestamp" not in message:
            message = {"timestamp": stamp(timestamp_ns), **message}
        self._write_message(topic, timestamp_ns, encode_message(message))

    def write_frame(
        self,
        timestamp_ns: int,
        frame_id: int,
        data: bytes,
        status: str,
        extended: bool = False,
        dlc: int | None = None,
        flags: int = 0,
    ) -> None:
        """Buffer a raw CAN frame for `TOPIC_FRAMES` (a cheap append).

        Parameters
        ----------
        timestamp_ns : int
            Arrival (or send) time, ns since the epoch.
        frame_id : int
            Arbitration id.
        data : bytes
            Payload (any length; more than 8 bytes are kept in the block's ``"long"`` map).
        status : str
            One of `FRAME_STATUSES` (or another short label).
        extended : bool
            29-bit identifier (sets `FLAG_EXTENDED`).
        dlc : int, optional
            Data length code when it differs from ``len(data)``.
        flags : int
            More `FLAG_REMOTE`, `FLAG_ERROR`, `FLAG_FD` bits.

        Raises
        ------
        ValueError
            After `close`.
        """
        now = self._begin_write()
        if self._frame_buffer.append(timestamp_ns, frame_id, data, status, extended, dlc, flags):
            self._frames.emit(self._out, now, full_only=True)

    def write_frames(
        self,
        block: FrameBlock,
        statuses: str | Sequence[str] | ArrayLike | None = None,
        status_names: Sequence[str] | None = None,
    ) -> None:
        """Buffer a block of raw CAN frames for `TOPIC_FRAMES`, vectorised.

        Parameters
        ----------
        block : FrameBlock
            The frames (canfdi.bus.frames); the payload padding beyond each DLC is recorded as
            given, and payloads longer than 8 bytes (``block.long``, CAN FD) whole.
        statuses : str, sequence of str, (N,) array of str, or (N,) integer array, optional
            Every frame's status (one string: all of them); integer codes index
            ``status_names`` (e.g. the assembler's codes into canfdi.bus.frames'
            ``STATUS_NAMES``: the fastest form). Default: the block's own ``status``.
        status_names : sequence of str, optional
            The names of integer ``statuses``.

        Raises
        ------
        ValueError
            After `close`, or for a block with no statuses given or held.
        """
        now = self._begin_write()
        if statuses is None:
            if block.status is None:
                raise ValueError("write_frames: the block holds no statuses and none are given")
            statuses = block.status
        if self._frame_buffer.extend(block, statuses, status_names):
            self._frames.emit(self._out, now, full_only=True)

    def write_metadata(self, name: str, values: dict[str, str]) -> None:
        """A named metadata record, now (teach-in's learned values, say) and at the head of
        every later segment."""
        if not all(isinstance(k, str) and isinstance(v, str) for k, v in values.items()):
            raise TypeError("metadata keys and values must be strings")
        self._file.keep_metadata(name, values)
        now = self._begin_write()
        self._file.add_metadata(name, values, now)

    def flush(self) -> None:
        """Write the buffered rows, end the open chunk and push everything written so far to
        the operating system.

        Also restarts the ``flush_interval`` timer. Errors are handled as in `write`; while
        failing the rows stay buffered.
        """
        if self._file.open:
            now = self._clock()
            self._emit_all(now)
            self._file.flush(now)

    def close(self) -> None:
        """Write the buffered rows, finish the current segment (summary, footer) and close it.

        Idempotent, never raises an OSError (it is recorded as in `write`); rows buffered while
        failing count as dropped.
        """
        if self._file.closed:
            return
        now = self._clock()
        try:
            self._emit_all(now)
        finally:
            self._file.mark_closed()
        self._file.finish(now)

    # -- the primitives of TopicWrites -----------------------------------------------------

    def _begin_write(self) -> float:
        """Refuse writes after close; run the timed flush when it is due; the clock's now."""
        if self._file.closed:
            raise ValueError("write to a closed McapRecorder")
        now = self._clock()
        if now >= self._file.deadline:
            self._tick(now)
        return now

    def _row_channel(self, topic: str, names: Sequence[Sequence[str]], drive: str | None,
                     now: float) -> Channel:
        """The channel of a row topic, its rows named ``names`` and of ``drive`` from now on
        (a change writes the buffered rows first)."""
        channel = self._rows.get(topic)
        if channel is None:
            raise ValueError(f"{topic} is not a row topic (canfdi.io.rowtopics.ROW_LAYOUTS)")
        encoder = channel.encoder
        if drive != encoder.drive:
            channel.emit(self._out, now, full_only=False)
            encoder.set_drive(drive)
        given = encoder.given
        if len(names) != len(given) or not all(map(is_, names, given)):
            listed = encoder.check_names(names)
            if listed != encoder.names:
                channel.emit(self._out, self._clock(), full_only=False)
                encoder.rename(listed)
            encoder.given = tuple(names)
        return channel

    def _append_row(self, channel: Channel, row: tuple[Any, ...], now: float) -> None:
        """Buffer one row (a value per column, in the layout's order) of a row channel."""
        if channel.buffer.append(row) >= channel.limit:
            channel.emit(self._out, now, full_only=True)

    def _add_rows(self, channel: Channel, columns: tuple[np.ndarray, ...], now: float) -> None:
        """Buffer checked columns (in the layout's order) of a row channel."""
        if not len(columns[0]):
            return
        channel.buffer.add(columns)
        if channel.full:
            channel.emit(self._out, now, full_only=True)

    def _write_message(self, topic: str, timestamp_ns: int, data: bytes) -> None:
        now = self._begin_write()
        channel = self._messages.get(topic)
        if channel is None:
            channel = self._messages[topic] = Channel(
                topic, MessageBuffer(), MessageEncoder(schema_bytes(topic)), 1)
        channel.buffer.append(timestamp_ns, data)
        channel.emit(self._out, now, full_only=True)

    # -- timing ----------------------------------------------------------------------------

    def _emit_all(self, now: float) -> None:
        for channel in self._buffered:
            channel.emit(self._out, now, full_only=False)

    def _tick(self, now: float) -> None:
        """The deadline passed: retry while failing, else write the buffers out and end the
        interval (timed flush or rotation)."""
        file = self._file
        if file.open or file.path is None:
            self._emit_all(now)
        file.end_interval(now)

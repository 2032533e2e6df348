"""`SegmentedFile`: the MCAP files a recording goes into, with timed flushes, rotation and
disk-full tolerance.

It takes encoded messages (canfdi.io.channels makes them) and knows nothing of topics' rows.
Segment names are canfdi.io.segments'; canfdi.io.writer's `McapRecorder` drives it.

Chunks and crash safety
-----------------------
The mcap writer keeps the open chunk in memory and writes it only when it exceeds
``chunk_size`` or on ``Writer.flush()``, which finishes the open chunk (if it holds a message),
writes it and flushes the output stream. Frame blocks go into chunks of their own (two chunks
are open: the frames' and the other topics'), so that a replay, which reads frames only,
inflates none of the per-sample messages (two thirds of a capture's bytes); both end together.
`SegmentedFile.deadline` is the next instant the caller must call `SegmentedFile.end_interval`
(after writing its buffers out): every ``flush_interval`` seconds the open chunks end and reach
the operating system's page cache, so a killed process (SIGKILL, crash) loses only the
messages of the chunks still open. There is no fsync: a power loss may lose what the kernel had
not yet written back. Such a file has no summary; canfdi.io.reader reads it in file order and
stops at the last complete record.

Rotation
--------
With ``rotate_bytes`` or ``rotate_seconds``, the first message added after the segment's file
reached ``rotate_bytes`` (bytes reach the file a chunk at a time, so a segment overshoots by at
most a chunk and its summary) or the first interval end after the segment has been open
``rotate_seconds`` finishes the segment cleanly (summary and footer) and continues in
``<stem>-0001<suffix>``, ``<stem>-0002<suffix>``... next to the first file, which keeps the
given name. A recording refuses to start over numbered segments of its name left by an earlier
run, so that the family is this run's only.

Write errors
------------
An `OSError` while writing (typically ENOSPC: disk full) never reaches the caller. It is
recorded (`SegmentedFile.last_error`, `SegmentedFile.write_errors`), logged once per episode,
the segment is abandoned (its flushed part stays readable as a truncated file), the rows of its
unflushed chunks and every message added while failing count as dropped
(`SegmentedFile.messages_dropped`), and at most once per `RETRY_INTERVAL` seconds the caller
retries by opening the next segment: recording resumes in a new segment when space returns.
`SegmentedFile.start` raises for errors that cannot heal by themselves (a missing directory, no
permission) so that a bad path is reported at start.
"""

from __future__ import annotations

import contextlib
import errno
import logging
import math
from collections.abc import Callable, Collection, Mapping
from pathlib import Path
from typing import IO, NamedTuple

import numpy as np
from mcap._chunk_builder import ChunkBuilder
from mcap.writer import LIBRARY_IDENTIFIER, CompressionType, IndexType, Writer

from canfdi import __version__
from canfdi.io.mcapwrite import Messages, add_messages
from canfdi.io.schemas import MESSAGE_ENCODING, METADATA_NAME, SCHEMA_ENCODING
from canfdi.io.segments import numbered_segments, segment_path

__all__ = ["DEFAULT_CHUNK_SIZE", "LOGGER_NAME", "RETRY_INTERVAL", "SegmentedFile", "open_file"]

LOGGER_NAME = "canfdi.io.writer"
"""The logger of the recording's own warnings (a full disk): the recorder's, by its module."""
logger = logging.getLogger(LOGGER_NAME)

RETRY_INTERVAL = 1.0
"""Seconds (on the recorder's clock) between attempts to resume after a write error."""

DEFAULT_CHUNK_SIZE = 1024 * 1024
# errno values of a failing first open that may heal (space freed), so that a monitor started
# on a full disk still monitors; anything else at start is a configuration error.
_TRANSIENT_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EIO})
# Every index but attachments' (canfdi writes none): mcap writes a summary group per index
# type even when it is empty, which MCAP checkers (pymcap-cli doctor) report as an error.
_INDEX_TYPES = IndexType.CHUNK | IndexType.MESSAGE | IndexType.METADATA

class Schema(NamedTuple):
    """A channel's schema as registered, and the encoding of its messages: a JSON schema and
    JSON messages unless it says otherwise (a plain ``(name, data)`` pair is taken as that)."""

    name: str
    data: bytes
    encoding: str = SCHEMA_ENCODING
    message_encoding: str = MESSAGE_ENCODING


def open_file(path: Path) -> IO[bytes]:
    """Open a segment file for binary writing (the default opener)."""
    return open(path, "wb")


class _CountingFile:
    """The output stream handed to the mcap writer: counts bytes so rotation needs no syscall.

    The writer opens every file fresh, so the count is also the position it asks for in tell().
    """

    __slots__ = ("_file", "count")

    def __init__(self, file: IO[bytes]) -> None:
        self._file = file
        self.count = 0

    def write(self, data: bytes) -> int:
        self._file.write(data)
        self.count += len(data)
        return len(data)

    def tell(self) -> int:
        return self.count

    def flush(self) -> None:
        self._file.flush()

    def close(self) -> None:
        self._file.close()


class _Segment:
    """One open MCAP file: its writer and the channel of every topic registered in it."""

    __slots__ = ("channel_ids", "channels", "chunks", "file", "metadata", "other_chunk", "path",
                 "schema_ids",
                 "separate_open", "writer")

    def __init__(self, path: Path, file: _CountingFile, writer: Writer) -> None:
        self.path = path
        self.file = file
        self.writer = writer
        # Each topic's current channel id and its schema (a row topic's may change: a new
        # schema, a new channel), and every channel registered, by topic and schema (the rows
        # of two drives may alternate between two).
        self.channels: dict[str, tuple[int, Schema]] = {}
        self.channel_ids: dict[tuple[str, Schema], int] = {}
        self.schema_ids: dict[Schema, int] = {}
        self.metadata = False
        self.chunks = False
        # The open chunk the writer is not filling (mcap 1.x's Writer holds one, in this
        # attribute; without it every topic shares the chunks).
        self.other_chunk: ChunkBuilder | None = (
            ChunkBuilder() if hasattr(writer, "_Writer__chunk_builder") else None)
        self.separate_open = False  # the writer is filling the separate topics' chunk

    def use(self, separate: bool) -> None:
        """Make the writer fill the separate topics' open chunk (or the other topics')."""
        if separate != self.separate_open and self.other_chunk is not None:
            writer = self.writer
            writer._Writer__chunk_builder, self.other_chunk = (  # type: ignore[attr-defined]
                self.other_chunk, writer._Writer__chunk_builder)  # type: ignore[attr-defined]
            self.separate_open = separate

    def end_chunks(self) -> None:
        """Write both open chunks (those holding a message) and flush the stream."""
        self.use(not self.separate_open)
        self.writer.flush()
        self.use(not self.separate_open)
        self.writer.flush()

    def channel(self, topic: str, schema: Schema) -> int:
        """The channel of ``topic`` with ``schema``, registered with its first message (so that
        the schema and channel records reach the file in the chunk that holds it: a segment
        without messages lists none in its summary either)."""
        known = self.channels.get(topic)
        if known is not None and known[1] is schema:
            return known[0]
        channel_id = self.channel_ids.get((topic, schema))
        if channel_id is None:
            full = Schema(*schema)
            schema_id = self.schema_ids.get(schema)
            if schema_id is None:
                schema_id = self.writer.register_schema(full.name, full.encoding, full.data)
                self.schema_ids[schema] = schema_id
            channel_id = self.writer.register_channel(topic, full.message_encoding, schema_id)
            self.channel_ids[(topic, schema)] = channel_id
        self.channels[topic] = (channel_id, schema)
        return channel_id

    def finish(self) -> None:
        # No summary group may be empty: leave out the chunk and metadata indexes of a segment
        # without chunks or metadata, and the repeated schemas and channels of one without
        # channels. (mcap's Writer fixes these when it is made; these are its attributes for
        # them. tests/integration/test_third_party_readers.py checks the result with
        # pymcap-cli doctor.)
        kinds = IndexType.MESSAGE
        if self.chunks:
            kinds |= IndexType.CHUNK
        if self.metadata:
            kinds |= IndexType.METADATA
        if hasattr(self.writer, "_Writer__index_types"):
            self.writer._Writer__index_types = kinds
            self.writer._Writer__repeat_schemas = bool(self.channels)
            self.writer._Writer__repeat_channels = bool(self.channels)
        self.end_chunks()
        self.writer.finish()
        self.file.flush()
        self.file.close()

    def abandon(self) -> None:
        # A full disk makes the buffered writer's flush-on-close fail too; the descriptor is
        # closed regardless, which is all that is wanted here.
        with contextlib.suppress(OSError):
            self.file.close()


class SegmentedFile:
    """The segment files of one recording: messages in, chunks ended on time, rotation, and
    write errors counted instead of raised (see the module docstring).

    Parameters
    ----------
    path : Path or None
        The first segment's file; None: no file (messages are only counted as not written,
        and the interval still ends on time, for a caller that taps its messages).
    metadata : dict of str to str, optional
        The ``"canfdi"`` metadata record at the head of every segment.
    flush_interval : float
        Seconds between interval ends (open chunks written out).
    rotate_bytes, rotate_seconds : int or float, optional
        Start a new segment once the current one holds this many bytes or has been open this
        long.
    opener : callable
        Opens a segment file for binary writing.
    chunk_size : int
        Uncompressed bytes after which the writer ends a chunk on its own.
    separate : collection of str
        Topics whose messages go into chunks of their own.

    Examples
    --------
    >>> import tempfile
    >>> from pathlib import Path
    >>> path = Path(tempfile.mkdtemp()) / "run.mcap"
    >>> schema = ("canfdi.Json", b'{"type": "object", "properties": {}}')
    >>> file = SegmentedFile(path, metadata=None, flush_interval=1.0)
    >>> file.start(now=0.0)
    >>> file.add_message("/x", schema, 5, b'{"a":1}', rows=1, now=0.0)
    >>> file.mark_closed()
    >>> file.finish(now=0.0)
    >>> file.messages_written, file.segments, file.failing
    (1, 1, False)
    """

    def __init__(
        self,
        path: Path | None,
        *,
        metadata: Mapping[str, str] | None,
        flush_interval: float,
        rotate_bytes: int | None = None,
        rotate_seconds: float | None = None,
        opener: Callable[[Path], IO[bytes]] = open_file,
        chunk_size: int = DEFAULT_CHUNK_SIZE,
        separate: Collection[str] = (),
    ) -> None:
        self.path = path
        self._metadata = dict(metadata) if metadata is not None else None
        self._later_metadata: dict[str, dict[str, str]] = {}
        self._flush_interval = float(flush_interval)
        # Infinite limits keep the hot-path test a plain comparison, with no None checks.
        self._byte_limit = rotate_bytes if rotate_bytes is not None else math.inf
        self._rotate_seconds = float(rotate_seconds) if rotate_seconds is not None else math.inf
        self._opener = opener
        self._chunk_size = int(chunk_size)
        self._separate = frozenset(separate)
        self._sequence: dict[str, int] = {}
        self._seg: _Segment | None = None
        # Segments 0 .. _next_index - 1 have been started (their names follow from the index:
        # no list of them grows with a run of months).
        self._next_index = 0
        self.closed = False
        self.messages_written = 0
        """Rows handed to a segment and not known to be lost."""
        self.messages_dropped = 0
        """Rows lost to write errors."""
        self._pending = 0  # rows accepted into the open chunks since the last successful flush
        self._bytes_done = 0  # bytes of segments no longer open
        self.write_errors = 0
        """OSErrors met (each failed write, flush, rotation or retry counts once)."""
        self.last_error: OSError | None = None
        """The most recent OSError, or None."""
        self.failing = False
        """True while messages are being dropped (no segment open after a write error)."""
        self._next_retry = -math.inf
        self._next_flush = math.inf
        self._rotate_at = math.inf
        self.deadline = math.inf
        """The next instant the caller must end the interval (`end_interval`): the earlier of
        the timed flush and the rotation while a segment is open, the next retry while
        failing."""

    # -- state -----------------------------------------------------------------------------

    @property
    def open(self) -> bool:
        """True while a segment is open."""
        return self._seg is not None

    @property
    def paths(self) -> list[Path]:
        """Segment files started so far, in order (an abandoned segment stays listed)."""
        if self.path is None:
            return []
        return [segment_path(self.path, i) for i in range(self._next_index)]

    @property
    def segments(self) -> int:
        """The number of segment files started so far."""
        return self._next_index

    @property
    def bytes_written(self) -> int:
        """Bytes handed to the segment files (compressed chunks, indexes, summaries)."""
        seg = self._seg
        return self._bytes_done + (seg.file.count if seg is not None else 0)

    # -- starting and ending ---------------------------------------------------------------

    def start(self, now: float) -> None:
        """Open the first segment (or, without a file, start the interval timer).

        Raises
        ------
        FileExistsError
            Numbered segments of this name exist already.
        OSError
            The first segment cannot be opened for a reason a full disk does not explain.
        """
        if self.path is None:
            self.restart_timer(now)
            return
        stale = numbered_segments(self.path)
        if stale:
            # Its segments would be read as this recording's: refuse rather than delete a
            # file this run did not write.
            raise FileExistsError(errno.EEXIST, f"{stale[0][1].name} exists (a segment of an "
                                  f"earlier recording named {self.path.name}?): move or "
                                  "remove it, or record under another name", str(stale[0][1]))
        try:
            self._open_segment(now, raise_errors=True)
        except OSError as exc:
            if exc.errno not in _TRANSIENT_ERRNOS:
                raise
            self._fail(exc, now)

    def restart_timer(self, now: float) -> None:
        """Without a file: the next interval ends ``flush_interval`` from now."""
        self._next_flush = self.deadline = now + self._flush_interval

    def mark_closed(self) -> None:
        """No more messages: no more retries or interval ends."""
        self.closed = True
        self.deadline = math.inf

    def finish(self, now: float) -> None:
        """Finish the open segment (summary, footer) and close it; errors are recorded."""
        seg = self._seg
        if seg is None:
            return
        try:
            self._finish_segment(seg)
        except OSError as exc:
            self._fail(exc, now)

    def end_interval(self, now: float) -> None:
        """The deadline passed (the caller's buffers are written): rotate if due, else end
        the open chunks. While failing: retry, at most once per `RETRY_INTERVAL`."""
        seg = self._seg
        if seg is None:
            if self.path is None:
                self.restart_timer(now)
            elif not self.closed and now >= self._next_retry:
                self._open_segment(now)
            return
        if now >= self._rotate_at:
            self._rotate(seg, now)
        else:
            self.flush(now)

    def flush(self, now: float) -> None:
        """End the open chunks and push them to the operating system; restart the timer."""
        seg = self._seg
        if seg is None:
            return
        try:
            seg.end_chunks()
        except OSError as exc:
            self._fail(exc, now)
            return
        self._pending = 0
        self._next_flush = now + self._flush_interval
        self.deadline = min(self._next_flush, self._rotate_at)

    # -- adding ----------------------------------------------------------------------------

    def keep_metadata(self, name: str, values: dict[str, str]) -> None:
        """Put a named metadata record at the head of every segment opened from now on."""
        self._later_metadata[name] = dict(values)

    def add_metadata(self, name: str, values: dict[str, str], now: float) -> None:
        """A named metadata record in the open segment, now."""
        if self._seg is None:
            return
        try:
            self._seg.writer.add_metadata(name, dict(values))
            self._seg.metadata = True
        except OSError as exc:
            self._fail(exc, now)

    def add_message(self, topic: str, schema: Schema, timestamp_ns: int, data: bytes,
                    rows: int, now: float) -> None:
        """Add one message holding ``rows`` rows (or count them dropped)."""
        sequence = self._sequence.get(topic, 0)
        self._sequence[topic] = sequence + 1
        seg = self._segment_for(rows, now)
        if seg is None:
            return
        try:
            seg.use(topic in self._separate)
            channel_id = seg.channel(topic, schema)
            seg.writer.add_message(channel_id, timestamp_ns, data, timestamp_ns, sequence)
        except OSError as exc:
            self.messages_dropped += rows
            self._fail(exc, now)
            return
        self._added(seg, rows)

    def add_row_messages(self, topic: str, schema: Schema, t_ns: np.ndarray, data: Messages,
                         now: float) -> None:
        """Add one message per row, at the rows' times (or count them dropped): a list of
        messages, or an (N, size) uint8 array of N messages of one size."""
        n = len(data)
        first = self._sequence.get(topic, 0)
        self._sequence[topic] = first + n
        seg = self._segment_for(n, now)
        if seg is None:
            return
        try:
            seg.use(topic in self._separate)
            add_messages(seg.writer, seg.channel(topic, schema), t_ns, data, first)
        except OSError as exc:
            self.messages_dropped += n
            self._fail(exc, now)
            return
        self._added(seg, n)

    def _segment_for(self, rows: int, now: float) -> _Segment | None:
        """The segment to add ``rows`` rows to, rotated first when it is full; None when no
        segment is open (the rows count as dropped when there is a file to miss them)."""
        seg = self._seg
        if seg is not None and seg.file.count >= self._byte_limit:
            self._rotate(seg, now)
            seg = self._seg
        if seg is None and self.path is not None:
            self.messages_dropped += rows
        return seg

    def _added(self, seg: _Segment, rows: int) -> None:
        """Count ``rows`` rows added to the open chunk of ``seg``."""
        seg.chunks = True
        self.messages_written += rows
        self._pending += rows

    # -- segments --------------------------------------------------------------------------

    def _rotate(self, seg: _Segment, now: float) -> None:
        try:
            self._finish_segment(seg)
        except OSError as exc:
            self._fail(exc, now)
            return
        self._open_segment(now)

    def _finish_segment(self, seg: _Segment) -> None:
        seg.finish()
        self._pending = 0
        self._bytes_done += seg.file.count
        self._seg = None

    def _open_segment(self, now: float, raise_errors: bool = False) -> bool:
        assert self.path is not None
        index = self._next_index
        path = segment_path(self.path, index)
        file: _CountingFile | None = None
        try:
            file = _CountingFile(self._opener(path))
            writer = Writer(file, chunk_size=self._chunk_size, compression=CompressionType.ZSTD,
                            index_types=_INDEX_TYPES, enable_crcs=True, enable_data_crcs=True)
            writer.start(profile="", library=f"canfdi/{__version__}; {LIBRARY_IDENTIFIER}")
            if self._metadata is not None:
                writer.add_metadata(METADATA_NAME, self._metadata)
            for name, values in self._later_metadata.items():
                writer.add_metadata(name, values)
            seg = _Segment(path, file, writer)
            seg.metadata = self._metadata is not None or bool(self._later_metadata)
            writer.flush()
        except OSError as exc:
            if file is not None:
                with contextlib.suppress(OSError):
                    file.close()
                # Nothing useful made it into the file; the next attempt reuses the name.
                with contextlib.suppress(OSError):
                    path.unlink()
            if raise_errors:
                raise
            self._fail(exc, now)
            return False
        self._seg = seg
        self._next_index = index + 1
        self._next_flush = now + self._flush_interval
        self._rotate_at = now + self._rotate_seconds
        self.deadline = min(self._next_flush, self._rotate_at)
        if self.failing:
            self.failing = False
            logger.warning("MCAP recording resumed in %s (%d messages dropped so far)", path,
                           self.messages_dropped)
        return True

    def _fail(self, exc: OSError, now: float) -> None:
        self.write_errors += 1
        self.last_error = exc
        if not self.failing:
            self.failing = True
            assert self.path is not None
            logger.warning(
                "MCAP recording to %s failed (%s); dropping messages, retrying every %.0f s",
                self._seg.path if self._seg is not None
                else segment_path(self.path, self._next_index),
                exc,
                RETRY_INTERVAL,
            )
        # The open chunks never reached the file: their rows are lost with the segment.
        self.messages_dropped += self._pending
        self.messages_written -= self._pending
        self._pending = 0
        seg = self._seg
        if seg is not None:
            seg.abandon()
            self._bytes_done += seg.file.count
            self._seg = None
        self._next_retry = now + RETRY_INTERVAL
        self.deadline = self._next_retry if not self.closed else math.inf

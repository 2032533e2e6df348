"""`McapRecorder`: write a monitor run into MCAP, crash-safely, with rotation and disk-full
tolerance.

The topics, schemas and block layouts it writes are canfdi.io.schemas'; the block messages are
packed by canfdi.io.blocks; segment names are canfdi.io.segments'. canfdi.io.reader reads the
files back.

Buffering and crash safety
--------------------------
Frames, samples and residual rows are appended to buffers inside the recorder (0.2 to 2 us a
row, no JSON) and written as one block message when a buffer holds
``block_frames``, ``block_samples`` or ``block_residuals`` rows, on every timed flush, on
`McapRecorder.flush` and on `McapRecorder.close`. The mcap writer in turn keeps the open chunk in
memory and writes it only when it exceeds ``chunk_size`` or on ``Writer.flush()``, which
finishes the open chunk (if it holds a message), writes it and flushes the output stream.
Frame blocks go into chunks of their own (two chunks are open: the frames' and the other
topics'), so that a replay, which reads frames only, inflates none of the per-sample messages
(two thirds of a capture's bytes); both end together.
Whenever ``flush_interval`` seconds (on the injected clock) have passed since the last flush,
the recorder writes every buffer out and calls ``Writer.flush()``: the check is a single
comparison inside every write or append (no thread, no lock), and `McapRecorder.flush` forces
it. The flushed bytes are in the operating system's page cache, so a killed process (SIGKILL,
crash) loses only the rows still buffered and the messages of the chunk still open: about the
last ``flush_interval`` seconds, as long as the caller writes at least that often (the
monitor's frames and status messages do; an idle caller should call `McapRecorder.flush`).
There is no fsync: a power loss may lose what the kernel had not yet written back. Such a file
has no summary; `read_log` reads it in file order and stops at the last complete record, so a
block is read back whole or not at all.

Rotation
--------
With ``rotate_bytes`` or ``rotate_seconds``, the first message written after the segment's
file reached ``rotate_bytes`` (bytes reach the file a chunk at a time, so a segment overshoots
by at most a chunk and its summary) or the first write after the segment has been open
``rotate_seconds`` (the buffers are written into it first) finishes the segment cleanly
(summary and footer) and continues in ``<stem>-0001<suffix>``, ``<stem>-0002<suffix>``... next
to the first file, which keeps the given name. `log_segments` lists the family in order. Stale
numbered segments of the same name left by an earlier run are deleted when a recorder starts,
so that the family is this run's only.

Write errors
------------
An `OSError` while writing (typically ENOSPC: disk full) never reaches the caller of the write
methods. The recorder records it (`McapRecorder.last_error`, `McapRecorder.write_errors`), logs
one warning per episode, abandons the segment (its flushed part stays readable as a truncated
file), counts the rows of its unflushed chunk and every block or message written while failing
as dropped (`McapRecorder.messages_dropped`), and retries at most once per ``RETRY_INTERVAL``
seconds, on a later write, by opening the next segment: recording resumes in a new segment when
space returns. Rows still in the recorder's buffers when recording resumes are not lost. The
constructor raises for errors that cannot heal by themselves (a missing directory, no
permission) so that a bad path is reported at start.
"""

from __future__ import annotations

import contextlib
import errno
import json
import logging
import math
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from types import TracebackType
from typing import IO, TYPE_CHECKING, Any, Self

import numpy as np
from mcap._chunk_builder import ChunkBuilder
from mcap.opcode import Opcode
from mcap.records import MessageIndex
from mcap.writer import LIBRARY_IDENTIFIER, CompressionType, IndexType, Writer
from numpy.typing import ArrayLike, NDArray

from canfdi import __version__
from canfdi.bus.frames import MAX_DATA, FrameBlock
from canfdi.io.blocks import (
    FRAME_SIZE,
    RowEncoder,
    Rows,
    check_column,
    check_matrix,
    encode_frame_block,
    encode_message,
    first_time,
    float_row,
    pack_frame,
    stamp,
    unique_names,
)
from canfdi.io.schemas import (
    FRAME_DTYPE,
    FRAME_STATUSES,
    GENERIC_SCHEMA,
    LOG_LEVELS,
    MESSAGE_ENCODING,
    METADATA_NAME,
    SCHEMA_ENCODING,
    SCHEMAS,
    TOPIC_ESTIMATES,
    TOPIC_EVENTS,
    TOPIC_FRAMES,
    TOPIC_LOG,
    TOPIC_RESIDUALS,
    TOPIC_SAMPLES,
    TOPIC_STATUS,
    residual_schema,
    sample_schema,
)
from canfdi.io.segments import numbered_segments, segment_path

if TYPE_CHECKING:
    from canfdi.core.records import FaultEvent, Sample

__all__ = ["RETRY_INTERVAL", "McapLogHandler", "McapRecorder", "Tap"]

logger = logging.getLogger(__name__)

if not hasattr(Writer, "flush"):  # pragma: no cover - depends on the installed mcap
    # Without Writer.flush a chunk only ends when full, which breaks the crash-loss bound.
    raise ImportError("canfdi.io.writer needs an mcap package whose Writer has flush() (1.6+)")

RETRY_INTERVAL = 1.0
"""Seconds (on the recorder's clock) between attempts to resume after a write error."""

_DEFAULT_CHUNK_SIZE = 1024 * 1024
# errno values of a failing first open that may heal (space freed), so that a monitor started
# on a full disk still monitors; anything else at start is a configuration error.
_TRANSIENT_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EIO})
_MAX_STATUSES = 256  # status is a uint8 code

# Serialised once: every segment registers the same bytes.
_SCHEMA_BYTES = {
    topic: (name, json.dumps(schema).encode()) for topic, (name, schema) in SCHEMAS.items()
}
_GENERIC_SCHEMA_BYTES = (GENERIC_SCHEMA[0], json.dumps(GENERIC_SCHEMA[1]).encode())
# Every index but attachments' (canfdi writes none): mcap writes a summary group per index
# type even when it is empty, which MCAP checkers (pymcap-cli doctor) report as an error.
_INDEX_TYPES = IndexType.CHUNK | IndexType.MESSAGE | IndexType.METADATA

ZSTD_LEVEL = 1
"""The zstd level of the logs' chunks. mcap's Python Writer compresses each chunk with
``zstandard.compress`` at its default level 3 and has no option for it (its Go writer records
at the fastest level by default, for the same reason): at level 1 a monitor log's chunks come
out the same size (81.1 against 81.4 bytes per frame) in 17 % less of the recorder's time,
which is most of what throughput spends. The level is given to the ``zstandard`` that
mcap.writer calls (below): every MCAP this process writes gets it, a valid zstd chunk that
every reader inflates."""


class _Zstandard:
    """``zstandard`` as mcap.writer uses it, compressing at `ZSTD_LEVEL`."""

    def __init__(self, module: Any) -> None:
        self._module = module

    def compress(self, data: bytes, level: int = ZSTD_LEVEL) -> bytes:
        return self._module.compress(data, level)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._module, name)


def _use_zstd_level() -> None:
    import mcap.writer as mcap_writer

    module = getattr(mcap_writer, "zstandard", None)
    if module is not None and not isinstance(module, _Zstandard):
        mcap_writer.zstandard = _Zstandard(module)


_use_zstd_level()

# A Message record's head: opcode, record length, channel id, sequence, log and publish time.
_MESSAGE_HEAD = np.dtype([("op", "u1"), ("length", "<u8"), ("channel", "<u2"),
                          ("sequence", "<u4"), ("log_time", "<u8"), ("publish_time", "<u8")])
_HEAD_SIZE = _MESSAGE_HEAD.itemsize  # 31: packed, no alignment
_OP_MESSAGE = 0x05


class _RowIndex(MessageIndex):
    """A row channel's message index in the open chunk: its ``records`` are (N, 2) arrays of
    (log time, offset), one per batch, packed by numpy when the chunk ends (mcap's holds a
    tuple per message and writes each with two struct calls: a fifth of a capture's time)."""

    def write(self, stream: Any) -> None:
        entries = np.concatenate(self.records).astype("<u8").tobytes()
        stream.start_record(Opcode.MESSAGE_INDEX)
        stream.write2(self.channel_id)
        stream.write4(len(entries))
        stream.write(entries)
        stream.finish_record()


def _add_messages(writer: Writer, channel_id: int, times: np.ndarray, data: list[bytes],
                  first_sequence: int) -> None:
    """Add N messages of one channel to the writer's open chunk at once, as N calls of
    ``Writer.add_message`` would (the same records, message index and statistics).

    A row topic writes a message per sample, and ``add_message`` costs about 3.5 us each in
    Python objects; here the record heads are one numpy array and the records one join. It uses
    the attributes of mcap's Writer that hold the open chunk and the statistics (mcap 1.x);
    without them it falls back to ``add_message``. The files are checked by third-party
    readers (tests/integration/test_third_party_readers.py).
    """
    builder = getattr(writer, "_Writer__chunk_builder", None)
    stats = getattr(writer, "_Writer__statistics", None)
    finalize = getattr(writer, "_Writer__maybe_finalize_chunk", None)
    n = len(data)
    if builder is None or stats is None or finalize is None:
        for i, (t, d) in enumerate(zip(times.tolist(), data, strict=True)):
            writer.add_message(channel_id, t, d, t, first_sequence + i)
        return
    if not n:
        return
    sizes = np.fromiter(map(len, data), dtype=np.int64, count=n)
    head = np.empty(n, dtype=_MESSAGE_HEAD)
    head["op"] = _OP_MESSAGE
    head["length"] = sizes + (_HEAD_SIZE - 9)
    head["channel"] = channel_id
    head["sequence"] = (first_sequence + np.arange(n)) & 0xFFFFFFFF
    head["log_time"] = times
    head["publish_time"] = times
    raw = head.tobytes()
    heads = [raw[i : i + _HEAD_SIZE] for i in range(0, n * _HEAD_SIZE, _HEAD_SIZE)]
    start = builder.count
    offsets = np.empty(n, dtype=np.int64)
    offsets[0] = start
    np.cumsum(sizes[:-1] + _HEAD_SIZE, out=offsets[1:])
    offsets[1:] += start
    builder.record_writer.write(b"".join(
        [part for pair in zip(heads, data, strict=True) for part in pair]))
    index = builder.message_indices.get(channel_id)
    if index is None:
        index = builder.message_indices[channel_id] = _RowIndex(channel_id=channel_id,
                                                                 records=[])
    index.records.append(np.column_stack([times, offsets]))
    t_min, t_max = int(times.min()), int(times.max())
    builder.message_start_time = (t_min if builder.num_messages == 0
                                  else min(builder.message_start_time, t_min))
    builder.message_end_time = max(builder.message_end_time, t_max)
    builder.num_messages += n
    stats.message_start_time = (t_min if stats.message_count == 0
                                else min(stats.message_start_time, t_min))
    stats.message_end_time = max(stats.message_end_time, t_max)
    stats.channel_message_counts[channel_id] += n
    stats.message_count += n
    finalize()


Tap = Callable[[str, tuple[str, bytes], int, bytes], None]
"""Sees every message the recorder writes: ``(topic, (schema name, JSON schema bytes),
log_time_ns, message bytes)`` (a live Foxglove server, say)."""

# ------------------------------------------------------------------------------------------
# files
# ------------------------------------------------------------------------------------------


def _open_file(path: Path) -> IO[bytes]:
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
    """One open MCAP file: its writer and the channel id of every topic registered in it."""

    __slots__ = ("channels", "chunks", "file", "frames_open", "generic_schema", "metadata",
                 "other_chunk", "path", "row_schemas", "writer")

    def __init__(self, path: Path, file: _CountingFile, writer: Writer) -> None:
        self.path = path
        self.file = file
        self.writer = writer
        self.channels: dict[str, int] = {}
        # The schema each row topic's channel was registered with (its names may widen).
        self.row_schemas: dict[str, tuple[str, bytes]] = {}
        self.generic_schema = 0
        self.metadata = False
        self.chunks = False
        # The open chunk the writer is not filling (mcap 1.x's Writer holds one, in this
        # attribute; without it frames share the chunks).
        self.other_chunk: ChunkBuilder | None = (
            ChunkBuilder() if hasattr(writer, "_Writer__chunk_builder") else None)
        self.frames_open = False  # the writer is filling the frames' chunk

    def use(self, frames: bool) -> None:
        """Make the writer fill the frames' open chunk (or the other topics')."""
        if frames != self.frames_open and self.other_chunk is not None:
            writer = self.writer
            writer._Writer__chunk_builder, self.other_chunk = (  # type: ignore[attr-defined]
                self.other_chunk, writer._Writer__chunk_builder)  # type: ignore[attr-defined]
            self.frames_open = frames

    def end_chunks(self) -> None:
        """Write both open chunks (those holding a message) and flush the stream."""
        self.use(not self.frames_open)
        self.writer.flush()
        self.use(not self.frames_open)
        self.writer.flush()

    def register_rows(self, topic: str, schema: tuple[str, bytes]) -> int:
        schema_id = self.writer.register_schema(schema[0], SCHEMA_ENCODING, schema[1])
        channel_id = self.writer.register_channel(topic, MESSAGE_ENCODING, schema_id)
        self.channels[topic] = channel_id
        self.row_schemas[topic] = schema
        return channel_id

    def register(self, topic: str) -> int:
        """A channel for ``topic``, registered with its first message (so that the schema and
        channel records reach the file in the chunk that holds it: a segment without messages
        lists none in its summary either)."""
        known = _SCHEMA_BYTES.get(topic)
        if known is not None:
            schema_id = self.writer.register_schema(known[0], SCHEMA_ENCODING, known[1])
            channel_id = self.writer.register_channel(topic, MESSAGE_ENCODING, schema_id)
            self.channels[topic] = channel_id
            return channel_id
        if not self.generic_schema:
            name, data = _GENERIC_SCHEMA_BYTES
            self.generic_schema = self.writer.register_schema(name, SCHEMA_ENCODING, data)
        channel_id = self.writer.register_channel(topic, MESSAGE_ENCODING, self.generic_schema)
        self.channels[topic] = channel_id
        return channel_id

    def abandon(self) -> None:
        # A full disk makes the buffered writer's flush-on-close fail too; the descriptor is
        # closed regardless, which is all that is wanted here.
        with contextlib.suppress(OSError):
            self.file.close()


# ------------------------------------------------------------------------------------------
# the recorder
# ------------------------------------------------------------------------------------------


class McapRecorder:
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

    Raises
    ------
    OSError
        When the first segment cannot be opened for a reason a full disk does not explain
        (missing directory, permissions). Later errors are reported, never raised.

    Notes
    -----
    Use as a context manager, or call `close`. Not thread-safe: one writer thread.
    """

    def __init__(
        self,
        path: str | Path,
        *,
        metadata: dict[str, str] | None = None,
        flush_interval: float = 1.0,
        rotate_bytes: int | None = None,
        rotate_seconds: float | None = None,
        clock: Callable[[], float] = time.monotonic,
        opener: Callable[[Path], IO[bytes]] = _open_file,
        chunk_size: int = _DEFAULT_CHUNK_SIZE,
        block_frames: int = 4096,
        block_samples: int = 1024,
        block_residuals: int = 1024,
        tap: Tap | None = None,
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
        self._path = Path(path) if path is not None else None
        self._tap = tap
        self._metadata = dict(metadata) if metadata is not None else None
        self._later_metadata: dict[str, dict[str, str]] = {}
        self._flush_interval = float(flush_interval)
        # Infinite limits keep the hot-path test a plain comparison, with no None checks.
        self._byte_limit = rotate_bytes if rotate_bytes is not None else math.inf
        self._rotate_seconds = float(rotate_seconds) if rotate_seconds is not None else math.inf
        self._clock = clock
        self._opener = opener
        self._chunk_size = int(chunk_size)

        # Frames: packed FRAME_DTYPE records; rows whose payload the record cannot hold.
        self._frames = bytearray()
        self._frames_limit = int(block_frames) * FRAME_SIZE
        self._long: dict[int, bytes] = {}
        self._status_codes: dict[str, int] = {}
        self._status_names: list[str] = []
        self._statuses_json = b"[]"
        self._reset_statuses()
        # Samples: k, t_ns, gap, U rows, Z rows.
        self._samples = Rows((np.int64, np.int64, np.int64, np.float64, np.float64))
        self._block_samples = int(block_samples)
        self._inputs: list[str] = []
        self._outputs: list[str] = []
        self._inputs_given: Any = None  # the caller's objects, for a cheap identity check
        self._outputs_given: Any = None
        # Residuals: k, t_ns, R rows, normalized rows, statistic rows.
        self._residuals = Rows((np.int64, np.int64, np.float64, np.float64, np.float64))
        self._block_residuals = int(block_residuals)
        self._residual_names: list[str] = []
        self._sample_drive: str | None = None
        self._residual_drive: str | None = None
        self._residual_names_given: Any = None
        self._sample_encoder: RowEncoder | None = None
        self._residual_encoder: RowEncoder | None = None
        # Every name each row topic has held so far, and the schema naming them.
        self._row_names: dict[str, list[list[str]]] = {
            TOPIC_SAMPLES: [[], []], TOPIC_RESIDUALS: [[]]}
        self._row_schema: dict[str, tuple[str, bytes]] = {}
        self._sequence: dict[str, int] = {}

        self._seg: _Segment | None = None
        # Segments 0 .. _next_index - 1 have been started (their names follow from the index:
        # no list of them grows with a run of months).
        self._next_index = 0
        self._closed = False
        self._messages_written = 0
        self._messages_dropped = 0
        self._pending = 0  # rows accepted into the open chunk since the last successful flush
        self._bytes_done = 0  # bytes of segments no longer open
        self._write_errors = 0
        self._last_error: OSError | None = None
        self._failing = False
        self._next_retry = -math.inf
        self._next_flush = math.inf
        self._rotate_at = math.inf
        # The next instant a write must look up from the hot path: the earlier of the timed
        # flush and the rotation while a segment is open, the next retry while failing.
        self._deadline = math.inf

        now = clock()
        if self._path is None:
            # No file: the buffers still go out on time, to the tap.
            self._next_flush = self._deadline = now + self._flush_interval
            return
        stale = numbered_segments(self._path)
        if stale:
            # Its segments would be read as this recording's: refuse rather than delete a
            # file this run did not write.
            raise FileExistsError(errno.EEXIST, f"{stale[0][1].name} exists (a segment of an "
                                  f"earlier recording named {self._path.name}?): move or "
                                  "remove it, or record under another name", str(stale[0][1]))

        try:
            self._open_segment(now, raise_errors=True)
        except OSError as exc:
            if exc.errno not in _TRANSIENT_ERRNOS:
                raise
            self._fail(exc, now)

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
        if self._path is None:
            return []
        return [segment_path(self._path, i) for i in range(self._next_index)]

    @property
    def segments(self) -> int:
        """The number of segment files started so far (``len(paths)``, without building
        them)."""
        return self._next_index

    @property
    def messages_written(self) -> int:
        """Rows (frames, samples, residual rows) and single messages (estimates, events, status,
        `write`) handed to a segment and not known to be lost. Rows still buffered in the
        recorder are not counted yet (`buffered`)."""
        return self._messages_written

    @property
    def messages_dropped(self) -> int:
        """Rows and messages lost to write errors: refused while failing, in an unflushed
        chunk, or still buffered at `close` while failing."""
        return self._messages_dropped

    @property
    def buffered(self) -> int:
        """Frames, samples and residual rows waiting in the recorder's buffers."""
        return len(self._frames) // FRAME_SIZE + self._samples.count + self._residuals.count

    @property
    def bytes_written(self) -> int:
        """Bytes handed to the segment files (compressed chunks, indexes, summaries)."""
        seg = self._seg
        return self._bytes_done + (seg.file.count if seg is not None else 0)

    @property
    def write_errors(self) -> int:
        """Number of OSErrors met (each failed write, flush, rotation or retry counts once)."""
        return self._write_errors

    @property
    def last_error(self) -> OSError | None:
        """The most recent OSError, or None if there never was one."""
        return self._last_error

    @property
    def failing(self) -> bool:
        """True while messages are being dropped (no segment open after a write error)."""
        return self._failing

    @property
    def closed(self) -> bool:
        """True once `close` has been called."""
        return self._closed

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
        self._write_now(topic, timestamp_ns, encode_message(message))

    def _begin_write(self) -> float:
        """Refuse writes after close; run the timed flush when it is due; the clock's now."""
        if self._closed:
            raise ValueError("write to a closed McapRecorder")
        now = self._clock()
        if now >= self._deadline:
            self._tick(now)
        return now

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
        code = self._status_codes.get(status)
        if code is None:
            code = self._new_status(status)
        if type(data) is not bytes:
            data = bytes(data)
        n = len(data)
        if dlc is None and n <= MAX_DATA:
            self._frames += pack_frame(timestamp_ns, frame_id, n, flags | extended, code, data)
        else:
            dlc = n if dlc is None else dlc
            if n != min(dlc, MAX_DATA):
                self._long[len(self._frames) // FRAME_SIZE] = data
            self._frames += pack_frame(timestamp_ns, frame_id, dlc, flags | extended, code, data)
        if len(self._frames) >= self._frames_limit:
            self._emit_frames(now, full_only=True)

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
        n = block.size
        if statuses is None:
            if block.status is None:
                raise ValueError("write_frames: the block holds no statuses and none are given")
            statuses = block.status
        records = np.zeros(n, dtype=FRAME_DTYPE)
        records["t_ns"] = block.t_ns
        records["id"] = block.id
        records["dlc"] = block.dlc
        records["data"] = block.data
        records["flags"] = block.flags
        records["status"] = self._status_array(statuses, n, status_names)
        if not n:
            return
        if block.long:  # (after _status_array, which may have written the buffer out)
            base = len(self._frames) // FRAME_SIZE
            dlc = block.dlc
            for row, data in block.long.items():
                if len(data) != min(int(dlc[row]), MAX_DATA):
                    self._long[base + row] = bytes(data)
        self._frames += records.tobytes()
        if len(self._frames) >= self._frames_limit:
            self._emit_frames(now, full_only=True)

    def write_sample(
        self, sample: Sample, input_names: Sequence[str], output_names: Sequence[str],
        drive: str | None = None,
    ) -> None:
        """Buffer a decoded sample for `TOPIC_SAMPLES` (a cheap append).

        Parameters
        ----------
        sample : Sample
            The sample; ``u`` and ``z`` are named by ``input_names`` and ``output_names``. Its
            arrays are kept until the block is written, so they must not be modified (a
            Sample is a frozen record).
        input_names, output_names : sequence of str
            The model's input and output names, in the sample's order. A change of names
            writes the buffered samples first.
        drive : str, optional
            The drive whose sample it is (several drives on one bus); a change of drive
            writes the buffered samples first.

        Raises
        ------
        ValueError
            After `close`, or if ``u`` or ``z`` does not match the names.
        """
        now = self._begin_write()
        if drive != self._sample_drive:
            self._emit_samples(now, full_only=False)
            self._sample_drive = drive
            self._sample_encoder = None
        if input_names is not self._inputs_given or output_names is not self._outputs_given:
            self._sample_names(input_names, output_names)
        u, z = sample.u, sample.z
        if len(u) != len(self._inputs) or len(z) != len(self._outputs):
            raise ValueError(
                f"sample has {len(u)} inputs and {len(z)} outputs for names "
                f"{self._inputs} and {self._outputs}"
            )
        rows = self._samples
        k_col, t_col, gap_col, u_col, z_col = rows.columns
        k_col.append(sample.k)
        t_col.append(sample.timestamp_ns)
        gap_col.append(sample.gap)
        u_col.append(u)
        z_col.append(z)
        rows.count += 1
        if rows.count >= self._block_samples:
            self._emit_samples(now, full_only=True)

    def write_samples(
        self,
        k: ArrayLike,
        t_ns: ArrayLike,
        U: ArrayLike,
        Z: ArrayLike,
        gap: ArrayLike,
        input_names: Sequence[str],
        output_names: Sequence[str],
        drive: str | None = None,
    ) -> None:
        """Buffer a block of decoded samples for `TOPIC_SAMPLES`, vectorised (copied).

        Parameters
        ----------
        k : (N,) int
            Sample indices.
        t_ns : (N,) int
            Sample times, ns since the epoch.
        U : (N, p) float
            Inputs, named by ``input_names``.
        Z : (N, q) float
            Outputs, named by ``output_names``.
        gap : (N,) int
            Samples lost just before each one.
        input_names, output_names : sequence of str
            The model's input and output names.
        drive : str, optional
            The drive whose samples they are (as `write_sample`).

        Raises
        ------
        ValueError
            After `close`, or for arrays of the wrong shape.
        """
        now = self._begin_write()
        if drive != self._sample_drive:
            self._emit_samples(now, full_only=False)
            self._sample_drive = drive
            self._sample_encoder = None
        if input_names is not self._inputs_given or output_names is not self._outputs_given:
            self._sample_names(input_names, output_names)
        n = len(np.asarray(k))
        arrays = (
            check_column(k, n, "k").astype(np.int64),
            check_column(t_ns, n, "t_ns").astype(np.int64),
            check_column(gap, n, "gap").astype(np.int64),
            check_matrix(U, n, len(self._inputs), "U"),
            check_matrix(Z, n, len(self._outputs), "Z"),
        )
        if not n:
            return
        self._samples.add(arrays)
        if self._samples.count >= self._block_samples:
            self._emit_samples(now, full_only=True)

    def write_residuals(
        self,
        timestamp_ns: int,
        k: int,
        names: Sequence[str],
        r: ArrayLike,
        normalized: ArrayLike,
        statistic: ArrayLike,
        drive: str | None = None,
    ) -> None:
        """Buffer one sample's residuals for `TOPIC_RESIDUALS` (a cheap append, copied).

        Parameters
        ----------
        timestamp_ns : int
            Time of the sample.
        k : int
            Sample index.
        names : sequence of str
            Residual names; ``r``, ``normalized`` and ``statistic`` are in this order. A
            change of names writes the buffered rows first.
        r : array_like
            Raw residual values.
        normalized : array_like
            Residuals divided by their standard deviation.
        statistic : array_like
            Page-Hinkley statistic max(g+, g-) of every residual.
        drive : str, optional
            The drive whose residuals they are; a change writes the buffered rows first.

        Raises
        ------
        ValueError
            After `close`, or if a row does not match the names.
        """
        now = self._begin_write()
        if drive != self._residual_drive:
            self._emit_residuals(now, full_only=False)
            self._residual_drive = drive
            self._residual_encoder = None
        if names is not self._residual_names_given:
            self._set_residual_names(names)
        r, normalized, statistic = float_row(r), float_row(normalized), float_row(statistic)
        m = len(self._residual_names)
        if len(r) != m or len(normalized) != m or len(statistic) != m:
            raise ValueError(f"residual rows do not match the {m} names {self._residual_names}")
        rows = self._residuals
        k_col, t_col, r_col, n_col, s_col = rows.columns
        k_col.append(k)
        t_col.append(timestamp_ns)
        r_col.append(r)
        n_col.append(normalized)
        s_col.append(statistic)
        rows.count += 1
        if rows.count >= self._block_residuals:
            self._emit_residuals(now, full_only=True)

    def write_residual_rows(
        self,
        k: ArrayLike,
        t_ns: ArrayLike,
        names: Sequence[str],
        R: ArrayLike,
        Rn: ArrayLike,
        stat: ArrayLike,
        drive: str | None = None,
    ) -> None:
        """Buffer many samples' residuals for `TOPIC_RESIDUALS`, vectorised (copied).

        Parameters
        ----------
        k : (N,) int
            Sample indices.
        t_ns : (N,) int
            Sample times, ns since the epoch.
        names : sequence of str
            The m residual names.
        R, Rn, stat : (N, m) float
            Raw residuals, normalized residuals, Page-Hinkley statistics.
        drive : str, optional
            The drive whose residuals they are (as `write_residuals`).

        Raises
        ------
        ValueError
            After `close`, or for arrays of the wrong shape.
        """
        now = self._begin_write()
        if drive != self._residual_drive:
            self._emit_residuals(now, full_only=False)
            self._residual_drive = drive
            self._residual_encoder = None
        if names is not self._residual_names_given:
            self._set_residual_names(names)
        n = len(np.asarray(k))
        m = len(self._residual_names)
        arrays = (
            check_column(k, n, "k").astype(np.int64),
            check_column(t_ns, n, "t_ns").astype(np.int64),
            check_matrix(R, n, m, "R"),
            check_matrix(Rn, n, m, "Rn"),
            check_matrix(stat, n, m, "stat"),
        )
        if not n:
            return
        self._residuals.add(arrays)
        if self._residuals.count >= self._block_residuals:
            self._emit_residuals(now, full_only=True)

    def write_estimates(
        self,
        timestamp_ns: int,
        k: int,
        hypothesis: str,
        estimates: Mapping[str, float],
        variances: Mapping[str, float],
    ) -> None:
        """Record a hypothesis' running estimates on `TOPIC_ESTIMATES`.

        Parameters
        ----------
        timestamp_ns : int
            Time of the sample.
        k : int
            Sample index.
        hypothesis : str
            Which fault hypothesis the estimates belong to (e.g. ``"actuator:torque"``).
        estimates, variances : mapping of str to float
            The estimates and their variances, same keys.
        """
        message = {
            "timestamp": stamp(timestamp_ns),
            "k": k,
            "hypothesis": hypothesis,
            "estimates": dict(estimates),
            "variances": dict(variances),
        }
        self._write_now(TOPIC_ESTIMATES, timestamp_ns, encode_message(message))

    def write_event(self, event: FaultEvent) -> None:
        """Record a diagnoser conclusion on `TOPIC_EVENTS` (at ``event.timestamp_ns``; fields
        that are None are left out, so that each has one JSON type). An accepted or refined
        fault's estimates go on `TOPIC_ESTIMATES` too (hypothesis ``drive/target:name``)."""
        message = {"timestamp": stamp(event.timestamp_ns),
                   **{k: v for k, v in event.as_dict().items() if v is not None}}
        self._write_now(TOPIC_EVENTS, event.timestamp_ns, encode_message(message))
        if event.kind in ("accepted", "refined") and event.estimates:
            who = f"{event.drive}/" if event.drive else ""
            self.write_estimates(event.timestamp_ns, event.sample,
                                 f"{who}{event.target}:{event.name}", event.estimates,
                                 event.variances or {})

    def write_log(self, timestamp_ns: int, level: str, message: str, name: str = "canfdi",
                  file: str = "", line: int = 0) -> None:
        """Record a log line on `TOPIC_LOG` (``foxglove.Log``: Foxglove's Log panel).

        Parameters
        ----------
        timestamp_ns : int
            Its time (the drive's).
        level : {"debug", "info", "warning", "error", "fatal"}
            Its level.
        message : str
            The line.
        name : str
            Who says it (``"canfdi.left"``: the monitor of drive left).
        file, line : str, int
            Where in the source, for log records that know.
        """
        if level not in LOG_LEVELS:
            raise ValueError(f"log level must be one of {', '.join(LOG_LEVELS)}, got {level!r}")
        record = {"timestamp": stamp(timestamp_ns), "level": LOG_LEVELS[level],
                  "message": message, "name": name, "file": file, "line": int(line)}
        self._write_now(TOPIC_LOG, timestamp_ns, encode_message(record))

    def write_status(
        self,
        timestamp_ns: int,
        state: str,
        samples: int,
        frames: Mapping[str, int],
        active_faults: int,
    ) -> None:
        """Record the monitor's periodic status on `TOPIC_STATUS`.

        Parameters
        ----------
        timestamp_ns : int
            Time of the report.
        state : str
            The monitor's state (e.g. ``"running"``).
        samples : int
            Samples decoded so far.
        frames : mapping of str to int
            Frame counters by kind (e.g. ``{"ok": .., "crc": ..}``).
        active_faults : int
            Faults currently accepted and compensated.
        """
        message = {
            "timestamp": stamp(timestamp_ns),
            "state": state,
            "samples": samples,
            "frames": dict(frames),
            "active_faults": active_faults,
        }
        self._write_now(TOPIC_STATUS, timestamp_ns, encode_message(message))

    def flush(self) -> None:
        """Write the buffered rows, end the open chunk and push everything written so far to
        the operating system.

        Also restarts the ``flush_interval`` timer. Errors are handled as in `write`; while
        failing the rows stay buffered.
        """
        if self._seg is not None:
            now = self._clock()
            self._emit_all(now)
            if self._seg is not None:
                self._flush_segment(now)

    def close(self) -> None:
        """Write the buffered rows, finish the current segment (summary, footer) and close it.

        Idempotent, never raises an OSError (it is recorded as in `write`); rows buffered while
        failing count as dropped.
        """
        if self._closed:
            return
        now = self._clock()
        try:
            self._emit_all(now)
        finally:
            self._closed = True
            self._deadline = math.inf
        seg = self._seg
        if seg is None:
            return
        try:
            self._finish_segment(seg)
        except OSError as exc:
            self._fail(exc, now)

    # -- internals: buffers ----------------------------------------------------------------

    def _reset_statuses(self) -> None:
        self._status_names = list(FRAME_STATUSES)
        self._status_codes = {name: code for code, name in enumerate(self._status_names)}
        self._statuses_json = json.dumps(self._status_names, separators=(",", ":")).encode()

    def _new_status(self, status: str) -> int:
        if not isinstance(status, str):
            raise TypeError(f"a frame status must be a str, got {type(status).__name__}")
        if len(self._status_names) >= _MAX_STATUSES:
            # Codes are bytes: the buffered frames keep the full table, the rest starts anew.
            self._emit_frames(self._clock(), full_only=False)
            self._reset_statuses()
        code = len(self._status_names)
        self._status_names.append(status)
        self._status_codes[status] = code
        self._statuses_json = json.dumps(self._status_names, separators=(",", ":")).encode()
        return code

    def _status_array(
        self, statuses: Any, n: int, status_names: Sequence[str] | None
    ) -> NDArray[np.uint8]:
        """uint8 codes into the status table of ``n`` frames' statuses."""
        if isinstance(statuses, str):
            names, index = [statuses], np.zeros(n, dtype=np.intp)
        else:
            values = np.asarray(statuses)
            if values.shape != (n,):
                raise ValueError(f"statuses must be ({n},), got shape {values.shape}")
            if values.dtype.kind in "iu":
                if status_names is None:
                    raise ValueError("integer statuses need status_names")
                names, index = list(status_names), values
            elif n:
                unique, index = np.unique(values, return_inverse=True)
                names = unique.tolist()
            else:
                names, index = [], values.astype(np.intp)
        missing = {name for name in names if name not in self._status_codes}
        if len(self._status_names) + len(missing) > _MAX_STATUSES:
            # Codes are bytes: the buffered frames keep the full table, the rest starts anew.
            self._emit_frames(self._clock(), full_only=False)
            self._reset_statuses()
            missing = {name for name in names if name not in self._status_codes}
            if len(self._status_names) + len(missing) > _MAX_STATUSES:
                raise ValueError(f"more than {_MAX_STATUSES} frame statuses in one call")
        codes = self._status_codes
        table = np.array(
            [codes[name] if name in codes else self._new_status(name) for name in names],
            dtype=np.uint8,
        )
        return table[index] if len(table) else np.zeros(n, dtype=np.uint8)

    def _sample_names(self, input_names: Sequence[str], output_names: Sequence[str]) -> None:
        inputs, outputs = unique_names(input_names, "input"), unique_names(output_names, "output")
        if inputs != self._inputs or outputs != self._outputs:
            self._emit_samples(self._clock(), full_only=False)
            self._inputs, self._outputs = inputs, outputs
            self._sample_encoder = None
        self._inputs_given, self._outputs_given = input_names, output_names

    def _set_residual_names(self, names: Sequence[str]) -> None:
        listed = unique_names(names, "residual")
        if listed != self._residual_names:
            self._emit_residuals(self._clock(), full_only=False)
            self._residual_names = listed
            self._residual_encoder = None
        self._residual_names_given = names

    def _widen(self, topic: str, groups: Sequence[Sequence[str]]) -> None:
        """Add names to a row topic's schema (a drive with other signals: the union)."""
        known = self._row_names[topic]
        if all(name in have for names, have in zip(groups, known, strict=True)
               for name in names) and topic in self._row_schema:
            return
        for names, have in zip(groups, known, strict=True):
            have.extend(name for name in names if name not in have)
        schema = (sample_schema(*known) if topic == TOPIC_SAMPLES else residual_schema(*known))
        self._row_schema[topic] = (schema["title"], json.dumps(schema).encode())

    def _emit_all(self, now: float) -> None:
        self._emit_frames(now, full_only=False)
        self._emit_samples(now, full_only=False)
        self._emit_residuals(now, full_only=False)

    def _emit_frames(self, now: float, full_only: bool) -> None:
        frames = self._frames
        size = len(frames)
        limit = self._frames_limit
        start = 0
        while size - start >= limit or (not full_only and start < size):
            end = min(start + limit, size)
            first = start // FRAME_SIZE
            count = (end - start) // FRAME_SIZE
            t0 = first_time(frames, start)[0]
            long = None
            if self._long:
                long = {
                    row - first: data
                    for row, data in self._long.items()
                    if first <= row < first + count
                }
            text = encode_frame_block(frames[start:end], count, t0, self._statuses_json, long)
            self._write(TOPIC_FRAMES, t0, text, count, now)
            start = end
        if start:
            del frames[:start]
            if self._long:
                shift = start // FRAME_SIZE
                self._long = {row - shift: d for row, d in self._long.items() if row >= shift}

    def _emit_samples(self, now: float, full_only: bool) -> None:
        rows, limit = self._samples, self._block_samples
        while rows.count >= limit or (not full_only and rows.count):
            k, t, gap, u, z = rows.take(min(limit, rows.count))
            encoder = self._sample_encoder
            if encoder is None:
                drive = {} if self._sample_drive is None else {"drive": self._sample_drive}
                encoder = self._sample_encoder = RowEncoder(
                    ("k", "gap"), (("u", self._inputs), ("z", self._outputs)), drive)
                self._widen(TOPIC_SAMPLES, (self._inputs, self._outputs))
            n = len(k)
            data = encoder.encode(t, np.column_stack([k, gap]),
                                  np.hstack([u.reshape(n, -1), z.reshape(n, -1)]))
            self._write_rows(TOPIC_SAMPLES, t, data, now)

    def _emit_residuals(self, now: float, full_only: bool) -> None:
        rows, limit = self._residuals, self._block_residuals
        while rows.count >= limit or (not full_only and rows.count):
            k, t, r, normalized, statistic = rows.take(min(limit, rows.count))
            names = self._residual_names
            encoder = self._residual_encoder
            if encoder is None:
                drive = {} if self._residual_drive is None else {"drive": self._residual_drive}
                encoder = self._residual_encoder = RowEncoder(
                    ("k",), (("r", names), ("normalized", names), ("statistic", names)), drive)
                self._widen(TOPIC_RESIDUALS, (names,))
            n, m = len(k), len(names)
            data = encoder.encode(t, k.reshape(n, 1), np.hstack(
                [r.reshape(n, m), normalized.reshape(n, m), statistic.reshape(n, m)]))
            self._write_rows(TOPIC_RESIDUALS, t, data, now)

    # -- internals: segments ---------------------------------------------------------------

    def write_metadata(self, name: str, values: dict[str, str]) -> None:
        """A named metadata record, now (teach-in's learned values, say) and at the head of
        every later segment."""
        if not all(isinstance(k, str) and isinstance(v, str) for k, v in values.items()):
            raise TypeError("metadata keys and values must be strings")
        self._later_metadata[name] = dict(values)
        now = self._begin_write()
        if self._seg is None:
            return
        try:
            self._seg.writer.add_metadata(name, dict(values))
            self._seg.metadata = True
        except OSError as exc:
            self._fail(exc, now)

    def _write_now(self, topic: str, timestamp_ns: int, data: bytes) -> None:
        now = self._begin_write()
        self._write(topic, timestamp_ns, data, 1, now)

    def _tick(self, now: float) -> None:
        """The deadline passed: retry while failing, else write the buffers and end the chunk
        (timed flush) or the segment (rotation)."""
        if self._seg is None:
            if self._path is None:  # no file: the buffers go to the tap on time
                self._emit_all(now)
                self._next_flush = self._deadline = now + self._flush_interval
            elif not self._closed and now >= self._next_retry:
                self._open_segment(now)
            return
        self._emit_all(now)
        seg = self._seg
        if seg is None:
            return
        if now >= self._rotate_at:
            self._rotate(seg, now)
        else:
            self._flush_segment(now)

    def _write(self, topic: str, timestamp_ns: int, data: bytes, rows: int, now: float) -> None:
        """Add one message of ``rows`` rows to the open segment (or count them dropped)."""
        sequence = self._sequence.get(topic, 0)
        self._sequence[topic] = sequence + 1
        if self._tap is not None:
            self._tap(topic, _SCHEMA_BYTES.get(topic, _GENERIC_SCHEMA_BYTES), timestamp_ns, data)
        seg = self._segment_for(rows, now)
        if seg is None:
            return
        try:
            seg.use(topic == TOPIC_FRAMES)
            channel_id = seg.channels.get(topic)
            if channel_id is None:
                channel_id = seg.register(topic)
            seg.writer.add_message(channel_id, timestamp_ns, data, timestamp_ns, sequence)
        except OSError as exc:
            self._messages_dropped += rows
            self._fail(exc, now)
            return
        self._added(seg, rows)

    def _write_rows(self, topic: str, t_ns: np.ndarray, data: list[bytes], now: float) -> None:
        """Add one message per row of a row topic (its channel registered with the schema
        naming every signal so far)."""
        n = len(data)
        times = t_ns.tolist()
        first = self._sequence.get(topic, 0)
        self._sequence[topic] = first + n
        schema = self._row_schema[topic]
        if self._tap is not None:
            tap = self._tap
            for t, d in zip(times, data, strict=True):
                tap(topic, schema, t, d)
        seg = self._segment_for(n, now)
        if seg is None:
            return
        try:
            seg.use(False)
            channel_id = seg.channels.get(topic)
            if channel_id is None or seg.row_schemas[topic] is not schema:
                channel_id = seg.register_rows(topic, schema)
            _add_messages(seg.writer, channel_id, t_ns, data, first)
        except OSError as exc:
            self._messages_dropped += n
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
        if seg is None and self._path is not None:
            self._messages_dropped += rows
        return seg

    def _added(self, seg: _Segment, rows: int) -> None:
        """Count ``rows`` rows added to the open chunk of ``seg``."""
        seg.chunks = True
        self._messages_written += rows
        self._pending += rows

    def _rotate(self, seg: _Segment, now: float) -> None:
        try:
            self._finish_segment(seg)
        except OSError as exc:
            self._fail(exc, now)
            return
        self._open_segment(now)

    def _flush_segment(self, now: float) -> None:
        seg = self._seg
        assert seg is not None
        try:
            seg.end_chunks()
        except OSError as exc:
            self._fail(exc, now)
            return
        self._pending = 0
        self._next_flush = now + self._flush_interval
        self._deadline = min(self._next_flush, self._rotate_at)

    def _finish_segment(self, seg: _Segment) -> None:
        # No summary group may be empty: leave out the chunk and metadata indexes of a segment
        # without chunks or metadata, and the repeated schemas and channels of one without
        # channels. (mcap's Writer fixes these when it is made; these are its attributes for
        # them. tests/integration/test_third_party_readers.py checks the result with
        # pymcap-cli doctor.)
        kinds = IndexType.MESSAGE
        if seg.chunks:
            kinds |= IndexType.CHUNK
        if seg.metadata:
            kinds |= IndexType.METADATA
        if hasattr(seg.writer, "_Writer__index_types"):
            seg.writer._Writer__index_types = kinds
            seg.writer._Writer__repeat_schemas = bool(seg.channels)
            seg.writer._Writer__repeat_channels = bool(seg.channels)
        seg.end_chunks()
        seg.writer.finish()
        seg.file.flush()
        seg.file.close()
        self._pending = 0
        self._bytes_done += seg.file.count
        self._seg = None

    def _open_segment(self, now: float, raise_errors: bool = False) -> bool:
        index = self._next_index
        path = segment_path(self._path, index)
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
        self._deadline = min(self._next_flush, self._rotate_at)
        if self._failing:
            self._failing = False
            logger.warning(
                "MCAP recording resumed in %s (%d messages dropped so far)",
                path,
                self._messages_dropped,
            )
        return True

    def _fail(self, exc: OSError, now: float) -> None:
        self._write_errors += 1
        self._last_error = exc
        if not self._failing:
            self._failing = True
            logger.warning(
                "MCAP recording to %s failed (%s); dropping messages, retrying every %.0f s",
                self._seg.path
                if self._seg is not None
                else segment_path(self._path, self._next_index),
                exc,
                RETRY_INTERVAL,
            )
        # The open chunk never reached the file: its rows are lost with the segment.
        self._messages_dropped += self._pending
        self._messages_written -= self._pending
        self._pending = 0
        seg = self._seg
        if seg is not None:
            seg.abandon()
            self._bytes_done += seg.file.count
            self._seg = None
        self._next_retry = now + RETRY_INTERVAL
        self._deadline = self._next_retry if not self._closed else math.inf


class McapLogHandler(logging.Handler):
    """A logging handler that records log lines on the recorder's `TOPIC_LOG` (Foxglove's Log
    panel), at the drive's time.

    Parameters
    ----------
    recorder : McapRecorder
        Where the lines go (nothing once it is closed).
    clock : callable
        The drive's time now, integer ns (the time of the last frame the monitor saw).
    level : int
        The least level recorded (default WARNING).

    The recorder's own warnings (a full disk) are not recorded through it: they are about the
    recording itself, and writing them would re-enter the recorder while it fails.
    """

    def __init__(self, recorder: McapRecorder, clock: Callable[[], int],
                 level: int = logging.WARNING) -> None:
        super().__init__(level)
        self.recorder = recorder
        self._clock = clock

    def emit(self, record: logging.LogRecord) -> None:
        if record.name == __name__ or self.recorder.closed:
            return
        level = {logging.DEBUG: "debug", logging.INFO: "info", logging.WARNING: "warning",
                 logging.ERROR: "error"}.get(record.levelno,
                                             "fatal" if record.levelno > logging.ERROR else "info")
        try:
            self.recorder.write_log(self._clock(), level, record.getMessage(), record.name,
                                     record.pathname, record.lineno)
        except Exception:  # a log line must never break what logged it
            self.handleError(record)

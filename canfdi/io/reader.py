"""Read canfdi's MCAP logs back: messages, metadata, frames, samples and residuals as arrays.

`read_log` streams one file's messages in file order (no summary needed: a file cut short by a
killed writer reads up to its last complete record); `read_metadata` gives the run-level
``"canfdi"`` record; `read_frames` (`iter_frame_blocks` a block at a time), `read_samples`
and `read_residuals` give a whole log (every rotated segment, canfdi.io.segments) as arrays,
of the block layout canfdi.io.blocks decodes and of the older one-row-per-message layout.
`mcap_frame_blocks` is the fast path replay reads frames with (canfdi.io.scan and a read-ahead
thread).
"""

from __future__ import annotations

import errno
import json
import logging
import queue
import threading
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from typing import IO, Any, NamedTuple

import numpy as np
from mcap.exceptions import EndOfFile
from mcap.records import Channel, Chunk, Footer, Message, Metadata
from mcap.stream_reader import StreamReader
from numpy.typing import NDArray

from canfdi.bus.frames import FrameBlock
from canfdi.io.blocks import (
    Rows,
    decode_frame_rows,
    decode_frames,
    decode_residual_block,
    decode_sample_block,
    gathered,
    no_frames,
)
from canfdi.io.scan import UnsupportedLog, scan_topic
from canfdi.io.schemas import METADATA_NAME, TOPIC_FRAMES, TOPIC_RESIDUALS, TOPIC_SAMPLES
from canfdi.io.segments import log_segments

__all__ = [
    "LogReader",
    "ResidualArrays",
    "SampleArrays",
    "iter_frame_blocks",
    "log_drives",
    "mcap_frame_blocks",
    "read_frames",
    "read_log",
    "read_metadata",
    "read_residuals",
    "read_samples",
]

logger = logging.getLogger(__name__)


class _ExactReader:
    """A file view whose read(n) returns n bytes or raises EndOfFile.

    mcap's ReadDataStream only fails on an empty read, so a record cut short by truncation
    would be parsed from too few bytes (a garbled message, or a zstd error on a partial
    chunk). Failing on any short read makes every incomplete record an EndOfFile.
    """

    __slots__ = ("_read",)

    def __init__(self, file: IO[bytes]) -> None:
        self._read = file.read

    def read(self, n: int) -> bytes:
        data = self._read(n)
        if len(data) != n:
            raise EndOfFile()
        return data


class LogReader:
    """Messages of one MCAP file in file order: an iterator of (topic, log_time ns, message).

    Streams the file (no seeking, no sorting, no summary needed), so it reads a file cut short
    by a killed writer as well as a complete one: it stops at the last complete record without
    raising. After iteration, `messages_read`, `complete` and `truncated` describe what was
    found. Use `read_log` to make one.

    Parameters
    ----------
    path : str or Path
        The MCAP file.
    topics : iterable of str, optional
        Only these topics (all when None).

    Raises
    ------
    mcap.exceptions.InvalidMagic
        While iterating, if the file is not an MCAP file.
    """

    def __init__(self, path: str | Path, topics: Iterable[str] | None = None) -> None:
        self.path = Path(path)
        self._topics = frozenset(topics) if topics is not None else None
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
        topics = self._topics
        wanted: dict[int, str] = {}
        loads = json.loads
        with open(self.path, "rb") as file:
            records = StreamReader(_ExactReader(file)).records
            try:
                for record in records:
                    if isinstance(record, Message):
                        topic = wanted.get(record.channel_id)
                        if topic is not None:
                            self.messages_read += 1
                            yield topic, record.log_time, loads(record.data)
                    elif isinstance(record, Channel):
                        if topics is None or record.topic in topics:
                            wanted[record.id] = record.topic
                    elif isinstance(record, Footer):
                        self.complete = True
            except EndOfFile:
                self.truncated = True
                logger.info(
                    "%s ends early (killed writer?): read %d messages up to the last complete "
                    "record",
                    self.path,
                    self.messages_read,
                )


def read_log(path: str | Path, topics: Iterable[str] | None = None) -> LogReader:
    """Read back one log file's messages, tolerating a truncated end.

    Parameters
    ----------
    path : str or Path
        One MCAP file (for a rotated log, read each of `log_segments` in turn).
    topics : iterable of str, optional
        Only these topics (all when None).

    Returns
    -------
    LogReader
        An iterator of ``(topic, log_time_ns, message)`` in file order; its ``messages_read``,
        ``complete`` and ``truncated`` attributes tell what was found once it is exhausted.
    """
    return LogReader(path, topics)


def read_metadata(path: str | Path) -> dict[str, str]:
    """The run-level metadata (records named ``"canfdi"``) of one log file.

    Streams the file and stops at the first chunk after the metadata, where the recorder puts
    it; a truncated file is fine.

    Parameters
    ----------
    path : str or Path
        One MCAP file.

    Returns
    -------
    dict of str to str
        The metadata (merged in file order if there are several records); empty if none.
    """
    found: dict[str, str] = {}
    seen = False
    with open(path, "rb") as file:
        # emit_chunks: the message data is not needed, so it is not decompressed.
        records = StreamReader(_ExactReader(file), emit_chunks=True).records
        try:
            for record in records:
                if isinstance(record, Metadata) and record.name == METADATA_NAME:
                    found.update(record.metadata)
                    seen = True
                elif seen and isinstance(record, Chunk):
                    break
        except EndOfFile:
            pass
    return found


# ------------------------------------------------------------------------------------------
# reading rows back
# ------------------------------------------------------------------------------------------


class SampleArrays(NamedTuple):
    """Decoded samples of a log: ``(k, t_ns, gap, U, Z, input_names, output_names)``.

    ``k``, ``t_ns``, ``gap`` are (N,) int64; ``U`` (N, p) and ``Z`` (N, q) float64 with NaN
    where the log holds null; the names are the model's, in column order.
    """

    k: NDArray[np.int64]
    t_ns: NDArray[np.int64]
    gap: NDArray[np.int64]
    U: NDArray[np.float64]
    Z: NDArray[np.float64]
    input_names: list[str]
    output_names: list[str]


class ResidualArrays(NamedTuple):
    """Residuals of a log: ``(k, t_ns, names, R, Rn, stat)``.

    ``k``, ``t_ns`` are (N,) int64; ``R`` (raw), ``Rn`` (normalized), ``stat`` (Page-Hinkley)
    are (N, m) float64 with NaN where the log holds null, columns in ``names`` order.
    """

    k: NDArray[np.int64]
    t_ns: NDArray[np.int64]
    names: list[str]
    R: NDArray[np.float64]
    Rn: NDArray[np.float64]
    stat: NDArray[np.float64]


def _segments(path: str | Path, segments: bool) -> list[Path]:
    """The segment files to read: ``path`` alone or its whole family; FileNotFoundError if
    none exists."""
    if not segments:
        if not Path(path).exists():
            raise FileNotFoundError(errno.ENOENT, "no such log", str(path))
        return [Path(path)]
    segments_found = log_segments(path)
    if not segments_found:
        raise FileNotFoundError(errno.ENOENT, "no such log", str(path))
    return segments_found


_OLD_ROWS_PER_BLOCK = 4096


def iter_frame_blocks(path: str | Path, *, segments: bool = True) -> Iterator[FrameBlock]:
    """The raw frames of a log, a block at a time: constant memory for any log length.

    Reads the segments in order, tolerating a truncated end as `read_log` does (a block cut
    short is dropped whole). Logs of the older one-frame-per-message layout
    are read too, in blocks of up to 4096 frames.

    Parameters
    ----------
    path : str or Path
        The log's name (its first segment).
    segments : bool
        Also read the rotated segments that follow ``path`` (`log_segments`); False reads
        ``path`` alone.

    Yields
    ------
    FrameBlock
        The frames of one block, in recording order.

    Raises
    ------
    FileNotFoundError
        If no segment of the log exists.
    ValueError
        For a ``/can/frames`` message of an unknown layout.
    """
    messages = (
        (segment, log_time, message)
        for segment in _segments(path, segments)
        for _, log_time, message in read_log(segment, topics=[TOPIC_FRAMES])
    )
    return _frame_blocks_of(messages)


def _frame_blocks_of(
    messages: Iterable[tuple[Path, int, Mapping[str, Any]]],
) -> Iterator[FrameBlock]:
    """FrameBlocks of ``/can/frames`` messages (segment, log_time, message) of either layout:
    a block message as one block, one-frame messages gathered up to 4096 a block."""
    rows: list[tuple[int, Mapping[str, Any]]] = []
    for segment, log_time, message in messages:
        if "frames" in message:
            if rows:
                yield decode_frame_rows(rows)
                rows = []
            yield decode_frames(message)
        elif "id" in message and "data" in message:
            rows.append((log_time, message))
            if len(rows) >= _OLD_ROWS_PER_BLOCK:
                yield decode_frame_rows(rows)
                rows = []
        else:
            raise ValueError(f"unrecognised {TOPIC_FRAMES} message in {segment}")
    if rows:
        yield decode_frame_rows(rows)


def read_frames(path: str | Path, *, segments: bool = True) -> FrameBlock:
    """Every raw frame of a log, as arrays.

    Parameters
    ----------
    path : str or Path
        The log's name (its first segment); read as by `iter_frame_blocks`.
    segments : bool
        Also read the rotated segments that follow ``path`` (`log_segments`); False reads
        ``path`` alone.

    Returns
    -------
    FrameBlock
        All the frames in recording order (including the monitor's own, status ``"sent"``).

    Raises
    ------
    FileNotFoundError
        If no segment of the log exists.
    ValueError
        For a ``/can/frames`` message of an unknown layout.
    """
    blocks = list(iter_frame_blocks(path, segments=segments))
    return FrameBlock.concat(blocks) if blocks else no_frames()


def _same_names(found: Any, names: Any, topic: str, path: str | Path) -> Any:
    """``found``, checked equal to the ``names`` read before (None: none yet)."""
    if names is not None and found != names:
        raise ValueError(f"{topic} of {path} changes names: {names} then {found}")
    return found


def log_drives(path: str | Path, *, segments: bool = True) -> list[str]:
    """The drives whose samples a log holds, in order of appearance ([] for a log of one
    unnamed drive: logs written before drives had names)."""
    found: list[str] = []
    for segment in _segments(path, segments):
        for _, _, msg in read_log(segment, topics=[TOPIC_SAMPLES]):
            drive = msg.get("drive")
            if drive is not None and drive not in found:
                found.append(drive)
    return found


def _wanted(msg: Mapping[str, Any], drive: str | None, first: list) -> bool:
    """Whether a block belongs to ``drive`` (None: the first drive the log shows)."""
    found = msg.get("drive")
    if drive is not None:
        return found == drive
    if not first:
        first.append(found)
    return found == first[0]


def read_samples(path: str | Path, *, segments: bool = True, drive: str | None = None
                 ) -> SampleArrays:
    """Every decoded sample of a log (``/canfdi/samples``), as arrays.

    Reads every segment in order, tolerating a truncated end as `read_log` does, and logs of
    the older one-sample-per-message layout.

    Parameters
    ----------
    path : str or Path
        The log's name (its first segment).
    segments : bool
        Also read the rotated segments that follow ``path`` (`log_segments`); False reads
        ``path`` alone.
    drive : str, optional
        Whose samples (a log of several drives, `log_drives`); default the first drive's.

    Returns
    -------
    SampleArrays
        ``(k, t_ns, gap, U, Z, input_names, output_names)``; empty arrays (and no names) when
        the log holds no sample.

    Raises
    ------
    FileNotFoundError
        If no segment of the log exists.
    ValueError
        For a block of an unknown layout, or names that change within the log.
    """
    rows = Rows((np.int64, np.int64, np.int64, np.float64, np.float64))
    k_col, t_col, gap_col, u_col, z_col = rows.columns
    names: tuple[list[str], list[str]] | None = None
    first: list = []
    for segment in _segments(path, segments):
        for _, log_time, msg in read_log(segment, topics=[TOPIC_SAMPLES]):
            if not _wanted(msg, drive, first):
                continue
            found = (list(msg["u"]), list(msg["z"]))
            names = _same_names(found, names, TOPIC_SAMPLES, path)
            if "count" in msg:
                rows.add(decode_sample_block(msg, *found))
            else:
                k_col.append(msg["k"])
                t_col.append(log_time)
                gap_col.append(msg.get("gap", 0))
                u_col.append(list(msg["u"].values()))
                z_col.append(list(msg["z"].values()))
                rows.count += 1
    inputs, outputs = names if names is not None else ([], [])
    k, t, gap, u, z = gathered(rows, (len(inputs), len(outputs)))
    n = len(k)
    return SampleArrays(
        k, t, gap, u.reshape(n, len(inputs)), z.reshape(n, len(outputs)), inputs, outputs
    )


def read_residuals(path: str | Path, *, segments: bool = True, drive: str | None = None
                   ) -> ResidualArrays:
    """Every residual row of a log (``/canfdi/residuals``), as arrays.

    Reads every segment in order, tolerating a truncated end as `read_log` does, and logs of
    the older one-row-per-message layout. (``/canfdi/residuals_plot`` is not read: it only
    repeats some of these rows.)

    Parameters
    ----------
    path : str or Path
        The log's name (its first segment).
    segments : bool
        Also read the rotated segments that follow ``path`` (`log_segments`); False reads
        ``path`` alone.
    drive : str, optional
        Whose residuals (a log of several drives); default the first drive's.

    Returns
    -------
    ResidualArrays
        ``(k, t_ns, names, R, Rn, stat)``; empty arrays (and no names) when the log holds no
        residuals.

    Raises
    ------
    FileNotFoundError
        If no segment of the log exists.
    ValueError
        For a block of an unknown layout, or names that change within the log.
    """
    rows = Rows((np.int64, np.int64, np.float64, np.float64, np.float64))
    k_col, t_col, r_col, n_col, s_col = rows.columns
    names: list[str] | None = None
    first: list = []
    for segment in _segments(path, segments):
        for _, log_time, msg in read_log(segment, topics=[TOPIC_RESIDUALS]):
            if not _wanted(msg, drive, first):
                continue
            if "count" in msg:
                found = list(msg["names"])
                names = _same_names(found, names, TOPIC_RESIDUALS, path)
                rows.add(decode_residual_block(msg, found))
            else:
                found = list(msg["r"])
                names = _same_names(found, names, TOPIC_RESIDUALS, path)
                k_col.append(msg["k"])
                t_col.append(log_time)
                r_col.append(list(msg["r"].values()))
                n_col.append([msg["normalized"][name] for name in found])
                s_col.append([msg["statistic"][name] for name in found])
                rows.count += 1
    names = names if names is not None else []
    m = len(names)
    k, t, r, rn, stat = gathered(rows, (m, m, m))
    n = len(k)
    return ResidualArrays(k, t, names, r.reshape(n, m), rn.reshape(n, m), stat.reshape(n, m))


# ------------------------------------------------------------------------------------------
# the fast path: frame blocks for replay
# ------------------------------------------------------------------------------------------


def _scanned_messages(segment: Path) -> Iterator[tuple[Path, int, Mapping[str, Any]]]:
    """(segment, log_time, message) of the ``/can/frames`` messages of one segment: through
    canfdi.io.scan (fast), continued with `read_log` from where the scanner gave up if it
    meets something it does not read (an unusual chunk compression)."""
    done = 0
    try:
        for log_time, message in scan_topic(segment, TOPIC_FRAMES):
            yield segment, log_time, message
            done += 1
        return
    except UnsupportedLog as exc:
        logger.info("%s: %s; reading it with the full reader", segment, exc)
    for i, (_, log_time, message) in enumerate(read_log(segment, topics=[TOPIC_FRAMES])):
        if i >= done:
            yield segment, log_time, message


def mcap_frame_blocks(
    path: str | Path, frames_per_block: int = 65536, *, received: bool = True
) -> Iterator[FrameBlock]:
    """The frames of a log (every segment) in blocks of about ``frames_per_block``, fast.

    The scanner (canfdi.io.scan) pulls the frame blocks out of each segment, and a thread
    reads ahead (at most four blocks), so that inflating and decoding the log overlaps with
    the caller's work on a second core (zstd and numpy release the GIL). Reads what
    `iter_frame_blocks` reads, a truncated end included.

    Parameters
    ----------
    path : str or Path
        The log's name (its first segment).
    frames_per_block : int
        Frames per yielded block, about (the log's blocks are merged up to at least this).
    received : bool
        Only the frames the monitor received: without its own transmissions (status
        ``"sent"``), which a live monitor does not hear. False: every frame.

    Yields
    ------
    FrameBlock
        Frames in recording order, with their recorded statuses.

    Raises
    ------
    FileNotFoundError
        If no segment of the log exists.
    ValueError
        For a ``/can/frames`` message of an unknown layout, or a file that is not MCAP.
    """
    segments = _segments(path, True)
    merged = FrameBlock.concat
    done = object()
    q: queue.Queue = queue.Queue(maxsize=4)
    stop = threading.Event()  # the consumer went away: the producer ends too

    def put(item: Any) -> bool:
        while not stop.is_set():
            try:
                q.put(item, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def produce() -> None:
        try:
            pending: list[FrameBlock] = []
            count = 0
            messages = (m for segment in segments for m in _scanned_messages(segment))
            for block in _frame_blocks_of(messages):
                if received:
                    block = block.received()
                pending.append(block)
                count += block.size
                if count >= frames_per_block:
                    if not put(merged(pending)):
                        return
                    pending, count = [], 0
            if pending and not put(merged(pending)):
                return
            put(done)
        except Exception as exc:  # handed to the consumer, which raises it
            put(exc)

    thread = threading.Thread(target=produce, daemon=True, name="canfdi-read-ahead")
    thread.start()
    try:
        while (item := q.get()) is not done:
            if isinstance(item, Exception):
                raise item
            yield item
    finally:
        stop.set()
        thread.join()

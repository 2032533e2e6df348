"""Read canfdi's MCAP logs back: messages, metadata, frames, samples and residuals as arrays.

`read_log` streams one file's messages in file order (no summary needed: a file cut short by a
killed writer reads up to its last complete record); `read_metadata` gives the run-level
``"canfdi"`` record; `read_frames` (`iter_frame_blocks` a block at a time), `read_samples`
and `read_residuals` give a whole log (every rotated segment, canfdi.io.segments) as arrays,
of the block layout canfdi.io.blocks decodes and of the one-row-per-message layout.
`mcap_frame_blocks` is the fast path replay reads frames with (a read-ahead thread).

Every one of them reads through canfdi.io.scan's `McapFile`, which checks each chunk's CRC,
skips what is damaged and resynchronises after it: a damaged log reads what is left of it,
never raises for the damage, and records what it lost in the canfdi.io.damage `Damage` given
as ``damage=`` (pass one `Damage` to every read of a log, print its lines at the end).
"""

from __future__ import annotations

import errno
import logging
import queue
import threading
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
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
from canfdi.io.damage import Damage
from canfdi.io.scan import OP_CHUNK, OP_METADATA, McapFile
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


def iter_frame_blocks(path: str | Path, *, segments: bool = True,
                      damage: Damage | None = None) -> Iterator[FrameBlock]:
    """The raw frames of a log, a block at a time: constant memory for any log length.

    Reads the segments in order, tolerating a truncated end and damage as `read_log` does (a
    block cut short or in a damaged chunk is dropped whole). Logs of the older
    one-frame-per-message layout are read too, in blocks of up to 4096 frames.

    Parameters
    ----------
    path : str or Path
        The log's name (its first segment).
    segments : bool
        Also read the rotated segments that follow ``path`` (`log_segments`); False reads
        ``path`` alone.
    damage : Damage, optional
        Where what damaged segments lost is recorded.

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
        for _, log_time, message in read_log(segment, [TOPIC_FRAMES], damage)
    )
    return _frame_blocks_of(messages)


def _frame_blocks_of(
    messages: Iterable[tuple[Path, int, Mapping[str, Any]]],
) -> Iterator[FrameBlock]:
    """FrameBlocks of ``/can/frames`` messages (segment, log_time, message) of either layout:
    a block message as one block, one-frame messages gathered up to 4096 a block."""
    rows: list[tuple[int, Mapping[str, Any]]] = []
    for segment, log_time, message in messages:
        if not isinstance(message, Mapping):
            raise ValueError(f"unrecognised {TOPIC_FRAMES} message in {segment}")
        if "frames" in message:
            if rows:
                yield decode_frame_rows(rows)
                rows = []
            try:
                block = decode_frames(message)
            except (KeyError, TypeError, ValueError):  # only a chunk without a CRC lets one in
                raise ValueError(f"a damaged {TOPIC_FRAMES} message in {segment}") from None
            yield block
        elif "id" in message and "data" in message:
            rows.append((log_time, message))
            if len(rows) >= _OLD_ROWS_PER_BLOCK:
                yield decode_frame_rows(rows)
                rows = []
        else:
            raise ValueError(f"unrecognised {TOPIC_FRAMES} message in {segment}")
    if rows:
        yield decode_frame_rows(rows)


def read_frames(path: str | Path, *, segments: bool = True,
                damage: Damage | None = None) -> FrameBlock:
    """Every raw frame of a log, as arrays.

    Parameters
    ----------
    path : str or Path
        The log's name (its first segment); read as by `iter_frame_blocks`.
    segments : bool
        Also read the rotated segments that follow ``path`` (`log_segments`); False reads
        ``path`` alone.
    damage : Damage, optional
        Where what damaged segments lost is recorded.

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
    blocks = list(iter_frame_blocks(path, segments=segments, damage=damage))
    return FrameBlock.concat(blocks) if blocks else no_frames()


def _same_names(found: Any, names: Any, topic: str, path: str | Path) -> Any:
    """``found``, checked equal to the ``names`` read before (None: none yet)."""
    if names is not None and found != names:
        raise ValueError(f"{topic} of {path} changes names: {names} then {found}")
    return found


def log_drives(path: str | Path, *, segments: bool = True,
               damage: Damage | None = None) -> list[str]:
    """The drives whose samples a log holds, in order of appearance ([] for a log of one
    unnamed drive: logs written before drives had names); damage recorded in ``damage``."""
    found: list[str] = []
    for segment in _segments(path, segments):
        for _, _, msg in read_log(segment, [TOPIC_SAMPLES], damage):
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


def read_samples(path: str | Path, *, segments: bool = True, drive: str | None = None,
                 damage: Damage | None = None                 ) -> SampleArrays:
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
    damage : Damage, optional
        Where what damaged segments lost is recorded (the samples in them are not read).

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
        for _, log_time, msg in read_log(segment, [TOPIC_SAMPLES], damage):
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


def read_residuals(path: str | Path, *, segments: bool = True, drive: str | None = None,
                   damage: Damage | None = None                   ) -> ResidualArrays:
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
    damage : Damage, optional
        Where what damaged segments lost is recorded (the rows in them are not read).

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
        for _, log_time, msg in read_log(segment, [TOPIC_RESIDUALS], damage):
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


def mcap_frame_blocks(
    path: str | Path, frames_per_block: int = 65536, *, received: bool = True,
    damage: Damage | None = None,
) -> Iterator[FrameBlock]:
    """The frames of a log (every segment) in blocks of about ``frames_per_block``, fast.

    A thread reads ahead (at most four blocks), so that inflating and decoding the log
    overlaps with the caller's work on a second core (zstd and numpy release the GIL). Reads
    what `iter_frame_blocks` reads, a truncated end and damaged chunks included (skipped).

    Parameters
    ----------
    path : str or Path
        The log's name (its first segment).
    frames_per_block : int
        Frames per yielded block, about (the log's blocks are merged up to at least this).
    received : bool
        Only the frames the monitor received: without its own transmissions (status
        ``"sent"``), which a live monitor does not hear. False: every frame.
    damage : Damage, optional
        Where what damaged segments lost is recorded (complete once the iteration ends).

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
            messages = ((segment, log_time, message) for segment in segments
                        for _, log_time, message in read_log(segment, [TOPIC_FRAMES], damage))
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

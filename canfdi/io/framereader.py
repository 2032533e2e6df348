"""The raw frames of a canfdi log as `FrameBlock`s: a block at a time (`iter_frame_blocks`),
all at once (`read_frames`), or merged and read ahead on a thread (`mcap_frame_blocks`, replay's
fast path). Both layouts are read: blocks of frames, and one frame per message (older logs).
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from typing import Any

from canfdi.bus.frames import FrameBlock
from canfdi.io.blocks import decode_frame_rows, decode_frames, no_frames
from canfdi.io.damage import Damage
from canfdi.io.logreader import log_files, read_log
from canfdi.io.schemas import TOPIC_FRAMES

__all__ = ["iter_frame_blocks", "mcap_frame_blocks", "read_frames"]

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
        for segment in log_files(path, segments)
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
    segments = log_files(path)
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

"""The frames of a log, whatever its format: canfdi's MCAP or any log python-can reads.

`frame_blocks` is what replay, identify and bench read logs with: FrameBlocks (canfdi.bus.frames)
of the frames the monitor received, in order.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

from canfdi.bus.frames import FrameBlock

__all__ = ["PYTHON_CAN_SUFFIXES", "frame_blocks", "truth_of"]

PYTHON_CAN_SUFFIXES = {".log", ".asc", ".blf", ".trc", ".csv"}


def frame_blocks(path: Path, frames_per_block: int = 65536) -> Iterator[FrameBlock]:
    """The received frames of a log in blocks of about ``frames_per_block``: python-can's
    readers for its suffixes, canfdi's MCAP readers otherwise."""
    if Path(path).suffix.lower() in PYTHON_CAN_SUFFIXES:
        return python_can_blocks(Path(path), frames_per_block)
    return mcap_blocks(Path(path), frames_per_block)


def mcap_frames(path: Path) -> Iterator[tuple[int, int, bytes, bool, bool]]:
    """(timestamp_ns, id, data, extended, error) of the frames a canfdi MCAP received."""
    from canfdi.io.recorder import iter_frame_blocks

    for block in iter_frame_blocks(path):
        received = block.status != "sent"  # the monitor's own: a live monitor does not hear them
        if not received.all():
            block = block.select(received)
        yield from zip(block.t_ns.tolist(), block.id.tolist(), block.payloads(),
                       block.extended.tolist(), (block.status == "error_frame").tolist(),
                       strict=True)


def mcap_frame_arrays(path: Path) -> FrameBlock:
    """The frames a canfdi MCAP received, as arrays (`canfdi.io.recorder.FrameBlock`): every
    segment, in order, without the monitor's own transmissions (status "sent"). Error frames
    have status "error_frame"; `FrameBlock.payloads` gives payloads longer than 8 bytes."""
    from canfdi.io.recorder import read_frames

    frames = _scanned_frames(path)
    if frames is None:
        frames = read_frames(path)
    received = frames.status != "sent"
    return frames if received.all() else frames.select(received)


def frame_array_blocks(path: Path, frames_per_block: int = 65536):
    """Blocks of received frames (FrameBlock, "sent" removed) of about ``frames_per_block``,
    read ahead in a thread so that inflating and decoding the log overlaps with the diagnosis
    (zstd releases the GIL) on a second core."""
    import queue
    import threading

    from canfdi.io.recorder import TOPIC_FRAMES, _frame_block, log_segments
    from canfdi.io.scan import UnsupportedLog, scan_topic

    merged = FrameBlock.concat

    def produce(out: queue.Queue) -> None:
        try:
            pending, count = [], 0
            for segment in log_segments(path):
                for _, message in scan_topic(segment, TOPIC_FRAMES):
                    block = _frame_block(message)
                    if block.long:
                        raise UnsupportedLog("payloads over 8 bytes")
                    keep = block.status != "sent"
                    pending.append(block if keep.all() else block.select(keep))
                    count += len(pending[-1].t_ns)
                    if count >= frames_per_block:
                        out.put(merged(pending))
                        pending, count = [], 0
            if pending:
                out.put(merged(pending))
            out.put(None)
        except Exception as exc:  # handed to the consumer, which decides
            out.put(exc)

    q: queue.Queue = queue.Queue(maxsize=4)
    thread = threading.Thread(target=produce, args=(q,), daemon=True)
    thread.start()
    while (item := q.get()) is not None:
        if isinstance(item, Exception):
            raise item
        yield item
    thread.join()


def _scanned_frames(path: Path):
    """The frame blocks of every segment through canfdi.io.scan (fast), or None when a
    segment needs the full reader (an old one-frame-per-message log, an unusual chunk)."""

    from canfdi.io.recorder import TOPIC_FRAMES, FrameBlock, _frame_block, log_segments
    from canfdi.io.scan import UnsupportedLog, scan_topic

    blocks = []
    try:
        for segment in log_segments(path):
            for _, message in scan_topic(segment, TOPIC_FRAMES):
                if "frames" not in message:
                    return None
                blocks.append(_frame_block(message))
    except (UnsupportedLog, ValueError, KeyError):
        return None
    if not blocks:
        return None
    return FrameBlock.concat(blocks)


def mcap_blocks(path: Path, frames_per_block: int = 65536):
    """FrameBlocks of a canfdi MCAP's received frames: the fast
    scanner when it can read the log, the full reader otherwise (older layouts)."""
    from canfdi.io.scan import UnsupportedLog

    try:
        yield from frame_array_blocks(path, frames_per_block)
        return
    except (UnsupportedLog, ValueError, KeyError):
        pass
    arr = mcap_frame_arrays(path)
    for i in range(0, arr.size, frames_per_block):
        yield arr.slice(i, i + frames_per_block)


def python_can_blocks(path: Path, frames_per_block: int = 65536):
    """FrameBlocks of a log python-can reads."""
    import can

    with can.LogReader(str(path)) as reader:
        pending = []
        for msg in reader:
            pending.append(msg)
            if len(pending) >= frames_per_block:
                yield FrameBlock.from_messages(pending, now=0.0)
                pending = []
        if pending:
            yield FrameBlock.from_messages(pending, now=0.0)


def truth_of(path: Path) -> list[dict] | None:
    from canfdi.io.recorder import read_metadata

    try:
        meta = read_metadata(path)
    except Exception:  # a foreign or damaged file simply has no truth
        return None
    return json.loads(meta["truth_json"]) if "truth_json" in meta else None



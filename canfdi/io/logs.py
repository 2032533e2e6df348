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
    from canfdi.io.reader import mcap_frame_blocks

    return mcap_frame_blocks(Path(path), frames_per_block)


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
    from canfdi.io.reader import read_metadata

    try:
        meta = read_metadata(path)
    except Exception:  # a foreign or damaged file simply has no truth
        return None
    return json.loads(meta["truth_json"]) if "truth_json" in meta else None

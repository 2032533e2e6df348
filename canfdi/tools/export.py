"""The library behind `canfdi export`: a log's raw frames written in another format."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from pathlib import Path

from canfdi.io.formats import LogFormat, formats


def writable_formats() -> list[LogFormat]:
    """The log formats canfdi can write, in canfdi.io.formats' order."""
    return [f for f in formats() if f.writable]


def counted(blocks: Iterable, progress: Callable[[int], None] | None) -> Iterator:
    """``blocks`` (FrameBlocks) as they come, telling ``progress`` the frames so far."""
    count = 0
    for block in blocks:
        yield block
        count += block.size
        if progress is not None:
            progress(count)


def write_export(out: Path, blocks: Iterable, fmt: str,
                 progress: Callable[[int], None] | None = None):
    """Write ``blocks`` to ``out`` in format ``fmt``; returns what canfdi.io.logs.write_frames
    wrote (frames, skipped). A file that would look like an export and is none is removed:
    one begun before the input failed (LogReadError, or ValueError for a block of an unknown
    layout: both raised again), one that got no frame."""
    from canfdi.io.logs import write_frames

    try:
        written = write_frames(out, counted(blocks, progress), fmt)
    except ValueError:  # LogReadError is one: the input failed, the output is worth nothing
        out.unlink(missing_ok=True)
        raise
    if written.frames == 0:
        out.unlink(missing_ok=True)
    return written


def export_frames(log: Path, out: Path, fmt: str, progress=None, damage=None) -> int:
    """Write every frame of ``log`` to ``out`` in format ``fmt`` (a name of
    canfdi.io.formats); returns the number of frames written. What a damaged log lost is
    recorded in ``damage`` (a canfdi.io.damage.Damage), the rest is written."""
    from canfdi.io.logs import frame_blocks, write_frames

    blocks = frame_blocks(log, received=False, damage=damage)
    return write_frames(out, counted(blocks, progress), fmt).frames

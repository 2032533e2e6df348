"""The frames, metadata and truth of any log, and writing frames into one: by its file name.

What replay, identify, bench, report and export call. Each function asks canfdi.io.formats for
the log's format (by suffix: canfdi's MCAP, or any format python-can reads and writes,
gzip-compressed text logs included) and does what the format says; nothing here knows a
format.

>>> from canfdi.io.formats import format_of
>>> format_of("drive.asc.gz").description
'gzip-compressed Vector ASCII (CANalyzer, CANoe, SavvyCAN)'
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from pathlib import Path

from canfdi.bus.frames import FrameBlock
from canfdi.io.damage import Damage
from canfdi.io.formats import LogFormatError, Written, format_named, format_of

__all__ = ["frame_blocks", "metadata_of", "truth_of", "write_frames"]


def frame_blocks(path: str | Path, frames_per_block: int = 65536, *,
                 received: bool = True, damage: Damage | None = None) -> Iterator[FrameBlock]:
    """The frames of a log in blocks of about ``frames_per_block``, in log order.

    Parameters
    ----------
    path : str or Path
        The log; its suffix says its format (canfdi.io.formats).
    frames_per_block : int
        Frames per block, about.
    received : bool
        Only the frames the monitor received (default): an MCAP's own transmissions (status
        ``"sent"``) are left out. False: every frame.
    damage : Damage, optional
        Where what a damaged log lost is recorded (canfdi's MCAP skips damaged chunks and
        reads the rest); complete once the iteration ends.

    Returns
    -------
    iterator of FrameBlock
        With a status column (the monitor's for MCAP; ``"rx"`` / ``"tx"`` for python-can's
        formats).

    Raises
    ------
    LogFormatError
        At once, for a suffix no format claims (the message lists the known ones) or a
        format that needs a package that is not installed.
    FileNotFoundError
        No such log.
    LogReadError
        While iterating: the file is not a readable log of its format.
    """
    return format_of(path).frame_blocks(path, frames_per_block, received=received,
                                        damage=damage)


def write_frames(path: str | Path, blocks: Iterable[FrameBlock],
                 fmt: str | None = None) -> Written:
    """Write frames into a new log: of format ``fmt`` (a name of canfdi.io.formats), or the
    one its suffix says. Returns ``(frames, skipped)`` (frames of a kind the format cannot
    hold). Raises LogFormatError for a format that cannot be written, OSError when the file
    cannot."""
    target = format_named(fmt) if fmt is not None else format_of(path)
    return target.write_frames(path, blocks)


def metadata_of(path: str | Path) -> dict[str, str]:
    """The run-level metadata of a log (``config_yaml``, ``design_json``, ``truth_json``...):
    empty for a format that has none. Raises LogFormatError for an unknown suffix and
    LogReadError for a damaged log."""
    return format_of(path).metadata(path)


def truth_of(path: str | Path) -> list[dict] | None:
    """The faults injected into the run a log recorded (a demo's ``truth_json``), or None
    when the log does not say (a format without metadata, an unknown or damaged file)."""
    try:
        fmt = format_of(path)
    except LogFormatError:
        return None
    return fmt.truth(path)

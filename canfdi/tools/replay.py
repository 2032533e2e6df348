"""One log through a monitor: what `canfdi replay` does for its log and `canfdi fleet` for each.

The log is read block by block (canfdi.io.logs.frame_blocks: any format canfdi.io reads, a
damaged MCAP around its damage) into ``Monitor.on_frames``, then ``Monitor.finish``; what the
monitor concluded stays on it (events, counters, ``summary``). Printing, exit statuses and
tables are the callers'.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from canfdi.io.damage import Damage
from canfdi.io.logs import frame_blocks, truth_of

if TYPE_CHECKING:
    from canfdi.monitor import Monitor

__all__ = ["Replayed", "replay_log"]


@dataclass
class Replayed:
    """What reading one log gave besides the monitor's own state.

    damage : what a damaged log lost (false when nothing); truth : the faults the run that
    wrote the log injected (a demo's), None when the log does not say; frames : frames read.
    """

    damage: Damage
    truth: list[dict] | None
    frames: int


def replay_log(monitor: Monitor, path: str | Path,
               on_block: Callable[[int], None] | None = None) -> Replayed:
    """Feed every frame of the log at ``path`` to ``monitor``, then finish it.

    Parameters
    ----------
    monitor : a fresh Monitor of the log's config (with a sink to see the frames' statuses and
        the residuals as they pass).
    path : the log; its suffix says its format.
    on_block : called after each block with the frames read so far (a caller's progress line
        and event printing; the monitor's ``events`` grow as the blocks go).

    Raises
    ------
    LogFormatError
        At once: a suffix canfdi does not know, or a format whose package is missing.
    FileNotFoundError
        At once: no such log.
    OSError
        While reading: the disk failed (``on_block`` has seen the frames read before).
    ValueError
        While reading: not a log of its suffix (LogReadError), an unknown layout.
    """
    damage = Damage()
    blocks = frame_blocks(path, damage=damage)
    truth = truth_of(path)
    count = 0
    for block in blocks:
        monitor.on_frames(block)
        count += block.size
        if on_block is not None:
            on_block(count)
    monitor.finish()
    return Replayed(damage, truth, count)

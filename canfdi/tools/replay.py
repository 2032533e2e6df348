"""One log through a monitor: what `canfdi replay` does for its log and `canfdi fleet` for each.

The log is read block by block (canfdi.io.logs.frame_blocks: any format canfdi.io reads, a
damaged MCAP around its damage) into ``Monitor.on_frames``, then ``Monitor.finish``; what the
monitor concluded stays on it (events, counters, ``summary``). `replay_diagnosis` adds what
`canfdi replay` does around that: the diagnosis recorded as a live run's MCAP, kept only when
something was diagnosed. `recorded_config` is the monitor config a canfdi MCAP carries.
Printing, exit statuses and tables are the callers'.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from canfdi.io.damage import Damage
from canfdi.io.logs import frame_blocks, truth_of

if TYPE_CHECKING:
    from canfdi.config import MonitorConfig
    from canfdi.monitor import Monitor

__all__ = [
    "CannotWriteDiagnosis",
    "Diagnosis",
    "NoRecordedConfig",
    "Replayed",
    "recorded_config",
    "replay_diagnosis",
    "replay_log",
]


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


class NoRecordedConfig(ValueError):
    """A log that carries no monitor config that loads here.

    ``log`` is the log; ``error`` the ConfigError of the recorded config, None when the log
    holds none (only a canfdi MCAP does).

    Examples
    --------
    >>> NoRecordedConfig(Path("drive.blf")).error is None
    True
    """

    def __init__(self, log: Path, error: Exception | None = None) -> None:
        super().__init__(f"{log}: " + ("holds no monitor config" if error is None
                                       else f"its config does not load ({error})"))
        self.log, self.error = log, error


def recorded_config(log: Path, scratch: Path) -> MonitorConfig:
    """The monitor config recorded in a canfdi MCAP (its ``config_yaml`` metadata), loaded
    from a copy in ``scratch`` (a relative DBC path is then relative to ``scratch``).

    Raises
    ------
    NoRecordedConfig
        The log holds no config (not a canfdi MCAP, another format), or it does not load here.
    """
    from canfdi.config import ConfigError, load_config
    from canfdi.io.reader import read_metadata
    from canfdi.io.scan import NotMcap

    try:
        meta = read_metadata(log) if log.suffix == ".mcap" else {}
    except (NotMcap, OSError):
        meta = {}
    text = meta.get("config_yaml", "")
    if not text:
        raise NoRecordedConfig(log)
    # (the name is the log's to say: its last part only, so the copy stays in scratch)
    copy = scratch / f"{Path(meta.get('config_name') or 'recorded').name or 'recorded'}.yaml"
    copy.write_text(text)
    try:
        return load_config(copy)
    except ConfigError as exc:
        raise NoRecordedConfig(log, exc) from None


class CannotWriteDiagnosis(Exception):
    """The MCAP the diagnosis was to be recorded in cannot be opened (``error``: the OSError
    or ValueError of the recorder).

    Examples
    --------
    >>> CannotWriteDiagnosis(PermissionError(13, "Permission denied")).error.errno
    13
    """

    def __init__(self, error: Exception) -> None:
        super().__init__(str(error))
        self.error = error


@dataclass
class Diagnosis:
    """What `replay_diagnosis` concluded.

    replayed : what reading the log gave (damage, truth, frames); result : the monitor's
    ``summary`` against the log's truth, with ``"damage"`` (what a damaged log lost) added;
    recorded : the files the diagnosis was recorded in (none without ``output``, and none
    kept when nothing was diagnosed).

    Examples
    --------
    >>> nothing = Diagnosis(Replayed(Damage(), None, 0), {"no_samples": "0 samples"}, [])
    >>> nothing.diagnosed
    False
    """

    replayed: Replayed
    result: dict
    recorded: list[Path]

    @property
    def diagnosed(self) -> bool:
        """Whether any frame made a sample (the summary then has no ``no_samples``)."""
        return "no_samples" not in self.result


def replay_diagnosis(monitor: Monitor, log: Path, output: Path | None = None,
                 on_block: Callable[[int], None] | None = None) -> Diagnosis:
    """`replay_log` of ``log`` into ``monitor``, recorded with ``output`` as a live run records
    (the monitor's records and the canfdi loggers' warnings); the log is removed again when
    nothing was diagnosed, so that no file looks like a diagnosis that is none.

    Parameters
    ----------
    monitor : a fresh Monitor of the log's config (``record_residuals`` when ``output``).
    log : the log; its suffix says its format.
    output : the MCAP to record the diagnosis in, or None.
    on_block : as for `replay_log`.

    Raises
    ------
    CannotWriteDiagnosis
        Before reading: ``output`` cannot be opened.
    LogFormatError, OSError, ValueError
        As `replay_log` (the recorded files removed).
    """
    from canfdi.tools.session import close_recorder, open_recorder

    recorder = None
    if output is not None:
        try:
            recorder = open_recorder(output, monitor.metadata(truth_of(log)),
                                     drive_clock=lambda: monitor.last_timestamp_ns or 0,
                                     recording=monitor.config.recording)
        except (OSError, ValueError) as exc:
            raise CannotWriteDiagnosis(exc) from exc
        monitor.sink = recorder
    diagnosis = None
    try:
        replayed = replay_log(monitor, log, on_block)
        result = monitor.summary(replayed.truth)
        result["damage"] = replayed.damage.as_dict()
        diagnosis = Diagnosis(replayed, result, [])
    finally:
        if recorder is not None:
            close_recorder(recorder)
            if diagnosis is not None and diagnosis.diagnosed:
                diagnosis.recorded = list(recorder.paths)
            else:
                for path in recorder.paths:
                    path.unlink(missing_ok=True)
    return diagnosis

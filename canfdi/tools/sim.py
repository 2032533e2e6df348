"""The library behind `canfdi sim`: a scenario's drive as a recorded log, and how long it
plays. The bus itself (opening it, playing in real time) is canfdi.tools.session's bus factory
and canfdi.firmware_sim.emitter.emit, which the verb runs."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from canfdi.firmware_sim.emitter import Disturbance
    from canfdi.firmware_sim.scenario import Scenario

__all__ = ["samples_to_play", "write_scenario_log"]


def samples_to_play(scenario: Scenario, duration: float | None = None) -> int:
    """The samples of the scenario's drive in ``duration`` seconds (default: the scenario's
    duration), at its plant's period."""
    return round((duration or scenario.duration) / scenario.make_plant().dt)


def write_scenario_log(scenario: Scenario, disturbance: Disturbance, output: Path,
                       duration: float | None = None) -> dict[str, Any]:
    """The scenario's frames, disturbed, with their times in the drive's run, written to the
    log ``output`` in the format its suffix names (parent directories created), as fast as
    they are made: what `candump -L` would record on the real bus.

    Returns
    -------
    The outcome: scenario, output, frames written, frames skipped (the format cannot hold
    them), and the emitter's counters.

    Raises
    ------
    OSError, LogFormatError
        The log cannot be written.
    """
    from canfdi.firmware_sim.emitter import frame_log
    from canfdi.io.logs import write_frames

    log = frame_log(scenario, disturbance, duration=duration)
    output.parent.mkdir(parents=True, exist_ok=True)
    written = write_frames(output, [log.frames])
    return {"scenario": scenario.name, "output": str(output), "frames": written.frames,
            "skipped": written.skipped, **log.stats.as_dict()}

"""The library behind `canfdi demo`: a scenario's emulated drive and the monitor on one
python-can virtual bus, in one process.

Like the soak and evaluate tools, this one imports canfdi.firmware_sim: it needs the drive.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from canfdi.tools.session import Session, StopEvent

if TYPE_CHECKING:
    from canfdi.config import MonitorConfig
    from canfdi.monitor import Monitor


def demo_truth(scenario) -> list[dict]:
    """The faults ``scenario`` injects, each as its truth record (with its drive's name on a
    bus of several drives)."""
    plant = scenario.make_plant()
    names = {"actuator": plant.input_names, "sensor": plant.output_names}
    several = len(scenario.drives) > 1
    return [{**f.truth(plant.dt, names[f.target]), **({"drive": d.name} if several else {})}
            for d in scenario.drives for f in d.faults]


def truth_document(scenario) -> dict[str, Any]:
    """What `canfdi sim --truth` writes: the scenario, its plant, dt and bus profile, the
    injected faults ("faults": `demo_truth`) and each drive's own ("drives")."""
    plant = scenario.make_plant()
    names = {"actuator": plant.input_names, "sensor": plant.output_names}
    drives = [{"name": d.name, "node": d.node,
               "faults": [f.truth(plant.dt, names[f.target]) for f in d.faults]}
              for d in scenario.drives]
    return {"scenario": scenario.name, "plant": plant.name, "dt": plant.dt,
            "profile": scenario.profile, "faults": demo_truth(scenario), "drives": drives}


async def play_demo(session: Session, scenario, *, speed: float = 0.0,
                    channel: str = "canfdi-demo", on_event=None,
                    announce: Callable[[str], None] | None = None,
                    stop: StopEvent | None = None):
    """Serve ``session`` on virtual bus ``channel`` while the scenario's drive plays on it, at
    ``speed`` times real time (0: as fast as the monitor keeps up); returns the emitter's
    counters once the monitor has caught up with every frame (or ``stop`` was set: SIGINT,
    SIGTERM).

    ``announce``: gets the line that says what plays, once the live view (if any) shows."""
    import can

    from canfdi.firmware_sim.emitter import emit

    plant = scenario.make_plant()
    stop = stop if stop is not None else StopEvent()
    emitted: list[Any] = []

    async def drive(service, monitor_task: asyncio.Task) -> None:
        while service.bus is None and not monitor_task.done():
            await asyncio.sleep(0.01)
        # The emulator stamps each frame with its time in the drive's run (at speed 0, faster
        # than the wall clock); the bus keeps it, as the frames' timing is what a grid clock
        # samples.
        sim_bus = can.Bus(interface="virtual", channel=channel, preserve_timestamps=True)
        try:
            if announce is not None:
                announce(f"canfdi demo: {scenario.name} ({scenario.duration:g} s of "
                         f"{plant.name}) on virtual bus {channel!r}")
            stats = await emit(sim_bus, scenario, speed=speed, stop=stop)
            emitted.append(stats)
            # Let the monitor catch up with every frame the drive sent (unless it died: then
            # its exception is raised instead of waiting forever).
            while (service.stats.frames < stats.frames_sent and not stop.is_set()
                   and not monitor_task.done()):
                await asyncio.sleep(0.01)
        finally:
            sim_bus.shutdown()

    # The drive's time is the emulator's (the frames carry it): what the monitor's own frames
    # are recorded at too, so that the log's time is the drive's throughout.
    await session.serve(stop, opener=lambda: can.Bus(interface="virtual", channel=channel),
                        alongside=drive, status_period=session.monitor.config.bus.status_period,
                        on_event=on_event, clock=session.drive_time)
    return emitted[0]


async def run_demo(scenario, config: MonitorConfig, *, speed: float = 0.0,
                   channel: str = "canfdi-demo", recorder=None, on_event=None, announce=None,
                   live=None, stop: StopEvent | None = None
                   ) -> tuple[Monitor, Any, list[dict]]:
    """Emulator and monitor on one virtual bus; returns (monitor, emitter stats, truth).

    ``stop``: the event SIGINT and SIGTERM set while the demo runs (its ``interrupted`` says
    whether Ctrl-C did); a private one when None.

    ``recorder``: a callable (metadata, drive_time) -> record sink, where drive_time() is the
    drive's time now (ns), for the sink's log lines.

    ``live``: a callable monitor -> canfdi.liveview.LiveView, shown while the demo runs.

    `canfdi demo` builds its session with canfdi.tools.session.open_session and plays it with
    `play_demo`; this is the same with the sinks given as callables."""
    from canfdi.monitor import Monitor

    truth = demo_truth(scenario)
    monitor = Monitor(config)
    session = Session(monitor)
    if recorder is not None:
        monitor.sink = recorder(monitor.metadata(truth),
                                lambda: monitor.last_timestamp_ns or time.time_ns())
    if live is not None:
        session.view = live(monitor)
    stats = await play_demo(session, scenario, speed=speed, channel=channel, on_event=on_event,
                            announce=announce, stop=stop)
    return monitor, stats, truth

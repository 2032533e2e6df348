"""`canfdi demo`: the emulator and the monitor in one process on python-can's virtual bus."""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
import time
from pathlib import Path

from canfdi.cli.common import (
    StopEvent,
    add_foxglove_option,
    close_recorder,
    config_error,
    format_event,
    load_config_or_exit,
    open_foxglove,
    open_recorder,
    print_comparison,
)
from canfdi.configs import CONFIG_DIR

HELP = """\
Run a scenario's drive (canfdi.firmware_sim) and the canfdi monitor together on python-can's
in-process virtual bus: the emulator publishes the drive's frames, the monitor decodes them,
diagnoses each fault as it happens (printed live), sends its fault frames back on the bus, and
at the end prints the injected faults against the diagnosed ones. In a terminal a live view
shows each residual's Page-Hinkley statistic against its threshold, the detector state, the
active (compensated) faults and the frame counters (--no-live turns it off; it is off when
stdout is not a terminal).

Defaults: scenario dc_motor_consecutive; the shipped monitor config (canfdi.configs, which is
deploy/config/ in a checkout) that reads the scenario's bus (its bus profile's DBC, as many
drives): the plant's own config (<plant>.yaml) on canfdi's bus, dc_motor_cia402.yaml for a CiA
402 scenario, and
so on; as fast as the monitor keeps up (--speed 0: each frame carries its time in the drive's
run, so every sample clock sees the drive's timing).
Exit status: 0 done, 2 bad scenario, config or arguments."""


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="emulator + monitor on a virtual bus, live diagnoses",
                       description=HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scenario", default="dc_motor_consecutive", metavar="FILE",
                   help="scenario YAML or shipped name (default: dc_motor_consecutive)")
    p.add_argument("--config", type=Path, metavar="FILE",
                   help="monitor config (default: the one in deploy/config/ that reads the "
                        "scenario's bus)")
    p.add_argument("--speed", type=float, default=0.0, metavar="N",
                   help="N times real time; 0 = as fast as possible (default: 0)")
    p.add_argument("--json", action="store_true",
                   help="print the result as one JSON object (faults, frames, truth)")
    p.add_argument("-o", "--output", type=Path, metavar="OUT.mcap",
                   help="record the run in an MCAP log")
    p.add_argument("--channel", default="canfdi-demo", help="virtual bus channel name")
    add_foxglove_option(p)
    p.add_argument("--no-live", action="store_true",
                   help="no live view (it is on when stdout is a terminal, off otherwise)")


async def run_demo(scenario, config, *, speed: float = 0.0, channel: str = "canfdi-demo",
                   recorder=None, on_event=None, announce=None, live=None,
                   stop: StopEvent | None = None):
    """Emulator and monitor on one virtual bus; returns (monitor, emitter stats, truth).

    ``stop``: the event SIGINT and SIGTERM set while the demo runs (its ``interrupted`` says
    whether Ctrl-C did); a private one when None.

    ``recorder``: a callable (metadata, drive_time) -> record sink, where drive_time() is the
    drive's time now (ns), for the sink's log lines.

    ``live``: a callable monitor -> canfdi.liveview.LiveView, shown while the demo runs."""
    import can

    from canfdi.firmware_sim.emitter import emit
    from canfdi.monitor import Monitor
    from canfdi.service import MonitorService

    plant = scenario.make_plant()
    names = {"actuator": plant.input_names, "sensor": plant.output_names}
    several = len(scenario.drives) > 1
    truth = [{**f.truth(plant.dt, names[f.target]), **({"drive": d.name} if several else {})}
             for d in scenario.drives for f in d.faults]
    monitor = Monitor(config)
    if recorder is not None:
        monitor.sink = recorder(monitor.metadata(truth),
                                lambda: monitor.last_timestamp_ns or time.time_ns())
    stop = (stop if stop is not None else StopEvent()).arm()
    # The drive's time is the emulator's (the frames carry it): what the monitor's own frames
    # are recorded at too, so that the log's time is the drive's throughout.
    service = MonitorService(monitor, lambda: can.Bus(interface="virtual", channel=channel),
                             status_period=config.bus.status_period, on_event=on_event,
                             clock=lambda: monitor.last_timestamp_ns or time.time_ns())
    monitor_task = asyncio.create_task(service.run(stop))
    view = live(monitor) if live is not None else None
    view_task = None
    if view is not None:
        view.__enter__()
        view_task = asyncio.create_task(view.run(stop))
    while service.bus is None and not monitor_task.done():
        await asyncio.sleep(0.01)
    # The emulator stamps each frame with its time in the drive's run (at speed 0, faster than
    # the wall clock); the bus keeps it, as the frames' timing is what a grid clock samples.
    sim_bus = can.Bus(interface="virtual", channel=channel, preserve_timestamps=True)
    try:
        if announce is not None:
            announce(f"canfdi demo: {scenario.name} ({scenario.duration:g} s of {plant.name}) "
                     f"on virtual bus {channel!r}")
        stats = await emit(sim_bus, scenario, speed=speed, stop=stop)
        # Let the monitor catch up with every frame the drive sent (unless it died: then its
        # exception is raised below instead of waiting forever).
        while (service.stats.frames < stats.frames_sent and not stop.is_set()
               and not monitor_task.done()):
            await asyncio.sleep(0.01)
    finally:
        sim_bus.shutdown()
        stop.set()
        try:
            await monitor_task
        finally:
            if view is not None:
                await view_task
                view.__exit__(None, None, None)
        stop.disarm()
    return monitor, stats, truth


def run(args: argparse.Namespace) -> int:
    from canfdi.firmware_sim.scenario import ScenarioError, load_scenario

    try:
        scenario = load_scenario(args.scenario)
    except ScenarioError as exc:
        print(f"canfdi demo: scenario error: {exc}", file=sys.stderr)
        return 2
    if args.speed < 0:
        print("canfdi demo: --speed: must be >= 0", file=sys.stderr)
        return 2
    plant = scenario.make_plant()
    if args.config is None:
        from canfdi.tools.pairing import NoPairing, config_for

        try:
            args.config = config_for(scenario, CONFIG_DIR)
        except NoPairing as exc:
            print(f"canfdi demo: {exc}", file=sys.stderr)
            return 2
    config = load_config_or_exit(args.config, "demo")
    if isinstance(config, int):
        return config
    quiet = args.json
    live = open_foxglove(args.foxglove, "demo")
    if isinstance(live, int):
        return live
    recorders = []
    views = []

    def make_view(monitor):
        from canfdi.liveview import LiveView

        views.append(LiveView(monitor, title=f"canfdi demo: {scenario.name}"))
        return views[-1]

    def say(line: str) -> None:
        if views:
            views[0].print(line)
        else:
            print(line, flush=True)

    def make_recorder(metadata, drive_time):
        recorders.append(open_recorder(args.output, metadata, drive_clock=drive_time, tap=live))
        return recorders[-1]

    def on_event(event) -> None:
        if not quiet:
            say(format_event(event, plant.dt, len(config.drive_list) > 1))

    stop = StopEvent()
    try:
        monitor, stats, truth = asyncio.run(run_demo(
            scenario, config, speed=args.speed, channel=args.channel,
            recorder=make_recorder if args.output or live else None, on_event=on_event,
            announce=None if quiet else say,
            live=make_view if not quiet and not args.no_live and sys.stdout.isatty() else None,
            stop=stop))
    except ValueError as exc:
        return config_error(exc, "demo")
    except OSError as exc:
        print(f"canfdi demo: cannot write {args.output}: {exc.strerror or exc}", file=sys.stderr)
        return 1
    finally:
        for r in recorders:
            close_recorder(r)
        if live is not None:
            live.close()
    result = monitor.summary(truth)
    result["emitter"] = stats.as_dict()
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        print_comparison(result, truth)
        if args.output:
            print(f"log: {args.output}")
    return stop.exit_status

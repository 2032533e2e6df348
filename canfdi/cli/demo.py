"""`canfdi demo`: the emulator and the monitor in one process on python-can's virtual bus."""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
from pathlib import Path

from canfdi.cli.common import (
    add_foxglove_option,
    add_kernel_option,
    config_error,
    fail,
    format_event,
    kernel_or_exit,
    load_config_or_exit,
    print_comparison,
    say,
)
from canfdi.configs import CONFIG_DIR
from canfdi.tools.demo import demo_truth, play_demo
from canfdi.tools.session import CannotRecord, Recording, SessionError, StopEvent, open_session

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
    add_kernel_option(p)
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


def run(args: argparse.Namespace) -> int:
    from canfdi.firmware_sim.scenario import ScenarioError, load_scenario

    try:
        scenario = load_scenario(args.scenario)
    except ScenarioError as exc:
        return fail("demo", f"scenario error: {exc}")
    if args.speed < 0:
        return fail("demo", "--speed: must be >= 0")
    kernel = kernel_or_exit(args, "demo")
    if isinstance(kernel, int):
        return kernel
    if args.config is None:
        from canfdi.tools.pairing import NoPairing, config_for

        try:
            args.config = config_for(scenario, CONFIG_DIR)
        except NoPairing as exc:
            return fail("demo", str(exc))
    config = load_config_or_exit(args.config, "demo")
    if isinstance(config, int):
        return config
    stop = StopEvent()
    try:
        outcome = _play(args, scenario, config, stop, kernel)
    except SessionError as exc:
        return fail("demo", exc.message, exc.status)
    except ValueError as exc:
        return config_error(exc, "demo")
    except CannotRecord as exc:
        return fail("demo", f"cannot write {exc.path}: {exc.error.strerror or exc.error}", 1)
    except OSError as exc:
        return fail("demo", f"cannot write {args.output}: {exc.strerror or exc}", 1)
    result, truth = outcome
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        print_comparison(result, truth)
        if args.output:
            print(f"log: {args.output}")
    return stop.exit_status


def _play(args: argparse.Namespace, scenario, config, stop: StopEvent, kernel
          ) -> tuple[dict, list]:
    """The demo's session, played: (the monitor's summary with the emitter's counters, the
    injected faults)."""
    quiet = args.json
    truth = demo_truth(scenario)
    session = open_session(
        config, "demo", foxglove=args.foxglove, truth=truth, notice=say("demo"),
        kernel=kernel,
        recording=Recording(args.output) if args.output else None,
        view=scenario.name if not quiet and not args.no_live and sys.stdout.isatty() else None)
    dt = scenario.make_plant().dt

    def line(text: str) -> None:
        if session.view is not None:
            session.view.print(text)
        else:
            print(text, flush=True)

    def on_event(event) -> None:
        if not quiet:
            line(format_event(event, dt, len(config.drive_list) > 1))

    with session:
        stats = asyncio.run(play_demo(session, scenario, speed=args.speed, channel=args.channel,
                                      on_event=on_event, announce=None if quiet else line,
                                      stop=stop))
    result = session.monitor.summary(truth)
    result["emitter"] = stats.as_dict()
    return result, truth

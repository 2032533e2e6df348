"""`canfdi sim` (also `canfdi-sim`): play a scenario's drive on a CAN bus."""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
from pathlib import Path

from canfdi.cli.common import add_bus_overrides, bus_request
from canfdi.tools.session import BusArgumentError, StopEvent, bus_factory
from canfdi.tools.sim import samples_to_play

HELP = """\
Run the plant emulator (canfdi.firmware_sim) for a scenario and publish its drives' frames on a
python-can bus, in the scenario's bus profile (bus.profile): canfdi (the plant's DBC, alive
counter and CRC-8 in every frame; the default), cia402 (a CANopen drive and its master: SYNC,
PDOs, heartbeat) or float_node (node-ID float protocol, currents polled by RTR).

The default bus is python-can's in-process virtual bus, which only other code in the same
process can hear: use --interface socketcan --channel vcan0 to reach other programs. With
-o FILE no bus is opened: the frames, with their times in the drive's run, are written to a
log file in the format its suffix names (.log candump, .asc, .blf, .trc, .csv, .mcap, ...: any
that `canfdi export` writes), as fast as they are made: a recording of the drive, as
`candump -L can0 > FILE.log` would make on the real bus.

Scenarios: a YAML file, or the name of a shipped one (canfdi/firmware_sim/scenarios/), e.g.
dc_motor_consecutive. Exit status: 0 done, 1 bus error, 2 bad scenario or arguments."""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scenario", required=True, metavar="FILE",
                   help="scenario YAML, or a shipped scenario's name")
    add_bus_overrides(p, config=False)
    p.add_argument("--speed", type=float, default=1.0, metavar="N",
                   help="N times real time; 0 = as fast as the bus takes frames (default: 1)")
    p.add_argument("--duration", type=float, default=None, metavar="T",
                   help="seconds of scenario time to run (default: the scenario's duration)")
    p.add_argument("--healthy", action="store_true",
                   help="play the scenario's drives without their faults (a healthy "
                        "recording, for `canfdi identify` or `calibrate`)")
    p.add_argument("--truth", type=Path, metavar="FILE",
                   help="write the injected faults as JSON to FILE before sending")
    p.add_argument("--drop", type=float, default=0.0, metavar="P",
                   help="drop each frame with probability P")
    p.add_argument("--jitter", type=float, default=0.0, metavar="S",
                   help="delay each sample's frames by up to S seconds (uniform)")
    p.add_argument("--bad-crc", type=float, default=0.0, metavar="P",
                   help="corrupt each frame's CRC with probability P (profiles with a CRC)")
    p.add_argument("--wrong-dlc", type=float, default=0.0, metavar="P",
                   help="send each frame one byte short (or long) with probability P")
    p.add_argument("-o", "--output", type=Path, metavar="FILE",
                   help="write the frames to this log file instead of a bus (format by suffix)")
    p.add_argument("--quiet", action="store_true", help="no progress on stderr")
    p.add_argument("--json", action="store_true",
                   help="print the outcome as one JSON object on stdout (scenario, samples, "
                        "frames_sent, ...) instead of a line of words")


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("sim", help="play a scenario's drive on a CAN bus", description=HELP,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    add_arguments(p)


def _fail(message: str) -> int:
    print(f"canfdi sim: {message}", file=sys.stderr)
    return 2


def _check_args(args: argparse.Namespace, scenario) -> str | None:
    """The first option out of its range for ``scenario``, as the error line, or None."""
    from canfdi.firmware_sim.profiles import get_profile

    if args.speed < 0:
        return "--speed: must be >= 0"
    if args.duration is not None and args.duration <= 0:
        return "--duration: must be > 0 seconds"
    for name in ("drop", "bad_crc", "wrong_dlc"):
        if not 0.0 <= getattr(args, name) <= 1.0:
            return f"--{name.replace('_', '-')}: a probability in [0, 1]"
    if args.jitter < 0:
        return "--jitter: must be >= 0 seconds"
    if args.bad_crc and not get_profile(scenario.profile).has_crc:
        return f"--bad-crc: the {scenario.profile} profile's frames carry no CRC"
    return None


def run(args: argparse.Namespace) -> int:
    from canfdi.firmware_sim.emitter import Disturbance
    from canfdi.firmware_sim.scenario import ScenarioError, load_scenario
    from canfdi.tools.pairing import without_faults

    try:
        scenario = load_scenario(args.scenario)
    except ScenarioError as exc:
        return _fail(f"scenario error: {exc}")
    if args.healthy:
        scenario = without_faults(scenario)
    problem = _check_args(args, scenario)
    if problem:
        return _fail(problem)
    disturbance = Disturbance(drop=args.drop, jitter=args.jitter, bad_crc=args.bad_crc,
                              wrong_dlc=args.wrong_dlc, seed=scenario.seed)
    if args.truth:
        from canfdi.tools.demo import truth_document

        args.truth.write_text(json.dumps(truth_document(scenario), indent=2) + "\n")
    if args.output is not None:
        return _to_file(args, scenario, disturbance)
    return _to_bus(args, scenario, disturbance)


def _to_bus(args: argparse.Namespace, scenario, disturbance) -> int:
    """The scenario's frames on the bus the options ask for."""
    import can

    from canfdi.firmware_sim.emitter import emit

    try:
        interface, channel, opener = bus_factory(bus_request(args), None)
    except BusArgumentError as exc:
        print(f"canfdi sim: {exc}", file=sys.stderr)
        return 2
    try:
        bus = opener()
    except (can.CanError, OSError, ValueError, ImportError) as exc:
        print(f"canfdi sim: cannot open {interface} bus {channel!r}: {exc}", file=sys.stderr)
        return 1
    total = samples_to_play(scenario, args.duration)

    def progress(chunk, stats) -> None:
        if not args.quiet:
            print(f"\rcanfdi sim: {scenario.name} ({scenario.profile}, {len(scenario.drives)} "
                  f"drive{'s' if len(scenario.drives) > 1 else ''}): sample "
                  f"{stats.samples}/{total} "
                  f"({100 * stats.samples / total:.0f}%), {stats.frames_sent} frames",
                  end="", file=sys.stderr, flush=True)

    stop = StopEvent()

    async def main() -> object:
        return await emit(bus, scenario, speed=args.speed, duration=args.duration,
                          disturbance=disturbance, on_block=progress, stop=stop.arm(),
                          reopen=opener)

    try:
        stats = asyncio.run(main())
    except can.CanError as exc:
        print(f"\ncanfdi sim: bus error: {exc}", file=sys.stderr)
        return 1
    finally:
        bus.shutdown()
    if not args.quiet:
        print(file=sys.stderr)
    _report(args, {"scenario": scenario.name, **stats.as_dict()})
    return stop.exit_status


def _to_file(args: argparse.Namespace, scenario, disturbance) -> int:
    """The scenario's frames into a log file (no bus)."""
    from canfdi.io.formats import LogFormatError, format_of
    from canfdi.tools.sim import write_scenario_log

    try:
        format_of(args.output)
    except LogFormatError as exc:
        return _fail(f"-o {args.output}: {exc}")
    if args.output.exists():
        return _fail(f"-o {args.output}: exists (not overwritten)")
    if not args.quiet:
        print(f"canfdi sim: {scenario.name}: writing {args.output}", file=sys.stderr)
    try:
        outcome = write_scenario_log(scenario, disturbance, args.output, args.duration)
    except (OSError, LogFormatError) as exc:
        print(f"canfdi sim: cannot write {args.output}: {exc}", file=sys.stderr)
        return 1
    _report(args, outcome)
    return 0


def _report(args: argparse.Namespace, outcome: dict) -> None:
    """The outcome on stdout: one JSON object with --json, else a line of words."""
    if args.json:
        print(json.dumps(outcome))
        return
    where = f" -> {outcome['output']}" if "output" in outcome else ""
    sent = outcome.get("frames", outcome.get("frames_sent", 0))
    print(f"canfdi sim: {outcome['scenario']}: {outcome.get('samples', 0):,} samples, "
          f"{sent:,} frames{where}")


def main(argv: list[str] | None = None) -> int:
    """Entry point of the `canfdi-sim` console script."""
    parser = argparse.ArgumentParser(prog="canfdi-sim", description=HELP,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    add_arguments(parser)
    return run(parser.parse_args(argv))

"""`canfdi capture --config FILE -o OUT.mcap`: record a bus, decoded, without diagnosing."""

from __future__ import annotations

import argparse
import asyncio
import sys
from pathlib import Path

from canfdi.cli.common import (
    add_bus_overrides,
    bus_factory,
    config_error,
    load_config_or_exit,
    open_recorder,
    stop_event,
)

HELP = """\
Record every frame of a bus (valid or not, with its E2E status) and the decoded samples in an
MCAP log, until SIGINT/SIGTERM or --duration. The config gives the bus and the DBC; no
diagnosis runs, so `canfdi replay OUT.mcap --config FILE` can diagnose the log later."""


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("capture", help="record a bus to MCAP (decoded, no diagnosis)",
                       description=HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--config", required=True, type=Path, metavar="FILE", help="monitor config")
    p.add_argument("-o", "--output", required=True, type=Path, metavar="OUT.mcap")
    add_bus_overrides(p)
    p.add_argument("--duration", type=float, metavar="T", help="stop after T seconds")


def run(args: argparse.Namespace) -> int:
    from canfdi.monitor import Monitor
    from canfdi.service import MonitorService

    config = load_config_or_exit(args.config, "capture")
    if isinstance(config, int):
        return config
    try:
        monitor = Monitor(config, diagnose=False)
    except ValueError as exc:
        return config_error(exc, "capture")
    try:
        recorder = open_recorder(args.output, monitor.metadata())
    except OSError as exc:
        print(f"canfdi capture: cannot write {args.output}: {exc}", file=sys.stderr)
        return 1
    monitor.sink = recorder
    _, _, opener = bus_factory(args, config.bus)

    async def main():
        stop = stop_event(args.duration)
        service = MonitorService(monitor, opener, status_period=0)
        return await service.run(stop)

    try:
        stats = asyncio.run(main())
    finally:
        recorder.close()
    print(f"canfdi capture: {stats.frames} frames, {monitor.samples} samples -> {args.output}",
          file=sys.stderr)
    return 0

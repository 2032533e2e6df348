"""`canfdi capture --config FILE -o OUT.mcap`: record a bus, decoded, without diagnosing."""

from __future__ import annotations

import argparse
import asyncio
import signal
import sys
from pathlib import Path

from canfdi.cli.common import config_error, load_config_or_exit, open_recorder

HELP = """\
Record every frame of a bus (valid or not, with its E2E status) and the decoded samples in an
MCAP log, until SIGINT/SIGTERM or --duration. The config gives the bus and the DBC; no
diagnosis runs, so `canfdi replay OUT.mcap --config FILE` can diagnose the log later."""


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("capture", help="record a bus to MCAP (decoded, no diagnosis)",
                       description=HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--config", required=True, type=Path, metavar="FILE", help="monitor config")
    p.add_argument("-o", "--output", required=True, type=Path, metavar="OUT.mcap")
    p.add_argument("--interface", help="override bus.interface")
    p.add_argument("--channel", help="override bus.channel")
    p.add_argument("--bitrate", type=int, help="override bus.bitrate")
    p.add_argument("--duration", type=float, metavar="T", help="stop after T seconds")


def run(args: argparse.Namespace) -> int:
    from canfdi.monitor import Monitor
    from canfdi.service import MonitorService, open_bus

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
    bus = config.bus

    async def main():
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, stop.set)
        if args.duration:
            loop.call_later(args.duration, stop.set)
        service = MonitorService(
            monitor, lambda: open_bus(args.interface or bus.interface,
                                      args.channel or bus.channel,
                                      args.bitrate if args.bitrate is not None else bus.bitrate),
            status_period=0)
        return await service.run(stop)

    try:
        stats = asyncio.run(main())
    finally:
        recorder.close()
    print(f"canfdi capture: {stats.frames} frames, {monitor.samples} samples -> {args.output}",
          file=sys.stderr)
    return 0

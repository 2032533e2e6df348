"""`canfdi capture --config FILE -o OUT.mcap`: record a bus, decoded, without diagnosing."""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
from pathlib import Path

from canfdi.cli.common import (
    add_bus_overrides,
    add_kernel_option,
    add_retry_option,
    bus_request,
    fail,
    kernel_or_exit,
    load_config_or_exit,
)
from canfdi.tools.session import (
    CannotRecord,
    Recording,
    SessionError,
    StopEvent,
    open_session,
    recording_counts,
)

HELP = """\
Record every frame of a bus (valid or not, with its E2E status) and the decoded samples in an
MCAP log, until SIGINT/SIGTERM or --duration. The config gives the bus and the DBC; no
diagnosis runs, so `canfdi replay OUT.mcap --config FILE` can diagnose the log later.

On stderr: "canfdi capture: recording INTERFACE CHANNEL to OUT.mcap" once the bus is open, a
warning when the log cannot be written (a full disk: frames are dropped, and recording resumes
in a new segment OUT-0001.mcap when space returns) and a summary at the end. A killed capture
loses about the last second; `canfdi replay` reads the truncated file."""


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("capture", help="record a bus to MCAP (decoded, no diagnosis)",
                       description=HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--config", required=True, type=Path, metavar="FILE", help="monitor config")
    p.add_argument("-o", "--output", required=True, type=Path, metavar="OUT.mcap")
    add_kernel_option(p)
    add_bus_overrides(p)
    add_retry_option(p)
    p.add_argument("--duration", type=float, metavar="T", help="stop after T seconds")
    p.add_argument("--json", action="store_true",
                   help="print the outcome as one JSON object on stdout: output, frames, "
                        "samples, bus_errors, recording")


def run(args: argparse.Namespace) -> int:
    config = load_config_or_exit(args.config, "capture")
    if isinstance(config, int):
        return config
    kernel = kernel_or_exit(args, "capture")
    if isinstance(kernel, int):
        return kernel
    try:
        session = open_session(config, "capture", diagnose=False, bus=bus_request(args),
                               filters=False, recording=Recording(args.output, log_lines=False),
                               kernel=kernel)
    except SessionError as exc:
        return fail("capture", exc.message, exc.status)
    except CannotRecord as exc:
        return fail("capture", f"cannot write {exc.path}: {exc.error}", 1)
    interface, channel = session.interface, session.channel

    def on_ready() -> None:
        print(f"canfdi capture: recording {interface} {channel} to {args.output}",
              file=sys.stderr, flush=True)

    stop = StopEvent()
    with session:
        stats = asyncio.run(session.serve(stop, duration=args.duration, status_period=0,
                                          on_ready=on_ready, retry_for=args.retry_for or None))
    counts = recording_counts(session.recorder)
    if stats.frames == 0:
        # Nothing was recorded: no empty log that looks like a capture, and a status that says
        # so (a dead or silent bus, a wrong channel).
        session.discard_recording()
        why = "the bus could not be opened" if stats.gave_up else "no frame was received"
        print(f"canfdi capture: {why} on {interface} {channel}; nothing recorded",
              file=sys.stderr)
        if args.json:
            print(json.dumps({"output": None, "frames": 0, "samples": 0,
                              "bus_errors": stats.bus_errors, "recording": counts}))
        return 1
    print(f"canfdi capture: {stats.frames} frames, {session.monitor.samples} samples -> "
          f"{args.output}", file=sys.stderr)
    if counts["write_errors"]:
        print(f"canfdi capture: {counts['write_errors']} log write errors (last: "
              f"{counts['last_error']}), {counts['dropped']} records dropped; segments: "
              f"{', '.join(counts['segments'])}", file=sys.stderr)
    if args.json:
        print(json.dumps({"output": str(args.output), "frames": stats.frames,
                          "samples": session.monitor.samples, "bus_errors": stats.bus_errors,
                          "recording": counts}))
    return stop.exit_status

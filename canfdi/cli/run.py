"""`canfdi run --config FILE`: the monitor on a live bus, until SIGTERM or SIGINT."""

from __future__ import annotations

import argparse
import asyncio
import json
import logging
import sys
from pathlib import Path

from canfdi.bus.traffic import NO_TRAFFIC_MIN_S, NO_TRAFFIC_PERIODS, no_traffic_default
from canfdi.cli.common import (
    add_bus_overrides,
    add_foxglove_option,
    add_kernel_option,
    add_retry_option,
    bus_request,
    fail,
    format_event,
    kernel_or_exit,
    load_config_or_exit,
    say,
)
from canfdi.tools.session import (
    CannotRecord,
    SessionError,
    StopEvent,
    open_session,
    run_recording,
)

HELP = """\
Monitor a drive's CAN bus: decode its frames with the config's DBC, diagnose faults, send
FDI_FAULT / FDI_ESTIMATE frames when a fault is accepted and FDI_STATUS every status period,
and record everything in MCAP logs (rotated by size and age) under the recording directory;
with recording.keep_days or keep_mib, the older logs it wrote there are removed at start and
every 10 minutes (never the file being written, never a file it did not name). With
`bus.transmit: false` it is listen-only: it sends nothing at all (diagnoses are printed and
recorded). The config's bus: section says how the drive talks (its DBC, map, E2E profiles,
sample clock, drives); docs/bus.md has every key.

The bus comes from the config's bus: section (interface, channel, bitrate), overridable here. A
lost bus is reopened with backoff (the recorded status says bus_error meanwhile, the log and
the stopped: line how long it was down); one that cannot be opened for --retry-for seconds
(default 60) ends the run with exit status 1, so that a supervisor restarts it. Unless taught
(--teach), each drive is first checked: its first 5 s or so (the noise watchdog's first window)
are diagnosed only once the watchdog has judged the configured noise on them (FDI_STATUS says
"checking"), so that a drive noisier than its config announces no alarm; a residual quieter
than configured is said ("quiet") but detection keeps the configured noise. A bus on which
no frame of the drives arrives for --no-traffic seconds (default 50 control periods, at least 1
s) is said: a warning in the log, state no_traffic on FDI_STATUS, in systemd's STATUS= and in
the live view, until the frames resume (said too). A log that cannot be written (a full disk)
never stops the monitoring: the error is logged once, records are dropped and counted,
FDI_STATUS says "degraded", and recording resumes in a new segment when space returns. SIGTERM
or SIGINT stops it in order: the bus is closed, the log flushed and closed, a "stopped:" line
gives the counters (frames, sent, bus_errors, bus_down_s, faults, gave_up; with "recording":
segments, written, dropped, write_errors; with --foxglove, "foxglove": lagging viewers, whose
oldest messages were dropped, and oversize messages not shown live), exit status 0 (130 after
SIGINT, Ctrl-C). A bad config exits with status 2. In a terminal a live view shows each
residual's Page-Hinkley statistic against its threshold, the detector state, the active faults
and the frame counters, with diagnoses and log lines printed above it (--no-live, --quiet or a
non-terminal stdout turn it off: a daemon's journal gets plain lines). What the monitor
computes at start from the config (the parity thresholds' calibration, a second or more) is
kept in a cache directory ($CANFDI_CACHE_DIR, else systemd's $CACHE_DIRECTORY, else
~/.cache/canfdi): a restarted daemon monitors sooner."""


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("run", help="monitor a live bus (the daemon)", description=HELP,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--config", required=True, type=Path, metavar="FILE", help="monitor config")
    add_bus_overrides(p)
    add_kernel_option(p)
    add_retry_option(p)
    p.add_argument("--no-traffic", type=float, metavar="SECONDS",
                   help="say no_traffic after this many seconds without a frame of the drives "
                        f"(default: {NO_TRAFFIC_PERIODS} control periods, at least "
                        f"{NO_TRAFFIC_MIN_S:g} s; 0: never)")
    p.add_argument("--no-filters", action="store_true",
                   help="receive every frame of the bus: no receive filters (by default the "
                        "bus passes only the IDs the config's bus map and sample clock read, "
                        "in the kernel on SocketCAN; frames of other IDs are then neither "
                        "seen nor counted as unknown_id)")
    p.add_argument("--log-dir", type=Path, metavar="DIR",
                   help="where MCAP logs go (default: recording.directory of the config)")
    p.add_argument("-o", "--output", type=Path, metavar="FILE.mcap",
                   help="log to this file (rotated segments get -0001, -0002, ...)")
    p.add_argument("--no-record", action="store_true", help="do not write MCAP logs")
    add_foxglove_option(p)
    p.add_argument("--duration", type=float, metavar="T", help="stop after T seconds")
    p.add_argument("--json", action="store_true",
                   help="at the end, print the stopped: counters as one JSON object on stdout "
                        "(frames, sent, bus_errors, bus_down_s, faults, gave_up, recording, "
                        "foxglove)")
    p.add_argument("--log-format", choices=("text", "json"), default="text",
                   help="format of the service's log lines on stderr (default: text)")
    p.add_argument("--quiet", action="store_true", help="do not print diagnoses on stdout")
    p.add_argument("--no-live", action="store_true",
                   help="no live view (it is on when stdout is a terminal, off otherwise)")
    p.add_argument("--teach", type=float, metavar="SECONDS",
                   help="teach-in: learn the drive's noise from its first SECONDS of samples "
                        "(the drive must be healthy meanwhile; FDI_STATUS says 'teaching'), "
                        "as `canfdi calibrate` does from logs, then monitor with it; the "
                        "learned values go to the log's metadata (canfdi.teach.<drive>)")


class _JsonFormatter(logging.Formatter):
    def format(self, record: logging.LogRecord) -> str:
        return json.dumps({"time": record.created, "level": record.levelname,
                           "logger": record.name, "message": record.getMessage()})


def setup_logging(fmt: str) -> None:
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(_JsonFormatter() if fmt == "json" else logging.Formatter(
        "%(asctime)s %(levelname)s %(name)s: %(message)s"))
    root = logging.getLogger()
    root.handlers[:] = [handler]
    root.setLevel(logging.INFO)


def run(args: argparse.Namespace) -> int:
    setup_logging(args.log_format)
    config = load_config_or_exit(args.config, "run")
    if isinstance(config, int):
        return config
    log = logging.getLogger("canfdi.run")
    kernel = kernel_or_exit(args, "run")
    if isinstance(kernel, int):
        return kernel
    try:
        session = open_session(
            config, "run", teach=args.teach, kernel=kernel, cache_designs=True,
            bus=bus_request(args),
            filters=not args.no_filters, foxglove=args.foxglove, systemd=True,
            recording=None if args.no_record else run_recording(config, args.output,
                                                                 args.log_dir, log),
            view=config.name if not args.quiet and not args.no_live and sys.stdout.isatty()
            else None, notice=say("run"))
    except SessionError as exc:
        return fail("run", exc.message, exc.status)
    except CannotRecord as exc:
        return fail("run", f"cannot write logs to {exc.path}: {exc.error}", 1)
    no_traffic = no_traffic_default(config.model.dt) if args.no_traffic is None else max(
        args.no_traffic, 0.0)
    monitor, view = session.monitor, session.view

    def on_event(event) -> None:
        log.info("event %s", json.dumps(event.as_dict()))
        if not args.quiet:
            line = format_event(event, monitor.dt, len(monitor.drives) > 1)
            if view is not None:
                view.print(line)
            else:
                print(line, flush=True)

    stop = StopEvent()
    with session:
        stats = asyncio.run(session.serve(
            stop, duration=args.duration, status_period=config.bus.status_period,
            on_event=on_event, retry_for=args.retry_for or None, no_traffic=no_traffic,
            on_ready=lambda: log.info("monitoring %s %s", session.interface, session.channel)))
    stopped = session.stopped(stats)
    log.info("stopped: %s", json.dumps(stopped))
    if stats.frames == 0 and not stats.gave_up:
        log.warning("no frame was received on %s %s", session.interface, session.channel)
    if args.json:
        print(json.dumps(stopped))
    if stats.gave_up:
        return 1
    return stop.exit_status

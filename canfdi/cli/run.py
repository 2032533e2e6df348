"""`canfdi run --config FILE`: the monitor on a live bus, until SIGTERM or SIGINT."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import logging
import sys
import time
from functools import partial
from pathlib import Path

from canfdi.bus.traffic import NO_TRAFFIC_MIN_S, NO_TRAFFIC_PERIODS, no_traffic_default
from canfdi.cli.common import (
    BusArgumentError,
    StopEvent,
    add_bus_overrides,
    add_foxglove_option,
    add_retry_option,
    bus_factory,
    close_recorder,
    config_error,
    format_event,
    load_config_or_exit,
    open_foxglove,
    open_recorder,
    recording_counts,
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


def remember_designs() -> None:
    """Keep what the monitor computes at start (canfdi.core.memo: the parity thresholds) in
    the cache directory (canfdi.io.memostore), so that a restarted daemon starts sooner."""
    from canfdi.core import memo
    from canfdi.io.memostore import DirectoryStore, cache_directory

    directory = cache_directory()
    if directory is not None:
        memo.install(DirectoryStore(directory))


def teacher(config, seconds: float):
    """The teach-in of ``seconds`` for the config (canfdi.tools.calibrate.Teach), or exit
    status 2 after one error line."""
    import math

    from canfdi.config import read_yaml
    from canfdi.core.settings import ConfigError
    from canfdi.tools.calibrate import MIN_SAMPLES, Teach

    dt = config.model.dt or 1.0
    samples = round(seconds / dt) if math.isfinite(seconds) and seconds > 0 else 0
    if samples < MIN_SAMPLES:
        print(f"canfdi run: --teach: {seconds:g} s is {samples} samples at dt = {dt:g} s; "
              f"teach-in needs at least {MIN_SAMPLES} ({MIN_SAMPLES * dt:g} s)", file=sys.stderr)
        return 2
    return Teach(config, read_yaml(config.path, ConfigError, "config"), samples)


PRUNE_INTERVAL_S = 600.0
"""How often a running daemon applies recording.keep_days / keep_mib (and at start)."""


def prune_run_logs(directory: Path, name: str, keep_days: float | None, keep_bytes: int | None,
                   log: logging.Logger, current) -> None:
    """Apply the retention rule (canfdi.io.retention) to the run's logs in ``directory``,
    sparing the files ``current``; one line per pruning that removed anything, one warning
    when the directory cannot be pruned (recording goes on)."""
    from canfdi.io.retention import prune_logs

    try:
        removed = prune_logs(directory, name, time.time(), keep_days, keep_bytes, current)
    except OSError as exc:
        log.warning("cannot remove old logs in %s: %s", directory, exc)
        return
    if removed:
        log.info("removed %d old log file(s) (%.1f MiB) under recording.keep_days/keep_mib: "
                 "%s", len(removed), sum(f.size for f in removed) / 2**20,
                 ", ".join(f.path.name for f in removed[:5])
                 + (", ..." if len(removed) > 5 else ""))


async def keep_pruning(prune, recorder, stop: asyncio.Event) -> None:
    """Prune every PRUNE_INTERVAL_S until ``stop``, sparing the recorder's open segment."""
    while not stop.is_set():
        with contextlib.suppress(asyncio.TimeoutError):
            await asyncio.wait_for(stop.wait(), PRUNE_INTERVAL_S)
        if not stop.is_set():
            prune(recorder.paths[-1:])


def run(args: argparse.Namespace) -> int:
    from canfdi.monitor import Monitor
    from canfdi.sdnotify import Notifier
    from canfdi.service import MonitorService

    setup_logging(args.log_format)
    config = load_config_or_exit(args.config, "run")
    if isinstance(config, int):
        return config
    teach = None
    if args.teach is not None:
        teach = teacher(config, args.teach)
        if isinstance(teach, int):
            return teach
    remember_designs()
    try:
        monitor = Monitor(config, teach=teach)
    except ValueError as exc:
        return config_error(exc, "run")
    try:
        interface, channel, opener = bus_factory(
            args, config.bus, None if args.no_filters else monitor.receive_filters())
    except BusArgumentError as exc:
        print(f"canfdi run: {exc}", file=sys.stderr)
        return 2
    live = open_foxglove(args.foxglove, "run")
    if isinstance(live, int):
        return live
    recorder = None
    drive_time = lambda: monitor.last_timestamp_ns or time.time_ns()  # noqa: E731
    log = logging.getLogger("canfdi.run")
    prune = None
    if not args.no_record:
        rec = config.recording
        directory = args.log_dir or Path(rec.directory)
        path = args.output or directory / (
            f"{config.name}-{time.strftime('%Y%m%d-%H%M%S')}.mcap")
        if args.output is None and (rec.keep_days is not None or rec.keep_mib is not None):
            prune = partial(prune_run_logs, directory, config.name, rec.keep_days,
                            None if rec.keep_mib is None else int(rec.keep_mib * 2**20), log)
            prune(())
        try:
            recorder = open_recorder(path, monitor.metadata(), drive_clock=drive_time, tap=live,
                                     rotate_bytes=int(rec.rotate_mib * 2**20),
                                     rotate_seconds=rec.rotate_minutes * 60.0)
        except OSError as exc:
            print(f"canfdi run: cannot write logs to {path}: {exc}", file=sys.stderr)
            if live is not None:
                live.close()
            return 1
    elif live is not None:
        recorder = open_recorder(None, monitor.metadata(), drive_clock=drive_time, tap=live)
    monitor.sink = recorder
    systemd = Notifier()
    no_traffic = no_traffic_default(config.model.dt) if args.no_traffic is None else max(
        args.no_traffic, 0.0)

    def on_ready() -> None:
        log.info("monitoring %s %s", interface, channel)
        systemd.ready(f"monitoring {interface} {channel}")

    view = None
    if not args.quiet and not args.no_live and sys.stdout.isatty():
        from canfdi.liveview import LiveView

        view = LiveView(monitor, title=f"canfdi run: {config.name} on {interface} {channel}")

    def on_event(event) -> None:
        log.info("event %s", json.dumps(event.as_dict()))
        if not args.quiet:
            line = format_event(event, monitor.dt, len(monitor.drives) > 1)
            if view is not None:
                view.print(line)
            else:
                print(line, flush=True)

    stop = StopEvent()

    async def main():
        stop.arm(args.duration)
        if prune is not None:
            pruner = asyncio.create_task(keep_pruning(prune, recorder, stop))
        service = MonitorService(
            monitor, opener, status_period=config.bus.status_period, on_event=on_event,
            on_ready=on_ready, on_tick=systemd.watchdog, retry_for=args.retry_for or None,
            no_traffic=no_traffic, on_status=systemd.status)
        if view is not None:
            view.condition = lambda: service.condition
        if view is None:
            stats = await service.run(stop)
        else:
            # Log lines print above the view instead of tearing it.
            for handler in logging.getLogger().handlers:
                if isinstance(handler, logging.StreamHandler):
                    handler.setStream(view.stream())
            with view:
                refresher = asyncio.create_task(view.run(stop))
                try:
                    stats = await service.run(stop)
                finally:
                    stop.set()
                    await refresher
        systemd.stopping()
        if prune is not None:
            await pruner
        return stats

    try:
        stats = asyncio.run(main())
    finally:
        if recorder is not None:
            close_recorder(recorder)
        if live is not None:
            live.close()
    summary = monitor.summary()
    stopped = {"frames": stats.frames, "sent": stats.sent, "bus_errors": stats.bus_errors,
               "bus_down_s": round(stats.bus_down_s, 3), "faults": len(summary["faults"]),
               "gave_up": stats.gave_up}
    if recorder is not None and not args.no_record:
        stopped["recording"] = recording_counts(recorder)
    if live is not None:  # viewers that fell behind, messages too large to show live
        stopped["foxglove"] = {"lagging": live.lagging, "oversize": live.oversize}
    log.info("stopped: %s", json.dumps(stopped))
    if stats.frames == 0 and not stats.gave_up:
        log.warning("no frame was received on %s %s", interface, channel)
    if args.json:
        print(json.dumps(stopped))
    if stats.gave_up:
        return 1
    return stop.exit_status

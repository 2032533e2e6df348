"""`canfdi replay LOG --config FILE`: the same diagnoser, offline, over a recorded log."""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Iterator
from pathlib import Path

from canfdi.cli.common import config_error, format_event, load_config_or_exit, print_comparison

HELP = """\
Run the monitor offline over a log: an MCAP written by canfdi (run, demo, capture), whose raw
frames are replayed with their timestamps, or any log python-can reads (candump .log, .asc,
.blf, .trc, .csv). Replaying a live run's MCAP gives the live run's diagnoses. A truncated MCAP
(a killed process) is read up to its last complete record.

Prints each diagnosis and a summary table, or with --json one object: {"faults": [...],
"frames": {...}, "samples": N, "truth": [...] when the log holds it}."""

PYTHON_CAN_SUFFIXES = {".log", ".asc", ".blf", ".trc", ".csv"}


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("replay", help="diagnose a recorded log offline", description=HELP,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("log", type=Path, help="MCAP log, or a python-can log (.log .asc .blf .trc)")
    p.add_argument("--config", required=True, type=Path, metavar="FILE", help="monitor config")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--no-progress", action="store_true", help="no progress line on stderr")


def mcap_frames(path: Path) -> Iterator[tuple[int, int, bytes, bool, bool]]:
    """(timestamp_ns, id, data, extended, error) of the frames a canfdi MCAP received."""
    from canfdi.recorder import TOPIC_FRAMES, log_segments, read_log

    for segment in log_segments(path):
        for _, log_time, msg in read_log(segment, topics=[TOPIC_FRAMES]):
            if msg.get("status") == "sent":
                continue  # the monitor's own transmissions: a live monitor does not hear them
            yield (log_time, int(msg["id"]), bytes.fromhex(msg["data"]),
                   bool(msg.get("extended", False)), msg.get("status") == "error_frame")


def python_can_frames(path: Path) -> Iterator[tuple[int, int, bytes, bool, bool]]:
    import can

    with can.LogReader(str(path)) as reader:
        for msg in reader:
            yield (round(msg.timestamp * 1e9), msg.arbitration_id, bytes(msg.data),
                   msg.is_extended_id, msg.is_error_frame)


def truth_of(path: Path) -> list[dict] | None:
    from canfdi.recorder import read_metadata

    try:
        meta = read_metadata(path)
    except Exception:  # a foreign or damaged file simply has no truth
        return None
    return json.loads(meta["truth_json"]) if "truth_json" in meta else None


def run(args: argparse.Namespace) -> int:
    from canfdi.monitor import Monitor

    config = load_config_or_exit(args.config, "replay")
    if isinstance(config, int):
        return config
    if not args.log.exists():
        print(f"canfdi replay: no such log: {args.log}", file=sys.stderr)
        return 2
    try:
        monitor = Monitor(config, record_residuals=False)
    except ValueError as exc:
        return config_error(exc, "replay")
    suffix = args.log.suffix.lower()
    if suffix in PYTHON_CAN_SUFFIXES:
        frames, truth = python_can_frames(args.log), None
    else:
        frames, truth = mcap_frames(args.log), truth_of(args.log)
    progress = not args.no_progress and sys.stderr.isatty()
    shown, start, count = 0, time.monotonic(), 0
    n_events = 0
    try:
        for ts, frame_id, data, extended, error in frames:
            monitor.on_frame(ts, frame_id, data, is_extended=extended, is_error=error)
            count += 1
            if len(monitor.events) != n_events:
                if not args.json:
                    for event in monitor.events[n_events:]:
                        print(format_event(event, monitor.dt), flush=True)
                n_events = len(monitor.events)
            if progress and count % 4096 == 0 and time.monotonic() - shown > 0.5:
                shown = time.monotonic()
                print(f"\rcanfdi replay: {count} frames, {monitor.samples} samples, "
                      f"{count / (shown - start):,.0f} frames/s", end="", file=sys.stderr)
    except (OSError, ValueError) as exc:
        print(f"\ncanfdi replay: cannot read {args.log}: {exc}", file=sys.stderr)
        return 1
    monitor.finish()
    if progress:
        print(file=sys.stderr)
    result = monitor.summary(truth)
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        print_comparison(result, truth)
    return 0

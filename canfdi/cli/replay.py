"""`canfdi replay LOG --config FILE`: the same diagnoser, offline, over a recorded log."""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

from canfdi.cli.common import config_error, format_event, load_config_or_exit, print_comparison

if TYPE_CHECKING:
    from canfdi.io.recorder import FrameArrays

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
    from canfdi.io.recorder import iter_frame_blocks

    for block in iter_frame_blocks(path):
        received = block.status != "sent"  # the monitor's own: a live monitor does not hear them
        if not received.all():
            block = block.select(received)
        yield from zip(block.t_ns.tolist(), block.id.tolist(), block.payloads(),
                       block.extended.tolist(), (block.status == "error_frame").tolist(),
                       strict=True)


def mcap_frame_arrays(path: Path) -> FrameArrays:
    """The frames a canfdi MCAP received, as arrays (`canfdi.io.recorder.FrameArrays`): every
    segment, in order, without the monitor's own transmissions (status "sent"). Error frames
    have status "error_frame"; `FrameArrays.payloads` gives payloads longer than 8 bytes."""
    from canfdi.io.recorder import read_frames

    frames = _scanned_frames(path)
    if frames is None:
        frames = read_frames(path)
    received = frames.status != "sent"
    return frames if received.all() else frames.select(received)


def frame_array_blocks(path: Path, frames_per_block: int = 65536):
    """Blocks of received frames (FrameArrays, "sent" removed) of about ``frames_per_block``,
    read ahead in a thread so that inflating and decoding the log overlaps with the diagnosis
    (zstd releases the GIL) on a second core."""
    import queue
    import threading

    import numpy as np

    from canfdi.io.recorder import TOPIC_FRAMES, FrameArrays, _frame_block, log_segments
    from canfdi.io.scan import UnsupportedLog, scan_topic

    fields = ("t_ns", "id", "dlc", "data", "extended", "status", "flags")

    def merged(parts):
        return FrameArrays(*(np.concatenate([getattr(b, f) for b in parts]) for f in fields),
                           {})

    def produce(out: queue.Queue) -> None:
        try:
            pending, count = [], 0
            for segment in log_segments(path):
                for _, message in scan_topic(segment, TOPIC_FRAMES):
                    block = _frame_block(message)
                    if block.long:
                        raise UnsupportedLog("payloads over 8 bytes")
                    keep = block.status != "sent"
                    pending.append(block if keep.all() else block.select(keep))
                    count += len(pending[-1].t_ns)
                    if count >= frames_per_block:
                        out.put(merged(pending))
                        pending, count = [], 0
            if pending:
                out.put(merged(pending))
            out.put(None)
        except Exception as exc:  # handed to the consumer, which decides
            out.put(exc)

    q: queue.Queue = queue.Queue(maxsize=4)
    thread = threading.Thread(target=produce, args=(q,), daemon=True)
    thread.start()
    while (item := q.get()) is not None:
        if isinstance(item, Exception):
            raise item
        yield item
    thread.join()


def _scanned_frames(path: Path):
    """The frame blocks of every segment through canfdi.io.scan (fast), or None when a
    segment needs the full reader (an old one-frame-per-message log, an unusual chunk)."""
    import numpy as np

    from canfdi.io.recorder import TOPIC_FRAMES, FrameArrays, _frame_block, log_segments
    from canfdi.io.scan import UnsupportedLog, scan_topic

    blocks = []
    try:
        for segment in log_segments(path):
            for _, message in scan_topic(segment, TOPIC_FRAMES):
                if "frames" not in message:
                    return None
                blocks.append(_frame_block(message))
    except (UnsupportedLog, ValueError, KeyError):
        return None
    if not blocks:
        return None
    long: dict[int, bytes] = {}
    offset = 0
    for b in blocks:
        long.update({offset + row: data for row, data in b.long.items()})
        offset += len(b.t_ns)
    return FrameArrays(*(np.concatenate([getattr(b, f) for b in blocks])
                         for f in ("t_ns", "id", "dlc", "data", "extended", "status", "flags")),
                       long)


def mcap_blocks(path: Path, frames_per_block: int = 65536):
    """(t_ns, ids, dlc, flags, payloads) blocks of a canfdi MCAP's received frames: the fast
    scanner when it can read the log, the full reader otherwise (older layouts)."""
    from canfdi.io.scan import UnsupportedLog

    try:
        for arr in frame_array_blocks(path, frames_per_block):
            yield arr.t_ns, arr.id, arr.dlc, arr.flags, arr.data
        return
    except (UnsupportedLog, ValueError, KeyError):
        pass
    arr = mcap_frame_arrays(path)
    for i in range(0, len(arr.t_ns), frames_per_block):
        j = i + frames_per_block
        yield arr.t_ns[i:j], arr.id[i:j], arr.dlc[i:j], arr.flags[i:j], arr.data[i:j]


def python_can_blocks(path: Path, frames_per_block: int = 65536):
    """(t_ns, ids, dlc, flags, payloads) blocks of a log python-can reads."""
    import can

    from canfdi.monitor import messages_to_arrays

    with can.LogReader(str(path)) as reader:
        pending = []
        for msg in reader:
            pending.append(msg)
            if len(pending) >= frames_per_block:
                yield messages_to_arrays(pending, now=0.0)
                pending = []
        if pending:
            yield messages_to_arrays(pending, now=0.0)


def truth_of(path: Path) -> list[dict] | None:
    from canfdi.io.recorder import read_metadata

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
        blocks, truth = python_can_blocks(args.log), None
    else:
        blocks, truth = mcap_blocks(args.log), truth_of(args.log)
    progress = not args.no_progress and sys.stderr.isatty()
    start = time.monotonic()
    count = n_events = 0
    try:
        for t_ns, ids, dlc, flags, payloads in blocks:
            monitor.on_frames(t_ns, ids, dlc, payloads, flags)
            count += len(ids)
            if len(monitor.events) != n_events:
                if not args.json:
                    for event in monitor.events[n_events:]:
                        print(format_event(event, monitor.dt), flush=True)
                n_events = len(monitor.events)
            if progress:
                rate = monitor.samples / max(time.monotonic() - start, 1e-9)
                print(f"\rcanfdi replay: {count:,} frames, {monitor.samples:,} samples, "
                      f"{rate:,.0f} samples/s", end="", file=sys.stderr)
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

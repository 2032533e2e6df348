"""`canfdi export LOG --format blf|asc|log|csv`: a canfdi MCAP's raw frames for other tools."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

FORMATS = {"blf": ".blf", "asc": ".asc", "log": ".log", "csv": ".csv"}

HELP = """\
Write every raw frame of a canfdi MCAP log (all segments, valid or not, the drive's and the
monitor's own "sent" frames) to a file the usual CAN tools open, through python-can's writers:

  blf  Vector binary logging format (CANalyzer, CANoe, SavvyCAN)
  asc  Vector ASCII (CANalyzer, SavvyCAN)
  log  candump -L text (can-utils canplayer, SavvyCAN)
  csv  python-can's CSV (timestamp, arbitration_id, extended, remote, error, dlc, data)

Timestamps are the log's (seconds since the epoch). A frame's E2E status (crc, dlc, ...) has no
place in these formats: `canfdi replay OUT --config FILE` re-derives it. A truncated MCAP (a
killed process) is exported up to its last complete block. Exit status: 0 written, 2 bad log
or arguments, 1 the output could not be written."""


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("export", help="write a log's raw frames as BLF, ASC, candump or CSV",
                       description=HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("log", type=Path, help="canfdi MCAP log (its first segment)")
    p.add_argument("--format", required=True, choices=sorted(FORMATS), help="output format")
    p.add_argument("-o", "--output", type=Path, metavar="OUT",
                   help="output file (default: the log's name with the format's suffix)")
    p.add_argument("--no-progress", action="store_true", help="no progress line on stderr")


def export_frames(log: Path, out: Path, fmt: str, progress=None) -> int:
    """Write every frame of ``log`` to ``out`` in format ``fmt``; returns the frame count."""
    import can

    from canfdi.bus.frames import FLAG_ERROR, FLAG_EXTENDED, FLAG_FD, FLAG_REMOTE
    from canfdi.io.reader import iter_frame_blocks

    writer_class = {"blf": can.BLFWriter, "asc": can.ASCWriter,
                    "log": can.CanutilsLogWriter, "csv": can.CSVWriter}[fmt]
    count = 0
    with writer_class(str(out)) as writer:
        for block in iter_frame_blocks(log):
            # The monitor's own frames are transmissions (Tx), every other one was received.
            received = (block.status != "sent").tolist()
            for t, frame_id, dlc, data, flag, rx in zip(
                    block.t_ns.tolist(), block.id.tolist(), block.dlc.tolist(), block.payloads(),
                    block.flags.tolist(), received, strict=True):
                writer.on_message_received(can.Message(
                    timestamp=t / 1e9, arbitration_id=frame_id,
                    is_extended_id=bool(flag & FLAG_EXTENDED),
                    is_remote_frame=bool(flag & FLAG_REMOTE),
                    is_error_frame=bool(flag & FLAG_ERROR), is_fd=bool(flag & FLAG_FD),
                    is_rx=rx, dlc=dlc, data=data, channel=0, check=False))
            count += block.size
            if progress is not None:
                progress(count)
    return count


def run(args: argparse.Namespace) -> int:
    from canfdi.io.segments import log_segments

    try:
        segments = log_segments(args.log)
    except (FileNotFoundError, ValueError) as exc:
        print(f"canfdi export: {args.log}: {exc}", file=sys.stderr)
        return 2
    if not segments:
        print(f"canfdi export: {args.log}: no such log", file=sys.stderr)
        return 2
    out = args.output or args.log.with_suffix(FORMATS[args.format])
    if out.resolve() == args.log.resolve():
        print(f"canfdi export: the output {out} would overwrite the log", file=sys.stderr)
        return 2
    start = time.monotonic()
    last = [start]

    def progress(n: int) -> None:
        now = time.monotonic()
        if not args.no_progress and sys.stderr.isatty() and now - last[0] > 0.5:
            last[0] = now
            print(f"\rcanfdi export: {n:,} frames", end="", file=sys.stderr)

    try:
        count = export_frames(args.log, out, args.format, progress)
    except OSError as exc:
        print(f"canfdi export: cannot write {out}: {exc.strerror or exc}", file=sys.stderr)
        return 1
    except ValueError as exc:  # not an MCAP, or a block of an unknown layout
        print(f"canfdi export: {args.log}: {exc}", file=sys.stderr)
        return 2
    if not args.no_progress and sys.stderr.isatty():
        print("\r", end="", file=sys.stderr)
    print(f"canfdi export: {count:,} frames -> {out} ({time.monotonic() - start:.1f} s)",
          file=sys.stderr)
    return 0

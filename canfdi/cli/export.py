"""`canfdi export LOG --format FMT`: a log's raw frames in another format, for other tools."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from canfdi.tools.export import writable_formats, write_export

HELP_HEAD = """\
Write every raw frame of a log (a canfdi MCAP: all segments, valid or not, the drive's and the
monitor's own "sent" frames; or any log canfdi reads) to a file the usual CAN tools open, through
python-can's writers (or canfdi's own, for mcap):
"""

HELP_TAIL = """
Timestamps are the log's (seconds since the epoch). A frame's E2E status (crc, dlc, ...) has no
place in these formats: `canfdi replay OUT --config FILE` re-derives it. The monitor's own
frames are written as transmissions (Tx) where the format keeps directions; frames of a kind a
format cannot hold (remote, error or CAN FD frames in .trc) are left out and counted. A
truncated MCAP (a killed process) is exported up to its last complete block; a damaged one
around its damage (chunks that fail their CRC are skipped; what was lost is said on stderr, one
line per damaged file). The format is --format, or the suffix of -o. Exit status: 0 written
(also from a damaged log, its loss said), 2 bad log or arguments (one line, no output left), 1
the output could not be written, or the log holds no frame (one line, no output left)."""


def _help() -> str:
    lines = [f"  {f.name:<7} {f.description}" + (f" (needs canfdi[{f.extra}])" if f.extra else "")
             for f in writable_formats()]
    return HELP_HEAD + "\n" + "\n".join(lines) + "\n" + HELP_TAIL


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("export", help="write a log's raw frames as BLF, ASC, candump, CSV...",
                       description=_help(), formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("log", type=Path, help="the log (for a canfdi MCAP, its first segment)")
    p.add_argument("--format", choices=[f.name for f in writable_formats()], metavar="FMT",
                   help="output format: " + ", ".join(f.name for f in writable_formats())
                   + " (default: the suffix of -o)")
    p.add_argument("-o", "--output", type=Path, metavar="OUT",
                   help="output file (default: the log's name with the format's suffix)")
    p.add_argument("--no-progress", action="store_true", help="no progress line on stderr")
    p.add_argument("--json", action="store_true",
                   help="print the outcome as one JSON object on stdout: output, format, frames, "
                        "skipped, seconds, damage")


def run(args: argparse.Namespace) -> int:
    from canfdi.io.damage import Damage
    from canfdi.io.formats import LogFormatError, LogReadError, format_named, format_of
    from canfdi.io.logs import frame_blocks

    try:
        source = format_of(args.log)
        if args.format is None and args.output is None:
            raise LogFormatError("give --format or -o OUT")
        target = format_named(args.format) if args.format else format_of(args.output)
        target.check(write=True)
        source.check()
    except LogFormatError as exc:
        print(f"canfdi export: {exc}", file=sys.stderr)
        return 2
    damage = Damage()
    try:
        blocks = frame_blocks(args.log, received=False, damage=damage)
    except FileNotFoundError:
        print(f"canfdi export: {args.log}: no such log", file=sys.stderr)
        return 2
    stem = args.log.name[: len(args.log.name) - len(source.suffix)]
    out = args.output or args.log.with_name(stem + target.suffix)
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
        written = write_export(out, blocks, target.name, progress)
    except LogReadError as exc:
        print(f"canfdi export: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"canfdi export: cannot write {out}: {exc.strerror or exc}", file=sys.stderr)
        return 1
    except ValueError as exc:  # a block of an unknown layout
        print(f"canfdi export: {args.log}: {exc}", file=sys.stderr)
        return 2
    if not args.no_progress and sys.stderr.isatty():
        print("\r", end="", file=sys.stderr)
    if written.frames == 0:
        lost = "; ".join(damage.lines())
        print(f"canfdi export: {args.log}: no frame to export{f' ({lost})' if lost else ''}",
              file=sys.stderr)
        return 1
    skipped = (f", {written.skipped:,} left out ({target.suffix} cannot hold them)"
               if written.skipped else "")
    seconds = time.monotonic() - start
    print(f"canfdi export: {written.frames:,} frames -> {out}{skipped} ({seconds:.1f} s)",
          file=sys.stderr)
    if args.json:
        print(json.dumps({"output": str(out), "format": target.name, "frames": written.frames,
                          "skipped": written.skipped, "seconds": round(seconds, 3),
                          "damage": damage.as_dict()}))
    for line in damage.lines():
        print(f"canfdi export: {line}", file=sys.stderr)
    return 0


"""`canfdi replay LOG --config FILE`: the same diagnoser, offline, over a recorded log."""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

from canfdi.cli.common import (
    add_kernel_option,
    config_error,
    format_event,
    kernel_or_exit,
    load_config_or_exit,
    print_comparison,
)
from canfdi.tools.replay import (
    CannotWriteDiagnosis,
    NoRecordedConfig,
    recorded_config,
    replay_diagnosis,
)

HELP = """\
Run the monitor offline over a log: an MCAP written by canfdi (run, demo, capture), whose raw
frames are replayed with their timestamps, or any log python-can reads (candump .log, .asc,
.blf, .trc, .csv, .db, .mf4, and gzip-compressed ones such as .asc.gz); the suffix says which.
Replaying a live run's MCAP gives the live run's diagnoses. A truncated MCAP (a killed process)
is read up to its last complete record; a damaged one around its damage: chunks that fail their
CRC are skipped and what was lost (bytes, log time, messages per topic) is said on stderr, one
line per damaged file, and in the JSON's "damage".

Exit status: 0 replayed (also a damaged log, with its loss said); 1 no frame of an intact log
made a sample (the summary says why: "0 samples: no frame matched ...") or the log cannot be
read from the disk; 2 bad config, no such log, a suffix canfdi does not know, a file that is
not a log of its suffix, or a damaged log of which nothing made a sample (one line).

Prints each diagnosis and a summary table, or with --json one object: {"faults": [...],
"frames": {...}, "samples": N, "truth": [...] when the log holds it, "damage": [...] (one
entry per damaged file, [] when none)}.

-o OUT.mcap writes what was diagnosed as a live run writes it (frames, samples, residuals and
their statistics, events, the log lines), whatever the input's format, for `canfdi report` and
Foxglove. Without --config, a canfdi MCAP is replayed with the config recorded in it (said on
stderr); a config whose DBC is a relative path then needs --config."""

def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("replay", help="diagnose a recorded log offline", description=HELP,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("log", type=Path,
                   help="MCAP log, or a python-can log (.asc .blf .log .trc .csv .db .mf4 .gz)")
    p.add_argument("--config", type=Path, metavar="FILE",
                   help="monitor config (default for a canfdi MCAP: the one recorded in it)")
    p.add_argument("-o", "--output", type=Path, metavar="OUT.mcap",
                   help="write the diagnosis as a live run's MCAP (for report and Foxglove)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--no-progress", action="store_true", help="no progress line on stderr")
    add_kernel_option(p)


def run(args: argparse.Namespace) -> int:
    from canfdi.monitor import Monitor

    if not args.log.exists():
        print(f"canfdi replay: no such log: {args.log}", file=sys.stderr)
        return 2
    if args.output is not None and (args.output.exists() or args.output.resolve()
                                    == args.log.resolve()):
        print(f"canfdi replay: -o {args.output}: exists (not overwritten)", file=sys.stderr)
        return 2
    kernel = kernel_or_exit(args, "replay")
    if isinstance(kernel, int):
        return kernel
    with tempfile.TemporaryDirectory(prefix="canfdi-replay-") as scratch:
        config = (load_config_or_exit(args.config, "replay") if args.config is not None
                  else _recorded_config(args.log, Path(scratch)))
        if isinstance(config, int):
            return config
        try:
            monitor = Monitor(config, record_residuals=args.output is not None, kernel=kernel)
        except ValueError as exc:
            return config_error(exc, "replay")
        return _replay(args, monitor)


def _recorded_config(log: Path, scratch: Path):
    """canfdi.tools.replay.recorded_config, said on stderr; 2 after one line when there is
    none."""
    try:
        config = recorded_config(log, scratch)
    except NoRecordedConfig as exc:
        if exc.error is None:
            print(f"canfdi replay: give --config: {log} holds no monitor config (only a canfdi "
                  "MCAP does)", file=sys.stderr)
        else:
            print(f"canfdi replay: the config recorded in {log} does not load here "
                  f"({exc.error}); give --config", file=sys.stderr)
        return 2
    print(f"canfdi replay: using the config recorded in {log} ({config.name}); --config "
          "gives another", file=sys.stderr)
    return config


def _replay(args: argparse.Namespace, monitor) -> int:
    """canfdi.tools.replay.replay_diagnosis into ``monitor``, its events and progress printed as
    the blocks go; the exit status."""
    from canfdi.io.formats import LogFormatError

    progress = not args.no_progress and sys.stderr.isatty()
    start = time.monotonic()
    seen = {"frames": 0, "events": 0}

    def on_block(count: int) -> None:
        seen["frames"] = count
        if len(monitor.events) != seen["events"]:
            if not args.json:
                for event in monitor.events[seen["events"]:]:
                    print(format_event(event, monitor.dt, len(monitor.drives) > 1), flush=True)
            seen["events"] = len(monitor.events)
        if progress:
            rate = monitor.samples / max(time.monotonic() - start, 1e-9)
            print(f"\rcanfdi replay: {count:,} frames, {monitor.samples:,} samples, "
                  f"{rate:,.0f} samples/s", end="", file=sys.stderr)

    try:
        diagnosis = replay_diagnosis(monitor, args.log, args.output, on_block)
    except CannotWriteDiagnosis as exc:
        print(f"canfdi replay: cannot write {args.output}: {exc.error}", file=sys.stderr)
        return 1
    except LogFormatError as exc:
        print(f"canfdi replay: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        lead = "\n" if progress and seen["frames"] else ""  # end the progress line first
        print(f"{lead}canfdi replay: cannot read {args.log}: {exc.strerror or exc}",
              file=sys.stderr)
        return 1
    except ValueError as exc:  # LogReadError (not a log of its suffix), an unknown layout
        lead = "\n" if progress and seen["frames"] else ""
        print(f"{lead}canfdi replay: {exc}", file=sys.stderr)
        return 2
    if progress:
        print(file=sys.stderr)
    return _print_diagnosis(args, diagnosis)


def _print_diagnosis(args: argparse.Namespace, diagnosis) -> int:
    """The diagnosis as a table or JSON, what a damaged log lost on stderr; the exit
    status."""
    damage, truth, result = diagnosis.replayed.damage, diagnosis.replayed.truth, diagnosis.result
    if not diagnosis.diagnosed and damage:
        print(f"canfdi replay: {'; '.join(damage.lines())}; no sample left to replay "
              f"({result['no_samples']})", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        print_comparison(result, truth)
    for line in damage.lines():
        print(f"canfdi replay: {line}", file=sys.stderr)
    if not diagnosis.diagnosed:
        if args.json:  # the table printed it already
            print(f"canfdi replay: {result['no_samples']}", file=sys.stderr)
        return 1
    if args.output is not None and not args.json:
        print(f"log: {args.output}")
    return 0

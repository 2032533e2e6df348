"""`canfdi report LOG [-o DIR]`: PNG figures and an HTML page of a recorded run."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

HELP = """\
Figures of a canfdi MCAP log (canfdi run or demo), in the manner of Chan et al. 2006, Figs.
1-6, and an index.html that shows them with the diagnosis table:

  overview.png          inputs u, outputs z, normalised residuals, Page-Hinkley statistics over
                        their thresholds, with injected onsets, detections and acceptances
  residuals.png         per residual: r/sigma, and the statistic against its threshold h
  fault_<n>_<...>.png   per accepted fault: the residuals around it and each estimate
                        converging, against the truth when the log holds it (demo logs)
  index.html            the figures and the table (fault, onset, detected, accepted,
                        estimates +/- std, truth, error)

Estimate trajectories are recomputed from the log's residuals with the log's embedded config
(--config overrides it). What the log lacks (residuals, config, thresholds) is said on stderr
and in the page; the rest is made anyway. A damaged log is read around its damage (chunks that
fail their CRC are skipped): what was lost is said on stderr (one line per damaged file), in
the page and in the JSON's "damage".
Exit status: 0 report written (also of a damaged log, its loss said), 1 the log holds no
sample, residual or event (nothing to report: one line), or no residuals (a capture, another
tool's log: its samples are drawn, and a line says to run `canfdi replay LOG -o
diagnosed.mcap` first), 2 bad input (no such file, not an MCAP, bad --config: one line)."""


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("report", help="PNG figures and an HTML page of a recorded log",
                       description=HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("log", type=Path, help="MCAP log written by canfdi run or demo")
    p.add_argument("-o", "--output", type=Path, metavar="DIR",
                   help="output directory (default: <log name>_report next to the log)")
    p.add_argument("--config", type=Path, metavar="FILE",
                   help="monitor config (default: the one embedded in the log)")
    p.add_argument("--json", action="store_true",
                   help="print one JSON object: html, figures, faults, missing, damage")
    p.add_argument("--no-progress", action="store_true", help="no progress lines on stderr")


def run(args: argparse.Namespace) -> int:
    from canfdi.tools.report import NothingToReport, ReportError, make_report

    out = args.output or args.log.with_name(args.log.stem + "_report")

    def progress(message: str) -> None:
        if not args.no_progress:
            print(f"canfdi report: {message}", file=sys.stderr, flush=True)

    try:
        report = make_report(args.log, out, args.config, progress)
    except NothingToReport as exc:
        print(f"canfdi report: {exc}", file=sys.stderr)
        return 1
    except ReportError as exc:
        print(f"canfdi report: {exc}", file=sys.stderr)
        return 2
    for note in report.notes:
        print(f"canfdi report: missing: {note}", file=sys.stderr)
    for line in report.damage.lines() if report.damage is not None else []:
        print(f"canfdi report: {line}", file=sys.stderr)
    # A log without residuals (a capture, another tool's log) gets its samples drawn, but it
    # is not a report of a diagnosis: 1, with the note above saying how to get one.
    status = 0 if report.residuals else 1
    if args.json:
        print(json.dumps(report.as_dict(), indent=2))
        return status
    for path in report.figures:
        print(path)
    print(report.html)
    return status

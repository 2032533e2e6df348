"""`canfdi fleet LOGS...|DIR -o OUT.parquet`: many logs diagnosed in parallel on Dask.

The work is in canfdi.tools.fleet (inputs, one log, tables, the engine) and the HTML report in
canfdi.tools.fleetreport; this module parses arguments, shows progress and prints the summary.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

from canfdi.cli.common import add_kernel_option, config_error, kernel_or_exit

HELP = """\
Diagnose many logs at once: every log (any format canfdi replay reads: canfdi's MCAP, candump
.log, .asc, .blf, .trc, .csv, .db, .mf4, gzip-compressed ones) of the files and directories
given (directories are searched recursively for files of those suffixes), each through a
fresh monitor of its config exactly as `canfdi replay` does, in parallel on Dask: a local
cluster of --jobs worker processes (default: one per CPU), or the workers of a running Dask
scheduler (--scheduler ADDRESS; its workers must see the logs and configs at the same
absolute paths, e.g. on a shared file system, and have canfdi installed; start them without
the malloc trim threshold Dask sets by default, which halves the monitor's speed: `dask
worker --no-nanny`, or distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_: null in
their Dask config; the local cluster does so itself).

Configs: --config FILE for every log, or --config-map FILE.yaml, a mapping of glob patterns
of log paths to config files (relative to the mapping file), the first pattern that matches
a log's path (as given, or absolute; * matches across /) wins:
    "*/trucks/*": truck.yaml
    "*": car.yaml
Drive of a log: the group "drive" of --drive-pattern REGEX searched in its path, e.g.
--drive-pattern '(?P<drive>truck[0-9]+)'; else the directory it is in, for a log found under
a DIR argument in a subdirectory (DIR/<drive>/<day>.mcap); else its file name up to the first
'_' (truck7_2025-03-01.blf is truck7).

Writes, with pyarrow:
  OUT.parquet         the faults: one row per accepted fault and estimated parameter:
                      drive, log, log_start, onset (timestamps, ns, UTC), onset_s (s since
                      the log's start), k (onset sample), bus_drive (the config's drive on a
                      bus of several, else null), kind (actuator / sensor), channel,
                      parameter (eta / lambda / bias), estimate, variance, candidates (the
                      channels that explain the data as well), method
  OUT.logs.parquet    one row per log: drive, log, log_start, log_end, samples, frames,
                      frames_<status> per frame status, lost_bytes, lost_messages,
                      lost_seconds (what damage lost), damage (it in words: every kind of
                      loss, null when none), residual_names, residual_variances
                      (each residual's variance over the log), alarms (detections), faults,
                      error (null when fine: an unreadable log, or one of which no frame made
                      a sample, is a row with its error, not a failed run), seconds
  OUT-report/         the HTML fleet report: index.html (drives ranked by what needs
                      attention, the fleet's fault timeline) and a page per drive (its
                      timeline, its estimates over time with a trend line, its logs)
A progress bar on stderr (when it is a terminal; not with --no-progress), then a summary.

Exit status: 0 every log diagnosed (a log with an error is a row, said in the summary); 2 bad
arguments, a bad config or mapping, a pattern that names no drive, no log found, no scheduler
at --scheduler, or the Dask/pyarrow extra not installed (pip install 'canfdi[fleet]')."""


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("fleet", help="diagnose many logs on Dask into Parquet and a report",
                       description=HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("logs", nargs="+", type=Path, metavar="LOG|DIR",
                   help="logs, and directories to search for logs")
    which = p.add_mutually_exclusive_group(required=True)
    which.add_argument("--config", type=Path, metavar="FILE", help="monitor config of every log")
    which.add_argument("--config-map", type=Path, metavar="FILE.yaml",
                       help="glob patterns of log paths to config files, first match wins")
    p.add_argument("--drive-pattern", metavar="REGEX",
                   help="regular expression with a group (?P<drive>...) naming a log's drive "
                        "in its path")
    add_kernel_option(p)
    p.add_argument("-o", "--output", required=True, type=Path, metavar="OUT.parquet",
                   help="faults table; OUT.logs.parquet (per log) and OUT-report/ (HTML) "
                        "beside it")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--jobs", type=int, metavar="N",
                       help="local cluster of N worker processes (default: one per CPU)")
    where.add_argument("--scheduler", metavar="ADDRESS",
                       help="a running Dask scheduler (tcp://host:8786) to run on instead")
    p.add_argument("--no-report", action="store_true", help="write the tables only")
    p.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    p.add_argument("--json", action="store_true",
                   help="print the summary as one JSON object on stdout (the summary's numbers, "
                        "the errors and the files written) instead of the table")


def _fail(message: str) -> int:
    print(f"canfdi fleet: {message}", file=sys.stderr)
    return 2


def run(args: argparse.Namespace) -> int:
    from canfdi.tools.fleet import (
        ConfigMap,
        FleetError,
        check_configs,
        find_logs,
        need_fleet_extra,
        parse_drive_pattern,
        plan_tasks,
    )

    missing = need_fleet_extra()
    if missing:
        return _fail(missing)
    if args.jobs is not None and args.jobs < 1:
        return _fail("--jobs: at least 1 worker")
    if not args.output.name.endswith(".parquet"):
        return _fail(f"-o {args.output}: a file name ending in .parquet")
    kernel = kernel_or_exit(args, "fleet")
    if isinstance(kernel, int):
        return kernel
    try:
        pattern = parse_drive_pattern(args.drive_pattern) if args.drive_pattern else None
        mapping = ConfigMap.load(args.config_map) if args.config_map is not None else None
        tasks = plan_tasks(find_logs(args.logs), config=args.config, config_map=mapping,
                           pattern=pattern, kernel=kernel.name)
    except FleetError as exc:
        return _fail(str(exc))
    try:
        check_configs(sorted({t.config for t in tasks}))
    except ValueError as exc:
        return config_error(exc, "fleet")
    return _run(args, tasks)


def _run(args: argparse.Namespace, tasks: list) -> int:
    from canfdi.tools.fleet import (
        FleetError,
        dask_client,
        fleet_summary,
        fleet_tables,
        report_dir,
        run_fleet,
        workers_of,
        write_tables,
    )

    start = time.monotonic()
    show = not args.no_progress and sys.stderr.isatty()
    try:
        with dask_client(args.jobs or os.cpu_count() or 1, args.scheduler) as client:
            workers = workers_of(client)
            with _Progress(len(tasks), show, workers) as bar:
                results = run_fleet(tasks, client, bar.advance)
    except FleetError as exc:
        return _fail(str(exc))
    wall = time.monotonic() - start
    faults, logs = fleet_tables(results)
    try:
        written = write_tables(faults, logs, args.output)
    except OSError as exc:
        return _fail(f"cannot write {args.output}: {exc.strerror or exc}")
    if not args.no_report:
        try:
            from canfdi.tools.fleetreport import write_fleet_report

            written += write_fleet_report(faults, logs, report_dir(args.output))[:1]
        except OSError as exc:
            return _fail(f"cannot write the report: {exc.strerror or exc}")
    summary = fleet_summary([r.log for r in results], wall, workers)
    if args.json:
        print(json.dumps({**summary, "errors_by_log": {r.log["log"]: r.log["error"]
                                                       for r in results
                                                       if r.log["error"] is not None},
                          "written": [str(p) for p in written]}))
    else:
        _print_summary(summary, results, written)
    return 0


class _Progress:
    """A rich progress bar on stderr over the logs (nothing when ``show`` is False)."""

    def __init__(self, total: int, show: bool, workers: int) -> None:
        self.total, self.show, self.workers = total, show, workers
        self.samples = 0

    def __enter__(self) -> _Progress:
        if self.show:
            from rich.console import Console
            from rich.progress import (
                BarColumn,
                MofNCompleteColumn,
                Progress,
                TextColumn,
                TimeElapsedColumn,
                TimeRemainingColumn,
            )

            self.bar = Progress(TextColumn("canfdi fleet"), BarColumn(), MofNCompleteColumn(),
                                TextColumn("logs {task.fields[rate]}"), TimeElapsedColumn(),
                                TimeRemainingColumn(), console=Console(stderr=True),
                                transient=True)
            self.bar.start()
            self.task = self.bar.add_task("logs", total=self.total, rate="")
            self.started = time.monotonic()
        return self

    def advance(self, result) -> None:
        self.samples += result.log["samples"]
        if self.show:
            rate = self.samples / max(time.monotonic() - self.started, 1e-9)
            self.bar.update(self.task, advance=1,
                            rate=f"{rate:,.0f} samples/s on {self.workers} workers")

    def __exit__(self, *exc) -> None:
        if self.show:
            self.bar.stop()


_ERRORS_SHOWN = 10
"""Errors listed in the summary; the logs table has every one."""


def _print_summary(s: dict, results: list, written: list[Path]) -> None:
    lost = (f"{s['damaged_logs']} damaged log{'s' if s['damaged_logs'] != 1 else ''}: "
            f"{s['lost_bytes']:,} bytes, {s['lost_messages']:,} messages, "
            f"{s['lost_seconds']:.1f} s lost" if s["damaged_logs"] else "none")
    print(f"logs      {s['logs']} of {s['drives']} drive{'s' if s['drives'] != 1 else ''}, "
          f"{s['errors']} with an error")
    print(f"faults    {s['faults']} accepted")
    print(f"lost data {lost}")
    print(f"samples   {s['samples']:,} in {s['wall_s']:.1f} s wall on {s['workers']} "
          f"worker{'s' if s['workers'] != 1 else ''} = {s['samples_per_s']:,.0f} samples/s "
          f"({s['samples_per_core_s']:,.0f} per core-second of diagnosis)")
    errors = [r.log for r in results if r.log["error"] is not None]
    for log in errors[:_ERRORS_SHOWN]:
        print(f"error     {log['log']}: {log['error']}")
    if len(errors) > _ERRORS_SHOWN:
        print(f"error     ... and {len(errors) - _ERRORS_SHOWN} more (the logs table's error "
              "column)")
    for path in written:
        print(f"wrote     {path}")

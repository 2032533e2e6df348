"""`canfdi calibrate LOG... --config FILE -o OUT.yaml`: the drive's noise from healthy logs."""

from __future__ import annotations

import argparse
import datetime
import json
import sys
from pathlib import Path

from canfdi.cli.common import load_config_or_exit

HELP = """\
Learn the drive's measurement noise from healthy logs and write the config with it, so that the
thresholds fit the drive rather than the noise the config guessed.

The logs (canfdi MCAP, or any log python-can reads: .asc .blf .log .trc .csv .mf4 .db, also
gzipped) are decoded and assembled with the config's bus. The sensor noise is estimated
through the model's parity space: residuals that neither the state nor the unknown inputs
reach, whose autocovariances are linear in the noise covariance (canfdi/core/noise.py). A
sensor the data see only together with others (i_a and i_f + i_a of the DC motor: only their
difference reaches a residual) gets the combination split in the config's proportions, and is
reported so. The config's method is then built with the estimated noise and run over the same
data; per residual the report gives its variance and long-run variance (1 when the calibrated
noise explains it), its mean, its correlation with each input (a model whose B is off leaves
the input in the residual), the threshold the data themselves give for the configured
false-alarm interval, and what looks wrong.

A log in which the calibrated monitor detects anything is refused (exit 1), naming the log,
the sample and the residual: calibrate on fault-free data. Writes the input config with
noise.measurement replaced and its provenance (logs, samples, date) in comments, to -o or
stdout. A damaged MCAP is read around its damage (chunks that fail their CRC are skipped, their
samples missing as lost samples are): what was lost is said on stderr (one line per damaged
file) and in the JSON's "damage". Progress goes to stderr unless --json (in a terminal, always).
Exit status: 0 done (also from damaged logs, their loss said), 1 a log is not healthy, 2 bad
input (config, unreadable log, too few samples: one line)."""


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("calibrate", help="learn the drive's noise from healthy logs",
                       description=HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("logs", type=Path, nargs="+", metavar="LOG", help="healthy logs of the drive")
    p.add_argument("--config", required=True, type=Path, metavar="FILE",
                   help="monitor config (model, signals, bus)")
    p.add_argument("-o", "--output", type=Path, metavar="OUT.yaml",
                   help="write the calibrated config here (default: print it)")
    p.add_argument("--window", type=int, metavar="S",
                   help="parity window order for the noise estimate (default: the config's "
                        "design.max_window, at most 10)")
    p.add_argument("--full-covariance", action="store_true",
                   help="estimate the sensors' noise covariances too (reported; the config "
                        "takes standard deviations)")
    p.add_argument("--json", action="store_true", help="print the report as JSON")


def run(args: argparse.Namespace) -> int:
    from canfdi.io.damage import Damage
    from canfdi.tools.calibrate import LogFault, calibrate, config_document
    from canfdi.tools.configdoc import ConfigDocument

    config = load_config_or_exit(args.config, "calibrate")
    if isinstance(config, int):
        return config
    for log in args.logs:
        if not log.exists():
            print(f"canfdi calibrate: no such log: {log}", file=sys.stderr)
            return 2
    if args.window is not None and not 1 <= args.window <= 50:
        print("canfdi calibrate: --window: expected an integer in [1, 50]", file=sys.stderr)
        return 2

    def progress(msg: str) -> None:
        if sys.stderr.isatty() or not args.json:
            print(f"canfdi calibrate: {msg}", file=sys.stderr, flush=True)

    try:
        # the config as written (comments, literals), which the calibrated one is an edit of
        document = ConfigDocument.load(args.config)
    except ValueError as exc:
        print(f"canfdi calibrate: {exc}", file=sys.stderr)
        return 2
    damage = Damage()

    def lost() -> str:  # what damaged logs lost, for a one-line error
        return f" ({'; '.join(damage.lines())})" if damage else ""

    try:
        result = calibrate(args.logs, config, document.plain(), window=args.window,
                           full=args.full_covariance, progress=progress, damage=damage)
    except LogFault as exc:
        print(f"canfdi calibrate: {exc}{lost()}", file=sys.stderr)
        return 1
    except (OSError, ValueError) as exc:
        print(f"canfdi calibrate: {exc}{lost()}", file=sys.stderr)
        return 2
    for line in damage.lines():
        print(f"canfdi calibrate: {line}", file=sys.stderr)
    when = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC")
    out = args.output or Path("calibrated.yaml")
    text = config_document(result, document, args.config, out, when).dump()
    report = result.report()
    report["damage"] = damage.as_dict()
    if args.json:
        print(json.dumps(report, indent=2))
    else:
        _print_report(report)
    if args.output:
        args.output.parent.mkdir(parents=True, exist_ok=True)
        args.output.write_text(text)  # the text printed otherwise, so both say the same
        print(f"wrote {args.output}", file=sys.stderr if args.json else sys.stdout)
    elif not args.json:
        print(text)
    return 0


def _print_report(report: dict) -> None:
    print(f"{report['samples']} samples from {len(report['logs'])} log(s); noise through "
          f"windows of {report['window'] + 1} samples")
    for n in report["noise"]:
        ratio = n["std"] / n["config_std"] if n["config_std"] else float("nan")
        print(f"  {n['sensor']:<14} std {n['std']:.4g} +/- {n['std_error']:.2g}   (config "
              f"{n['config_std']:.4g}, x{ratio:.2f}; {n['identified']})")
    print("residuals with the calibrated noise:")
    for r in report["residuals"]:
        print(f"  {r['name']:<14} variance {r['variance']:.2f}  long-run {r['long_run']:.2f}  "
              f"mean {r['mean']:+.3f}  threshold {r['threshold']:.1f} (data: "
              f"{r['data_threshold']:.1f})")
        for finding in r["findings"]:
            print(f"    {r['name']}: {finding}")

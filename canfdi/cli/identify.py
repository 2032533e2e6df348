"""`canfdi identify LOG... --config FILE -o OUT.yaml`: the drive's model, its unknown inputs and
its noise, learned from healthy logs."""

from __future__ import annotations

import argparse
import datetime
import json
import sys
from pathlib import Path

HELP = """\
Learn the drive's model from healthy logs and write the config with it, ready to monitor.

The config names the signals, the DBC and the sample clock as for `canfdi run`; its model:
section may leave the matrices out and say how to learn them instead (a config with matrices
and no identify: is learned again with as many unknown inputs as its F has):

  model:
    identify:
      unknown_inputs: 1      # unmeasured inputs acting on the drive (a load, friction, ...)
      order: 4               # optional: states (default: from the data)
      delay: 1               # optional: samples from a command to its first effect
      template: servo_axis   # optional: a grey-box template (dc_motor, servo_axis) with
                             # datasheet parameters as the start, any of them fixable

The logs (canfdi MCAP, or any log python-can reads: .log candump, .asc, .blf, .trc, .csv, ...)
are decoded and assembled with the config's bus, one sample per period (dt: model.dt, the
clock's period, or the DBC's cycle time). Record them while the drive is commanded steps of
several sizes and a chirp (or a PRBS), over its whole working range, with no fault.

What is learned, by the config's method:
  parity, uio   a state-space model (A, B, C, F): black-box (the state the outputs show, the
                unknown inputs' directions F from what the noise does not explain; or a
                PBSID subspace fit, consistent in closed loop, when the outputs show less
                than the data hold), or the template's parameters fitted by prediction error;
  output_error  the output-error paper's OE models (--orders, --oe-delay, --min-gain-snr, --skip).
The last 30 % of each log (--holdout) or the --validate logs are left out of the fit and
judge it: one-step and simulation fits per output (NRMSE %, as MATLAB's compare), the
one-step errors' whiteness and correlation with the inputs, stability, minimality; then the
noise is learned as `canfdi calibrate` does, over all the data (a channel without noise of
its own, an echo or a quantised counter, gets its resolution as a floor), and the design
(what `canfdi design` prints) is summarised.

Writes the input config with model:, signals.unknown_inputs and noise.measurement filled in,
its comments, keys and hex literals kept, relative paths rewritten for OUT's folder, and the
provenance (logs, samples, date, order, fits) in comments on top; to -o or stdout.

Exit status: 0 done; 1 the data cannot support a model (too short, not exciting, a fault in
a log, a poor fit on the data left out, an unstable or non-minimal result: one line saying
what to record instead); 2 bad input (config, options, unreadable log: one line)."""


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("identify", help="learn the drive's model from healthy logs",
                       description=HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("logs", type=Path, nargs="+", metavar="LOG",
                   help="healthy logs of the drive: MCAP, or a python-can log")
    p.add_argument("--config", required=True, type=Path, metavar="FILE",
                   help="monitor config naming the signals, the DBC and model.identify")
    p.add_argument("-o", "--output", type=Path, metavar="OUT.yaml",
                   help="write the identified config here (default: print it)")
    p.add_argument("--validate", type=Path, action="append", default=[], metavar="LOG",
                   help="validate on this log instead of the last part of each (repeatable)")
    p.add_argument("--holdout", type=float, default=0.3, metavar="F",
                   help="part of each log (its end) left out of the fit (default: 0.3)")
    p.add_argument("--force", action="store_true",
                   help="identify even when a log's metadata says faults were injected")
    p.add_argument("--json", action="store_true", help="print the report as JSON")
    oe = p.add_argument_group("output_error method")
    oe.add_argument("--orders", action="append", default=[], metavar="OUT:IN=NB,NF,D",
                    help="fix one pair's orders (or OUT:IN=none: no path); repeatable")
    oe.add_argument("--oe-delay", type=int, default=1, metavar="D",
                    help="delay of the pairs not fixed by --orders (default: 1)")
    oe.add_argument("--min-gain-snr", type=float, default=5.0, metavar="X",
                    help="drop a pair whose |static gain| < X times its std (default: 5)")
    oe.add_argument("--skip", type=int, default=200, metavar="N",
                    help="samples left out of the fit at the start (default: 200)")


def _fail(message: str, status: int = 2) -> int:
    print(f"canfdi identify: {message}", file=sys.stderr)
    return status


def _parse_orders(specs: list[str], inputs: list[str], outputs: list[str]) -> dict:
    """{(j, i): (nb, nf, d) or None}; ValueError naming the bad spec."""
    fixed = {}
    for spec in specs:
        try:
            pair, value = spec.split("=", 1)
            out, inp = pair.split(":", 1)
        except ValueError:
            raise ValueError(f"--orders {spec!r}: expected OUTPUT:INPUT=NB,NF,D or =none"
                             ) from None
        if out not in outputs or inp not in inputs:
            raise ValueError(f"--orders {spec!r}: outputs are {', '.join(outputs)}, inputs "
                             f"{', '.join(inputs)}")
        if value.strip().lower() == "none":
            fixed[(outputs.index(out), inputs.index(inp))] = None
            continue
        try:
            nb, nf, d = (int(x) for x in value.split(","))
        except ValueError:
            raise ValueError(f"--orders {spec!r}: expected three integers NB,NF,D") from None
        if nb < 1 or nf < 0 or d < 0 or nb > 10 or nf > 10 or d > 100:
            raise ValueError(f"--orders {spec!r}: need 1 <= NB <= 10, 0 <= NF <= 10, "
                             f"0 <= D <= 100")
        fixed[(outputs.index(out), inputs.index(inp))] = (nb, nf, d)
    return fixed


def _check_args(args: argparse.Namespace) -> str | None:
    """A missing log or an option out of its range, as the error line, or None."""
    for log in [*args.logs, *args.validate]:
        if not log.exists():
            return f"no such log: {log}"
    if not 0.05 <= args.holdout <= 0.7:
        return "--holdout: expected a fraction in [0.05, 0.7]"
    if args.oe_delay < 0 or args.skip < 0 or args.min_gain_snr < 0:
        return "--oe-delay, --skip and --min-gain-snr: must be >= 0"
    return None


def _faulty_log(args: argparse.Namespace) -> str | None:
    """The error line for the first log that holds injected faults, or None."""
    from canfdi.tools.identify import first_faulty_log

    faulty = first_faulty_log([*args.logs, *args.validate])
    if faulty is None:
        return None
    log, truth = faulty
    onsets = ", ".join(f"{f.get('target', '?')} {f.get('name', f.get('index'))} at "
                       f"{f.get('onset', '?')} s" for f in truth)
    return (f"{log} holds injected faults ({onsets}): a model is learned from a healthy "
            "drive; record a fault-free log (or --force)")


def run(args: argparse.Namespace) -> int:
    from canfdi.config import ConfigError, load_config
    from canfdi.io.damage import Damage
    from canfdi.methods.output_error.fit import FitOptions
    from canfdi.tools.configdoc import ConfigDocument
    from canfdi.tools.identify import Refusal, config_document, identify, jsonable

    try:
        config = load_config(args.config, allow_unidentified=True)
    except ConfigError as exc:
        return _fail(f"config error: {exc}")
    problem = _check_args(args)
    if problem:
        return _fail(problem)
    try:
        fixed = _parse_orders(args.orders, config.inputs, config.outputs)
    except ValueError as exc:
        return _fail(str(exc))
    faulty = None if args.force else _faulty_log(args)
    if faulty:
        return _fail(faulty, 1)

    def progress(msg: str) -> None:
        if sys.stderr.isatty() or not args.json:
            print(f"canfdi identify: {msg}", file=sys.stderr, flush=True)

    try:
        # the config as written (comments, literals), which the identified one is an edit of
        document = ConfigDocument.load(args.config)
    except ValueError as exc:
        return _fail(str(exc))
    damage = Damage()
    oe = FitOptions(fixed=fixed, delay=args.oe_delay, min_gain_snr=args.min_gain_snr,
                    skip=args.skip)
    try:
        result = identify(args.logs, config, document.plain(), validate=args.validate,
                          holdout=args.holdout, fit_options=oe, progress=progress, damage=damage)
    except Refusal as exc:
        return _fail(str(exc), 1)
    except ConfigError as exc:
        return _fail(f"config error: {exc}")
    except (OSError, ValueError) as exc:
        lost = f" ({'; '.join(damage.lines())})" if damage else ""
        return _fail(f"{exc}{lost}")
    for line in damage.lines():
        print(f"canfdi identify: {line}", file=sys.stderr)
    when = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC")
    text = config_document(result, document, args.config, args.logs, args.output, when).dump()
    report = dict(result.report)
    report["damage"] = damage.as_dict()
    if args.json:
        print(json.dumps(report, indent=2, default=jsonable))
    else:
        _print_report(report)
    if args.output:
        args.output.parent.mkdir(parents=True, exist_ok=True)
        args.output.write_text(text)
        print(f"wrote {args.output}", file=sys.stderr if args.json else sys.stdout)
    elif not args.json:
        print(text)
    return 0


def _print_report(report: dict) -> None:
    if report["path"].startswith("output error"):
        print(f"{report['samples']['fit']} samples; output-error models (the output-error paper)")
        for rep in report["outputs"]:
            print(f"  {rep['output']}: residual std {rep['residual_std']:.4g}, long-run "
                  f"variance ratio {rep['long_run_variance']:.3g}")
            for p in rep["pairs"]:
                print(f"    <- {p['input']:<10} gain {p['static_gain']:+.4g} +/- "
                      f"{p['gain_std']:.2g}  B {[round(b, 5) for b in p['b']]}  "
                      f"F {[round(f, 5) for f in p['f']]}  delay {p['delay']}")
        return
    s = report["samples"]
    print(f"model: {report['path']}, {report['order']} states ({', '.join(report['states'])}), "
          f"{report['unknown_inputs']['count']} unknown input(s) "
          f"{report['unknown_inputs']['names'] or ''}, dt {report['dt']:g} s")
    print(f"data: {s['fit']} samples fitted, {s['validation']} left out for validation")
    ev = report["order_evidence"]
    if ev.get("output_eigenvalues"):
        print(f"order: the outputs show {ev['visible_order']} states (whitened output "
              "variances " + ", ".join(f"{v:.3g}" for v in ev["output_eigenvalues"]) + ")"
              + (f"; the subspace fit's canonical correlations say {ev['subspace_order']}"
                 if "subspace_order" in ev else ""))
    d = report.get("details", {})
    if d.get("rows_reached"):
        print("unknown inputs reach: " + ", ".join(d["rows_reached"]) + " (one-step error over "
              "noise per row: " + ", ".join(f"{k} {v:.2f}" for k, v in d["row_excess"].items())
              + ")")
    if d.get("pruned"):
        print("set to zero (not significant): " + ", ".join(d["pruned"]))
    if d.get("constant_state"):
        print("a constant state holds the operating point's offset")
    if "template" in report:
        print(f"template {report['template']['name']}:")
        for row in report["template"]["parameters"]:
            print("  " + row["text"])
    for note in report.get("notes", []):
        print(f"note: {note}")
    print("validation on the data left out of the fit:")
    print(f"  {'output':<18} {'one-step':>9} {'simulation':>11}  whiteness (lags outside 99 %)"
          "  input correlation")
    for o in report["validation"]["outputs"]:
        w = o["whiteness"]
        corr = ", ".join(f"{k} {c['max']:.2f}" for k, c in o["input_correlation"].items())
        print(f"  {o['output']:<18} {_pct(o['one_step_fit']):>9} {_pct(o['simulation_fit']):>11}"
              f"  {w['outside']}/{w['lags']} (max {w['max']:.2f})"
              f"{'':<6}{corr} (band {o['band']:.3f})"
              + ("" if o["moves"] else "  [not moved]"))
    print("design (canfdi design):")
    for dsg in report["design"]:
        same = (f"; same signature as {', '.join(dsg['same_signature_as'])}"
                if dsg["same_signature_as"] else "")
        verdict = ("NOT detectable" if not dsg["detectable"] else "detectable"
                   if dsg["strongly_detectable"] else "transient only")
        print(f"  {dsg['kind']:<8} {dsg['name']:<18} {verdict:<15} "
              f"window {dsg['window']}, best fault/noise {dsg['fault_to_noise']:.3g}{same}")
    print("noise (as canfdi calibrate):")
    for n in report["calibration"]["noise"]:
        print(f"  {n['sensor']:<18} std {n['std']:.4g} +/- {n['std_error']:.2g} "
              f"{n['identified']}")


def _pct(x) -> str:
    return "-" if x is None else f"{x:.1f} %"

"""`canfdi identify LOG --config FILE`: fit the output_error method's OE models (seed 003) from a
fault-free log and write a config that uses them."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from canfdi.cli.common import load_config_or_exit

HELP = """\
Identify the parallel output-error models of seed 003 from a fault-free log: for every output,
y = y0 + sum_i B_i(q)/F_i(q) q^-d (u_c,i - u0), fitted by the OE prediction-error method
(Steiglitz-McBride start, then Levenberg-Marquardt on the simulation error;
canfdi.methods.output_error.model). The log is an MCAP written by `canfdi demo -o`, `run` or
`capture`, or a python-can log (.log .asc .blf .trc .csv); its frames are decoded and assembled
with the config's DBC and signals.

Orders: by default every (output, input) pair starts as B, F of first order with delay
--delay; pairs whose static gain is not significant (|K| < --min-gain-snr std(K)) are dropped
(no path), then each remaining pair is raised to second order when the Bayesian information
criterion improves. --orders OUTPUT:INPUT=NB,NF,D (or =none) fixes a pair; repeat it.

Prints the fit per output (residual std against the config's noise, static gains with their
standard deviations, and the gains of the config's state-space model when it has one) and
writes the config (the input config with method: output_error and the output_error section
filled in) to -o, or prints it. A damaged MCAP is read around its damage (chunks that fail their
CRC are skipped, their samples missing as lost samples are): what was lost is said on stderr
(one line per damaged file) and in the JSON's "damage". Exit status: 0 done (also from a
damaged log, its loss said), 2 bad input (config, log, orders, too few samples: one line)."""


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("identify", help="fit the output_error method's models from a log",
                       description=HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("log", type=Path, help="fault-free log: MCAP, or a python-can log")
    p.add_argument("--config", required=True, type=Path, metavar="FILE",
                   help="monitor config naming the signals and the DBC")
    p.add_argument("--orders", action="append", default=[], metavar="OUT:IN=NB,NF,D",
                   help="fix one pair's orders (or OUT:IN=none: no path); repeatable")
    p.add_argument("--delay", type=int, default=1, metavar="D",
                   help="delay of the pairs not fixed by --orders (default: 1)")
    p.add_argument("--min-gain-snr", type=float, default=5.0, metavar="X",
                   help="drop a pair whose |static gain| < X times its std (default: 5)")
    p.add_argument("--skip", type=int, default=200, metavar="N",
                   help="samples left out of the fit at the start (default: 200)")
    p.add_argument("--force", action="store_true",
                   help="fit even when the log's metadata says faults were injected")
    p.add_argument("-o", "--output", type=Path, metavar="OUT.yaml",
                   help="write the config here (default: print it)")
    p.add_argument("--json", action="store_true", help="print the fit report as JSON")


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


def run(args: argparse.Namespace) -> int:
    import numpy as np
    import yaml

    from canfdi.config import read_yaml
    from canfdi.io.damage import Damage
    from canfdi.methods.output_error import METHOD as OUTPUT_ERROR
    from canfdi.methods.output_error import output_error_section
    from canfdi.tools.identify import identify, log_samples

    config = load_config_or_exit(args.config, "identify")
    if isinstance(config, int):
        return config
    if not args.log.exists():
        print(f"canfdi identify: no such log: {args.log}", file=sys.stderr)
        return 2
    try:
        fixed = _parse_orders(args.orders, config.inputs, config.outputs)
    except ValueError as exc:
        print(f"canfdi identify: {exc}", file=sys.stderr)
        return 2
    if args.delay < 0 or args.skip < 0 or args.min_gain_snr < 0:
        print("canfdi identify: --delay, --skip and --min-gain-snr must be >= 0",
              file=sys.stderr)
        return 2
    if args.log.suffix.lower() == ".mcap" and not args.force:
        from canfdi.io.logs import truth_of

        truth = truth_of(args.log)
        if truth:
            print(f"canfdi identify: {args.log} holds injected faults ({len(truth)} in its "
                  "metadata); fit a fault-free log, or --force", file=sys.stderr)
            return 2

    def progress(msg: str) -> None:
        if sys.stderr.isatty() or not args.json:
            print(f"canfdi identify: {msg}", file=sys.stderr, flush=True)

    progress(f"reading {args.log}")
    damage = Damage()
    try:
        k, U, Z = log_samples(args.log, config, damage)
    except (OSError, ValueError) as exc:
        print(f"canfdi identify: cannot read {args.log}: {exc}", file=sys.stderr)
        return 2
    if len(k) < args.skip + 500:
        lost = f" ({'; '.join(damage.lines())})" if damage else ""
        print(f"canfdi identify: {len(k)} samples in {args.log}: need at least "
              f"{args.skip + 500} (--skip {args.skip} + 500){lost}", file=sys.stderr)
        return 2
    for line in damage.lines():
        print(f"canfdi identify: {line}", file=sys.stderr)
    result = identify(k, U, Z, config.inputs, config.outputs, fixed, args.delay,
                      args.min_gain_snr, args.skip, progress)
    reference = None
    m = config.model
    if not m.continuous:
        try:  # the config's state-space model, as a reference for the fitted gains
            reference = m.C @ np.linalg.solve(np.eye(m.n) - m.A, m.B) + m.D
        except np.linalg.LinAlgError:
            reference = None
    noise = config.design.measurement_std
    report = {"log": str(args.log), "samples": result["samples"], "outputs": result["fits"],
              "damage": damage.as_dict()}
    if args.json:
        print(json.dumps(report, indent=2))
    else:
        _print_report(result, config, noise, reference)
    fit_note = {"log": args.log.name, "samples": result["samples"],
                "method": "OE prediction error (Steiglitz-McBride start, Levenberg-Marquardt)"}
    # The decision settings are written out (at their defaults) so that the file shows them.
    from dataclasses import asdict

    from canfdi.methods.output_error.diagnoser import OeSettings

    settings = {key: value for key, value in asdict(OeSettings()).items()
                if key not in ("drift", "false_alarm_interval")}
    section = output_error_section(result["model"], result["sigma"], result["long_run"],
                                   config.inputs, config.outputs, fit=fit_note, **settings)
    doc = read_yaml(args.config, ValueError, "config")
    doc["method"] = OUTPUT_ERROR.name
    doc[OUTPUT_ERROR.section] = section
    header = (f"# Written by `canfdi identify {args.log.name} --config {args.config.name}`: the\n"
              "# output_error method (seed 003) with OE models fitted from that fault-free log.\n"
              "# The model: section is the input config's (the output_error method does not "
              "use it).\n")
    text = header + yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=100)
    if args.output:
        args.output.parent.mkdir(parents=True, exist_ok=True)
        args.output.write_text(text)
        if not args.json:
            print(f"wrote {args.output}")
    elif not args.json:
        print(text)
    return 0


def _print_report(result: dict, config, noise, reference) -> None:
    print(f"{result['samples']} samples")
    for j, rep in enumerate(result["fits"]):
        ref_noise = f" (noise {noise[j]:.4g})" if noise is not None else ""
        print(f"{rep['output']}: residual std {rep['residual_std']:.4g}{ref_noise}, long-run "
              f"variance ratio {rep['long_run_variance']:.3g}")
        fitted = {p["input"]: p for p in rep["pairs"]}
        for i, name in enumerate(config.inputs):
            truth = (f"   config model {reference[j, i]:+.4g}" if reference is not None else "")
            p = fitted.get(name)
            if p is None:
                print(f"  <- {name:<8} no path{truth}")
                continue
            print(f"  <- {name:<8} gain {p['static_gain']:+.4g} +/- {p['gain_std']:.2g}{truth}"
                  f"   B {[round(b, 5) for b in p['b']]}  F {[round(f, 5) for f in p['f']]}"
                  f"  delay {p['delay']}")

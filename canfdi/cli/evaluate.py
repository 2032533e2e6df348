"""`canfdi evaluate`: Monte Carlo over generated fault scenarios through the monitor's diagnoser.

Issue 10. The work is in canfdi.tools.evaluate (generation, simulation, matching, metrics),
canfdi.tools.evaluate_monitor (the monitor evaluated), canfdi.tools.evaluate_files (the figure
and the JSON of -o) and canfdi.tools.fleet (the Dask engine); this module parses arguments and
prints. Like soak and demo, it needs the plant emulator.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

from canfdi import methods
from canfdi.cli.common import (
    add_kernel_option,
    config_error,
    kernel_or_exit,
    load_config_or_exit,
)
from canfdi.config import ConfigError
from canfdi.configs import CONFIG_DIR

HELP = """\
Monte Carlo evaluation of the diagnosis: generate --runs fault scenarios for --plant, run each
through the emulated plant and a fresh copy of the diagnoser the config describes (built and
calibrated once; its batch path, update_block), match the events to the injected faults and
report detection rate, detection delay (mean, 95th percentile, in samples) and how far it
is from the fastest possible (the CUSUM bound below), the delay from detection and from onset
to the accepted diagnosis, isolation accuracy with a confusion matrix, false alarms per hour
of fault-free time, missed faults and relative estimate errors, overall, per fault-to-noise
bin, per fault kind and per channel.

Scenarios (seeded: run i draws from SeedSequence(--seed).spawn(runs)[i]): 0..--max-faults
consecutive faults, never repaired, on distinct channels the parity design says are
detectable (undetectable ones are listed, not drawn): actuator bias (lambda), actuator scale
(eta) or sensor bias. Magnitudes are drawn log-uniformly in fault-to-noise ratio (FNR,
--fnr LO HI): the steady change the fault makes in the residual most sensitive to it, in that
residual's noise standard deviations (the "best f/n" of `canfdi design` times the fault's size,
over the run's noise scale; an actuator scale's size is |eta - 1| times the rms of the
fault-free command). The measurement noise of each run is the config's times a factor drawn
log-uniformly in [1/--noise-spread, --noise-spread]. Onsets follow a fault-free lead-in of 300
to 1000 samples and are identification.max_samples + 1000 samples apart (--spacing), so each
fault can be detected and diagnosed before the next; runs with no fault are fault-free time.
Values are rounded to the DBC's signal resolution, as the bus carries them (--no-quantize:
exact).

Matching: a detection in [onset, next onset) belongs to that fault (delay = detection sample -
onset); a detection before the first onset, or after that fault's diagnosis was accepted, is a
false alarm; a fault with no detection in its segment is missed. Isolation is correct when the
accepted channel is the injected one ("exact") or the injected one is among the accepted
event's candidates (twins with the same residual signature, e.g. the DC motor's i_a and
i_f_plus_i_a: "candidate"); isolation accuracy is correct / faults with an accepted diagnosis.
Relative estimate error: |estimate - true| / |true| for eta, for lambda when the true lambda is
nonzero and for a sensor bias; a fault's error is its largest; over correctly isolated faults.
False alarms per hour count over fault-free samples: from the first residual to the first
onset (the whole run without faults) and from each acceptance to the next onset.
CUSUM bound: no detector of a fault's mean change, at the config's false-alarm interval T
(detection.false_alarm_interval), detects it in fewer than ln(T) / (FNR^2 / 2) samples on
average (Lorden; Basseville and Nikiforov ch. 5); "delay / bound" is each detection's delay
over its fault's bound (1 is optimal; the bound counts the most sensitive residual alone).
The bank's bound is the same at the FNR the parity bank sees in the long run (FNR sqrt(I), I
the channel's bank_information: the information the whole bank carries, its residuals'
correlation in time and across the bank counted), at least one sample. Excitation bound: the
first sample at which least squares that knows a fault's form and onset settles, by the parity
method's acceptance test, on the run's recorded commands; "excitation" is onset to acceptance
over onset to that bound (parity only: what the data allowed, against what the diagnoser took).

--method chooses the default config among the shipped ones (canfdi.configs, deploy/config/ in
a checkout): <plant>.yaml (parity), <plant>_oe.yaml (output_error) or <plant>_uio.yaml (uio);
--config gives any. --faults-from TRUE.yaml draws
the faults, their sizes and the drive's noise from TRUE.yaml's design (the drive's true model)
and evaluates the --config monitor on them: an identified model (`canfdi identify`) and the
true one, evaluated with the same --faults-from and --seed, see the same runs. -o DIR writes
<plant>_<method>.png (detection delay and isolation accuracy against FNR) and
<plant>_<method>.json. Progress on stderr; --json prints one object. Exit status 0, or 2 on bad
arguments or config.

--jobs N runs the runs on a local Dask cluster of N worker processes, --scheduler ADDRESS on
the workers of a running Dask scheduler (pip install 'canfdi[fleet]'); the results are those
of the serial run for the same --seed (each run is seeded on its own, the outcomes are put
back in run order)."""

def add_parser(sub: argparse._SubParsersAction) -> None:
    from canfdi.firmware_sim.plants import PLANTS

    p = sub.add_parser("evaluate", help="Monte Carlo evaluation: detection, isolation, delays",
                       description=HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--plant", required=True, metavar="PLANT",
                   help=f"emulated plant: {', '.join(PLANTS)}")
    p.add_argument("--method", choices=methods.names(), default=None,
                   help="diagnosis method; picks the first config for the plant and method in "
                        "deploy/config (default: parity, or the --config's)")
    p.add_argument("--config", type=Path, default=None, metavar="FILE",
                   help="monitor config (default: by --plant and --method)")
    p.add_argument("--faults-from", type=Path, default=None, metavar="FILE",
                   help="draw the faults and the drive's noise from this config's design (the "
                        "true model) and evaluate --config's monitor on them")
    p.add_argument("--runs", type=int, default=100, metavar="N",
                   help="generated runs (default 100)")
    p.add_argument("--seed", type=int, default=1, metavar="S", help="master seed (default 1)")
    p.add_argument("--max-faults", type=int, default=3, metavar="K",
                   help="at most K consecutive faults per run; 0..K uniformly (default 3)")
    p.add_argument("--fnr", type=float, nargs=2, default=(0.5, 50.0), metavar=("LO", "HI"),
                   help="fault-to-noise ratio range, drawn log-uniformly (default 0.5 50)")
    p.add_argument("--noise-spread", type=float, default=1.25, metavar="X",
                   help="noise factor drawn log-uniformly in [1/X, X] (default 1.25; 1: the "
                        "config's noise)")
    p.add_argument("--noise-scale", type=float, default=1.0, metavar="F",
                   help="the drive's measurement noise is F times the config's (default 1); "
                        "fault sizes follow, so each keeps its fault-to-noise ratio")
    p.add_argument("--calibrate", type=float, default=None, metavar="SECONDS",
                   help="first calibrate the monitor on SECONDS of the same drive, healthy (as "
                        "`canfdi calibrate` does on a log), then evaluate that monitor")
    p.add_argument("--kinds", default=None, metavar="LIST",
                   help="fault kinds to draw, comma-separated, among actuator_bias, "
                        "actuator_scale, sensor_bias (default: the method's fault model: all "
                        "three for parity; the additive ones, actuator_bias and sensor_bias, "
                        "for output_error (the output-error paper) and uio (Hwang, Chang and Hsu))")
    p.add_argument("--spacing", type=int, default=None, metavar="SAMPLES",
                   help="samples between onsets (default identification.max_samples + 1000)")
    p.add_argument("--no-quantize", action="store_true",
                   help="feed exact values, not rounded to the DBC's signal resolution")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("-o", "--output", type=Path, default=None, metavar="DIR",
                   help="write <plant>_<method>.png and .json into DIR")
    p.add_argument("--no-progress", action="store_true", help="no progress lines on stderr")
    add_kernel_option(p)
    where = p.add_mutually_exclusive_group()
    where.add_argument("--jobs", type=int, metavar="N",
                       help="run on a local Dask cluster of N worker processes")
    where.add_argument("--scheduler", metavar="ADDRESS",
                       help="run on a running Dask scheduler's workers (tcp://host:8786)")


def _fail(message: str) -> int:
    print(f"canfdi evaluate: {message}", file=sys.stderr)
    return 2


def _config_path(args: argparse.Namespace) -> Path | int:
    from canfdi.tools.evaluate import default_config

    if args.config is not None:
        return args.config
    method = args.method or methods.DEFAULT
    path = default_config(args.plant, method, CONFIG_DIR)
    if path is None:
        return _fail(f"no {method} config for the {args.plant} plant in {CONFIG_DIR} "
                     "(give one with --config)")
    return path


def _check_args(args: argparse.Namespace) -> str | None:
    from canfdi.firmware_sim.plants import PLANTS
    from canfdi.methods import FAULT_KINDS

    if args.plant not in PLANTS:
        return f"--plant: unknown plant {args.plant!r} (known: {', '.join(PLANTS)})"
    if args.runs < 1:
        return "--runs: at least 1"
    if args.seed < 0:
        return "--seed: an integer >= 0"
    if args.max_faults < 0:
        return "--max-faults: an integer >= 0"
    lo, hi = args.fnr
    if not (0 < lo <= hi and math.isfinite(hi)):
        return "--fnr: 0 < LO <= HI"
    if not (args.noise_spread >= 1 and math.isfinite(args.noise_spread)):
        return "--noise-spread: a number >= 1"
    if not (args.noise_scale > 0 and math.isfinite(args.noise_scale)):
        return "--noise-scale: a number > 0"
    if args.calibrate is not None and not (args.calibrate >= 10 and
                                           math.isfinite(args.calibrate)):
        return "--calibrate: at least 10 seconds of healthy drive"
    if args.kinds is not None:
        kinds = [k.strip() for k in args.kinds.split(",") if k.strip()]
        bad = [k for k in kinds if k not in FAULT_KINDS]
        if bad or not kinds:
            return (f"--kinds: {', '.join(bad) or '(empty)'}: not among "
                    f"{', '.join(FAULT_KINDS)}")
        args.kinds = kinds
    if args.spacing is not None and args.spacing < 100:
        return "--spacing: at least 100 samples"
    if args.jobs is not None and args.jobs < 1:
        return "--jobs: at least 1 worker"
    return None


def _monitored(args: argparse.Namespace, path: Path, config, progress):
    """canfdi.tools.evaluate_monitor.evaluated_monitor for --faults-from and --calibrate, or
    the exit status after one error line."""
    from canfdi.tools.evaluate_monitor import SignalsDiffer, evaluated_monitor

    reference = None
    if args.faults_from is not None:
        if args.calibrate is not None:
            return _fail("--faults-from and --calibrate: give one")
        reference = load_config_or_exit(args.faults_from, "evaluate")
        if isinstance(reference, int):
            return reference
    try:
        return evaluated_monitor(config, args.plant, faults_from=reference,
                                 calibrate_seconds=args.calibrate,
                                 noise_scale=args.noise_scale, seed=args.seed,
                                 progress=progress)
    except SignalsDiffer:
        return _fail(f"--faults-from {args.faults_from}: its signals differ from {path}'s")
    except ValueError as exc:
        return _fail(f"--calibrate: {exc}")


def _evaluate(args: argparse.Namespace, chosen, progress, kernel) -> dict[str, Any] | int:
    """canfdi.tools.evaluate.evaluate of the chosen monitor, on the engine --jobs or
    --scheduler ask for; the result, or the exit status after one error line."""
    from canfdi.tools.evaluate import evaluate
    from canfdi.tools.fleet import FleetError, NoDask, task_mapper

    try:
        with task_mapper(args.jobs, args.scheduler) as mapper:
            return evaluate(chosen.drawn, args.plant, runs=args.runs, seed=args.seed,
                            max_faults=args.max_faults, fnr=tuple(args.fnr),
                            noise_spread=args.noise_spread, kinds=args.kinds,
                            spacing=args.spacing, quantize=not args.no_quantize,
                            noise_scale=args.noise_scale, monitor=chosen.monitor,
                            progress=progress, mapper=mapper, kernel=kernel)
    except NoDask as exc:
        return _fail(f"--jobs/--scheduler {exc}")
    except FleetError as exc:  # no scheduler there
        return _fail(str(exc))
    except (ConfigError, ValueError) as exc:
        return config_error(exc, "evaluate")


def _plant_mismatch(name: str, config) -> ConfigError | None:
    """The error of a config whose signals are not the --plant's, or None."""
    from canfdi.firmware_sim.plants import make_plant

    plant = make_plant(name)
    if (tuple(config.inputs), tuple(config.outputs)) == (plant.input_names, plant.output_names):
        return None
    return ConfigError(
        "signals", f"the {name} plant has inputs {list(plant.input_names)}, outputs "
                   f"{list(plant.output_names)}; this config has inputs {config.inputs}, "
                   f"outputs {config.outputs}")


def run(args: argparse.Namespace) -> int:
    problem = _check_args(args)
    if problem:
        return _fail(problem)
    path = _config_path(args)
    if isinstance(path, int):
        return path
    config = load_config_or_exit(path, "evaluate")
    if isinstance(config, int):
        return config
    if args.method is not None and config.method != args.method:
        return _fail(f"--method {args.method}, but {path} is a {config.method} config")
    mismatch = _plant_mismatch(args.plant, config)
    if mismatch is not None:
        return config_error(mismatch, "evaluate")
    start = time.monotonic()

    def progress(msg: str) -> None:
        if not args.no_progress:
            print(f"canfdi evaluate [{time.monotonic() - start:6.1f} s] {msg}", file=sys.stderr,
                  flush=True)

    kernel = kernel_or_exit(args, "evaluate")
    if isinstance(kernel, int):
        return kernel
    chosen = _monitored(args, path, config, progress)
    if isinstance(chosen, int):
        return chosen
    result = _evaluate(args, chosen, progress, kernel)
    if isinstance(result, int):
        return result
    config, calibration = chosen.drawn, chosen.calibration
    result["config"] = str(path)
    if args.faults_from is not None:
        result["faults_from"] = str(args.faults_from)
    if calibration is not None:
        result["calibration"] = {"seconds": args.calibrate, "samples": calibration.samples,
                                 "measurement_std": calibration.noise.std.tolist()}
    result["wall_s"] = time.monotonic() - start
    if args.output is not None:
        from canfdi.tools.evaluate_files import write_evaluation

        stem = args.output / f"{args.plant}_{config.method}"
        write_evaluation(stem, result)
        progress(f"wrote {stem}.png and {stem}.json")
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        print_report(result)
    return 0


# -- output --------------------------------------------------------------------------------------

def _f(x: float | None, fmt: str = ".3g") -> str:
    return "-" if x is None else format(x, fmt)


def _pct(x: float | None) -> str:
    return "-" if x is None else f"{100 * x:.1f}%"


def print_report(r: dict[str, Any]) -> None:
    s = r["settings"]
    print(f"evaluation of {r['config']} ({r['method']}) on the emulated {r['plant']}: "
          f"{r['runs']} runs, seed {r['seed']}, {r['wall_s']:.1f} s")
    print(f"  faults drawn: 0..{s['max_faults']} per run, {', '.join(s['kinds'])}; "
          f"fault-to-noise {s['fnr_range'][0]:g}..{s['fnr_range'][1]:g}, noise x "
          f"1/{s['noise_spread']:g}..{s['noise_spread']:g}, onsets {s['spacing_samples']} "
          f"samples apart{', bus resolution' if s['quantized'] else ', exact values'}")
    if s["noise_scale"] != 1.0:
        print(f"  the drive's noise is {s['noise_scale']:g}x the config's")
    if "calibration" in r:
        c = r["calibration"]
        print(f"  monitor calibrated first on {c['seconds']:g} s of the healthy drive: noise "
              + ", ".join(f"{v:.4g}" for v in c["measurement_std"]))
    if r["undetectable"]:
        print(f"  not drawn (the design says undetectable): {', '.join(r['undetectable'])}")
    iso = r["isolation"]
    rows = [
        ("faults", f"{r['faults']} in {r['runs']} runs ({r['runs_fault_free']} fault-free)"),
        ("detection rate", f"{_pct(r['detection_rate'])} ({r['detected']} detected, "
                           f"{r['missed']} missed)"),
        ("delay (samples)", f"mean {_f(r['delay_mean_samples'])}, median "
                            f"{_f(r['delay_median_samples'])}, p95 {_f(r['delay_p95_samples'])}"
                            f", max {_f(r['delay_max_samples'])}"),
        ("CUSUM bound", f"delay / bound median {_f(r['delay_over_bound_median'])}, p95 "
                        f"{_f(r['delay_over_bound_p95'])} (bound: ln(false-alarm interval) / "
                        "(FNR^2 / 2) samples)"),
        ("bank's bound", f"delay / bound median {_f(r['delay_over_bank_bound_median'])}, p95 "
                         f"{_f(r['delay_over_bank_bound_p95'])} (the same at the FNR the parity "
                         "bank sees in the long run: channels' bank_information)"),
        ("named", f"from onset median {_f(r['named_delay_median_samples'])}, p95 "
                  f"{_f(r['named_delay_p95_samples'])} (samples: the faulty component said, "
                  "before its form and size are known)"),
        ("to acceptance", f"from detection median {_f(r['acceptance_delay_median_samples'])},"
                          f" p95 {_f(r['acceptance_delay_p95_samples'])}; from onset median "
                          f"{_f(r['diagnosis_delay_median_samples'])}, p95 "
                          f"{_f(r['diagnosis_delay_p95_samples'])} (samples)"),
        ("excitation", f"onset to acceptance over onset to the excitation bound median "
                       f"{_f(r['acceptance_over_excitation_median'])}, p95 "
                       f"{_f(r['acceptance_over_excitation_p95'])} (the bound: least squares "
                       "that knows the fault's form and onset settles on the run's commands)"),
        ("decisions", f"{r['accepted']} accepted, {r['unexplained']} unexplained, "
                      f"{r['undecided']} undecided"),
        ("isolation", f"{_pct(r['isolation_accuracy'])} of accepted ({iso['exact']} exact, "
                      f"{iso['candidate']} among twin candidates, {iso['design_twin']} a design "
                      f"twin, {iso['wrong']} wrong); exact only "
                      f"{_pct(r['isolation_accuracy_exact'])}"),
        ("false alarms", f"{r['false_alarms']} in {r['fault_free_hours']:.3g} h fault-free = "
                         f"{_f(r['false_alarms_per_hour'])} per hour "
                         f"({r['false_alarms_before_fault']} before a fault, "
                         f"{r['false_alarms_after_accepted']} after an accepted diagnosis)"),
        ("refinements", f"{r['refinements']} re-detections of an accepted fault refined its "
                        "estimate (not counted as false alarms)"),
        ("estimate error", f"median {_pct(r['estimate_error_median'])}, p95 "
                           f"{_pct(r['estimate_error_p95'])} over {r['estimate_errors']} faults"),
        ("confidence", f"{_pct(r['estimates_within_3_std'])} of {r['estimates_judged']} "
                       "estimates within 3 of their standard deviations of the truth"),
    ]
    for name, value in rows:
        print(f"  {name:<17}{value}")
    print("\nby fault-to-noise ratio:")
    print(f"  {'FNR':<11}{'faults':>7}{'detected':>10}{'delay mean':>12}{'delay p95':>11}"
          f"{'/ bound':>9}{'/ bank':>8}{'to accept':>11}{'isolated':>10}{'est. err':>10}")
    for b in r["by_fnr"]:
        print(f"  {b['fnr_lo']:>4g}-{b['fnr_hi']:<5g}{b['faults']:>7}"
              f"{_pct(b['detection_rate']):>10}{_f(b['delay_mean_samples']):>12}"
              f"{_f(b['delay_p95_samples']):>11}{_f(b['delay_over_bound_median']):>9}"
              f"{_f(b['delay_over_bank_bound_median']):>8}"
              f"{_f(b['acceptance_delay_median_samples']):>11}"
              f"{_pct(b['isolation_accuracy']):>10}{_pct(b['estimate_error_median']):>10}")
    print("\nby kind / channel:")
    for name, b in list(r["by_kind"].items()) + list(r["by_channel"].items()):
        print(f"  {name:<28}{b['faults']:>4} faults, detected {_pct(b['detection_rate'])}, "
              f"delay mean {_f(b['delay_mean_samples'])}, isolated "
              f"{_pct(b['isolation_accuracy'])}, est. err {_pct(b['estimate_error_median'])}")
    conf = r["confusion"]
    if conf:
        cols = list(next(iter(conf.values())))
        width = max(8, *(len(c) + 1 for c in cols))
        print("\nconfusion (rows: injected channel; columns: diagnosed):")
        print(f"  {'':<28}" + "".join(f"{c:>{width}}" for c in cols))
        for row, counts in conf.items():
            print(f"  {row:<28}" + "".join(f"{counts[c]:>{width}}" for c in cols))
    for f in r.get("files", []):
        print(f"wrote {f}")


"""`canfdi soak`: fault-free samples through the monitor's batch path; any alarm is false.

Issue 7 asks for 10^7 fault-free samples at nominal noise and nonlinearity with no false alarm,
and for the false-alarm rate bound that supports. `Simulator.advance` is too slow for that, so
the plant runs as K independent closed loops at once (canfdi.firmware_sim.ensemble) in time chunks,
and each run feeds its own copy of the monitor's diagnoser through ``Diagnoser.update_block``.
Like the demo verb, this one imports canfdi.firmware_sim: it needs the emulated drive.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

from canfdi.cli.common import config_error, load_config_or_exit
from canfdi.config import ConfigError
from canfdi.configs import CONFIG_DIR

HELP = """\
Soak test: run the DC motor drive emulator fault-free, at the noise and nonlinearity of the
scenario (default dc_motor_nominal: measurement noise 0.01, the nonlinear plant, the PI speed
loop with its PRBS dither), through the monitor's diagnoser for --config, and count false
alarms: every detection (Page-Hinkley alarm) and every accepted fault is one, as no fault is
ever injected.

The samples are split into --runs independent runs of samples/runs each, simulated together
(vectorised across runs). Each run has its own noise generator (SeedSequence(seed).spawn(K)[i])
and starts its dither at a different point of the 65535-sample PRBS, and feeds a fresh copy of
the diagnoser canfdi run would build (same design, calibrated thresholds and settings) through
its batch path (Diagnoser.update_block, tested equal to the streaming path). By default the
values are rounded to the DBC's signal resolution first, as the monitor decodes them from the
bus (--no-quantize feeds the exact values).

Only monitored samples count: the first S samples of each run fill the residual window and
have no residual (S, the longest parity window, is printed), and samples spent diagnosing
after a (false) detection cannot raise another one. The Page-Hinkley statistics start at zero
in each run; no other warm-up is needed.

With x false alarms in N monitored samples the one-sided 95% upper bound on the per-sample
alarm rate is chi2.ppf(0.95, 2x + 2) / (2 N); for x = 0 that is -ln(0.05) / N = 3.0 / N (the
rule of three). It is also given per hour of monitoring at the plant's dt, and compared with
the rate the thresholds were calibrated for: detection.false_alarm_interval samples between
false alarms per residual, so about m / interval per sample for a bank of m residuals.

--threshold-scale X multiplies every calibrated threshold: a sensitivity check that the soak
can fail (0.2 gives many alarms); the default 1 is the monitor as deployed.

--noise-scale F makes the drive's measurement noise F times the scenario's: the drive a config
describes wrongly. --calibrate first runs `canfdi calibrate` on --calibrate-seconds (default
90) of a healthy run of that same drive (another seed) through the config's bus, and soaks the
calibrated config: the monitor as deployed after calibration.

Exit status: 0 no false alarm, 1 at least one (so it can gate CI), 2 bad config, scenario or
arguments. Only the dc_motor plant is emulated: a config whose signals are not the DC motor's
exits 2 naming signals. Progress on stderr; --json prints one object."""

DEFAULT_SCENARIO = "dc_motor_nominal"
DETAILS_SHOWN = 20  # detections listed in the text report (all of them in --json)


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("soak", help="fault-free soak: count false alarms, bound their rate",
                       description=HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--config", type=Path, default=CONFIG_DIR / "dc_motor.yaml",
                   metavar="FILE", help="monitor config (default: the DC motor's)")
    p.add_argument("--scenario", default=DEFAULT_SCENARIO, metavar="FILE",
                   help="fault-free dc_motor scenario giving the noise and seed "
                        f"(default: {DEFAULT_SCENARIO})")
    p.add_argument("--samples", type=int, default=10_000_000, metavar="N",
                   help="samples to simulate in all (default 10^7); rounded up to a multiple "
                        "of --runs")
    p.add_argument("--runs", type=int, default=1000, metavar="K",
                   help="independent runs the samples are split into (default 1000)")
    p.add_argument("--seed", type=int, default=None, metavar="S",
                   help="master noise seed (default: the scenario's)")
    p.add_argument("--threshold-scale", type=float, default=1.0, metavar="X",
                   help="multiply the calibrated thresholds by X (sensitivity check; default 1)")
    p.add_argument("--noise-scale", type=float, default=1.0, metavar="F",
                   help="the drive's measurement noise is F times the scenario's (default 1)")
    p.add_argument("--calibrate", action="store_true",
                   help="calibrate the config on a healthy run of the drive first")
    p.add_argument("--calibrate-seconds", type=float, default=90.0, metavar="T",
                   help="seconds of healthy data for --calibrate (default 90)")
    p.add_argument("--no-quantize", action="store_true",
                   help="feed exact values, not rounded to the DBC's signal resolution")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--no-progress", action="store_true", help="no progress lines on stderr")


def _fail(message: str) -> int:
    print(f"canfdi soak: {message}", file=sys.stderr)
    return 2


def _check_args(args: argparse.Namespace) -> str | None:
    """The first option out of its range, as the error line, or None."""
    checks = [
        (args.runs >= 1, "--runs: at least 1"),
        (args.samples >= 1, "--samples: at least 1"),
        (args.seed is None or args.seed >= 0, "--seed: an integer >= 0"),
        (args.threshold_scale > 0 and math.isfinite(args.threshold_scale),
         "--threshold-scale: a number > 0"),
        (args.noise_scale > 0 and math.isfinite(args.noise_scale),
         "--noise-scale: a number > 0"),
        (args.calibrate_seconds >= 10, "--calibrate-seconds: at least 10"),
    ]
    return next((message for ok, message in checks if not ok), None)


def run(args: argparse.Namespace) -> int:
    from canfdi.firmware_sim.plants import make_plant
    from canfdi.firmware_sim.scenario import ScenarioError, load_scenario
    from canfdi.tools.soak import (
        PLANT,
        SoakArgumentError,
        calibrated,
        scenario_problem,
        soak,
        with_noise_scale,
    )

    config = load_config_or_exit(args.config, "soak")
    if isinstance(config, int):
        return config
    plant = make_plant(PLANT)
    if (tuple(config.inputs), tuple(config.outputs)) != (plant.input_names, plant.output_names):
        return config_error(ConfigError(
            "signals", f"canfdi soak emulates the {PLANT} plant only (inputs "
                       f"{list(plant.input_names)}, outputs {list(plant.output_names)}); this "
                       f"config has inputs {config.inputs}, outputs {config.outputs}"), "soak")
    try:
        scenario = load_scenario(args.scenario)
    except ScenarioError as exc:
        return _fail(f"scenario error: {exc}")
    problem = scenario_problem(scenario)
    problem = f"scenario error: {problem}" if problem else _check_args(args)
    if problem:
        return _fail(problem)
    scenario = with_noise_scale(scenario, args.noise_scale)
    start = time.monotonic()

    def progress(msg: str) -> None:
        if not args.no_progress:
            print(f"canfdi soak [{time.monotonic() - start:6.1f} s] {msg}", file=sys.stderr,
                  flush=True)

    calibration = None
    seed = scenario.seed if args.seed is None else args.seed
    if args.calibrate:
        try:
            calibration = calibrated(config, args.config, scenario, args.calibrate_seconds,
                                     seed, progress)
        except ValueError as exc:  # LogFault too
            return _fail(f"calibration: {exc}")
        config = calibration.config
    try:
        result = soak(config, scenario, samples=args.samples, runs=args.runs, seed=seed,
                      threshold_scale=args.threshold_scale, quantize=not args.no_quantize,
                      progress=progress)
    except SoakArgumentError as exc:
        return _fail(str(exc))
    except ValueError as exc:  # a design the config cannot build, a bad DBC: ConfigError
        return config_error(exc, "soak")
    result["wall_s"] = time.monotonic() - start
    result["noise_scale"] = args.noise_scale
    if calibration is not None:
        result["calibrated_noise"] = [float(v) for v in calibration.noise.std]
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        print_report(result)
    return 0 if result["passed"] else 1


# -- the report -------------------------------------------------------------------------------

def print_report(r: dict[str, Any]) -> None:
    b, c = r["rate_bound_95"], r["configured"]
    noise = ", ".join(f"{v:g}" for v in sorted(set(r["measurement_std"])))
    print(f"soak of {r['config']} on {r['scenario']} (measurement noise {noise}"
          f"{', bus resolution' if r['quantized'] else ', exact values'}, seed {r['seed']})")
    if "calibrated_noise" in r:
        print("  calibrated first on a healthy run of the drive: noise "
              + ", ".join(f"{v:.4g}" for v in r["calibrated_noise"]))
    if r["threshold_scale"] != 1.0:
        print(f"  thresholds scaled by {r['threshold_scale']:g}: a sensitivity check, "
              "not the deployed monitor")
    rows = [
        ("samples", f"{r['samples']:,} = {r['runs']} runs x {r['samples_per_run']:,} "
                    f"({r['seconds_simulated']:,.0f} s of plant time at dt {r['dt']:g} s)"),
        ("monitored", f"{r['samples_monitored']:,} ({r['hours_monitored']:.2f} h): without the "
                      f"{r['window_fill_per_run']}-sample window fill of each run"),
        ("", f"and {r['samples_diagnosing']:,} samples diagnosing after false detections"
             if r["samples_diagnosing"] else ""),
        ("detections", f"{r['detections']}"),
        ("accepted faults", f"{r['accepted_faults']}"
                            + (f" ({r['unexplained']} unexplained)" if r["unexplained"] else "")),
        ("wall time", f"{r['wall_s']:.1f} s"),
        ("95% rate bound", f"{b['per_sample']:.3g} false alarms per sample = "
                           f"{b['per_hour']:.3g} per hour"),
        ("", f"(a mean interval of at least {b['mean_samples_between_alarms_at_least']:,.0f} "
             "samples)"),
        ("configured", f"{c['per_sample']:.3g} per sample = {c['per_hour']:.3g} per hour "
                       f"({c['residuals']} residuals x 1/"
                       f"{c['false_alarm_interval_per_residual']:.3g})"),
        ("", f"{c['expected_alarms_in_this_soak']:.2g} alarms expected here; "
             f"{c['samples_to_show_it_with_no_alarm']:,.0f} alarm-free samples would confirm it"),
    ]
    for name, value in rows:
        if value:
            print(f"  {name:<17}{value}")
    print("  per residual (configured: 1 false alarm per "
          f"{c['false_alarm_interval_per_residual']:.3g} samples each):")
    print(f"    {'residual':<16}{'peak statistic / threshold':>31}  {'alarms':>6}  "
          "95% rate interval")
    for q in r["per_residual"]:
        print(f"    {q['name']:<16}{q['peak_statistic']:8.2f} / {q['threshold']:6.2f} = "
              f"{q['peak_statistic'] / q['threshold']:4.2f}  {q['alarms']:6d}  "
              f"[{q['rate_lower_95']:.2g}, {q['rate_upper_95']:.2g}]: {q['verdict']}")
    if r["detection_list"]:
        print("false detections (run, sample k, residual: normalised residual, statistic / "
              "threshold at the alarm; change point):")
        for d in r["detection_list"][:DETAILS_SHOWN]:
            parts = "; ".join(f"{n}: r={a['normalized_residual']:+.2f}, "
                              f"g={a['statistic']:.2f} / {a['threshold']:.2f}"
                              for n, a in d["at_alarm"].items())
            print(f"  run {d['run']:<5} k={d['k']:<8} {parts}; change near k="
                  f"{d['change_point_k']}")
        if len(r["detection_list"]) > DETAILS_SHOWN:
            print(f"  ... {len(r['detection_list']) - DETAILS_SHOWN} more (--json lists all)")
    for a in r["accepted_list"][:DETAILS_SHOWN]:
        est = ", ".join(f"{k}={v:.4g}" for k, v in a["estimates"].items())
        print(f"  run {a['run']:<5} k={a['k']:<8} accepted a false {a['target']} fault on "
              f"{a['name']}: {est} (detected k={a['detected_k']})")

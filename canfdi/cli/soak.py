"""`canfdi soak`: fault-free samples through the monitor's batch path; any alarm is false.

Issue 7 asks for 10^7 fault-free samples at nominal noise and nonlinearity with no false alarm,
and for the false-alarm rate bound that supports. `Simulator.advance` is too slow for that, so
the plant runs as K independent closed loops at once (firmware_sim.ensemble) in time chunks,
and each run feeds its own copy of the monitor's diagnoser through ``Diagnoser.update_block``.
Like the demo verb, this one imports firmware_sim: it needs the emulated drive.
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from canfdi.cli.common import DEFAULT_CONFIG_DIR, config_error, load_config_or_exit
from canfdi.config import ConfigError, MonitorConfig

if TYPE_CHECKING:
    from firmware_sim.scenario import Scenario

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

Exit status: 0 no false alarm, 1 at least one (so it can gate CI), 2 bad config, scenario or
arguments. Only the dc_motor plant is emulated: a config whose signals are not the DC motor's
exits 2 naming signals. Progress on stderr; --json prints one object."""

DEFAULT_SCENARIO = "dc_motor_nominal"
PLANT = "dc_motor"
DETAILS_SHOWN = 20  # detections listed in the text report (all of them in --json)


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("soak", help="fault-free soak: count false alarms, bound their rate",
                       description=HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--config", type=Path, default=DEFAULT_CONFIG_DIR / "dc_motor.yaml",
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
    p.add_argument("--no-quantize", action="store_true",
                   help="feed exact values, not rounded to the DBC's signal resolution")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--no-progress", action="store_true", help="no progress lines on stderr")


class SoakArgumentError(ValueError):
    """Arguments the config makes impossible (too few samples per run for its window)."""


def _fail(message: str) -> int:
    print(f"canfdi soak: {message}", file=sys.stderr)
    return 2


def run(args: argparse.Namespace) -> int:
    from firmware_sim.plants import make_plant
    from firmware_sim.scenario import ScenarioError, load_scenario

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
    if scenario.plant != PLANT:
        return _fail(f"scenario error: plant: {scenario.plant!r}; canfdi soak emulates {PLANT}")
    if scenario.faults:
        return _fail(f"scenario error: faults: a soak is fault-free; {scenario.name} has "
                     f"{len(scenario.faults)}")
    if args.runs < 1:
        return _fail("--runs: at least 1")
    if args.samples < 1:
        return _fail("--samples: at least 1")
    if args.seed is not None and args.seed < 0:
        return _fail("--seed: an integer >= 0")
    if not (args.threshold_scale > 0 and math.isfinite(args.threshold_scale)):
        return _fail("--threshold-scale: a number > 0")
    start = time.monotonic()

    def progress(msg: str) -> None:
        if not args.no_progress:
            print(f"canfdi soak [{time.monotonic() - start:6.1f} s] {msg}", file=sys.stderr,
                  flush=True)

    try:
        result = soak(config, scenario, samples=args.samples, runs=args.runs,
                      seed=scenario.seed if args.seed is None else args.seed,
                      threshold_scale=args.threshold_scale, quantize=not args.no_quantize,
                      progress=progress)
    except SoakArgumentError as exc:
        return _fail(str(exc))
    except ValueError as exc:  # a design the config cannot build, a bad DBC: ConfigError
        return config_error(exc, "soak")
    result["wall_s"] = time.monotonic() - start
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        print_report(result)
    return 0 if result["passed"] else 1


# -- the soak ---------------------------------------------------------------------------------

def soak(config: MonitorConfig, scenario: Scenario, *, samples: int, runs: int, seed: int,
         threshold_scale: float = 1.0, quantize: bool = True,
         progress: Callable[[str], None] = lambda msg: None) -> dict[str, Any]:
    """Simulate ``runs`` fault-free runs of ceil(samples / runs) samples and diagnose them.

    Returns the JSON-ready result: the counts (samples, samples_monitored, detections,
    accepted_faults, unexplained, passed), rate_bound_95 and configured (whole bank, per
    sample and per hour), per_residual (threshold, peak statistic, alarms, 95% rate interval,
    verdict against 1 / false_alarm_interval) and detection_list (run, k, change point, and
    each alarming residual's normalised value, statistic and threshold at the alarm).
    """
    from canfdi.methods import build_diagnoser
    from firmware_sim.ensemble import DcMotorEnsemble

    per_run = math.ceil(samples / runs)
    progress("designing and calibrating the monitor")
    base = build_diagnoser(config)
    base.thresholds = base.thresholds * threshold_scale
    S, m = base.bank.S, base.bank.m
    dt = scenario.make_plant().dt
    if base.design.model.dt not in (None, dt):
        raise ConfigError("model.dt", f"{base.design.model.dt} s, but the {PLANT} plant runs "
                                      f"at {dt} s")
    if per_run <= S:
        raise SoakArgumentError(f"--samples: {per_run} samples per run leave nothing to "
                                f"monitor after the {S}-sample window fill; use more samples "
                                "or fewer runs")
    resolution = _bus_resolution(config) if quantize else None
    # One diagnoser per run, each a deep copy of the monitor's (sharing the read-only design),
    # so whatever build_diagnoser sets up, every run gets exactly that.
    diagnosers = [copy.deepcopy(base, {id(base.design): base.design}) for _ in range(runs)]
    ensemble = DcMotorEnsemble.from_scenario(scenario, runs, seed)
    # About 2.5e5 samples per chunk: tens of MB of arrays whatever K is.
    chunk = max(1, min(per_run, 250_000 // runs))
    dt_ns = round(dt * 1e9)
    names = base.residual_names
    with_residual = 0
    diagnosing = 0
    open_diag: dict[int, int] = {}  # run -> sample of its pending detection
    peak = np.zeros(m)  # largest Page-Hinkley statistic of each residual, over every run
    peak_at = [None] * m
    detections: list[dict] = []
    accepted: list[dict] = []
    unexplained: list[dict] = []
    progress(f"{runs} runs x {per_run:,} samples, {chunk} per chunk")
    last = time.monotonic()
    done = 0
    while done < per_run:
        count = min(chunk, per_run - done)
        sim = ensemble.advance(count)
        k = sim.k
        t_ns = k * dt_ns
        U, Z = sim.u_c, sim.z
        if resolution is not None:
            U, Z = _quantize(U, resolution[0]), _quantize(Z, resolution[1])
        for i, dg in enumerate(diagnosers):
            res = dg.update_block(k, t_ns, U[i], Z[i])
            have = ~np.isnan(res.residuals[:, 0])
            with_residual += int(have.sum())
            if have.any():
                row = np.argmax(res.statistic, axis=0)
                top = res.statistic[row, np.arange(m)]
                for j in np.flatnonzero(top > peak):
                    peak[j] = top[j]
                    peak_at[j] = {"run": i, "k": int(k[row[j]])}
            for ev in res.events:
                r = int(ev.sample - k[0])
                if ev.kind == "detected":
                    open_diag[i] = ev.sample
                    found = _detection(i, ev, res, r, names, dg.thresholds)
                    found["dither_offset"] = int(ensemble.dither_offsets[i])
                    detections.append(found)
                    continue
                if i in open_diag:
                    diagnosing += ev.sample - open_diag.pop(i)
                entry = {"run": i, "k": ev.sample, "detected_k": ev.detected_sample}
                if ev.kind == "accepted":
                    entry.update(target=ev.target, name=ev.name, estimates=ev.estimates,
                                 onset_k=ev.onset_sample)
                    accepted.append(entry)
                elif ev.kind == "unexplained":
                    unexplained.append(entry)
        done += count
        now = time.monotonic()
        if now - last >= 5.0 or done == per_run:
            last = now
            progress(f"{done * runs:,} / {per_run * runs:,} samples, "
                     f"{len(detections)} detections, {len(accepted)} accepted faults")
    for k_d in open_diag.values():  # still diagnosing at the end of the run
        diagnosing += per_run - 1 - k_d
    monitored = with_residual - diagnosing
    total = per_run * runs
    x = len(detections)
    bound = rate_upper_bound(x, monitored)
    per_hour = 3600.0 / dt
    interval = config.detection.false_alarm_interval
    target = m / interval
    result: dict[str, Any] = {
        "config": str(config.path) if config.path else config.name,
        "scenario": scenario.name,
        "measurement_std": [float(v) for v in scenario.measurement_std],
        "process_std": [float(v) for v in scenario.process_std],
        "quantized": resolution is not None,
        "seed": seed,
        "runs": runs,
        "samples_per_run": per_run,
        "samples": total,
        "seconds_simulated": total * dt,
        "dt": dt,
        "window_fill_per_run": S,
        "samples_with_residual": with_residual,
        "samples_diagnosing": diagnosing,
        "samples_monitored": monitored,
        "hours_monitored": monitored * dt / 3600.0,
        "residuals": names,
        "thresholds": [float(h) for h in base.thresholds],
        "threshold_scale": threshold_scale,
        "detections": x,
        "accepted_faults": len(accepted),
        "unexplained": len(unexplained),
        # Every accepted (or unexplained) fault follows a detection: detections count the
        # false alarms, and any detection or accepted fault fails the soak.
        "passed": x == 0 and not accepted,
        "rate_bound_95": {
            "per_sample": bound,
            "per_hour": bound * per_hour,
            "mean_samples_between_alarms_at_least": 1.0 / bound,
        },
        "configured": {
            "false_alarm_interval_per_residual": interval,
            "residuals": m,
            "per_sample": target,
            "per_hour": target * per_hour,
            "expected_alarms_in_this_soak": target * monitored,
            "samples_to_show_it_with_no_alarm": -math.log(0.05) / target,
        },
        # The thresholds are calibrated per residual: each residual's alarms against 1/interval,
        # with a two-sided 90% interval (so each side is a one-sided 95% bound).
        "per_residual": [_residual_figures(name, float(h), float(g), at, detections,
                                           monitored, interval)
                         for name, h, g, at in zip(names, base.thresholds, peak, peak_at,
                                                   strict=True)],
        "detection_list": detections,
        "accepted_list": accepted,
        "unexplained_list": unexplained,
    }
    return result


def rate_lower_bound(alarms: int, samples: int, confidence: float = 0.95) -> float:
    """One-sided lower confidence bound on a Poisson per-sample rate: chi2.ppf(1-c, 2x)/(2N)."""
    from scipy.stats import chi2

    if alarms == 0 or samples <= 0:
        return 0.0
    return float(chi2.ppf(1.0 - confidence, 2 * alarms)) / (2.0 * samples)


def _residual_figures(name: str, threshold: float, peak: float, peak_at: dict | None,
                      detections: list[dict], monitored: int, interval: float
                      ) -> dict[str, Any]:
    alarms = sum(name in d["residuals"] for d in detections)
    upper, lower = rate_upper_bound(alarms, monitored), rate_lower_bound(alarms, monitored)
    target = 1.0 / interval
    verdict = ("above the configured rate" if lower > target else
               "supports the configured rate" if upper <= target else
               "consistent with the configured rate, cannot confirm it")
    return {"name": name, "threshold": threshold, "peak_statistic": peak, "peak_at": peak_at,
            "alarms": alarms, "rate_lower_95": lower, "rate_upper_95": upper,
            "configured_per_sample": target, "verdict": verdict}


def rate_upper_bound(alarms: int, samples: int, confidence: float = 0.95) -> float:
    """One-sided upper confidence bound on a Poisson per-sample rate: chi2.ppf(c, 2x+2)/(2N).

    For x = 0 it is -ln(1 - c) / N (3.0 / N at 95%, the rule of three).
    """
    from scipy.stats import chi2

    if samples <= 0:
        return math.inf
    if alarms == 0:
        return -math.log(1.0 - confidence) / samples
    return float(chi2.ppf(confidence, 2 * alarms + 2)) / (2.0 * samples)


def _detection(run: int, event, res, row: int, names: list[str], thresholds: np.ndarray
               ) -> dict[str, Any]:
    """What a false detection looked like: residuals, statistics and thresholds at the alarm."""
    out: dict[str, Any] = {"run": run, "k": event.sample, "change_point_k": event.onset_sample,
                           "residuals": list(event.residuals), "at_alarm": {}}
    for name in event.residuals:
        j = names.index(name)
        out["at_alarm"][name] = {
            "normalized_residual": float(res.normalized[row, j]),
            "statistic": float(res.statistic[row, j]),
            "threshold": float(thresholds[j]),
        }
    return out


# -- bus resolution ---------------------------------------------------------------------------

def _bus_resolution(config: MonitorConfig) -> tuple[list, list]:
    """Per model input and output, its DBC signal layout (what encode/decode does to it)."""
    from canfdi.bus.dbc import BusMap

    bus_map = BusMap.from_config(config)
    u: list = [None] * bus_map.p
    z: list = [None] * bus_map.q
    for layout, fields in zip(bus_map.layouts, bus_map.fields, strict=True):
        for name, vec, j in fields:
            (u if vec == "u" else z)[j] = layout.signal(name)
    return u, z


def _quantize(values: np.ndarray, signals: list) -> np.ndarray:
    """(..., c) values as the monitor decodes them after the drive encodes them: clipped to
    each signal's range and rounded to its resolution (float32 for float signals); the same
    arithmetic as MessageLayout.encode then decode, without building payloads."""
    out = np.empty_like(values)
    for j, sig in enumerate(signals):
        v = values[..., j]
        if sig.is_float:
            out[..., j] = v.astype(np.float32).astype(np.float64)
            continue
        lo, hi = sig.physical_limits()
        v = np.clip(np.nan_to_num(v, nan=0.0), lo, hi)
        out[..., j] = np.rint((v - sig.offset) / sig.scale) * sig.scale + sig.offset
    return out


# -- the report -------------------------------------------------------------------------------

def print_report(r: dict[str, Any]) -> None:
    b, c = r["rate_bound_95"], r["configured"]
    noise = ", ".join(f"{v:g}" for v in sorted(set(r["measurement_std"])))
    print(f"soak of {r['config']} on {r['scenario']} (measurement noise {noise}"
          f"{', bus resolution' if r['quantized'] else ', exact values'}, seed {r['seed']})")
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

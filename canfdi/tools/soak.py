"""The library behind `canfdi soak`: fault-free runs of the emulated DC motor through the
monitor's diagnoser (its batch path), every detection a false alarm, and the statistics of the
false-alarm rate (Poisson confidence bounds against the configured interval).

`firmware_sim.ensemble` simulates the K runs at once, vectorised across runs; each run has its
own copy of the diagnoser the config describes (canfdi.methods).
"""

from __future__ import annotations

import copy
import dataclasses
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from canfdi.bus.dbc import BusMap
from canfdi.core.settings import ConfigError, MonitorConfig
from canfdi.firmware_sim.ensemble import DcMotorEnsemble
from canfdi.methods import build_diagnoser

if TYPE_CHECKING:
    from canfdi.firmware_sim.scenario import Scenario
    from canfdi.tools.calibrate import Calibration

__all__ = ["PLANT", "SoakArgumentError", "calibrated", "rate_lower_bound", "rate_upper_bound",
           "scenario_problem", "soak", "with_noise_scale"]

PLANT = "dc_motor"


class SoakArgumentError(ValueError):
    """Arguments the config makes impossible (too few samples per run for its window)."""


def scenario_problem(scenario: Scenario) -> str | None:
    """What makes ``scenario`` no soak of the emulated plant (another plant, faults), or
    None."""
    if scenario.plant != PLANT:
        return f"plant: {scenario.plant!r}; canfdi soak emulates {PLANT}"
    if scenario.faults:
        return f"faults: a soak is fault-free; {scenario.name} has {len(scenario.faults)}"
    return None


def with_noise_scale(scenario: Scenario, noise_scale: float) -> Scenario:
    """``scenario`` with its drive's measurement noise ``noise_scale`` times the scenario's:
    the drive a config describes wrongly."""
    return dataclasses.replace(scenario, measurement_std=scenario.measurement_std * noise_scale)


def calibrated(config: MonitorConfig, config_path: Path, scenario: Scenario, seconds: float,
               seed: int, progress: Callable[[str], None] = lambda msg: None) -> Calibration:
    """`canfdi calibrate` of the config at ``config_path`` on ``seconds`` of a healthy run of
    the scenario's drive (seeded ``seed + 1``: none of the soak's noise), through the config's
    bus: the monitor as deployed after calibration.

    Raises
    ------
    ValueError
        The run cannot calibrate the config (too few samples; LogFault: a detection in it).
    """
    from canfdi.config import read_yaml
    from canfdi.tools.calibrate import calibrate_records, scenario_records

    progress(f"calibrating on {seconds:g} s of the healthy drive")
    records = scenario_records(config, scenario, seconds, seed + 1)
    return calibrate_records(records, config, read_yaml(config_path, ValueError, "config"),
                             progress=progress)


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
    bus_map = BusMap.from_config(config) if quantize else None
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
        if bus_map is not None:
            U, Z = bus_map.quantize(U, Z)
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
        "quantized": bus_map is not None,
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

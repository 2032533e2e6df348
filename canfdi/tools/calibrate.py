"""The library behind `canfdi calibrate`: a drive's noise and its residuals' behaviour, learnt
from healthy logs.

`calibrate` reads the logs (any format canfdi.io reads) with the config's bus, estimates the
sensor noise through the model's parity space (canfdi.core.noise), builds the config's method
with that noise, runs it over the same data and reports per residual: its variance and
long-run variance against what the calibrated noise predicts (1), its mean, its correlation
with each input (a model whose B is off leaves the input in the residual), the threshold the
data themselves give for the configured false-alarm interval. A log on which the calibrated
monitor detects anything holds a fault (or a drive the model does not describe): it is
refused, with where.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from canfdi import methods
from canfdi.bus.dbc import BusMap
from canfdi.config import parse_config
from canfdi.core.calibrate import threshold_for_long_run_variance
from canfdi.core.noise import NoiseEstimate, estimate_measurement_noise
from canfdi.core.settings import ConfigError, MonitorConfig
from canfdi.core.sysid import regular_grid, stack_records
from canfdi.core.unknown_inputs import Record as FitRecord
from canfdi.io.damage import Damage
from canfdi.tools.configdoc import ConfigDocument
from canfdi.tools.samples import assembled_samples, log_samples

__all__ = [
    "Calibration",
    "LogFault",
    "Record",
    "ResidualCheck",
    "Teach",
    "calibrate",
    "calibrate_records",
    "calibrated_document",
    "config_document",
    "read_records",
    "scenario_records",
]

MIN_SAMPLES = 1000
"""Fewer healthy samples than this (10 s at 100 Hz) say too little about the noise."""
BATCH = 200
"""Samples per batch mean for the long-run variance."""
MEAN_LIMIT = 0.2
"""A residual mean beyond this many of its noise stds (and 4 standard errors) is reported."""
INPUT_CORRELATION_LIMIT = 0.2
"""A residual correlating more than this with an input is reported (its model is off)."""


class LogFault(ValueError):
    """A log holds what the calibrated monitor detects: a fault, or a drive the model does not
    describe. Calibration needs healthy data."""


@dataclass(frozen=True)
class ResidualCheck:
    """What the healthy data say of one residual (normalised by the calibrated noise).

    variance : its variance (1 when the calibrated noise explains it); long_run : its long-run
    variance (sum of all autocovariances; the white-noise value is 1, a windowed residual's
    more); mean, mean_se : its mean and that mean's standard error; input_correlation :
    {input: correlation}; threshold : the method's threshold; data_threshold : Siegmund's
    threshold on the measured long-run variance for the false-alarm interval.
    """

    name: str
    variance: float
    long_run: float
    mean: float
    mean_se: float
    input_correlation: dict[str, float]
    threshold: float
    data_threshold: float
    findings: list[str] = field(default_factory=list)


@dataclass(frozen=True)
class Calibration:
    """The result: the noise estimate, the residual checks, the calibrated config."""

    logs: list[str]
    samples: int
    noise: NoiseEstimate
    prior_std: np.ndarray
    outputs: list[str]
    residuals: list[ResidualCheck]
    config: MonitorConfig
    document: dict
    floored: np.ndarray | None = None

    def report(self) -> dict[str, Any]:
        """A JSON-able summary."""
        floored = (np.zeros(len(self.outputs), dtype=bool) if self.floored is None
                   else self.floored)
        return {
            "logs": self.logs, "samples": self.samples, "window": self.noise.s,
            "noise": [{"sensor": name, "std": float(s), "std_error": float(e),
                       "config_std": float(p),
                       "identified": ("its resolution (the data show less)" if low else
                                      "alone" if ident else "with others (prior's split)"
                                      if seen else "not seen (prior x the others' scale)")}
                      for name, s, e, p, ident, seen, low in zip(
                          self.outputs, self.noise.std, self.noise.std_error, self.prior_std,
                          self.noise.identifiable, self.noise.seen, floored, strict=True)],
            "covariance": self.noise.covariance.tolist(),
            "residuals": [dataclasses.asdict(r) for r in self.residuals],
        }


def calibrated_document(doc: Mapping[str, Any], config: MonitorConfig, std: np.ndarray
                        ) -> dict:
    """The config document with its noise set to ``std`` (q,): ``noise.measurement``, and the
    method's own section where it holds a noise level (the registry's ``with_noise``)."""
    out = dict(doc)
    noise = dict(out.get("noise") or {})
    noise["measurement"] = [float(f"{v:.4g}") for v in np.asarray(std, dtype=float)]
    out["noise"] = noise
    method = methods.get(config.method)
    if method.with_noise is not None and method.section is not None:
        out[method.section] = method.with_noise(out.get(method.section) or {}, std)
    return out


class Record(NamedTuple):
    """One healthy record on a regular sample grid: its name (a log's path), k (N,)
    consecutive sample indices, U (N, p) commands (lost ones held), Z (N, q) measurements
    (NaN where lost)."""

    name: Path
    k: np.ndarray
    U: np.ndarray
    Z: np.ndarray


def _record(name: Path, k: np.ndarray, U: np.ndarray | None, Z: np.ndarray | None) -> Record:
    """The record of assembled samples (k, U, Z), put on a regular grid."""
    if len(k) == 0:
        raise ValueError(f"{name}: no sample formed (no frame matched the config's bus map)")
    Ug, Zg = regular_grid(k, U, Z)
    return Record(name, np.arange(int(k[0]), int(k[-1]) + 1), Ug, Zg)


def read_records(paths: Sequence[Path], config: MonitorConfig, progress: Callable[[str], None],
                 damage: Damage | None = None, dt: float | None = None) -> list[Record]:
    """Each log's record, assembled with the config's bus at the sample period ``dt``
    (default the config's; damaged logs around their damage, recorded in ``damage``)."""
    out = []
    for path in paths:
        progress(f"reading {path}")
        out.append(_record(path, *log_samples(path, config, damage, dt)))
    return out


def calibrate(paths: Sequence[Path], config: MonitorConfig, doc: Mapping[str, Any], *,
              window: int | None = None, full: bool = False,
              progress: Callable[[str], None] = lambda _: None,
              damage: Damage | None = None) -> Calibration:
    """Calibrate a config (``doc``: its YAML document, as read) from healthy logs; what
    damaged logs lost (their samples there are missing, as lost samples are) is recorded in
    ``damage``.

    Raises
    ------
    ValueError : a log without samples, or too few samples in all.
    LogFault : the calibrated monitor detects something in a log (where, in the message).
    """
    return calibrate_records(read_records(paths, config, progress, damage), config, doc,
                             window=window, full=full, progress=progress)


def resolution_floor(config: MonitorConfig, Z: np.ndarray) -> np.ndarray:
    """(q,) the rounding noise each output carries on the config's bus (its DBC scale, or its
    float type's spacing at the values Z (N, q)); zeros when the config has no readable DBC."""
    try:
        _, floor = BusMap.from_config(config).resolution(np.zeros((1, len(config.inputs))), Z)
    except (ConfigError, OSError, ValueError):
        return np.zeros(len(config.outputs))
    return floor


def calibrate_records(records: Sequence[Record], config: MonitorConfig,
                      doc: Mapping[str, Any], *, window: int | None = None, full: bool = False,
                      progress: Callable[[str], None] = lambda _: None,
                      floor_std: np.ndarray | None = None) -> Calibration:
    """`calibrate` on records already assembled. A sensor whose noise the data put below its
    resolution on the bus (``floor_std``, default `resolution_floor`: an echo of a setpoint,
    a quantised counter) gets its resolution: a threshold needs some noise, and the rounding
    is there."""
    paths = [r.name for r in records]
    total = sum(len(r.k) for r in records)
    if total < MIN_SAMPLES:
        raise ValueError(f"{total} samples in the logs: calibration needs at least "
                         f"{MIN_SAMPLES} healthy samples")
    model = config.model.discretize() if config.model.continuous else config.model
    s = window if window is not None else min(max(config.design.max_window, 1), 10)
    # The logs end to end, s+1 lost samples between two, so that no window straddles them.
    U, Z = stack_records([FitRecord(r.U, r.Z) for r in records], s + 1)
    prior = config.design.measurement_std
    prior = np.ones(model.q) if prior is None else np.broadcast_to(prior, (model.q,)).copy()
    progress(f"estimating the noise of {model.q} sensors over windows of {s + 1} samples")
    noise = estimate_measurement_noise(model, s, U, Z, prior, full=full)
    floor = (resolution_floor(config, Z[~np.isnan(Z).any(axis=1)]) if floor_std is None
             else np.asarray(floor_std, dtype=float))
    floored = noise.std < floor
    if np.any(floored):
        noise = dataclasses.replace(noise, std=np.maximum(noise.std, floor))
    if np.any(noise.std <= 0):
        zero = [n for n, v in zip(config.outputs, noise.std, strict=True) if v <= 0]
        raise ValueError(f"the data show no noise on {', '.join(zero)} and its bus signal "
                         "has no resolution to stand for it: a threshold cannot be set")
    document = calibrated_document(doc, config, noise.std)
    new = parse_config(document, config.path)
    progress("checking the residuals with the calibrated noise")
    checks = _check_residuals(records, new)
    return Calibration(logs=[str(p) for p in paths], samples=total, noise=noise,
                       prior_std=prior, outputs=list(config.outputs), residuals=checks,
                       config=new, document=document, floored=floored)


def _check_residuals(records: Sequence[Record], config: MonitorConfig
                     ) -> list[ResidualCheck]:
    """Run the calibrated method over each log; refuse one it detects anything in."""
    diagnoser = methods.build_diagnoser(config)
    names = list(diagnoser.residual_names)
    thresholds = np.asarray(diagnoser.thresholds, dtype=float)
    normalized, inputs = [], []
    dt_ns = round((config.model.dt or 1.0) * 1e9)
    for path, grid, Ug, Zg in records:
        diagnoser.reset()
        result = diagnoser.update_block(grid, grid * dt_ns, Ug, Zg)
        detected = [e for e in result.events if e.kind == "detected"]
        if detected:
            first = detected[0]
            seconds = (first.sample - int(grid[0])) * (config.model.dt or 1.0)
            raise LogFault(f"{path}: not healthy: the calibrated monitor detects a change at "
                           f"sample {first.sample} ({seconds:.2f} s into the log) on "
                           f"{', '.join(first.residuals) or 'a residual'}; calibrate on a "
                           "fault-free stretch")
        normalized.append(result.normalized)
        inputs.append(Ug)
    R = np.vstack(normalized)
    Uall = np.vstack(inputs)
    drift = config.detection.drift
    interval = config.detection.false_alarm_interval
    checks = []
    for i, name in enumerate(names):
        r = R[:, i]
        ok = ~np.isnan(r)
        x = r[ok]
        var = float(x.var()) if len(x) > 1 else float("nan")
        n_batches = len(x) // BATCH
        long_run = (float(x[: n_batches * BATCH].reshape(n_batches, BATCH).mean(axis=1)
                          .var(ddof=1) * BATCH) if n_batches >= 10 else float("nan"))
        mean = float(x.mean()) if len(x) else float("nan")
        mean_se = float(np.sqrt(max(long_run, var) / max(len(x), 1)))
        corr = {}
        for j, inp in enumerate(config.inputs):
            u = Uall[ok, j]
            corr[inp] = (float(np.corrcoef(x, u)[0, 1])
                         if len(x) > 2 and u.std() > 0 and x.std() > 0 else 0.0)
        lr = long_run if np.isfinite(long_run) else var
        data_h = float(threshold_for_long_run_variance(drift, interval, [lr])[0])
        findings = []
        if abs(mean) > MEAN_LIMIT and abs(mean) > 4 * mean_se:
            findings.append(f"mean {mean:+.2f} noise stds: an offset the model does not have "
                            "(a sensor offset, or the operating point's nonlinearity)")
        for inp, c in corr.items():
            if abs(c) > INPUT_CORRELATION_LIMIT:
                findings.append(f"correlates {c:.2f} with {inp}: the model's B (or A) is off?")
        if np.isfinite(var) and not 0.7 < var < 1.4:
            findings.append(f"variance {var:.2f} of the calibrated noise's: noise the model "
                            "does not describe (process noise, or sensors sharing noise)")
        checks.append(ResidualCheck(name=name, variance=var, long_run=lr, mean=mean,
                                    mean_se=mean_se, input_correlation=corr,
                                    threshold=float(thresholds[i]), data_threshold=data_h,
                                    findings=findings))
    return checks


def config_document(calibration: Calibration, document: ConfigDocument, source: Path,
                    output: Path, when: str) -> ConfigDocument:
    """The calibrated config to write to ``output``: ``document`` (the config as read from
    ``source``, whose `plain` form calibration took) with the calibrated values of
    `calibrated_document` set in place (``noise.measurement``; the method's own section, where
    its ``with_noise`` puts a noise level), its relative DBC paths pointing at the same files
    from ``output``'s folder, and the provenance (logs, samples, date ``when``) as comment
    lines at the top. Everything else keeps the user's comments, order and literals.

    Parameters
    ----------
    calibration : the result of `calibrate`; document : the config's round-trip document
        (edited and returned); source : the config's path; output : where it will be
        written (the relative paths are rewritten for its folder); when : the date to state.

    Returns
    -------
    ``document``, edited.
    """
    calibrated = calibration.document
    document.set("noise.measurement", calibrated["noise"]["measurement"])
    method = methods.get(calibration.config.method)
    if method.with_noise is not None and method.section is not None:
        # merged key by key: only what with_noise changed is rewritten
        document.set(method.section, calibrated[method.section])
    document.relocate_paths(source, output)
    noise = calibration.noise
    lines = [f"Calibrated by `canfdi calibrate` on {when} from {calibration.samples} healthy",
             f"samples of {len(calibration.logs)} log(s): "
             + ", ".join(Path(p).name for p in calibration.logs) + ".",
             f"noise.measurement estimated through the parity space over windows of "
             f"{noise.s + 1} samples",
             f"({noise.windows} windows); the config's {source.name} said "
             + ", ".join(f"{n} {p:.4g}" for n, p in zip(calibration.outputs,
                                                        calibration.prior_std, strict=True))
             + "."]
    shared = [n for n, ident, seen in zip(calibration.outputs, noise.identifiable, noise.seen,
                                          strict=True) if seen and not ident]
    unseen = [n for n, seen in zip(calibration.outputs, noise.seen, strict=True) if not seen]
    if shared:
        lines.append("Seen only together with other sensors (split in the prior's "
                     "proportions): " + ", ".join(shared) + ".")
    if unseen:
        lines.append("Read by no parity relation (the prior times the others' scale): "
                     + ", ".join(unseen) + ".")
    document.header(lines)
    return document


def scenario_records(config: MonitorConfig, scenario: Any, seconds: float, seed: int
                     ) -> list[Record]:
    """The healthy record `calibrate_records` takes from ``seconds`` of a fault-free emulated
    run of the scenario's drive (seed ``seed``), through the config's bus as a log would be:
    its DBC's resolution, its clock."""
    from canfdi.firmware_sim.emitter import frame_log

    run = dataclasses.replace(scenario, faults=(), drives=(), seed=seed, duration=seconds)
    name = Path(f"{scenario.name}-seed{seed}-{seconds:g}s")
    return [_record(name, *assembled_samples([frame_log(run).frames], config))]


@dataclass(frozen=True)
class Teach:
    """Teach-in (`canfdi run --teach SECONDS`): the monitor's `Teacher`. ``learn`` calibrates
    on the first ``samples`` samples of a running drive exactly as `calibrate` does on logs
    (same noise estimate, same residual check, same refusal of data holding a fault) and
    returns the diagnoser built on the learned noise, with the learned values as metadata
    strings.

    config : the monitor config; doc : its YAML document (what calibration rewrites).
    """

    config: MonitorConfig
    doc: Mapping[str, Any]
    samples: int

    def learn(self, k: np.ndarray, U: np.ndarray, Z: np.ndarray
              ) -> tuple[Any, dict[str, str]]:
        """Samples k (N,), U (N, p), Z (N, q) -> (diagnoser, {"status": "learned",
        "samples", "first_sample", "noise_json", "residuals_json"}); ValueError (LogFault for
        a fault in them) when they cannot be learned from."""
        import json

        calibration = calibrate_records([_record(Path("teach-in"), k, U, Z)], self.config,
                                        self.doc)
        diagnoser = methods.build_diagnoser(calibration.config)
        report = calibration.report()
        learned = {"status": "learned", "samples": str(calibration.samples),
                   "first_sample": str(int(k[0])), "noise_json": json.dumps(report["noise"]),
                   "covariance_json": json.dumps(report["covariance"]),
                   "residuals_json": json.dumps(report["residuals"])}
        return diagnoser, learned

"""Monte Carlo evaluation of a diagnoser (issue 10, `canfdi evaluate`).

Generated scenarios (seeded) run through the emulated plant (firmware_sim.simulate) and through
a fresh copy of the diagnoser the config describes (its batch path, ``update_block``); the events
are matched to the injected faults and summarised.

Four pieces, each usable alone:

1. ``plan_runs``: the scenarios. Run i draws from its own generator
   (``SeedSequence(seed).spawn(runs)[i]``), so it is the same whatever ``runs`` is. Each run has
   0..max_faults consecutive, never repaired faults, on distinct channels drawn among those the
   parity design says are detectable (undetectable channels are listed, never drawn), each
   kind drawn among actuator bias (lambda), actuator scale (eta) and sensor bias. Onsets are
   spaced by ``spacing`` samples (enough to detect and diagnose before the next); the first
   comes after a fault-free lead-in, and runs with no fault give fault-free time too.
2. ``run_evaluation``: simulation and diagnosis.
3. ``match_run`` (pure): events against injected faults.
4. ``aggregate`` (pure): the metrics.

Fault-to-noise ratio (FNR). For a fault of constant size f on channel c:
``FNR = |f| * G_c / noise_scale``, where G_c is the design's best unit fault-to-noise gap for c
(max over the residuals that respond to c of |response to a unit constant fault| / residual
noise std, at the config's noise: the "best f/n" column of `canfdi design`) and noise_scale is
the run's measurement noise over the config's. f is the bias for a sensor bias or an actuator
bias (lambda), and |eta - 1| * rms(u_c) for an actuator scale (rms of that actuator's command in
a fault-free run of the plant). In words: the steady change the fault makes in the residual most
sensitive to it, in that residual's noise standard deviations. Magnitudes are drawn
log-uniformly in FNR.
"""

from __future__ import annotations

import copy
import math
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import yaml

from canfdi.core.records import FaultEvent, increment
from canfdi.core.residuals import ResidualBank
from canfdi.methods import DEFAULT, FAULT_KINDS
from canfdi.methods.parity.hypotheses import steady_response
from canfdi.methods.parity.thresholds import long_run_covariance

if TYPE_CHECKING:
    from canfdi.core.design import Design
    from canfdi.core.kernel import Kernel
    from canfdi.core.settings import MonitorConfig

__all__ = [
    "FAULT_KINDS",
    "FNR_BINS",
    "Channel",
    "EvaluationSetup",
    "FaultOutcome",
    "InjectedFault",
    "Mapper",
    "RunOutcome",
    "RunSpec",
    "aggregate",
    "bank_bound",
    "bank_information",
    "cusum_bound",
    "default_config",
    "evaluate",
    "label",
    "match_run",
    "plan_runs",
    "relative_errors",
    "run_evaluation",
    "run_one",
    "setup_from_config",
]

#: Edges of the fault-to-noise bins the report and the plot use.
FNR_BINS = (0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 50.0)


def label(target: str | None, index: int | None, names: dict[str, Sequence[str]] | None = None
          ) -> str:
    """'a:V' / 's:i_f' (or 'a:0' / 's:1' without names), as residual names are written."""
    if target is None or index is None:
        return "?"
    prefix = "a" if target == "actuator" else "s"
    if names is not None:
        return f"{prefix}:{names[target][index]}"
    return f"{prefix}:{index}"


# -- what is injected ----------------------------------------------------------------------------

@dataclass(frozen=True)
class InjectedFault:
    """One injected fault.

    target : "actuator" or "sensor"; index : 0-based channel; name : the signal's name.
    kind : one of FAULT_KINDS. onset_sample : first faulty sample k.
    params : the true parameters: {"eta", "lambda"} for actuators, {"bias"} for sensors.
    fnr : fault-to-noise ratio (module docstring).
    bank_fnr : the fault-to-noise ratio the parity bank sees in the long run, fnr *
        sqrt(information) (`Channel.information`; None where unknown): the bank's bound's.
    """

    target: str
    index: int
    name: str
    kind: str
    onset_sample: int
    params: dict[str, float]
    fnr: float = math.nan
    bank_fnr: float | None = None

    @property
    def label(self) -> str:
        return f"{'a' if self.target == 'actuator' else 's'}:{self.name}"

    def scenario_entry(self, dt: float) -> dict[str, Any]:
        """The fault as canfdi.firmware_sim.scenario.parse_scenario takes it."""
        out: dict[str, Any] = {"target": self.target, "index": self.index,
                               "onset": self.onset_sample * dt}
        if self.target == "actuator":
            out.update(eta=float(self.params.get("eta", 1.0)),
                       **{"lambda": float(self.params.get("lambda", 0.0))})
        else:
            out["bias"] = float(self.params["bias"])
        return out

    def as_dict(self) -> dict[str, Any]:
        return {"target": self.target, "index": self.index, "name": self.name,
                "channel": self.label, "kind": self.kind, "onset_sample": self.onset_sample,
                "params": dict(self.params), "fnr": self.fnr, "bank_fnr": self.bank_fnr}


@dataclass(frozen=True)
class RunSpec:
    """One generated run: ``samples`` samples at ``noise_scale`` times the config's measurement
    noise, scenario seed ``seed``, faults in onset order."""

    run: int
    seed: int
    samples: int
    noise_scale: float
    faults: tuple[InjectedFault, ...]

    def scenario_dict(self, plant: str, dt: float, measurement_std: np.ndarray) -> dict:
        """The scenario as canfdi.firmware_sim.scenario.parse_scenario takes it."""
        return {
            "name": f"evaluate_{plant}_{self.run}", "plant": plant,
            "duration": self.samples * dt, "seed": self.seed,
            "noise": {"measurement": [float(v) for v in measurement_std * self.noise_scale],
                      "process": 0.0},
            "faults": [f.scenario_entry(dt) for f in self.faults],
        }


@dataclass(frozen=True)
class Channel:
    """A fault channel of the design: its unit gap G (residual noise stds per unit constant
    fault, at the config's noise), whether the design says it is detectable, and the
    information per sample its constant fault of FNR 1 gives the whole bank in the long run
    (`bank_information`)."""

    target: str
    index: int
    name: str
    gap: float
    detectable: bool
    reason: str = ""
    information: float | None = None

    @property
    def label(self) -> str:
        return f"{'a' if self.target == 'actuator' else 's'}:{self.name}"


@dataclass(frozen=True)
class EvaluationSetup:
    """What plan_runs needs to know about a plant and its monitor.

    dt : sample period (s). channels : every actuator and sensor channel.
    u_rms : (p,) rms of each fault-free command (actuator scale faults' FNR).
    measurement_std : (q,) the config's sensor noise.
    spacing : samples between consecutive onsets; lead : (min, max) samples before the first.
    twins : label -> labels with the same residual signature (design.confused_with).
    """

    plant: str
    dt: float
    channels: tuple[Channel, ...]
    u_rms: np.ndarray
    measurement_std: np.ndarray
    spacing: int
    lead: tuple[int, int]
    twins: dict[str, frozenset[str]] = field(default_factory=dict)

    @property
    def detectable(self) -> list[Channel]:
        return [c for c in self.channels if c.detectable]


def setup_from_config(config: MonitorConfig, plant: str, design: Design | None = None,
                      spacing: int | None = None, lead: tuple[int, int] = (300, 1000)
                      ) -> EvaluationSetup:
    """The channels, gaps and twins of the config's parity design, and the plant's nominal
    command level (one fault-free 30 s run at the config's noise).

    spacing defaults to identification.max_samples + 1000: a fault detected up to 1000 samples
    after its onset can still be decided before the next one."""
    from canfdi.core.design import design_bank
    from canfdi.firmware_sim.plants import make_plant
    from canfdi.firmware_sim.scenario import parse_scenario
    from canfdi.firmware_sim.simulate import simulate

    design = design or design_bank(config.model, config.inputs, config.outputs, config.design)
    plant_obj = make_plant(plant)
    dt = float(config.model.dt or plant_obj.dt)
    meas = (np.asarray(config.design.measurement_std, dtype=float) * np.ones(design.model.q)
            if config.design.measurement_std is not None
            else np.asarray(plant_obj.noise_defaults().measurement, dtype=float))
    responds = design.responds
    sigma = np.array([r.noise_std for r in design.actuators + design.sensors])
    bank = ResidualBank(design)
    omega = long_run_covariance(bank, meas)
    p = design.model.p
    channels = []
    for kind, j, det in design.detectability:
        col = j if kind == "actuator" else p + j
        with np.errstate(divide="ignore", invalid="ignore"):
            ratios = np.abs(design.gain[:, col]) / sigma
        ok = np.isfinite(ratios) & responds[:, col]
        gap = float(ratios[ok].max()) if ok.any() else 0.0
        names = design.input_names if kind == "actuator" else design.output_names
        detectable = bool(det.detectable) and bool(responds[:, col].any()) and gap > 0
        reason = "" if detectable else (det.reason or "no residual responds to it")
        info = bank_information(bank, omega, kind, j, gap) if detectable else None
        channels.append(Channel(kind, j, names[j], gap, detectable, reason, info))
    confused = design.confused_with()
    labels = [c.label for c in channels]
    order = {(c.target, c.index): i for i, c in enumerate(channels)}
    twins = {}
    for c in channels:
        col = c.index if c.target == "actuator" else p + c.index
        twins[c.label] = frozenset(labels[order[("actuator", k) if k < p else ("sensor", k - p)]]
                                   for k in confused[col])
    nominal = parse_scenario({"plant": plant, "duration": 30.0, "seed": 0,
                              "noise": {"measurement": [float(v) for v in meas],
                                        "process": 0.0}})
    u_rms = np.sqrt(np.mean(simulate(nominal).u_c ** 2, axis=0))
    spacing = spacing if spacing is not None else config.identification.max_samples + 1000
    return EvaluationSetup(plant=plant, dt=dt, channels=tuple(channels), u_rms=u_rms,
                           measurement_std=meas, spacing=int(spacing), lead=lead, twins=twins)


def plan_runs(setup: EvaluationSetup, runs: int, seed: int, *, max_faults: int = 3,
              fnr_range: tuple[float, float] = (0.5, 50.0), noise_spread: float = 1.25,
              kinds: Sequence[str] = FAULT_KINDS, max_eta_change: float = 0.9,
              noise_scale: float = 1.0) -> list[RunSpec]:
    """``runs`` generated runs (module docstring).

    Per run: the number of faults uniform in 0..max_faults (at most the number of detectable
    channels); channels without replacement, uniform among the detectable ones; an actuator's
    kind uniform among the actuator kinds allowed; FNR log-uniform in fnr_range; noise_scale
    log-uniform in [1/noise_spread, noise_spread] times ``noise_scale`` (the drive noisier than
    its config: faults keep their FNR against the drive's noise); a lead-in uniform in
    setup.lead, then one
    onset every setup.spacing samples (plus up to a tenth of it at random); a fault-free run
    lasts lead + spacing. An actuator scale keeps |eta - 1| <= max_eta_change when decreasing
    (eta stays positive) and takes eta = 1 + d otherwise.
    """
    act_kinds = [k for k in kinds if k.startswith("actuator")]
    sens = "sensor_bias" in kinds
    pool = [c for c in setup.detectable
            if (c.target == "actuator" and act_kinds) or (c.target == "sensor" and sens)]
    if not pool:
        raise ValueError("no detectable channel takes the fault kinds asked for")
    children = np.random.SeedSequence(seed).spawn(runs)
    lo, hi = np.log(fnr_range[0]), np.log(fnr_range[1])
    out = []
    for i, child in enumerate(children):
        rng = np.random.default_rng(child)
        n_faults = int(rng.integers(0, min(max_faults, len(pool)) + 1))
        factor = float(np.exp(rng.uniform(-np.log(noise_spread), np.log(noise_spread))))
        run_scale = noise_scale * factor
        lead = int(rng.integers(setup.lead[0], setup.lead[1] + 1))
        chosen = rng.choice(len(pool), size=n_faults, replace=False)
        k = lead
        faults = []
        for c_i in chosen:
            c = pool[int(c_i)]
            fnr = float(np.exp(rng.uniform(lo, hi)))
            size = fnr * run_scale / c.gap  # the constant fault with that FNR
            sign = 1.0 if rng.random() < 0.5 else -1.0
            if c.target == "sensor":
                kind, params = "sensor_bias", {"bias": float(sign * size)}
            else:
                kind = str(act_kinds[int(rng.integers(len(act_kinds)))])
                if kind == "actuator_scale" and setup.u_rms[c.index] > 0:
                    d = size / setup.u_rms[c.index]
                    if sign < 0 and d > max_eta_change:
                        sign = 1.0
                    params = {"eta": float(1.0 + sign * d), "lambda": 0.0}
                else:
                    kind, params = "actuator_bias", {"eta": 1.0, "lambda": float(sign * size)}
            seen = None if c.information is None else fnr * math.sqrt(c.information)
            faults.append(InjectedFault(c.target, c.index, c.name, kind, k, params, fnr, seen))
            k += setup.spacing + int(rng.integers(0, setup.spacing // 10 + 1))
        samples = k if faults else lead + setup.spacing
        out.append(RunSpec(run=i, seed=int(rng.integers(0, 2**31 - 1)), samples=samples,
                           noise_scale=run_scale, faults=tuple(faults)))
    return out


# -- matching ------------------------------------------------------------------------------------

@dataclass(frozen=True)
class FaultOutcome:
    """What the diagnoser made of one injected fault.

    detected_sample : first detection in [onset, next onset) (None: missed); delay = that -
        onset (samples).
    decision : "accepted" (a diagnosis accepted for a detection of this fault), "unexplained"
        (its detections all ended unexplained), "none" (missed, or detected and undecided by the
        end of the run).
    diagnosed : the channel label accepted ("unexplained" / "none" otherwise).
    isolation : "exact" (accepted target and index are the truth), "candidate" (the truth is
        among the accepted event's candidates: a twin with the same signature), "design_twin"
        (another channel the design says has the same signature, not listed as a candidate),
        "wrong", or None when nothing was accepted.
    estimate : the estimates of the accepted (or candidate) channel that matched the truth.
    errors : relative estimate error per parameter (relative_errors); error : their maximum.
    final_estimate, final_errors : the same after the refinements of the accepted channel
        before the next onset (its last "refined" size; a twin candidate's scaled alike).
    named_sample : when a diagnosis of its own named its channel rightly (a "named" event
        naming it or a candidate of it; its acceptance at the latest; None: never).
    excitation_sample : the excitation bound: the first sample at which least squares that
        knows the fault's form and onset settles on the run's commands (the parity method's
        ``excitation_bound``; None: not within max_samples, or a method without it).
    estimate_std : the standard deviation the diagnoser gave each estimate (its event's
        variances; a twin candidate's scaled as its estimate is); within_3_std : whether every
        estimate lies within 3 of them of the truth (None: no estimate to judge).
    """

    fault: InjectedFault
    detected_sample: int | None
    delay: int | None
    decision: str
    diagnosed: str
    isolation: str | None
    accepted_sample: int | None = None
    estimate: dict[str, float] = field(default_factory=dict)
    errors: dict[str, float] = field(default_factory=dict)
    extra_channels: int = 0
    final_estimate: dict[str, float] = field(default_factory=dict)
    final_errors: dict[str, float] = field(default_factory=dict)
    estimate_std: dict[str, float] = field(default_factory=dict)
    named_sample: int | None = None
    excitation_sample: int | None = None

    @property
    def acceptance_over_excitation(self) -> float | None:
        """Onset to acceptance over onset to the excitation bound (None: either missing)."""
        if self.accepted_sample is None or self.excitation_sample is None:
            return None
        return self.diagnosis_delay / max(self.excitation_sample - self.fault.onset_sample, 1)

    @property
    def named_delay(self) -> int | None:
        """Samples from the onset to the fault's channel named (None: never)."""
        return None if self.named_sample is None else self.named_sample - self.fault.onset_sample

    @property
    def within_3_std(self) -> bool | None:
        """Whether each judged estimate (those `relative_errors` judges) lies within 3 of its
        standard deviations of the truth; None without an estimate and its deviation."""
        keys = [k for k in self.errors if k in self.estimate_std]
        if not keys:
            return None
        return all(abs(self.estimate[k] - float(self.fault.params[k]))
                   <= 3.0 * self.estimate_std[k] for k in keys)

    @property
    def detected(self) -> bool:
        return self.detected_sample is not None

    @property
    def correct(self) -> bool:
        return self.isolation in ("exact", "candidate")

    @property
    def error(self) -> float | None:
        return max(self.errors.values()) if self.errors else None

    @property
    def final_error(self) -> float | None:
        return max(self.final_errors.values()) if self.final_errors else None

    @property
    def acceptance_delay(self) -> int | None:
        """Samples from the first detection to the accepted diagnosis (None: none)."""
        if self.accepted_sample is None or self.detected_sample is None:
            return None
        return self.accepted_sample - self.detected_sample

    @property
    def diagnosis_delay(self) -> int | None:
        """Samples from the onset to the accepted diagnosis (None: none)."""
        if self.accepted_sample is None:
            return None
        return self.accepted_sample - self.fault.onset_sample

    def as_dict(self) -> dict[str, Any]:
        out = self.fault.as_dict()
        out.update(detected_sample=self.detected_sample, delay=self.delay,
                   decision=self.decision, diagnosed=self.diagnosed, isolation=self.isolation,
                   accepted_sample=self.accepted_sample, acceptance_delay=self.acceptance_delay,
                   diagnosis_delay=self.diagnosis_delay, named_sample=self.named_sample,
                   named_delay=self.named_delay, excitation_sample=self.excitation_sample,
                   acceptance_over_excitation=self.acceptance_over_excitation,
                   estimate=dict(self.estimate), errors=dict(self.errors), error=self.error,
                   final_estimate=dict(self.final_estimate), final_error=self.final_error,
                   estimate_std=dict(self.estimate_std), within_3_std=self.within_3_std,
                   extra_channels=self.extra_channels)
        return out


@dataclass(frozen=True)
class RunOutcome:
    """One run matched: per-fault outcomes, false alarms ({"sample", "context"}: context
    "before_fault" or "after_accepted"), refinements ({"sample", "channel"}: re-detections of a
    fault already accepted that refined its estimate), and the fault-free samples they were
    counted over."""

    faults: tuple[FaultOutcome, ...]
    false_alarms: tuple[dict, ...]
    fault_free_samples: int
    samples: int
    run: int = 0
    noise_scale: float = 1.0
    refinements: tuple[dict, ...] = ()


def relative_errors(fault: InjectedFault, estimates: dict[str, float]) -> dict[str, float]:
    """|estimate - true| / |true| per parameter: eta always (the true eta is 1 for a bias), lambda
    only when its true value is nonzero, a sensor's bias. Missing estimates are skipped."""
    out = {}
    for key in ("eta", "lambda", "bias"):
        if key not in fault.params or key not in estimates:
            continue
        true = float(fault.params[key])
        if key == "lambda" and true == 0.0:
            continue
        if true == 0.0:
            continue
        out[key] = abs(float(estimates[key]) - true) / abs(true)
    return out


def _std_of(estimate: dict[str, float], matched: FaultEvent) -> dict[str, float]:
    """The standard deviations of ``estimate``: the matched event's own for its parameters;
    for a twin candidate's (the event's estimate times a fixed ratio, possibly of the other
    kind: a bias for a lambda) the event's deviation scaled by the same ratio."""
    out = {}
    for key, value in estimate.items():
        ref = key if key in matched.variances else next(
            (k for k in ("bias", "lambda") if k in matched.variances), None)
        own = matched.estimates.get(ref) if ref is not None else None
        if not own:
            continue
        out[key] = float(np.sqrt(max(matched.variances[ref], 0.0)) * abs(value / own))
    return out


def _isolate(fault: InjectedFault, accepted: list[FaultEvent],
             twins: dict[str, frozenset[str]] | None, names: dict | None
             ) -> tuple[str, str, dict[str, float], int, FaultEvent | None]:
    """(isolation, diagnosed label, matching estimates, extra channels, the accepted event
    that matched) of one decision."""
    def lab(e: FaultEvent) -> str:
        if e.name is not None:
            return f"{'a' if e.target == 'actuator' else 's'}:{e.name}"
        return label(e.target, e.index, names)

    extra = len(accepted) - 1
    for e in accepted:
        if e.target == fault.target and e.index == fault.index:
            return "exact", lab(e), dict(e.estimates), extra, e
    for e in accepted:
        for c in e.candidates:
            if c.get("target") == fault.target and c.get("index") == fault.index:
                return "candidate", lab(e), dict(c.get("estimates", {})), extra, e
    first = accepted[0]
    if twins is not None and lab(first) in twins.get(fault.label, frozenset()):
        return "design_twin", lab(first), {}, extra, None
    return "wrong", lab(first), {}, extra, None


def _refined(estimate: dict[str, float], matched: FaultEvent, exact: bool,
             later: Sequence[FaultEvent]) -> dict[str, float]:
    """The estimate of a fault after the refinements of its accepted channel that follow
    (``later``: "refined" events, in order, each with the updated size of the channel's
    latest fault, which this one is until the next onset): the last size for the channel
    itself (``exact``); for a twin candidate (whose size is the named
    channel's times a fixed ratio) its estimate scaled as the named channel's own size moved."""
    mine = [e for e in later if (e.target, e.index) == (matched.target, matched.index)]
    if not mine:
        return dict(estimate)
    last = mine[-1].estimates
    if exact:
        return dict(last)
    key = next((k for k in ("bias", "lambda") if k in matched.estimates and k in last
                and matched.estimates[k] != 0.0), None)
    if key is None:
        return dict(estimate)
    ratio = float(last[key]) / float(matched.estimates[key])
    return {k: float(v) * ratio for k, v in estimate.items()}


def _explains(fault: InjectedFault, decided: list[FaultEvent]) -> bool:
    """Whether a decision names the fault's channel, itself or among its candidates."""
    return any((e.target, e.index) == (fault.target, fault.index)
               or any((c.get("target"), c.get("index")) == (fault.target, fault.index)
                      for c in e.candidates) for e in decided)


def _fault_outcome(f: InjectedFault, own: list[FaultEvent], accepted_at: int | None, end: int,
                   events: Sequence[FaultEvent], accepted_by: dict[int, list[FaultEvent]],
                   unexplained: set[int], twins: dict[str, frozenset[str]] | None,
                   names: dict | None) -> FaultOutcome:
    """The outcome of fault ``f`` from its ``own`` detections (`match_run`'s rules), accepted
    at ``accepted_at`` (None: never), its segment ending at ``end``."""
    if not own:
        return FaultOutcome(f, None, None, "none", "none", None)
    first = own[0].sample
    mine = {d.sample for d in own}
    named = [e.sample for e in events if e.kind == "named" and e.detected_sample in mine
             and _explains(f, [e])]
    decided = next((d for d in own if d.sample in accepted_by), None)
    if decided is None:
        decision = "unexplained" if any(d.sample in unexplained for d in own) else "none"
        return FaultOutcome(f, first, first - f.onset_sample, decision, decision, None,
                            named_sample=min(named, default=None))
    acc = accepted_by[decided.sample]
    isolation, diagnosed, est, extra, matched = _isolate(f, acc, twins, names)
    std = _std_of(est, matched) if matched is not None else {}
    if matched is not None and matched.kind == "refined":
        # A fault on a channel compensated already, within what the earlier estimate left:
        # the bus cannot tell it from more of the same. Its own size is what the refinement
        # added to the channel's latest fault.
        prior = [e for e in events if e.kind in ("accepted", "refined")
                 and (e.target, e.index) == (matched.target, matched.index)
                 and e.sample < matched.sample]
        if prior:
            scale = {k: v / matched.estimates[k] for k, v in est.items()
                     if matched.estimates.get(k)}
            own = increment(prior[-1].estimates, matched.estimates)
            est = {k: v * scale.get(k, 1.0) for k, v in own.items() if k in est}
    errors = relative_errors(f, est) if isolation in ("exact", "candidate") else {}
    final, final_errors = dict(est), dict(errors)
    if matched is not None and accepted_at is not None:
        later = [e for e in events if e.kind == "refined" and accepted_at < e.sample < end]
        final = _refined(est, matched, isolation == "exact", later)
        final_errors = relative_errors(f, final)
    if isolation in ("exact", "candidate") and accepted_at is not None:
        named.append(accepted_at)
    return FaultOutcome(f, first, first - f.onset_sample, "accepted", diagnosed, isolation,
                        accepted_at, est, errors, extra, final, final_errors, std,
                        min(named, default=None))


def match_run(faults: Sequence[InjectedFault], events: Sequence[FaultEvent], samples: int,
              first_monitored: int = 0, twins: dict[str, frozenset[str]] | None = None,
              names: dict | None = None, run: int = 0, noise_scale: float = 1.0,
              excitation: dict[int, int | None] | None = None) -> RunOutcome:
    """Match one run's events to its injected faults.

    Rules (faults sorted by onset; fault i owns the segment [onset_i, onset_{i+1}) or to the
    end of the run):

    - a detection in fault i's segment before fault i is accepted belongs to fault i (the first
      one gives its detection sample; re-detections after an "unexplained" end stay its own);
    - a detection whose diagnosis refined a fault already accepted (a "refined" event: the
      re-detection of what an inexact estimate left) is a refinement, neither a false alarm nor
      a detection of a new fault; except in a segment whose fault is not accepted yet and which
      the refined channel or one of its candidates is (a second fault on a twin of a channel
      already compensated: the bus cannot tell it from more of the same), where it is that
      fault's detection and decision;
    - a detection before the first onset, or in a segment after that segment's fault was
      accepted, is a false alarm ("before_fault" / "after_accepted");
    - fault i is missed when no detection falls in its segment;
    - its decision is the first detection of its own whose diagnosis was accepted (accepted
      events are tied to detections by detected_sample, so a decision may come after the next
      onset), else "unexplained" if one ended so, else "none";
    - fault-free samples: from first_monitored (the first sample with residuals) to the first
      onset (to the end in a run without faults), plus each segment from its fault's acceptance
      to its end.

    Parameters
    ----------
    faults : the injected faults; events : the diagnoser's events of the run, in order.
    samples : samples in the run. twins : label -> same-signature labels (design).
    names : {"actuator": input names, "sensor": output names} for events without a name.
    excitation : onset sample -> that fault's excitation bound (`FaultOutcome`), where known.
    """
    faults = sorted(faults, key=lambda f: f.onset_sample)
    onsets = [f.onset_sample for f in faults]
    ends = [*onsets[1:], samples]
    detections = sorted((e for e in events if e.kind == "detected"), key=lambda e: e.sample)
    accepted_by: dict[int, list[FaultEvent]] = {}
    unexplained = set()
    refined: dict[int, str] = {}
    for e in events:
        if e.kind == "refined":
            refined[e.detected_sample] = label(e.target, e.index, names)
        if e.kind in ("accepted", "refined"):
            accepted_by.setdefault(e.detected_sample, []).append(e)
        elif e.kind == "unexplained":
            unexplained.add(e.detected_sample)
    own: list[list[FaultEvent]] = [[] for _ in faults]
    accepted_at: list[int | None] = [None] * len(faults)
    false_alarms, refinements = [], []
    for d in detections:
        seg = next((i for i in range(len(faults)) if onsets[i] <= d.sample < ends[i]), None)
        after = seg is not None and accepted_at[seg] is not None and d.sample >= accepted_at[seg]
        if d.sample in refined and (seg is None or after or not _explains(
                faults[seg], accepted_by[d.sample])):
            refinements.append({"sample": d.sample, "channel": refined[d.sample]})
            continue
        if seg is None:
            false_alarms.append({"sample": d.sample, "context": "before_fault"})
            continue
        if after:
            false_alarms.append({"sample": d.sample, "context": "after_accepted"})
            continue
        own[seg].append(d)
        acc = accepted_by.get(d.sample)
        if acc and accepted_at[seg] is None:
            accepted_at[seg] = min(e.accepted_sample if e.accepted_sample is not None
                                   else e.sample for e in acc)
    outcomes = [replace(_fault_outcome(f, own[i], accepted_at[i], ends[i], events, accepted_by,
                                       unexplained, twins, names),
                        excitation_sample=(excitation or {}).get(f.onset_sample))
                for i, f in enumerate(faults)]
    if faults:
        free = max(0, onsets[0] - first_monitored)
        for i in range(len(faults)):
            if accepted_at[i] is not None:
                free += max(0, ends[i] - max(accepted_at[i], first_monitored))
    else:
        free = max(0, samples - first_monitored)
    return RunOutcome(tuple(outcomes), tuple(false_alarms), free, samples, run, noise_scale,
                      tuple(refinements))


# -- metrics -------------------------------------------------------------------------------------

def _stats(values: Sequence[float]) -> dict[str, float | None]:
    if not values:
        return {"mean": None, "median": None, "p95": None, "max": None}
    a = np.asarray(values, dtype=float)
    return {"mean": float(a.mean()), "median": float(np.median(a)),
            "p95": float(np.percentile(a, 95)), "max": float(a.max())}


def _ratio(num: int, den: int) -> float | None:
    return num / den if den else None


INFORMATION_RCOND = 1e-9
"""Eigenvalues of the residuals' long-run covariance below this share of the largest count as
none: the bank's residuals are linear in fewer noises than there are residuals."""


def bank_information(bank: ResidualBank, long_run: np.ndarray, target: str, index: int,
                     gap: float) -> float:
    """The information per sample a constant fault of FNR 1 on one channel gives the whole
    residual bank in the long run: mu' Omega^+ mu, mu the steady change of the normalised
    residuals (m,) under the fault of size 1 / ``gap``, Omega (m, m) their long-run covariance
    under white measurement noise (``long_run``: thresholds.long_run_covariance). The KL rate of
    the change is half of it times FNR^2: against 1/2 FNR^2 for the white residual `cusum_bound`
    assumes, it says how much of the fault's energy the residuals carry once their correlation
    in time and across the bank is counted. NaN for a channel of no gap.

    >>> from canfdi.core.design import design_bank
    >>> from canfdi.core.model import StateSpace
    >>> from canfdi.methods.parity.thresholds import long_run_covariance
    >>> bank = ResidualBank(design_bank(StateSpace(A=[[0.5]], B=[[1.0]], C=[[1.0], [1.0]]),
    ...                                 ["u"], ["y0", "y1"]))
    >>> omega = long_run_covariance(bank, np.ones(2))
    >>> gap = float(np.max(np.abs(steady_response(bank, "sensor", 0))))  # s:y1 sees it best
    >>> round(bank_information(bank, omega, "sensor", 0, gap), 6)
    5.0

    (Its residuals, y(k) - 0.5 y(k - 1) - u(k - 1) and alike, hold half of each noise sample
    in the long run: a long-run variance of a fifth of their variance, so five times the
    information a white residual would carry.)
    """
    if not gap > 0.0:
        return math.nan
    mu = steady_response(bank, target, index) / gap
    w, v = np.linalg.eigh(long_run)
    keep = w > INFORMATION_RCOND * max(float(w.max()), 0.0)
    coef = v[:, keep].T @ mu
    return float(np.sum(coef * coef / w[keep]))


def cusum_bound(fnr: float, false_alarm_interval: float) -> float:
    """Samples a CUSUM tuned to a fault's mean change needs to detect it with false alarms
    ``false_alarm_interval`` samples apart: ln(interval) / (fnr^2 / 2), Lorden's asymptotic
    bound (Basseville and Nikiforov, ch. 5), the information a change of ``fnr`` noise standard
    deviations in white Gaussian noise brings per sample being fnr^2 / 2. No detector of that
    change at that interval is faster on average; NaN for a fault of no size."""
    if not (fnr > 0.0 and false_alarm_interval > 1.0):
        return math.nan
    return math.log(false_alarm_interval) / (fnr * fnr / 2.0)


def bank_bound(bank_fnr: float, false_alarm_interval: float) -> float:
    """`cusum_bound` at the FNR the parity bank sees (``bank_fnr``), floored at one sample: no
    detection comes before the faulty sample itself, and where the residuals difference the
    noise away (the VTOL's carry 400 to 26,000 times FNR^2 in the long run) Lorden's
    asymptotic figure falls far below it."""
    return max(cusum_bound(bank_fnr, false_alarm_interval), 1.0)


def _over_bound(detected: Sequence[FaultOutcome], bound: Callable[[FaultOutcome], float | None]
                ) -> tuple[list[float], dict[str, float | None]]:
    """The finite bounds of the detected faults (``bound``: None or NaN where there is none)
    and the statistics of each detection delay over its bound."""
    pairs = [(o.delay, b) for o in detected if (b := bound(o)) is not None and math.isfinite(b)]
    return [b for _, b in pairs], _stats([max(d, 0) / b for d, b in pairs])


def _summary(outs: Sequence[FaultOutcome], false_alarm_interval: float | None = None
             ) -> dict[str, Any]:
    """Detection, delay, isolation and error figures of a set of fault outcomes; with the
    detectors' ``false_alarm_interval``, each detection delay over its fault's `cusum_bound`,
    at its FNR (the whole fault's energy) and at the FNR the bank sees (``bank_fnr``)."""
    n = len(outs)
    detected = [o for o in outs if o.detected]
    accepted = [o for o in outs if o.decision == "accepted"]
    timed = [o for o in accepted if o.accepted_sample is not None]
    to_accept = _stats([o.acceptance_delay for o in timed])
    to_diagnose = _stats([o.diagnosis_delay for o in timed])
    to_name = _stats([o.named_delay for o in outs if o.named_delay is not None])
    over_excitation = _stats([o.acceptance_over_excitation for o in outs
                              if o.correct and o.acceptance_over_excitation is not None])
    fai = false_alarm_interval
    bounds, over = _over_bound(detected if fai else [],
                               lambda o: cusum_bound(o.fault.fnr, fai))
    bank, over_bank = _over_bound(detected if fai else [],
                                  lambda o: None if o.fault.bank_fnr is None
                                  else bank_bound(o.fault.bank_fnr, fai))
    iso = {k: sum(o.isolation == k for o in accepted)
           for k in ("exact", "candidate", "design_twin", "wrong")}
    correct = iso["exact"] + iso["candidate"]
    delays = _stats([o.delay for o in detected])
    errors = _stats([o.error for o in outs if o.error is not None])
    final = _stats([o.final_error for o in outs if o.final_error is not None])
    judged = [o.within_3_std for o in outs if o.within_3_std is not None]
    return {
        "faults": n, "detected": len(detected), "missed": n - len(detected),
        "detection_rate": _ratio(len(detected), n),
        "delay_mean_samples": delays["mean"], "delay_median_samples": delays["median"],
        "delay_p95_samples": delays["p95"], "delay_max_samples": delays["max"],
        "cusum_bound_median_samples": _stats(bounds)["median"],
        "delay_over_bound_median": over["median"], "delay_over_bound_p95": over["p95"],
        "bank_bound_median_samples": _stats(bank)["median"],
        "delay_over_bank_bound_median": over_bank["median"],
        "delay_over_bank_bound_p95": over_bank["p95"],
        "acceptance_delay_median_samples": to_accept["median"],
        "acceptance_delay_p95_samples": to_accept["p95"],
        "diagnosis_delay_median_samples": to_diagnose["median"],
        "diagnosis_delay_p95_samples": to_diagnose["p95"],
        "named_delay_median_samples": to_name["median"],
        "named_delay_p95_samples": to_name["p95"],
        "acceptance_over_excitation_median": over_excitation["median"],
        "acceptance_over_excitation_p95": over_excitation["p95"],
        "accepted": len(accepted),
        "unexplained": sum(o.decision == "unexplained" for o in outs),
        "undecided": sum(o.detected and o.decision == "none" for o in outs),
        "isolation": iso,
        "isolation_accuracy": _ratio(correct, len(accepted)),
        "isolation_accuracy_exact": _ratio(iso["exact"], len(accepted)),
        "isolated_correctly_of_all": _ratio(correct, n),
        "estimate_error_median": errors["median"], "estimate_error_p95": errors["p95"],
        "final_estimate_error_median": final["median"],
        "final_estimate_error_p95": final["p95"],
        "estimate_errors": sum(o.error is not None for o in outs),
        "estimates_within_3_std": _ratio(sum(judged), len(judged)),
        "estimates_judged": len(judged),
    }


def aggregate(runs: Sequence[RunOutcome], dt: float,
              bins: Sequence[float] = FNR_BINS, false_alarm_interval: float | None = None
              ) -> dict[str, Any]:
    """The metrics of matched runs.

    detection_rate = detected / faults; delays over detected faults (numpy percentile, linear
    interpolation); isolation_accuracy = correctly isolated (exact or among the candidates) /
    faults with an accepted diagnosis (isolation_accuracy_exact: exact only); confusion[true
    channel][diagnosed channel, "unexplained" or "none"] counts every fault once;
    false_alarms_per_hour = false alarms / (fault-free samples * dt / 3600);
    estimate_error_* over the correctly isolated faults, each fault's error being the largest
    relative error of its parameters. by_fnr: the same per fault-to-noise bin [lo, hi) (faults
    below the first edge or at/above the last go to the end bins); by_kind: per fault kind.
    """
    outs = [o for r in runs for o in r.faults]
    out: dict[str, Any] = {"runs": len(runs),
                           "runs_fault_free": sum(not r.faults for r in runs)}
    out.update(_summary(outs, false_alarm_interval))
    params: dict[str, list[float]] = {}
    for o in outs:
        for k, v in o.errors.items():
            params.setdefault(k, []).append(v)
    out["estimate_error_by_parameter"] = {k: _stats(v) for k, v in sorted(params.items())}
    rows = sorted({o.fault.label for o in outs})
    cols = sorted(({o.diagnosed for o in outs} | set(rows)) - {"unexplained", "none"})
    cols += ["unexplained", "none"]
    confusion = {r: {c: 0 for c in cols} for r in rows}
    for o in outs:
        confusion[o.fault.label][o.diagnosed] += 1
    out["confusion"] = confusion
    fa = [a for r in runs for a in r.false_alarms]
    free = sum(r.fault_free_samples for r in runs)
    hours = free * dt / 3600.0
    out.update(
        false_alarms=len(fa),
        false_alarms_before_fault=sum(a["context"] == "before_fault" for a in fa),
        false_alarms_after_accepted=sum(a["context"] == "after_accepted" for a in fa),
        fault_free_samples=free, fault_free_hours=hours,
        false_alarms_per_hour=(len(fa) / hours) if hours > 0 else None,
        refinements=sum(len(r.refinements) for r in runs),
        samples=sum(r.samples for r in runs),
    )
    edges = list(bins)
    by_fnr = []
    for b in range(len(edges) - 1):
        lo, hi = edges[b], edges[b + 1]
        sel = [o for o in outs
               if (lo <= o.fault.fnr < hi) or (b == 0 and o.fault.fnr < lo)
               or (b == len(edges) - 2 and o.fault.fnr >= hi)]
        entry = {"fnr_lo": lo, "fnr_hi": hi}
        entry.update(_summary(sel, false_alarm_interval))
        by_fnr.append(entry)
    out["by_fnr"] = by_fnr
    out["by_kind"] = {k: _summary([o for o in outs if o.fault.kind == k], false_alarm_interval)
                      for k in FAULT_KINDS if any(o.fault.kind == k for o in outs)}
    out["by_channel"] = {c: _summary([o for o in outs if o.fault.label == c],
                                     false_alarm_interval) for c in rows}
    return out


# -- running -------------------------------------------------------------------------------------

Mapper = Callable[[Callable[..., Any], Sequence[Any], Sequence[Any]], Iterable[tuple[int, Any]]]
"""How the runs are spread: ``mapper(fn, items, shared)`` yields ``(index, fn(item,
*shared))`` for every item, in any order (canfdi.tools.fleet.map_tasks on a Dask client: a
local cluster or a scheduler's workers). The default runs them here, in order."""


def _serial(fn: Callable[..., Any], items: Sequence[Any], shared: Sequence[Any]
            ) -> Iterator[tuple[int, Any]]:
    for i, item in enumerate(items):
        yield i, fn(item, *shared)


def run_one(spec: RunSpec, setup: EvaluationSetup, base, names: dict[str, list[str]],
            preprocess: Callable[[np.ndarray, np.ndarray], tuple] | None = None,
            block: int = 2000) -> RunOutcome:
    """One run: simulate the spec's scenario, diagnose it with a fresh copy of ``base`` (the
    config's diagnoser, built and calibrated once; its design shared, not copied) through
    ``update_block`` in blocks of ``block`` samples, match the events to the injected faults.
    A pure function of its arguments (the scenario is seeded): the same outcome in any
    process."""
    from canfdi.firmware_sim.scenario import parse_scenario
    from canfdi.firmware_sim.simulate import simulate

    design = getattr(base, "design", None)
    memo = {id(design): design} if design is not None else {}
    dt_ns = round(setup.dt * 1e9)
    scenario = parse_scenario(spec.scenario_dict(setup.plant, setup.dt, setup.measurement_std))
    chunk = simulate(scenario)
    U, Z = chunk.u_c, chunk.z
    if preprocess is not None:
        U, Z = preprocess(U, Z)
    dg = copy.deepcopy(base, memo)
    bound = getattr(base, "excitation_bound", None)
    excitation = {} if bound is None else {
        f.onset_sample: bound(f.kind, f.index, f.params, f.onset_sample, U, spec.noise_scale)
        for f in spec.faults}
    events: list[FaultEvent] = []
    first_monitored = None
    for i in range(0, len(chunk.k), block):
        k = chunk.k[i: i + block]
        res = dg.update_block(k, k * dt_ns, U[i: i + block], Z[i: i + block])
        events.extend(res.events)
        if first_monitored is None:
            have = np.flatnonzero(~np.isnan(res.residuals).all(axis=1))
            if len(have):
                first_monitored = int(k[have[0]])
    return match_run(spec.faults, events, len(chunk.k),
                     first_monitored if first_monitored is not None else len(chunk.k),
                     setup.twins, names, spec.run, spec.noise_scale, excitation)


def run_evaluation(config: MonitorConfig, setup: EvaluationSetup, specs: Sequence[RunSpec], *,
                   block: int = 2000,
                   preprocess: Callable[[np.ndarray, np.ndarray], tuple] | None = None,
                   progress: Callable[[str], None] = lambda msg: None,
                   diagnoser=None, mapper: Mapper | None = None) -> list[RunOutcome]:
    """Simulate each run and diagnose it with a fresh copy of the config's diagnoser (built
    and calibrated once) through ``update_block`` in blocks of ``block`` samples (`run_one`),
    here or spread by ``mapper`` (`Mapper`); the outcomes in the specs' order, the same
    either way.

    preprocess(U, Z) -> (U, Z) is applied to the simulated commands and measurements first
    (the CLI rounds them to the DBC's resolution, as the bus does)."""
    from canfdi.methods import build_diagnoser

    base = diagnoser if diagnoser is not None else build_diagnoser(config)
    names = {"actuator": list(config.inputs), "sensor": list(config.outputs)}
    found: list[RunOutcome | None] = [None] * len(specs)
    done: list[RunOutcome] = []
    last = time.monotonic()
    for n, (i, outcome) in enumerate((mapper or _serial)(
            run_one, specs, (setup, base, names, preprocess, block))):
        found[i] = outcome
        done.append(outcome)
        now = time.monotonic()
        if now - last >= 2.0 or n == len(specs) - 1:
            last = now
            faults = sum(len(o.faults) for o in done)
            det = sum(f.detected for o in done for f in o.faults)
            ok = sum(f.correct for o in done for f in o.faults)
            fa = sum(len(o.false_alarms) for o in done)
            progress(f"run {n + 1}/{len(specs)}: {faults} faults, {det} detected, "
                     f"{ok} isolated, {fa} false alarms")
    return found  # type: ignore[return-value]


def default_config(plant: str, method: str, directory: Path) -> Path | None:
    """The first config (by name) in ``directory`` for the emulated ``plant`` (its signal names)
    and ``method``: what `canfdi evaluate --plant P --method M` runs without --config."""
    from canfdi.firmware_sim.plants import make_plant

    emulated = make_plant(plant)
    for path in sorted(directory.glob("*.yaml"), key=lambda p: (len(p.stem), p.stem)):
        try:
            data = yaml.safe_load(path.read_text())
        except (OSError, yaml.YAMLError):
            continue
        if not isinstance(data, dict) or data.get("method", DEFAULT) != method:
            continue
        signals = data.get("signals") or {}
        if (tuple(signals.get("inputs") or ()), tuple(signals.get("outputs") or ())) == (
                emulated.input_names, emulated.output_names):
            return path
    return None


def evaluate(config: MonitorConfig, plant: str, *, runs: int, seed: int, max_faults: int = 3,
             fnr: tuple[float, float] = (0.5, 50.0), noise_spread: float = 1.25,
             kinds: Sequence[str] | None = None, spacing: int | None = None,
             quantize: bool = True, noise_scale: float = 1.0,
             monitor: MonitorConfig | None = None,
             progress: Callable[[str], None] = lambda msg: None,
             mapper: Mapper | None = None, kernel: Kernel | None = None) -> dict[str, Any]:
    """`canfdi evaluate`: plan ``runs`` scenarios for the emulated ``plant``, simulate each,
    diagnose it with a copy of the config's diagnoser and aggregate the metrics (the JSON
    object the CLI prints). kinds default to the config's method's fault model; values are
    rounded to the DBC's resolution unless ``quantize`` is False. ``noise_scale``: the drive's
    noise is that many times the config's (the scenarios come from ``config``); ``monitor``:
    the config of the monitor evaluated, when it is not ``config`` (one calibrated on the
    drive, say); ``mapper``: how the runs are spread (`Mapper`; default here, one by one);
    ``kernel``: what the diagnoser's block forms run on (canfdi.core.kernel; by default the
    one a command would run on)."""
    from canfdi.bus.dbc import BusMap
    from canfdi.core import kernel as kernels
    from canfdi.methods import build_diagnoser, get

    progress(f"designing and calibrating the {config.method} monitor")
    kinds = list(kinds) if kinds is not None else list(get(config.method).fault_kinds)
    setup = setup_from_config(config, plant, spacing=spacing)
    specs = plan_runs(setup, runs, seed, max_faults=max_faults, fnr_range=tuple(fnr),
                      noise_spread=noise_spread, kinds=kinds, noise_scale=noise_scale)
    base = build_diagnoser(monitor or config)
    kernel = kernel or kernels.resolve()
    kernel.use_on(base)
    preprocess = None
    if quantize:
        try:
            preprocess = BusMap.from_config(config).quantize
        except (ValueError, OSError) as exc:
            progress(f"no bus resolution ({exc}): exact values")
    total = sum(s.samples for s in specs)
    progress(f"{len(specs)} runs, {sum(len(s.faults) for s in specs)} faults, "
             f"{total:,} samples")
    outcomes = run_evaluation(config, setup, specs, preprocess=preprocess, progress=progress,
                              diagnoser=base, mapper=mapper)
    interval = (monitor or config).detection.false_alarm_interval
    metrics = aggregate(outcomes, setup.dt, false_alarm_interval=interval)
    result: dict[str, Any] = {
        "plant": plant, "method": config.method, "seed": seed,
        "kernel": kernel.name,
        "settings": {"max_faults": max_faults, "fnr_range": list(fnr),
                     "noise_spread": noise_spread, "noise_scale": noise_scale,
                     "kinds": kinds,
                     "spacing_samples": setup.spacing, "lead_samples": list(setup.lead),
                     "quantized": preprocess is not None, "dt": setup.dt},
        "channels": [{"channel": c.label, "target": c.target, "index": c.index,
                      "unit_fault_to_noise": c.gap, "detectable": c.detectable,
                      "reason": c.reason,
                      "bank_information": c.information} for c in setup.channels],
        "undetectable": [c.label for c in setup.channels if not c.detectable],
    }
    result.update(metrics)
    result["fault_list"] = [dict(f.as_dict(), run=o.run, noise_scale=o.noise_scale,
                                 cusum_bound=cusum_bound(f.fault.fnr, interval),
                                 bank_bound=None if f.fault.bank_fnr is None
                                 else bank_bound(f.fault.bank_fnr, interval))
                            for o in outcomes for f in o.faults]
    result["false_alarm_list"] = [dict(a, run=o.run) for o in outcomes for a in o.false_alarms]
    return result

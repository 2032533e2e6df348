"""Records passed between the layers: frozen, numbers only, integer-nanosecond timestamps."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from canfdi.core.identify import chi2_sigma

__all__ = [
    "OWN_FAULT_SIGMA",
    "BlockResult",
    "Compensation",
    "FaultEvent",
    "Sample",
    "compensate",
    "compensated",
    "fault_onset",
    "fold",
    "increment",
    "latest_fault",
]


@dataclass(frozen=True)
class Sample:
    """One control period's decoded values.

    k : unwrapped sample index (the drive's alive counter k mod 256, unwrapped).
    timestamp_ns : arrival time of the frame that completed the sample (ns since the epoch).
    u : (p,) commanded inputs u_c(k), in the model's input order.
    z : (q,) measured outputs z(k), in the model's output order.
    gap : samples lost or broken just before this one (0 when the previous sample was k-1);
        the diagnoser restarts its data windows after a gap.

    Examples
    --------
    >>> sample = Sample(k=12, timestamp_ns=1_700_000_000_000_000_000, u=np.array([24.0]),
    ...                 z=np.array([1.9, 10.2, 100.5]), gap=2)
    >>> sample.k - sample.gap - 1, sample.z.shape
    (9, (3,))
    """

    k: int
    timestamp_ns: int
    u: np.ndarray
    z: np.ndarray
    gap: int = 0


@dataclass(frozen=True)
class FaultEvent:
    """Something the diagnoser concluded at sample ``sample``.

    kind : "detected" (a residual changed), "named" (the sequential test names the faulty
        component, or its look-alike set, before its form and size are known: its estimates
        are the size it acts with at the present operating point, an actuator's as an offset,
        and ``undecided`` says what is not known yet), "accepted" (a fault isolated and
        identified, folded into the compensation; its estimates are its own size, also on
        a channel compensated already), "refined" (what an accepted estimate left, found by a
        re-detection or by the tracking of accepted faults: its estimates are the updated
        size of the channel's latest fault, see `fold`), or "unexplained" (no hypothesis
        fitted within max_samples). The monitor adds "mismatch",
        "quiet" and "matched" (canfdi.core.watchdog: a residual's noise rose above its
        calibrated value, fell below it, or came back; estimates then hold each residual's std
        ratio), "taught" (teach-in
        learned the noise: estimates hold each sensor's std) and "teach_failed" (it could
        not: the reason in candidates).
    target : "actuator" or "sensor" for accepted faults, None otherwise.
    index, name : 0-based channel and its name (accepted faults).
    estimates : {"eta", "lambda"} for actuators, {"bias"} for sensors.
    variances : the estimates' variances, same keys.
    onset_sample : estimated fault onset k_f; detected_sample : k_d; accepted_sample : k_a.
    candidates : for a fault whose residual signature other channels share, every
        (target, index, name, estimates) that explains the data equally well.
    residuals : names of the residuals in alarm (detected events).
    undecided : what a "named" fault still waits for: "form" (an actuator's scale or bias:
        until the command moves, a scale acts as an offset), "size" (its size not yet known
        within the acceptance's precision).
    drive : the drive it concerns (several drives on one bus: the monitor sets it; a
        diagnoser, which sees one drive, leaves it None).

    Examples
    --------
    >>> event = FaultEvent("accepted", 1200, 0, target="sensor", index=1, name="i_a",
    ...                    estimates={"bias": 0.5}, onset_sample=1000)
    >>> event.as_dict()["estimates"], event.as_dict()["residuals"]
    ({'bias': 0.5}, [])
    """

    kind: str
    sample: int
    timestamp_ns: int
    target: str | None = None
    index: int | None = None
    name: str | None = None
    estimates: dict[str, float] = field(default_factory=dict)
    variances: dict[str, float] = field(default_factory=dict)
    onset_sample: int | None = None
    detected_sample: int | None = None
    accepted_sample: int | None = None
    candidates: tuple[dict, ...] = ()
    residuals: tuple[str, ...] = ()
    drive: str | None = None
    undecided: tuple[str, ...] = ()

    def as_dict(self) -> dict:
        """JSON-ready form."""
        out = {k: getattr(self, k) for k in self.__dataclass_fields__}
        out["candidates"] = list(self.candidates)
        out["residuals"] = list(self.residuals)
        out["undecided"] = list(self.undecided)
        return out


@dataclass(frozen=True)
class BlockResult:
    """What a diagnoser's ``update_block`` did for N samples.

    events : the events, in order.
    residuals, normalized : (N, m), NaN where a sample had no residual (window filling, lost
        values).
    statistic : (N, m) each residual's detection statistic after each sample.

    Examples
    --------
    >>> result = BlockResult(events=[], residuals=np.zeros((4, 2)), normalized=np.zeros((4, 2)),
    ...                      statistic=np.zeros((4, 2)))
    >>> len(result.events), result.statistic.shape
    (0, (4, 2))
    """

    events: list[FaultEvent]
    residuals: np.ndarray
    normalized: np.ndarray
    statistic: np.ndarray


@dataclass(frozen=True)
class Compensation:
    """An accepted fault folded into the data from its onset on (the output-error paper's Section
    3.3).

    target : "actuator" (the command becomes ``eta u_c + lam``) or "sensor" (the measurement
        becomes ``z - bias``).
    index : the channel, 0-based; onset : the first sample it applies to.
    eta, lam, bias : the accepted estimates (``lam`` is the paper's lambda).
    scale : whether the method estimates eta (its events report it); False: eta is 1.
    variances : the estimates' variances, keyed as `as_dict` names them ({}: unknown).
    correction : False for a fault of its own; True for a correction of the channel's latest
        fault (what its estimate left, found later: `fold`).
    fixed : the parameters its hypothesis held rather than estimated (("eta",): an actuator's
        bias accepted alone, eta = 1 while the command had not moved enough to tell a scale;
        its variance is what the data left it).

    Examples
    --------
    >>> fix = Compensation("actuator", 0, onset=100, eta=0.8, lam=2.0, scale=True)
    >>> fix.as_dict()
    {'target': 'actuator', 'index': 0, 'onset': 100, 'eta': 0.8, 'lambda': 2.0}
    >>> Compensation("sensor", 1, onset=50, bias=0.3).as_dict()
    {'target': 'sensor', 'index': 1, 'onset': 50, 'bias': 0.3}
    """

    target: str
    index: int
    onset: int
    eta: float = 1.0
    lam: float = 0.0
    bias: float = 0.0
    scale: bool = False
    variances: dict[str, float] = field(default_factory=dict, compare=False)
    correction: bool = False
    fixed: tuple[str, ...] = ()

    def as_dict(self) -> dict[str, float | int | str]:
        """{"target", "index", "onset"} and the estimates, named as in FaultEvent."""
        out: dict[str, float | int | str] = {"target": self.target, "index": self.index,
                                             "onset": self.onset}
        out.update(self.estimates)
        return out

    @property
    def estimates(self) -> dict[str, float]:
        """The estimates, named as in FaultEvent: {"bias"} for a sensor, {"eta", "lambda"} for
        an actuator ({"lambda"} alone for a method without the scale)."""
        if self.target == "sensor":
            return {"bias": self.bias}
        return {"eta": self.eta, "lambda": self.lam} if self.scale else {"lambda": self.lam}


def compensate(entries: tuple[Compensation, ...] | list[Compensation], k: np.ndarray,
               Z: np.ndarray | None, U: np.ndarray | None
               ) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Samples with the accepted faults undone, in the order they were accepted.

    Parameters
    ----------
    entries : the compensation, oldest first.
    k : (N,) sample indices; Z : (N, q) measurements; U : (N, p) commands (either may be None:
        it is left out).

    Returns
    -------
    (Z, U) compensated: new arrays (the inputs are not modified), None where given None.
    """
    Z = None if Z is None else np.array(Z, dtype=float)
    U = None if U is None else np.array(U, dtype=float)
    for c in entries:
        out = Z if c.target == "sensor" else U
        if out is None:
            continue
        on = k >= c.onset
        if not on.any():
            continue
        if c.target == "sensor":
            out[on, c.index] -= c.bias
        else:
            out[on, c.index] = c.eta * out[on, c.index] + c.lam
    return Z, U


def _on_channel(entries: list[Compensation] | tuple[Compensation, ...], target: str,
                index: int) -> list[Compensation]:
    """The entries of one channel, oldest first."""
    return [c for c in entries if c.target == target and c.index == index]


def _composed(same: list[Compensation]) -> dict[str, float]:
    """The entries of one channel composed in the order `compensate` applies them: sensor
    biases add; an actuator's ``eta2 (eta1 u + lam1) + lam2`` is eta = eta1 eta2,
    lambda = eta2 lam1 + lam2. Keys as `Compensation.estimates`."""
    eta, lam, bias = 1.0, 0.0, 0.0
    for c in same:
        bias += c.bias
        eta, lam = c.eta * eta, c.eta * lam + c.lam
    out = Compensation(same[0].target, same[0].index, same[0].onset, eta=eta, lam=lam,
                       bias=bias, scale=any(c.scale for c in same)).estimates
    return {key: float(v) for key, v in out.items()}


def increment(before: dict[str, float], after: dict[str, float]) -> dict[str, float]:
    """What was composed onto a channel's estimate ``before`` to give ``after`` (the inverse
    of `_composed`, keys as `Compensation.estimates`): biases and lambdas subtract; an
    actuator's ``eta2 (eta1 u + lam1) + lam2`` has eta2 = eta / eta1, lam2 = lam - eta2 lam1.

    >>> increment({"bias": 0.9}, {"bias": 1.1})["bias"] == 1.1 - 0.9
    True
    >>> increment({"eta": 0.5, "lambda": 1.0}, {"eta": 0.25, "lambda": 0.0})
    {'lambda': -0.5, 'eta': 0.5}
    """
    if "bias" in after:
        return {"bias": after["bias"] - before.get("bias", 0.0)}
    eta1, lam1 = before.get("eta", 1.0), before.get("lambda", 0.0)
    eta2 = after.get("eta", 1.0) / eta1 if eta1 else 1.0
    out = {"lambda": after.get("lambda", 0.0) - eta2 * lam1}
    if "eta" in after:
        out["eta"] = eta2
    return out


def compensated(entries: list[Compensation] | tuple[Compensation, ...], target: str,
                index: int) -> dict[str, float]:
    """The total fault already compensated on one channel ({} when none): every entry on it
    composed (`_composed`). A refinement's precision is judged against it: what matters is
    the total's accuracy, not the small increment's.

    >>> comp = [Compensation("sensor", 1, 100, bias=0.9), Compensation("sensor", 1, 900, bias=0.2)]
    >>> compensated(comp, "sensor", 1), compensated(comp, "sensor", 0)
    ({'bias': 1.1}, {})
    """
    same = _on_channel(entries, target, index)
    return _composed(same) if same else {}


def latest_fault(entries: list[Compensation] | tuple[Compensation, ...], target: str,
                 index: int) -> dict[str, float]:
    """The size of the channel's latest fault with the corrections found for it since ({}
    when the channel has none): the entries from its latest fault on, composed.

    >>> comp = [Compensation("sensor", 1, 100, bias=0.9), Compensation("sensor", 1, 900, bias=0.2),
    ...         Compensation("sensor", 1, 900, bias=-0.01, correction=True)]
    >>> {k: round(v, 6) for k, v in latest_fault(comp, "sensor", 1).items()}
    {'bias': 0.19}
    """
    same = _on_channel(entries, target, index)
    starts = [i for i, c in enumerate(same) if not c.correction]
    return _composed(same[starts[-1] if starts else 0:]) if same else {}


def fault_onset(entries: list[Compensation] | tuple[Compensation, ...], target: str,
                index: int) -> int | None:
    """The onset of the channel's latest fault (None when the channel has none): a diagnosis
    that dates its change there finds what that fault's estimate left, not a new fault.

    >>> comp = [Compensation("sensor", 1, 100, bias=0.9), Compensation("sensor", 1, 900, bias=0.2),
    ...         Compensation("sensor", 1, 100, bias=0.01, correction=True)]
    >>> fault_onset(comp, "sensor", 1), fault_onset(comp, "sensor", 0)
    (900, None)
    """
    same = [c for c in _on_channel(entries, target, index) if not c.correction]
    return same[-1].onset if same else None


OWN_FAULT_SIGMA = 4.0
"""The level (in standard deviations) at which a diagnosis on a compensated channel is a fault
of its own. What an estimate left lies within 3 of its standard deviations 99.7 % of the time
when they are honest; `canfdi evaluate` finds 91-99 % of the shipped methods' estimates within
3 of theirs (estimates_within_3_std), and at 3 the uio method took two leftovers of 3.3 and
3.4 of them for new faults in 100 VTOL runs. 4 holds them; a second fault that small is
refined into the first (its size then the difference of the two events)."""


def _own_fault(new: Compensation, latest: Compensation) -> bool:
    """Whether a diagnosis on a compensated channel is a fault of its own rather than what the
    channel's latest estimate left: its parameters relative to the compensation (eta - 1,
    lambda; a bias) differ from none significantly (chi-square at the `OWN_FAULT_SIGMA`
    level), their variance the diagnosis' own plus the channel's latest estimate's
    (``latest``: what an estimate leaves is distributed as its error). An estimate that held a
    parameter fixed (`Compensation.fixed`: an actuator's eta at 1, a bias taken while the
    command had not moved enough to tell it from a scale) did not estimate it: a diagnosis
    that now estimates it completes that fault's form (its offset, measured against the
    compensation, moves with the scale it finds: their joint uncertainty, not each one's,
    would judge it)."""
    known = latest.variances
    delta = {"eta": new.eta - 1.0, "lambda": new.lam, "bias": new.bias}
    stat, d = 0.0, 0
    for key in new.estimates:
        if key in new.fixed:  # held, not estimated: no evidence either way
            continue
        own = new.variances.get(key, 0.0)
        if key in latest.fixed and own > 0.0:
            return False
        var = own + known.get(key, 0.0)
        if var > 0.0 and np.isfinite(var):
            stat += delta[key] ** 2 / var
            d += 1
    return d > 0 and stat > chi2_sigma(d, OWN_FAULT_SIGMA)


def fold(entries: list[Compensation], new: Compensation) -> tuple[str, dict[str, float],
                                                                 dict[str, float]]:
    """Append an estimate to the compensation; (kind, estimates, variances) for its event:

    - a channel not compensated yet: ("accepted", the fault's own estimates and variances);
    - a diagnosis on a channel compensated already (``new.correction`` False): a fault of
      its own when its parameters differ from none significantly (`_own_fault`), then
      ("accepted", its own size, its variances plus the earlier estimate's: it is measured
      against that estimate); otherwise what the channel's latest estimate left (the output-error
      paper
      Section 3.3: a later residual of the same fault refines it), ("refined", that fault's
      updated size: `latest_fault`, the variances of the correction);
    - a correction (``new.correction`` True, a tracker's): ("refined", as above).

    So consecutive faults on one channel, or on channels whose signatures the residuals cannot
    tell apart (the name of the group is the same), are each reported with their own size.

    Examples
    --------
    >>> comp = [Compensation("sensor", 1, onset=100, bias=0.9, variances={"bias": 1e-4})]
    >>> fold(comp, Compensation("sensor", 1, onset=900, bias=0.012, variances={"bias": 1e-5}))
    ('refined', {'bias': 0.912}, {'bias': 1e-05})
    >>> fold(comp, Compensation("sensor", 1, onset=1500, bias=0.3, variances={"bias": 1e-5}))
    ('accepted', {'bias': 0.3}, {'bias': 2e-05})
    >>> [c.correction for c in comp]
    [False, True, False]
    """
    same = _on_channel(entries, new.target, new.index)
    if same and not new.correction:
        known = same[-1].variances
        if _own_fault(new, same[-1]):
            new = replace(new, variances={k: v + known.get(k, 0.0)
                                          for k, v in new.variances.items()})
        else:
            new = replace(new, correction=True)
    entries.append(new)
    if not new.correction:
        return "accepted", new.estimates, dict(new.variances)
    return ("refined", latest_fault(entries, new.target, new.index), dict(new.variances))

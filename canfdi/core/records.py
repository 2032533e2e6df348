"""Records passed between the layers: frozen, numbers only, integer-nanosecond timestamps."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["BlockResult", "Compensation", "FaultEvent", "Sample", "compensate",
           "compensated", "fold"]


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

    kind : "detected" (a residual changed), "accepted" (a fault isolated and identified, folded
        into the compensation), "refined" (a re-detection explained by a channel already
        compensated: its estimates are the channel's updated total, see `fold`), or
        "unexplained" (no hypothesis fitted within max_samples). The monitor adds "mismatch",
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

    def as_dict(self) -> dict:
        """JSON-ready form."""
        out = {k: getattr(self, k) for k in self.__dataclass_fields__}
        out["candidates"] = list(self.candidates)
        out["residuals"] = list(self.residuals)
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
    """An accepted fault folded into the data from its onset on (seed 003 Section 3.3).

    target : "actuator" (the command becomes ``eta u_c + lam``) or "sensor" (the measurement
        becomes ``z - bias``).
    index : the channel, 0-based; onset : the first sample it applies to.
    eta, lam, bias : the accepted estimates (``lam`` is the paper's lambda).
    scale : whether the method estimates eta (its events report it); False: eta is 1.

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

    def as_dict(self) -> dict[str, float | int | str]:
        """{"target", "index", "onset"} and the estimates, named as in FaultEvent."""
        out: dict[str, float | int | str] = {"target": self.target, "index": self.index,
                                             "onset": self.onset}
        if self.target == "sensor":
            out["bias"] = self.bias
        else:
            if self.scale:
                out["eta"] = self.eta
            out["lambda"] = self.lam
        return out


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


def compensated(entries: list[Compensation] | tuple[Compensation, ...], target: str,
                index: int) -> dict[str, float]:
    """The total fault already compensated on one channel ({} when none), composed in the
    order `compensate` applies the entries: sensor biases add; an actuator's
    ``eta2 (eta1 u + lam1) + lam2`` is eta = eta1 eta2, lambda = eta2 lam1 + lam2. Keys as
    `Compensation.as_dict` (eta only for a method that estimates it). A refinement's precision
    is judged against it: what matters is the total's accuracy, not the small increment's."""
    same = [c for c in entries if c.target == target and c.index == index]
    if not same:
        return {}
    eta, lam, bias = 1.0, 0.0, 0.0
    for c in same:
        bias += c.bias
        eta, lam = c.eta * eta, c.eta * lam + c.lam
    out = Compensation(target, index, same[0].onset, eta=eta, lam=lam, bias=bias,
                       scale=any(c.scale for c in same)).as_dict()
    return {key: float(v) for key, v in out.items() if key not in ("target", "index", "onset")}


def fold(entries: list[Compensation], new: Compensation) -> tuple[str, dict[str, float]]:
    """Append an accepted fault to the compensation; ("accepted", its estimates) for a channel
    not compensated yet, ("refined", the channel's new total: `compensated`) when it is (seed
    003 Section 3.3: a later residual of the same fault refines it).

    Examples
    --------
    >>> comp = [Compensation("sensor", 1, onset=100, bias=0.9)]
    >>> fold(comp, Compensation("sensor", 1, onset=900, bias=0.1))
    ('refined', {'bias': 1.0})
    >>> len(comp)
    2
    """
    known = any(c.target == new.target and c.index == new.index for c in entries)
    entries.append(new)
    kind = "refined" if known else "accepted"
    return kind, compensated(entries, new.target, new.index)

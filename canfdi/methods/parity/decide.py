"""A diagnosis' decision at one sample, from its fits: which hypothesis and onset fit best, and
whether to accept it, name it, wait, or give up (the seed's acceptance test, the diagnoser's
DIAGNOSE step).

Every sample of a diagnosis (from ``min_samples`` after the alarm) solves every hypothesis'
fit at every candidate onset; what follows is this decision. It is a pure function of the fits
and of fixed tables (`HypothesisTable`, the noise units of `unit_table`), so a kernel can run it
(canfdi.core.kernel: ``decide`` in C, cfdi_decide, the one an MCU runs too); `decide_reference`
is the numpy form the diagnoser runs otherwise. The events an accepted, named or unexplained
decision makes are the diagnoser's.

The rules, in order (ParitySettings names the numbers):

- each hypothesis' best onset is its cheapest (the first of equal costs); each parameter beyond
  the first costs ``2 isolation_margin`` (a likelihood-ratio penalty), and hypotheses are
  ranked by that cost (stably);
- the best one names its group of twins (proportional signatures, as many parameters, costs
  equal to 1e-6 relative): the group's first channel in config order, so the choice is the
  data's, never the floating point's;
- the margin holds when every hypothesis outside the group costs ``isolation_margin`` more;
- the fit "fits" when its cost per degree of freedom is at most ``max_fit_variance`` and it
  explains ``isolation_margin`` of the no-fault cost in its own noise (an F test);
- its size is known when each estimate's standard deviation (the long-run sandwich
  ``P M P``, `spread`) is within ``settle_rel_std`` of its size or ``settle_noise`` of its
  noise unit (canfdi.methods.parity.settling), and a bias alone is known only once its full
  actuator fit rules a scale out;
- accept (margin, fit, known, or ``max_samples`` reached); else name (margin and fit, not named
  yet, not a joint sensor fit, not what an earlier estimate left); else at ``max_samples``
  accept with the near twins as candidates (it fits) or give up (it does not).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from canfdi.methods.parity.hypotheses import Hypothesis, noise_units

if TYPE_CHECKING:
    from canfdi.core.identify import RlsSolution
    from canfdi.core.residuals import ResidualBank
    from canfdi.methods.parity.diagnoser import ParitySettings

__all__ = [
    "ACCEPT",
    "ACCEPT_NEAR",
    "NAME",
    "UNEXPLAINED",
    "WAIT",
    "Decision",
    "HypothesisTable",
    "decide_reference",
    "spread",
    "unit_table",
]

WAIT, ACCEPT, NAME, ACCEPT_NEAR, UNEXPLAINED = range(5)
"""A decision's action: go on, accept the best, name it, accept it with its near twins as
candidates (``max_samples`` reached), report the alarm unexplained."""

KINDS = ("actuator", "actuator_bias", "sensor", "sensors")
"""Hypothesis targets by their code in `HypothesisTable.kind` (cfdi.h's CFDI_HYP_*)."""

_NAME_RANK = {"actuator": 0, "actuator_bias": 1, "sensor": 2}


@dataclass(frozen=True)
class HypothesisTable:
    """The hypotheses as a decision reads them, H of them, d parameters at most.

    kind : (H,) int8, codes of KINDS; index : (H,) int32 channel (a joint fit: its first
    member); n_params : (H,) int32; full : (H,) int32, a bias-only actuator's full hypothesis
    (-1: none, or not a bias); name_key : (H,) int64, the order that names a group of twins
    (inputs before outputs, then the channel); twins : (H, H) uint8, proportional signatures;
    penalty : (H,) the cost each hypothesis' extra parameters add.

    Examples
    --------
    >>> hyps = [Hypothesis("actuator", 0, "V"), Hypothesis("sensor", 0, "y"),
    ...         Hypothesis("actuator_bias", 0, "V")]
    >>> table = HypothesisTable.of(hyps, {h: set() for h in hyps}, isolation_margin=50.0)
    >>> table.kind.tolist(), table.full.tolist(), table.penalty.tolist()
    ([0, 2, 1], [-1, -1, 0], [100.0, 0.0, 0.0])
    """

    kind: np.ndarray
    index: np.ndarray
    n_params: np.ndarray
    full: np.ndarray
    name_key: np.ndarray
    twins: np.ndarray
    penalty: np.ndarray

    @classmethod
    def of(cls, hypotheses: list[Hypothesis], twins: dict[Hypothesis, set[Hypothesis]],
           isolation_margin: float) -> HypothesisTable:
        """The table of ``hypotheses`` with their ``twins`` (the diagnoser's)."""
        position = {h: i for i, h in enumerate(hypotheses)}
        full = [next((i for i, g in enumerate(hypotheses)
                      if g.target == "actuator" and g.index == h.index), -1)
                if h.target == "actuator_bias" else -1 for h in hypotheses]
        mark = np.zeros((len(hypotheses), len(hypotheses)), dtype=np.uint8)
        for h, group in twins.items():
            for g in group:
                mark[position[h], position[g]] = 1
        return cls(
            kind=np.array([KINDS.index(h.target) for h in hypotheses], dtype=np.int8),
            index=np.array([h.index for h in hypotheses], dtype=np.int32),
            n_params=np.array([h.n_params for h in hypotheses], dtype=np.int32),
            full=np.array(full, dtype=np.int32),
            name_key=np.array([(_NAME_RANK.get(h.target, 3) << 32) + h.index
                               for h in hypotheses], dtype=np.int64),
            twins=mark,
            penalty=np.array([2.0 * isolation_margin * (h.n_params - 1) for h in hypotheses]))


def unit_table(bank: ResidualBank, hypotheses: list[Hypothesis], d: int,
               projection: np.ndarray | None = None) -> np.ndarray:
    """(H, d) each hypothesis' noise units at the bank's noise (hypotheses.noise_units), inf
    beyond its parameters; an actuator's both columns hold lambda's unit (eta's is it over the
    command's mean size, known only during a diagnosis)."""
    out = np.full((len(hypotheses), d), np.inf)
    for i, h in enumerate(hypotheses):
        units = noise_units(bank, h, None, projection)
        if h.target == "actuator":
            out[i, :2] = units[-1]  # lambda's (eta's needs the mean command)
        else:
            out[i, : len(units)] = units
    return out


class Decision(NamedTuple):
    """One sample's decision: ``action`` (WAIT .. UNEXPLAINED), the ``best`` hypothesis (its
    group's name) at onset position ``kb``, its fit's noise ``scale`` (cost per degree of
    freedom), whether its size and its form are known; best_onset (H,) each hypothesis'
    cheapest onset position, cost_h (H,) its penalised cost there, order (H,) the hypotheses
    by cost_h (stable), near (H,) bool the ones outside the group within the margin. (A
    kernel's decide returns these fields in this order: ``Decision(*fields)``.)

    Examples
    --------
    >>> from canfdi.core.identify import RlsSolution
    >>> from canfdi.methods.parity.diagnoser import ParitySettings
    >>> hyps = [Hypothesis("sensor", 0, "y0"), Hypothesis("sensor", 1, "y1")]
    >>> table = HypothesisTable.of(hyps, {h: set() for h in hyps}, isolation_margin=50.0)
    >>> fit = RlsSolution(theta=np.array([[[0.5]], [[0.2]]]), P=np.full((2, 1, 1, 1), 1e-6),
    ...                   cost=np.array([[100.0], [500.0]]), dof=100)  # y0 fits far better
    >>> dec = decide_reference(table, ParitySettings(), fit, rr=1e4, n_eq=101,
    ...                        meat=np.ones((2, 1, 1, 1)), u_abs=np.zeros(1), n_u=np.zeros(1),
    ...                        units=np.ones((2, 1)), leftover=np.full(2, -1), since=20,
    ...                        named=False)
    >>> dec.action == ACCEPT, dec.best, dec.kb, dec.scale
    (True, 0, 0, 1.0)
    """

    action: int
    best: int
    kb: int
    scale: float
    size_known: bool
    form_known: bool
    best_onset: np.ndarray
    cost_h: np.ndarray
    order: np.ndarray
    near: np.ndarray


def spread(P: np.ndarray, cost: float, n_eq: int, n_params: int, meat: np.ndarray
           ) -> tuple[np.ndarray, float]:
    """(d,) one fit's estimates' variances, the sandwich ``diag(P M P)`` times its noise scale,
    and that scale (``cost`` per degree of freedom, ``n_eq - n_params`` at least 1). P, meat:
    (d, d)."""
    scale = max(float(cost) / max(n_eq - n_params, 1), 1e-300)
    return np.diag(P @ meat @ P) * scale, scale


def _known(sd: np.ndarray, size: np.ndarray, unit: np.ndarray,
           settings: ParitySettings) -> bool:
    """settling.settled of one fit."""
    noise = (sd <= settings.settle_noise * unit if settings.settle_noise > 0.0
             else np.zeros(sd.shape, dtype=bool))
    return bool(np.all((sd <= settings.settle_rel_std * size) | noise))


def decide_reference(table: HypothesisTable, settings: ParitySettings, fit: RlsSolution,
                     rr: np.ndarray, n_eq: int, meat: np.ndarray, u_abs: np.ndarray,
                     n_u: np.ndarray, units: np.ndarray, leftover: np.ndarray, since: int,
                     named: bool) -> Decision:
    """The decision over every fit of a diagnosis (the module's rules).

    Parameters
    ----------
    fit : the fits solved (RlsSolution, batch (H, K)); rr : broadcastable to (H, K), the
    no-fault cost; n_eq : residual rows absorbed; meat : (H, K, d, d) the long-run sandwich's
    middle; u_abs, n_u : (p,) the sum of |u_c| and count of known commands since the alarm;
    units : (H, d) `unit_table`; leftover : (H,) the onset position of the latest accepted fault
    on each hypothesis' channel, -1 where none (its fit from there costs less than the margin
    more: what that estimate left); since : samples since the alarm; named : whether the
    diagnosis named its fault already.
    """
    s = table
    theta = fit.theta
    H = theta.shape[0]
    cost = np.broadcast_to(fit.cost, theta.shape[:2])
    rr = np.broadcast_to(rr, cost.shape)
    best_onset = np.argmin(cost, axis=1)
    cost_h = cost[np.arange(H), best_onset] + s.penalty
    order = np.argsort(cost_h, kind="stable")
    first = int(order[0])
    tol = 1e-6 * (1.0 + abs(float(cost_h[first])))
    group = [first] + [i for i in range(H) if s.twins[first, i]
                       and s.n_params[i] == s.n_params[first]
                       and abs(float(cost_h[i] - cost_h[first])) <= tol]
    best = min(group, key=lambda i: int(s.name_key[i]))
    outside = np.array([i != best and not s.twins[best, i] for i in range(H)])
    gap = cost_h - cost_h[best]
    margin = settings.isolation_margin
    margin_ok = bool(np.all(gap[outside] >= margin))
    kb = int(best_onset[best])
    n_b = int(s.n_params[best])
    var, scale = spread(fit.P[best, kb], cost[best, kb], n_eq, n_b, meat[best, kb])
    sd = np.sqrt(var[:n_b])
    th = theta[best, kb]
    kind = int(s.kind[best])
    j = int(s.index[best])
    unit = units[best, :n_b].copy()
    if kind == 0:  # actuator: eta - 1 and lambda, judged against the mean command
        u_mean = u_abs[j] / max(n_u[j], 1.0)
        unit[0] = unit[0] / u_mean if u_mean > 0.0 else np.inf
        size = np.array([abs(1.0 + th[0]), max(abs(th[1]), 0.1 * abs(th[0]) * u_mean)])
    else:
        size = np.abs(th[:n_b])
    size_known = _known(sd, size, unit, settings)
    form_known = kind != 1 or _scale_ruled_out(s, settings, fit, cost, n_eq, meat, u_abs, n_u,
                                               units, best_onset, int(s.full[best]))
    fits = bool(scale <= settings.max_fit_variance
                and (float(rr[best, kb]) - float(cost[best, kb])) / scale >= margin)
    near = outside & (gap < margin)
    at_end = since >= settings.max_samples
    if margin_ok and fits and ((size_known and form_known) or at_end):
        action = ACCEPT
    elif (margin_ok and fits and not named and kind != 3
          and not (leftover[best] >= 0
                   and float(cost[best, leftover[best]] - cost[best, kb]) < margin)):
        action = NAME
    elif fits and at_end:
        action = ACCEPT_NEAR
    elif at_end:
        action = UNEXPLAINED
    else:
        action = WAIT
    return Decision(action, best, kb, scale, size_known, form_known, best_onset, cost_h, order,
                    near)


def _scale_ruled_out(s: HypothesisTable, settings: ParitySettings, fit: RlsSolution,
                     cost: np.ndarray, n_eq: int, meat: np.ndarray, u_abs: np.ndarray,
                     n_u: np.ndarray, units: np.ndarray, best_onset: np.ndarray,
                     full: int) -> bool:
    """Whether the data rule a scale out for a bias-only actuator fit: its full fit (``full``,
    -1: none) knows eta - 1 as the settling test asks of any parameter, and finds it within 3
    standard deviations of 0 (a scale not yet earning its parameter's penalty is waited for,
    not taken for a bias)."""
    if full < 0:
        return True
    kb = int(best_onset[full])
    sd_eta = float(np.sqrt(spread(fit.P[full, kb], cost[full, kb], n_eq, 2,
                                  meat[full, kb])[0][0]))
    j = int(s.index[full])
    u_mean = u_abs[j] / max(n_u[j], 1.0)
    unit = units[full, 0] / u_mean if u_mean > 0.0 else np.inf
    noise = settings.settle_noise > 0.0 and sd_eta <= settings.settle_noise * unit
    return bool((sd_eta <= settings.settle_rel_std or noise)
                and abs(float(fit.theta[full, kb, 0])) <= 3.0 * sd_eta)

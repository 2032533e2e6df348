"""An accepted fault's estimate history, recomputed from a log (for `canfdi report`).

A log keeps the accepted estimate of each fault, not its trajectory. The parity method's fit is
linear, so the trajectory is recomputed exactly: the accepted hypothesis at the accepted onset,
its regressors at every logged residual row from the onset to the acceptance (the diagnoser's
own, canfdi.methods.parity.hypotheses), through the one least squares (canfdi.core.identify,
P reset at the alarm). Its last value is the accepted estimate to round-off. Nothing is
re-diagnosed.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from canfdi.core.identify import rls_batch, rls_init
from canfdi.core.records import Compensation, FaultEvent, compensate
from canfdi.core.residuals import ResidualBank
from canfdi.methods import EstimateHistory
from canfdi.methods.parity.hypotheses import Hypothesis, regressors

__all__ = ["estimate_history"]


def _group(accepted: list[FaultEvent], event: FaultEvent) -> list[FaultEvent]:
    """The accepted events of the same acceptance (a joint sensor fit gives several)."""
    return [e for e in accepted
            if e.accepted_sample == event.accepted_sample
            and e.detected_sample == event.detected_sample and e.target == event.target]


def _hypothesis(event: FaultEvent, group: list[FaultEvent]) -> Hypothesis:
    if event.target == "actuator":
        # The bias-only hypothesis fixes eta at exactly 1 (one parameter, lambda; the variance
        # it reports for eta is what the full fit knew of it, 0 in logs before issue 41): a
        # fitted eta is 1 + (eta - 1), never exactly 1 where the command moved at all.
        bias_only = event.estimates.get("eta") == 1.0
        return Hypothesis("actuator_bias" if bias_only else "actuator", event.index, event.name)
    if len(group) > 1:
        members = tuple(e.index for e in group)
        return Hypothesis("sensors", members[0], event.name, members=members)
    return Hypothesis("sensor", event.index, event.name)


def _commands(samples: Any, accepted: list[FaultEvent], event: FaultEvent, first: int,
              last: int, p: int) -> np.ndarray:
    """(last - first + 1, p) commands of samples first..last, compensated for the actuator
    faults accepted before this one was detected (as the diagnoser saw them); NaN where the
    log has none."""
    pos = np.arange(first, last + 1)
    U = np.full((len(pos), p), np.nan)
    if samples is not None and len(samples.k):
        idx = np.clip(np.searchsorted(samples.k, pos), 0, len(samples.k) - 1)
        found = samples.k[idx] == pos
        U[found] = samples.U[idx[found]]
    earlier = [Compensation("actuator", e.index, e.onset_sample, eta=e.estimates["eta"],
                            lam=e.estimates["lambda"], scale=True)
               for e in accepted
               if e.accepted_sample is not None and e.accepted_sample < event.detected_sample
               and e.target == "actuator"]
    _, U = compensate(earlier, pos, None, U)
    return U


def estimate_history(bank: ResidualBank, contents: Any, event: FaultEvent
                     ) -> EstimateHistory | None:
    """The running estimates of an accepted fault, or None (``contents.notes`` says why).

    Parameters
    ----------
    bank : the residual bank of the log's config (its names must be the log's residuals').
    contents : the log: ``residuals`` (k (N,), names, Rn (N, m)), ``samples`` (k, U) or None,
        ``accepted`` (the accepted FaultEvents), ``notes`` (a list this appends to).
    event : the accepted fault.
    """
    res = contents.residuals
    label = f"{event.target} {event.name}"
    if list(bank.names) != list(res.names):
        contents.notes.append(f"{label}: the config's residuals {bank.names} are not the "
                              f"log's {res.names} (wrong --config?): no trajectory")
        return None
    k_f, k_a = event.onset_sample, event.accepted_sample
    rows = (res.k >= k_f) & (res.k <= k_a)
    ks, rn = res.k[rows], res.Rn[rows]
    if len(ks) == 0:
        return None
    group = _group(contents.accepted, event)
    h = _hypothesis(event, group)
    S = bank.S
    U = _commands(contents.samples, contents.accepted, event, int(ks[0]) - S, int(ks[-1]),
                  bank.p)
    onsets, ks0 = np.array([k_f]), int(ks[0])
    # Row i of U is sample ks0 - S + i: sample k's window k-S..k starts at row k - ks0.
    phi = np.stack([regressors(bank, [h], h.n_params, int(k), onsets,
                               U[int(k) - ks0: int(k) - ks0 + S + 1])[0, 0] for k in ks])
    fit = rls_batch(rls_init(h.n_params), phi, rn)
    scale = np.maximum(fit.cost, 0.0) / np.maximum(
        np.cumsum((~np.isnan(rn)).sum(axis=1)) - h.n_params, 1)
    var = fit.variances * scale[:, None]
    theta = fit.theta.copy()
    if h.target == "actuator":
        theta[:, 0] += 1.0  # u = eta u_c + lambda: the regression estimates eta - 1
        names, col = ["eta", "lambda"], [0, 1]
    elif h.target == "actuator_bias":
        names, col = ["lambda"], [0]
    else:
        names = ["bias"]
        col = [h.members.index(event.index)] if h.members else [0]
    values, std = theta[:, col], np.sqrt(np.maximum(var[:, col], 0.0))
    joint = " (joint fit of " + ", ".join(e.name for e in group) + ")" if len(group) > 1 else ""
    return EstimateHistory(k=ks, names=names, values=values, std=std,
                           source="least squares over the log's residuals" + joint)

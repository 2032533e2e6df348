"""When a fit's estimates are known well enough to accept (the settling test), and the
excitation bound: the first sample at which they could be, for a fault's true form and onset
on the commands a run recorded (issue 41).

The diagnoser accepts a hypothesis once its isolation margin holds and each estimate's standard
deviation is below ``settle_rel_std`` of its size or ``settle_noise`` of its noise unit
(`settled`). How soon that can happen depends on the data: a sensor bias is known at a rate set
by the noise, an actuator's scale only as the command moves. `excitation_bound` answers it for
least squares that knows the fault's form and onset (no other hypothesis, no detection delay,
the noise of the run): what any diagnoser that still has to find them can be measured against.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from canfdi.core.identify import rls_batch, rls_init
from canfdi.core.residuals import ResidualBank
from canfdi.methods.parity.hypotheses import Hypothesis, noise_units, row_regressors

if TYPE_CHECKING:
    from canfdi.methods.parity.diagnoser import ParitySettings

__all__ = ["excitation_bound", "settle_sizes", "settled", "within"]


def within(sd: np.ndarray | float, fraction: float, unit: np.ndarray | float) -> np.ndarray:
    """Whether standard deviations are within ``fraction`` of their noise units (never, for a
    fraction of 0: no noise-unit test)."""
    if fraction <= 0.0:
        return np.zeros(np.shape(sd), dtype=bool)
    return np.asarray(sd) <= fraction * np.asarray(unit)


def settle_sizes(h: Hypothesis, theta: np.ndarray, u_mean: np.ndarray | float | None
                 ) -> np.ndarray:
    """(..., n) what the settling test measures hypothesis h's standard deviations against:
    each estimate's size; for an actuator ``theta = [eta - 1, lambda]``, eta itself and, for a
    pure scale fault (lambda = 0), a tenth of the offset the scale puts on the mean command
    ``u_mean`` when that is larger than lambda. theta (..., n) and u_mean (...) broadcast.

    >>> h = Hypothesis("actuator", 0, "V")
    >>> settle_sizes(h, np.array([1.0, 0.0]), 40.0).tolist()
    [2.0, 4.0]
    """
    theta = np.asarray(theta, dtype=float)
    if h.target == "actuator":
        u = 0.0 if u_mean is None else np.asarray(u_mean, dtype=float)
        lam = np.maximum(np.abs(theta[..., 1]), 0.1 * np.abs(theta[..., 0]) * u)
        eta = np.broadcast_to(np.abs(1.0 + theta[..., 0]), np.shape(lam))
        return np.stack([eta, lam], axis=-1)
    return np.abs(theta[..., : h.n_params])


def settled(sd: np.ndarray, size: np.ndarray, unit: np.ndarray,
            settings: ParitySettings) -> np.ndarray:
    """(...) whether every standard deviation (last axis) is below ``settle_rel_std`` of its
    size or ``settle_noise`` of its noise unit."""
    return np.all((np.asarray(sd) <= settings.settle_rel_std * np.asarray(size))
                  | within(sd, settings.settle_noise, unit), axis=-1)


def excitation_bound(bank: ResidualBank, settings: ParitySettings, long_run: np.ndarray,
                     projection: np.ndarray | None, h: Hypothesis, theta: np.ndarray,
                     onset: int, U: np.ndarray, noise_scale: float = 1.0) -> int | None:
    """The first sample at which least squares of hypothesis ``h`` with its onset fixed at
    ``onset`` settles (`settled`) on the commands ``U``, at least ``min_samples`` after the
    onset and at most ``max_samples``; None when it does not by then (or the run ends first).

    Its variances are the diagnoser's settling test's: the sandwich ``P M P`` with the
    long-run covariance ``long_run`` (m, m) of the normalised residuals as the meat's weight,
    times ``noise_scale^2`` (the run's noise over the config's, which the fit's own cost
    estimates in the diagnoser), plus the squared pull of the prior ``P J0 theta``: the mean
    squared error, which stays large for a parameter the commands do not identify. The
    regressors depend on the commands alone, so no measurement is needed; theta (n,) is the
    true fault (``[eta - 1, lambda]``, ``[lambda]`` or ``[bias]``) the sizes are judged by.

    Parameters
    ----------
    U : (N, p) commanded inputs of samples 0..N-1 (NaN taken as 0, as in the regressors).
    """
    S = bank.S
    U = np.asarray(U, dtype=float)
    theta = np.asarray(theta, dtype=float)
    first = max(int(onset), S)
    last = min(int(onset) + settings.max_samples, len(U) - 1)
    if last < first:
        return None
    k = np.arange(first, last + 1)
    windows = sliding_window_view(U, (S + 1, U.shape[1]))[:, 0][k - S]  # (n, S+1, p)
    phi = row_regressors(bank, [h], [int(onset)], k, windows)  # (n, m, d)
    fit = rls_batch(rls_init(h.n_params, settings.prior_precision), phi,
                    np.zeros(phi.shape[:2]))
    meat = np.cumsum(np.swapaxes(phi, 1, 2) @ (long_run @ phi), axis=0)
    var = np.diagonal(fit.P @ meat @ fit.P, axis1=1, axis2=2) * noise_scale ** 2
    # The prior's pull, P J0 theta: where the commands leave a parameter unidentified (a scale
    # under a constant command) the noise does not move its estimate, the prior holds it at 0.
    pull = fit.P @ (settings.prior_precision * theta)
    sd = np.sqrt(np.maximum(var, 0.0) + pull ** 2)
    u_mean = None
    if h.target in ("actuator", "actuator_bias"):
        u_abs = np.abs(np.nan_to_num(U[k, h.index]))
        u_mean = np.cumsum(u_abs) / np.arange(1, len(k) + 1)
    unit = noise_units(bank, h, u_mean, projection)
    size = settle_sizes(h, theta, u_mean)
    ok = settled(sd, size, unit, settings) & (k - onset >= settings.min_samples)
    hits = np.flatnonzero(ok)
    return int(k[hits[0]]) if hits.size else None

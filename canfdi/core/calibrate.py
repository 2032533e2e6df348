"""Choosing Page-Hinkley thresholds: Siegmund's approximation of the average run length (the
false-alarm interval of a threshold and, at a change's drift, its detection delay), its
inverse, the bound for correlated residuals (their long-run variance), and the calibration of
thresholds on fault-free residuals where the approximation does not hold.

References
----------
M. Basseville and I. V. Nikiforov, *Detection of Abrupt Changes: Theory and Application*,
Prentice Hall, 1993, Section 5.2.
D. Siegmund, *Sequential Analysis: Tests and Confidence Intervals*, Springer, 1985.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from canfdi.core.detect import (
    _as_2d,
    _per_residual,
    _run_restarts,
    _scalar_or_array,
)

__all__ = [
    "SIEGMUND_OVERSHOOT",
    "arl_one_sided",
    "arl_two_sided",
    "calibrate_threshold",
    "false_alarm_interval",
    "threshold_for_false_alarm_interval",
    "threshold_for_long_run_variance",
]

# Siegmund's correction b = h + 2 * rho * sigma: rho = -zeta(1/2) / sqrt(2 pi) ~ 0.583 is the
# expected overshoot of a Gaussian random walk over a far boundary, which the continuous
# (Brownian) run-length formula ignores.
SIEGMUND_OVERSHOOT = 1.166

# Below |2 mu b| < this the closed-form ARL cancels catastrophically; a series is used.
_SERIES_LIMIT = 0.1
_SERIES_TERMS = 10

def threshold_for_long_run_variance(delta: float, arl0: float, long_run: ArrayLike
                                    ) -> NDArray[np.float64]:
    """Thresholds (m,) for residuals of long-run variance ratios ``long_run`` (m,) (the sum of
    all autocovariances over the variance; 1 for white noise).

    Long excursions of a correlated residual behave as white noise of std sqrt(L) (the Brownian
    limit), so Siegmund's threshold on that scale, sqrt(L) h(delta / sqrt(L), arl0), bounds
    them; never below the white-noise threshold h(delta, arl0). Ratios below 1 count as 1.
    """
    white = threshold_for_false_alarm_interval(delta, arl0)
    out = []
    for ratio in np.asarray(long_run, dtype=float).ravel():
        lr = float(np.sqrt(max(float(ratio), 1.0)))
        out.append(max(white, lr * threshold_for_false_alarm_interval(delta / lr, arl0)))
    return np.array(out)



# --------------------------------------------------------------------------------------
# design: Siegmund's approximation of the average run length
# --------------------------------------------------------------------------------------


def arl_one_sided(mu: ArrayLike, h: ArrayLike) -> NDArray[np.float64] | float:
    """Siegmund's approximation of the average run length of a one-sided CUSUM.

    For g_k = max(0, g_{k-1} + z_k) with Gaussian increments z_k of mean ``mu`` and unit
    variance, stopped at the first k with g_k >= h (Basseville & Nikiforov 1993, Section
    5.2.2; Siegmund 1985)::

        ARL(mu) = (exp(-2 mu b) + 2 mu b - 1) / (2 mu^2),   b = h + 1.166,

    and ARL(0) = b^2. Near mu = 0 a Taylor series replaces the closed form, which cancels.

    Parameters
    ----------
    mu : float or array_like
        Increment mean in units of sigma: ``change - delta`` after a change (the detection
        delay), ``-delta`` before it (the false-alarm interval).
    h : float or array_like
        Threshold in units of sigma, >= 0; broadcast against ``mu``.

    Returns
    -------
    float or ndarray
        Mean number of samples to the alarm, counting the alarm sample, from a zero
        statistic; broadcast shape of ``mu`` and ``h``. ``inf`` where it overflows.
    """
    mm = np.asarray(mu, dtype=np.float64)
    hh = np.asarray(h, dtype=np.float64)
    if not np.all(np.isfinite(mm)):
        raise ValueError("mu: must be finite")
    if not np.all(np.isfinite(hh)) or np.any(hh < 0):
        raise ValueError("h: must be finite and >= 0")
    mm, hh = np.broadcast_arrays(mm, hh)
    b = hh + SIEGMUND_OVERSHOOT
    t = 2.0 * mm * b
    small = np.abs(t) < _SERIES_LIMIT
    # (exp(-t) + t - 1) / (t^2 / 2) = sum_n 2 (-t)^n / (n + 2)!, n >= 0
    series = np.zeros_like(t)
    for n in range(_SERIES_TERMS - 1, -1, -1):
        series = series * (-t) + 2.0 / _factorial(n + 2)
    mu_safe = np.where(small, 1.0, mm)
    with np.errstate(over="ignore"):
        closed = (np.exp(-np.where(small, 0.0, t)) + t - 1.0) / (2.0 * mu_safe**2)
    arl = np.where(small, b**2 * series, closed)
    return _scalar_or_array(arl)


def _factorial(n: int) -> float:
    out = 1.0
    for k in range(2, n + 1):
        out *= k
    return out


def arl_two_sided(arl_up: ArrayLike, arl_down: ArrayLike) -> NDArray[np.float64] | float:
    """Average run length of two one-sided CUSUMs run together (first alarm of either).

    Uses the standard combination 1/ARL = 1/ARL_up + 1/ARL_down (Basseville & Nikiforov
    1993, Section 5.2), exact when the two statistics are never positive together and a
    close approximation for Gaussian increments with delta > 0.

    Parameters
    ----------
    arl_up, arl_down : float or array_like
        One-sided average run lengths, > 0 (``inf`` allowed); broadcast together.

    Returns
    -------
    float or ndarray
        Two-sided average run length, broadcast shape.
    """
    up = np.asarray(arl_up, dtype=np.float64)
    down = np.asarray(arl_down, dtype=np.float64)
    if np.any(np.isnan(up)) or np.any(up <= 0):
        raise ValueError("arl_up: must be > 0")
    if np.any(np.isnan(down)) or np.any(down <= 0):
        raise ValueError("arl_down: must be > 0")
    with np.errstate(divide="ignore"):
        return _scalar_or_array(1.0 / (1.0 / up + 1.0 / down))


def _check_delta(delta: ArrayLike) -> NDArray[np.float64]:
    d = np.asarray(delta, dtype=np.float64)
    if not np.all(np.isfinite(d)) or np.any(d < 0):
        raise ValueError("delta: must be finite and >= 0")
    return d


def false_alarm_interval(delta: ArrayLike, h: ArrayLike) -> NDArray[np.float64] | float:
    """Mean time between false alarms (ARL0) of the symmetric two-sided test (Siegmund).

    Parameters
    ----------
    delta : float or array_like
        Drift in units of sigma, >= 0.
    h : float or array_like
        Threshold in units of sigma, >= 0.

    Returns
    -------
    float or ndarray
        Two-sided ARL0 in samples, for white Gaussian residuals with the known mean.
    """
    one = arl_one_sided(-_check_delta(delta), h)
    return arl_two_sided(one, one)


def threshold_for_false_alarm_interval(delta: float, arl0: float) -> float:
    """Threshold h whose two-sided false-alarm interval is ``arl0`` (inverts Siegmund).

    Parameters
    ----------
    delta : float
        Drift in units of sigma, >= 0.
    arl0 : float
        Target mean time between false alarms in samples; must exceed the value at h = 0.

    Returns
    -------
    float
        Threshold h in units of sigma, valid for white Gaussian residuals only (see
        `calibrate_threshold` for correlated ones).
    """
    d = float(_check_delta(delta))
    target = float(arl0)
    if not np.isfinite(target) or target <= 0:
        raise ValueError(f"arl0: must be finite and > 0, got {arl0!r}")
    floor = float(false_alarm_interval(d, 0.0))
    if target <= floor:
        raise ValueError(f"arl0: must exceed {floor:.4g}, the false-alarm interval at h = 0")

    # ARL0 grows exponentially in h, so match logarithms for a well-scaled root.
    def excess(h: float) -> float:
        return float(np.log(false_alarm_interval(d, h)) - np.log(target))

    hi = 1.0
    while excess(hi) < 0:
        hi *= 2.0
    from scipy import optimize  # here: ~0.1 s to import, on every daemon's start

    return float(optimize.brentq(excess, 0.0, hi, xtol=1e-12, rtol=1e-12))


def calibrate_threshold(
    x_fault_free: ArrayLike,
    delta: ArrayLike,
    target_arl0: float,
    *,
    tol: float = 1e-3,
) -> NDArray[np.float64]:
    """Empirical Page-Hinkley threshold per residual from a fault-free record.

    Residuals of parity equations computed over a window of samples are correlated in
    time (consecutive windows share samples), so their partial sums wander further than
    white noise of the same variance and `threshold_for_false_alarm_interval` underestimates
    h. Here, for each residual, h is the smallest threshold (to ``tol``) for which the
    two-sided test with a restart after each alarm gives at most ``N / target_arl0`` alarms
    on the record, found by bisection with `page_hinkley_batch` semantics. The alarm count
    is non-increasing in h up to the reshuffling of restart instants, so the result is the
    smallest such h up to that noise.

    Parameters
    ----------
    x_fault_free : array_like, shape (N, m)
        Fault-free residuals already normalised to zero mean and unit variance. N should
        be many times ``target_arl0`` for the count to be meaningful.
    delta : float or array_like, shape (m,)
        Drift in units of sigma, >= 0.
    target_arl0 : float
        Wanted mean number of samples between false alarms, > 0.
    tol : float, optional
        Absolute tolerance on h, > 0.

    Returns
    -------
    ndarray, shape (m,)
        Threshold h per residual, in units of sigma.
    """
    x = _as_2d(x_fault_free, "x_fault_free")
    n, m = x.shape
    if n == 0:
        raise ValueError("x_fault_free: empty record")
    d = _per_residual(delta, m, "delta", nonnegative=True)
    target = float(target_arl0)
    if not np.isfinite(target) or target <= 0:
        raise ValueError(f"target_arl0: must be finite and > 0, got {target_arl0!r}")
    if not np.isfinite(tol) or tol <= 0:
        raise ValueError(f"tol: must be finite and > 0, got {tol!r}")
    allowed = np.full(m, n / target)
    zeros = np.zeros((m, 2))

    def meets(h: NDArray[np.float64]) -> NDArray[np.bool_]:
        _, counts = _run_restarts(x, d, h, zeros, store=False, max_alarms=allowed)
        return counts <= allowed

    # The white-noise design is a good first guess; correlated residuals push h above it.
    start = np.array(
        [
            threshold_for_false_alarm_interval(di, target)
            if target > false_alarm_interval(di, 0.0)
            else tol
            for di in d
        ]
    )
    lo = np.zeros(m)
    hi = np.maximum(start, tol)
    ok = meets(hi)
    # Terminates: once h exceeds the largest possible partial sum no alarm is left.
    while not ok.all():
        lo = np.where(ok, lo, hi)
        hi = np.where(ok, hi, 2.0 * hi)
        ok = meets(hi)
    while np.any(hi - lo > tol):
        mid = 0.5 * (lo + hi)
        ok = meets(mid)
        hi = np.where(ok, mid, hi)
        lo = np.where(ok, lo, mid)
    return hi

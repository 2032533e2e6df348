"""Residual evaluation: fixed thresholds and the two-sided Page-Hinkley (CUSUM) test.

Two decision rules turn residuals into alarms:

* the fixed threshold of eq. 8 of Chan et al. (2006), ``|r| >= r_h`` means faulty, with
  ``r_h`` chosen from the residual's noise level and a false-alarm probability per sample;
* the two-sided Page-Hinkley stopping rule (Basseville & Nikiforov 1993, "Detection of
  Abrupt Changes", Sections 2.2 and 5.2), which accumulates small persistent deviations
  that a per-sample threshold would miss.

Every rule comes as a pure function (a step function with explicit state and a batch
function over a whole record, sharing the same arithmetic) and as a thin streaming class
with ``update(x) -> alarms`` and ``reset()``. Choosing the thresholds (Siegmund's
approximation of the run length, calibration on fault-free residuals) is canfdi.core.calibrate.

References
----------
M. Basseville and I. V. Nikiforov, *Detection of Abrupt Changes: Theory and Application*,
Prentice Hall, 1993.
D. Siegmund, *Sequential Analysis: Tests and Confidence Intervals*, Springer, 1985.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import special  # quantiles: 30 ms to import where scipy.stats takes 0.6 s

from canfdi.core._check import check_shape

__all__ = [
    "Alarm",
    "ChangePointDetector",
    "DetectorBacked",
    "PageHinkley",
    "PageHinkleyResult",
    "ThresholdDetector",
    "alarms_to_events",
    "onset_candidates",
    "page_hinkley_batch",
    "page_hinkley_step",
    "threshold_alarms",
    "threshold_from_false_alarm",
]

# Cumulative sums are restarted at least this often so that their magnitude (which drifts by
# -delta per sample) cannot eat the precision of g = S_k - min_j S_j on long records.
_MAX_BLOCK = 4096
_MIN_WINDOW = 16



# --------------------------------------------------------------------------------------
# records
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Alarm:
    """One alarm of one residual at one sample.

    Attributes
    ----------
    sample : int
        Sample index (offset by ``start_sample`` of `alarms_to_events`).
    residual : int
        Column index of the residual in alarm.
    direction : int
        +1 for an upward change (or a threshold violation), -1 for a downward change.
    """

    sample: int
    residual: int
    direction: int


@dataclass(frozen=True)
class PageHinkleyResult:
    """Output of `page_hinkley_batch`.

    Attributes
    ----------
    g_up : ndarray, shape (N, m)
        Upward statistic g+ after each sample.
    g_down : ndarray, shape (N, m)
        Downward statistic g- after each sample.
    alarms : ndarray of int8, shape (N, m)
        +1 (upward change), -1 (downward change) or 0 at each sample.
    state : ndarray, shape (m, 2)
        Final (g+, g-) per residual, to pass as ``state`` to the next chunk. With
        ``restart_on_alarm`` a residual that alarmed on the last sample has a zero state.
    """

    g_up: NDArray[np.float64]
    g_down: NDArray[np.float64]
    alarms: NDArray[np.int8]
    state: NDArray[np.float64]


def alarms_to_events(alarms: ArrayLike, start_sample: int = 0) -> list[Alarm]:
    """List the nonzero entries of an alarm array as `Alarm` records.

    Parameters
    ----------
    alarms : array_like of int or bool, shape (N, m)
        Alarm array as returned by `page_hinkley_batch` (signs) or `threshold_alarms`
        (booleans, reported with direction +1).
    start_sample : int, optional
        Sample index of the first row, so that chunks of a long record report absolute
        sample numbers.

    Returns
    -------
    list of Alarm
        Ordered by sample, then residual.
    """
    a = check_shape("alarms", alarms, ("N", "m"))
    if a.dtype == np.bool_:
        a = a.astype(np.int8)
    elif not np.issubdtype(a.dtype, np.integer):
        raise ValueError(f"alarms: expected an integer or boolean array, got {a.dtype}")
    start = int(start_sample)
    rows, cols = np.nonzero(a)
    signs = np.sign(a[rows, cols])
    return [
        Alarm(sample=int(s) + start, residual=int(r), direction=int(d))
        for s, r, d in zip(rows, cols, signs, strict=True)
    ]


# --------------------------------------------------------------------------------------
# argument checks
# --------------------------------------------------------------------------------------


def _as_2d(x: ArrayLike, name: str, missing_ok: bool = False) -> NDArray[np.float64]:
    arr = check_shape(name, x, ("N", "m"), dtype=np.float64)
    _check_finite(arr, name, missing_ok)
    return arr


def _as_row(x: ArrayLike, m: int, name: str, missing_ok: bool = False) -> NDArray[np.float64]:
    arr = check_shape(name, x, (m,), dtype=np.float64)
    _check_finite(arr, name, missing_ok)
    return arr


def _check_finite(arr: NDArray[np.float64], name: str, missing_ok: bool) -> None:
    bad = np.isinf(arr) if missing_ok else ~np.isfinite(arr)
    if np.any(bad):
        raise ValueError(f"{name}: must be finite" + (" (NaN marks a missing value)"
                                                      if missing_ok else ""))


def _per_residual(
    value: ArrayLike, m: int, name: str, *, positive: bool = False, nonnegative: bool = False
) -> NDArray[np.float64]:
    """Broadcast a scalar or (m,) parameter to shape (m,) and check its sign."""
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim > 1 or (arr.ndim == 1 and arr.shape[0] != m):
        raise ValueError(f"{name}: expected a scalar or shape ({m},), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: must be finite")
    if positive and np.any(arr <= 0):
        raise ValueError(f"{name}: must be > 0")
    if nonnegative and np.any(arr < 0):
        raise ValueError(f"{name}: must be >= 0")
    return np.broadcast_to(arr, (m,)).copy()


def _check_state(state: ArrayLike | None, m: int, name: str = "state") -> NDArray[np.float64]:
    if state is None:
        return np.zeros((m, 2))
    arr = check_shape(name, state, (m, 2), dtype=np.float64)
    if not np.all(np.isfinite(arr)) or np.any(arr < 0):
        raise ValueError(f"{name}: statistics must be finite and >= 0")
    return arr.copy()


def _scalar_or_array(arr: NDArray[np.float64]) -> NDArray[np.float64] | float:
    return float(arr) if arr.ndim == 0 else arr


# --------------------------------------------------------------------------------------
# fixed threshold (Chan et al. 2006, eq. 8)
# --------------------------------------------------------------------------------------


def threshold_from_false_alarm(sigma: ArrayLike, p_fa: float) -> NDArray[np.float64] | float:
    """Threshold r_h giving a false-alarm probability ``p_fa`` per sample on white noise.

    For a zero-mean Gaussian residual of standard deviation sigma,
    ``P(|r| >= r_h) = p_fa`` gives ``r_h = sigma * Phi^{-1}(1 - p_fa / 2)``.

    Parameters
    ----------
    sigma : float or array_like, shape (m,)
        Noise standard deviation of each residual, > 0.
    p_fa : float
        Target false-alarm probability per sample and residual, in (0, 1).

    Returns
    -------
    float or ndarray, shape (m,)
        Threshold r_h, same shape as ``sigma``.
    """
    s = np.asarray(sigma, dtype=np.float64)
    if s.ndim > 1:
        raise ValueError(f"sigma: expected a scalar or a 1-D array, got shape {s.shape}")
    if not np.all(np.isfinite(s)) or np.any(s <= 0):
        raise ValueError("sigma: must be finite and > 0")
    p = float(p_fa)
    if not 0.0 < p < 1.0:
        raise ValueError(f"p_fa: must be in (0, 1), got {p_fa!r}")
    # isf(p/2) rather than ppf(1 - p/2): no loss of the small tail probability to rounding.
    return _scalar_or_array(s * -special.ndtri(p / 2.0))  # norm.isf, as scipy.stats does


def threshold_alarms(r: ArrayLike, r_h: ArrayLike) -> NDArray[np.bool_]:
    """Apply eq. 8 of Chan et al. (2006): residual i is faulty where ``|r_i| >= r_h``.

    Parameters
    ----------
    r : array_like, shape (N, m)
        Residuals, one column per residual.
    r_h : float or array_like, shape (m,)
        Threshold of each residual, > 0.

    Returns
    -------
    ndarray of bool, shape (N, m)
        True where the residual is in alarm.
    """
    rr = _as_2d(r, "r")
    th = _per_residual(r_h, rr.shape[1], "r_h", positive=True)
    return np.abs(rr) >= th


class ThresholdDetector:
    """Streaming form of `threshold_alarms`.

    Parameters
    ----------
    threshold : float or array_like, shape (m,)
        Threshold r_h of each residual, > 0.
    """

    def __init__(self, threshold: ArrayLike) -> None:
        th = np.asarray(threshold, dtype=np.float64)
        if th.ndim > 1:
            raise ValueError(f"threshold: expected a scalar or 1-D array, got {th.shape}")
        if not np.all(np.isfinite(th)) or np.any(th <= 0):
            raise ValueError("threshold: must be finite and > 0")
        self.threshold = th

    def update(self, r_row: ArrayLike) -> NDArray[np.intp]:
        """Evaluate one sample.

        Parameters
        ----------
        r_row : array_like, shape (m,)
            Residuals at this sample.

        Returns
        -------
        ndarray of intp, shape (k,)
            Indices of the residuals in alarm, ascending.
        """
        row = check_shape("r_row", np.atleast_1d(r_row), ("m",), dtype=np.float64)
        # same comparison as the batch form, so both give identical alarms
        return np.flatnonzero(threshold_alarms(row[None, :], self.threshold)[0])

    def reset(self) -> None:
        """Do nothing: the rule has no memory (kept for a uniform detector interface)."""


# --------------------------------------------------------------------------------------
# Page-Hinkley / CUSUM
# --------------------------------------------------------------------------------------


def _lindley(z: NDArray[np.float64], g0: NDArray[np.float64],
             out: NDArray[np.float64] | None = None) -> NDArray[np.float64]:
    """Closed form of g_k = max(0, g_{k-1} + z_k) from g_0 = g0, for z of shape (n, m)
    (written into ``out`` when given).

    Unrolling the recursion, g_k = max(g0 + S_k, max_{0<=j<=k} (S_k - S_j)) with
    S_k = z_1 + ... + z_k and S_0 = 0: either the statistic never hit zero (first term) or
    it last restarted from zero after sample j (second term).
    """
    s = np.cumsum(z, axis=0, out=out)
    lift = np.minimum.accumulate(s, axis=0)
    np.minimum(lift, 0.0, out=lift)
    np.subtract(s, lift, out=lift)  # S_k - min(0, min_j S_j)
    np.add(s, g0, out=s)
    return np.maximum(s, lift, out=s)


def _increments(u: NDArray[np.float64], delta: NDArray[np.float64]
                ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Up and down increments; a missing value (NaN) adds 0, so its statistics hold."""
    up, down = u - delta, -u - delta
    missing = np.isnan(u)
    if missing.any():
        up = np.where(missing, 0.0, up)
        down = np.where(missing, 0.0, down)
    return up, down


def _ph_block(
    u: NDArray[np.float64], delta: NDArray[np.float64], g0: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    # the increments are formed exactly as in page_hinkley_step so both agree to rounding
    up, down = _increments(u, delta)
    return _lindley(up, g0[:, 0]), _lindley(down, g0[:, 1])


def _direction(
    g_up: NDArray[np.float64], g_down: NDArray[np.float64], h: NDArray[np.float64]
) -> NDArray[np.int8]:
    # Both statistics can exceed h together (a large jump reversing a long drift); the
    # larger one names the change, ties go upward. (In int8 arithmetic: no wider temporary.)
    in_alarm = (np.maximum(g_up, g_down) >= h).view(np.int8)
    sign = (g_up >= g_down).view(np.int8) * np.int8(2) - np.int8(1)
    return in_alarm * sign


def page_hinkley_step(
    state: ArrayLike,
    x: ArrayLike,
    delta: ArrayLike,
    h: ArrayLike,
    *,
    mu0: ArrayLike = 0.0,
    sigma: ArrayLike = 1.0,
) -> tuple[NDArray[np.float64], NDArray[np.int8]]:
    """Advance the two-sided Page-Hinkley test by one sample.

    With u = (x - mu0) / sigma,
    ``g+ = max(0, g+ + u - delta)``, ``g- = max(0, g- - u - delta)``; a residual is in
    alarm while either statistic is >= h. Nothing is reset on an alarm: the caller decides
    (pass a zero state to restart). A NaN residual is missing (its window lost a frame): its
    statistics hold.

    Parameters
    ----------
    state : array_like, shape (m, 2)
        (g+, g-) per residual before this sample, >= 0.
    x : array_like, shape (m,)
        Residuals at this sample.
    delta : float or array_like, shape (m,)
        Drift, half the smallest change to detect, in units of sigma, >= 0.
    h : float or array_like, shape (m,)
        Alarm threshold in units of sigma, > 0.
    mu0 : float or array_like, shape (m,), optional
        Known fault-free mean of the residual.
    sigma : float or array_like, shape (m,), optional
        Known fault-free standard deviation of the residual, > 0.

    Returns
    -------
    state : ndarray, shape (m, 2)
        (g+, g-) after this sample (a new array; the input is not modified).
    alarm : ndarray of int8, shape (m,)
        +1 (upward change), -1 (downward change) or 0.
    """
    xr = check_shape("x", np.atleast_1d(x), ("m",), dtype=np.float64)
    m = xr.shape[0]
    xr = _as_row(xr, m, "x", missing_ok=True)
    st = _check_state(state, m)
    d = _per_residual(delta, m, "delta", nonnegative=True)
    hh = _per_residual(h, m, "h", positive=True)
    mu = _per_residual(mu0, m, "mu0")
    sg = _per_residual(sigma, m, "sigma", positive=True)
    return _ph_advance(st, xr, d, hh, mu, sg)


def _ph_advance(st: NDArray[np.float64], xr: NDArray[np.float64], d: NDArray[np.float64],
                hh: NDArray[np.float64], mu: NDArray[np.float64], sg: NDArray[np.float64]
                ) -> tuple[NDArray[np.float64], NDArray[np.int8]]:
    """`page_hinkley_step` on checked arrays: (m, 2) state, (m,) row and parameters (the
    detector's per-sample path, whose parameters were checked once, at construction)."""
    up, down = _increments((xr - mu) / sg, d)
    g_up = np.maximum(0.0, st[:, 0] + up)
    g_down = np.maximum(0.0, st[:, 1] + down)
    return np.stack([g_up, g_down], axis=1), _direction(g_up, g_down, hh)


def _run_plain(
    u: NDArray[np.float64],
    delta: NDArray[np.float64],
    h: NDArray[np.float64],
    g0: NDArray[np.float64],
) -> PageHinkleyResult:
    n, m = u.shape
    g_up = np.empty((n, m))
    g_down = np.empty((n, m))
    state = g0
    for start in range(0, n, _MAX_BLOCK):
        stop = min(start + _MAX_BLOCK, n)
        up, down = _increments(u[start:stop], delta)
        _lindley(up, state[:, 0], out=g_up[start:stop])
        _lindley(down, state[:, 1], out=g_down[start:stop])
        state = np.stack([g_up[stop - 1], g_down[stop - 1]], axis=1)
    return PageHinkleyResult(g_up, g_down, _direction(g_up, g_down, h), state.copy())


def _run_restarts(
    u: NDArray[np.float64],
    delta: NDArray[np.float64],
    h: NDArray[np.float64],
    g0: NDArray[np.float64],
    *,
    store: bool = True,
    max_alarms: NDArray[np.float64] | None = None,
) -> tuple[PageHinkleyResult | None, NDArray[np.int64]]:
    """Run with a zero restart right after every alarm, looping over alarms, not samples.

    Each pass evaluates, for every residual still running, a window that starts at its own
    current position (gathered with fancy indexing), keeps the samples up to and including
    its first alarm, and restarts there. The window adapts to the spacing of the alarms.
    With ``max_alarms``, a residual stops as soon as its count exceeds it (all the caller
    needs to know during a calibration).
    """
    n, m = u.shape
    g_up = np.empty((n, m)) if store else None
    g_down = np.empty((n, m)) if store else None
    alarms = np.zeros((n, m), dtype=np.int8) if store else None
    counts = np.zeros(m, dtype=np.int64)
    pos = np.zeros(m, dtype=np.intp)
    state = g0.copy()
    active = np.arange(m) if n > 0 else np.arange(0)
    window = _MIN_WINDOW
    while active.size:
        w = max(1, min(window, n))
        offsets = np.arange(w)[:, None]
        rows = pos[active] + offsets
        valid = rows < n
        rows = np.minimum(rows, n - 1)
        gp, gm = _ph_block(u[rows, active], delta[active], state[active])
        sign = _direction(gp, gm, h[active])
        hit = (sign != 0) & valid
        found = hit.any(axis=0)
        seg_len = np.where(found, hit.argmax(axis=0) + 1, valid.sum(axis=0))
        keep_rows = offsets < seg_len
        if store:
            r_idx = rows[keep_rows]
            c_idx = np.broadcast_to(active, rows.shape)[keep_rows]
            g_up[r_idx, c_idx] = gp[keep_rows]
            g_down[r_idx, c_idx] = gm[keep_rows]
            alarms[r_idx, c_idx] = sign[keep_rows]
        cols = np.arange(active.size)
        last = seg_len - 1
        new_state = np.stack([gp[last, cols], gm[last, cols]], axis=1)
        new_state[found] = 0.0
        state[active] = new_state
        pos[active] += seg_len
        counts[active] += found
        keep = pos[active] < n
        if max_alarms is not None:
            keep &= counts[active] <= max_alarms[active]
        if found.all():
            # Residuals alarming often need short windows (a long one is mostly discarded).
            window = int(min(_MAX_BLOCK, max(_MIN_WINDOW, 2 * int(seg_len.max()))))
        else:
            window = min(_MAX_BLOCK, 2 * w)
        active = active[keep]
    if not store:
        return None, counts
    return PageHinkleyResult(g_up, g_down, alarms, state), counts


def page_hinkley_batch(
    x: ArrayLike,
    delta: ArrayLike,
    h: ArrayLike,
    mu0: ArrayLike = 0.0,
    sigma: ArrayLike = 1.0,
    state: ArrayLike | None = None,
    restart_on_alarm: bool = False,
) -> PageHinkleyResult:
    """Run the two-sided Page-Hinkley test over a whole record.

    Same arithmetic as `page_hinkley_step` applied sample by sample, vectorised with
    cumulative sums: between restarts, ``g_k = max(g_0 + S_k, S_k - min_{0<=j<=k} S_j)``
    with ``S`` the cumulative sum of the increments and ``S_0 = 0``. Calling it on
    consecutive chunks, passing ``result.state`` along, gives the same result as one call.

    Parameters
    ----------
    x : array_like, shape (N, m)
        Residuals, one column per residual; NaN marks a missing value (statistics hold).
    delta : float or array_like, shape (m,)
        Drift, half the smallest change to detect, in units of sigma, >= 0.
    h : float or array_like, shape (m,)
        Alarm threshold in units of sigma, > 0.
    mu0 : float or array_like, shape (m,), optional
        Known fault-free mean of the residual (not estimated from the data).
    sigma : float or array_like, shape (m,), optional
        Known fault-free standard deviation of the residual, > 0.
    state : array_like, shape (m, 2), optional
        Initial (g+, g-) per residual, >= 0; zeros by default.
    restart_on_alarm : bool, optional
        If True, a residual's statistics restart from zero right after each of its alarms,
        as a streaming user calling ``PageHinkley.reset([i])`` after each alarm would get;
        every alarm is then a single sample. If False (default) the statistics keep
        running, so a persistent change keeps the residual in alarm.

    Returns
    -------
    PageHinkleyResult
        Trajectories ``g_up`` and ``g_down`` (N, m), ``alarms`` (N, m) int8 and the final
        ``state`` (m, 2).
    """
    xx = _as_2d(x, "x", missing_ok=True)
    m = xx.shape[1]
    d = _per_residual(delta, m, "delta", nonnegative=True)
    hh = _per_residual(h, m, "h", positive=True)
    mu = _per_residual(mu0, m, "mu0")
    sg = _per_residual(sigma, m, "sigma", positive=True)
    g0 = _check_state(state, m)
    # (x - 0) / 1 is x, bit for bit: skip two passes over the record for the usual call.
    u = xx if not mu.any() and (sg == 1.0).all() else (xx - mu) / sg
    if restart_on_alarm:
        result, _ = _run_restarts(u, d, hh, g0)
        assert result is not None
        return result
    return _run_plain(u, d, hh, g0)


class ChangePointDetector:
    """Two-sided Page-Hinkley per residual that also dates the change: for each statistic it
    keeps the last sample where it was zero after a (non-missing) residual, so an alarm's change
    point is the sample after that. The streaming form (``step``) and the block form (``run``)
    leave the same state. A diagnoser restarts it after each decision.

    Beside the residuals it can run the same test on projections of them (``projection``):
    column c of the statistics is then residual row @ projection[:, c], with its own drift
    and threshold (canfdi.methods.parity.signatures: one CUSUM per fault signature and drift).
    A projection of a row with a missing residual is missing.

    Parameters
    ----------
    m : number of residuals; delta : drift; h : (m,) thresholds (noise-std units).
    projection : (m, c) extra columns; drifts, h_projected : (c,) their drifts and thresholds.

    Examples
    --------
    >>> det = ChangePointDetector(2, 0.5, [5.0, 5.0], projection=np.array([[1.0], [1.0]]),
    ...                           drifts=[0.5], h_projected=[6.0])
    >>> [det.step(k, np.array([1.2, 1.2])).tolist() for k in range(4)]
    [[0, 0, 0], [0, 0, 0], [0, 0, 0], [0, 0, 1]]
    >>> det.columns
    3
    """

    def __init__(self, m: int, delta: float, h: ArrayLike,
                 projection: ArrayLike | None = None, drifts: ArrayLike = (),
                 h_projected: ArrayLike = ()) -> None:
        self.m = m
        self.projection = (None if projection is None
                           else check_shape("projection", projection, (m, "c")))
        c = 0 if self.projection is None else self.projection.shape[1]
        self.columns = m + c
        self._delta = np.concatenate([np.full(m, float(delta)),
                                      np.asarray(drifts, dtype=float).reshape(c)])
        self._h = np.concatenate([np.asarray(h, dtype=float).reshape(m),
                                  np.asarray(h_projected, dtype=float).reshape(c)])
        self.restart()

    @property
    def h(self) -> NDArray[np.float64]:
        """(m,) the residuals' thresholds (settable; the projections' stay)."""
        return self._h[: self.m]

    @h.setter
    def h(self, value: ArrayLike) -> None:
        self._h = np.concatenate([np.asarray(value, dtype=float).reshape(self.m),
                                  self._h[self.m:]])

    @property
    def all_thresholds(self) -> NDArray[np.float64]:
        """(columns,) the thresholds of the residuals, then of the projections."""
        return self._h.copy()

    def restart(self, k: int = -1) -> None:
        """Zero the statistics; a change point cannot predate sample k."""
        self.state = np.zeros((self.columns, 2))
        self.last_zero = np.full((self.columns, 2), k, dtype=np.int64)

    @property
    def statistics(self) -> NDArray[np.float64]:
        """(m,) the larger statistic of each residual."""
        return self.state[: self.m].max(axis=1)

    def _columns(self, rn: NDArray[np.float64]) -> NDArray[np.float64]:
        """rn (..., m) -> (..., columns): the residuals, then their projections."""
        if self.projection is None:
            return rn
        return np.concatenate([rn, rn @ self.projection], axis=-1)

    def step(self, k: int, rn: NDArray[np.float64]) -> NDArray[np.int8]:
        """Sample k's normalised residuals (m,) (NaN = missing); the (columns,) alarm signs."""
        # page_hinkley_step's arithmetic without its checks of parameters already checked:
        # this runs once per sample on the live path. (x - 0) / 1 is x, bit for bit.
        _check_finite(rn, "x", missing_ok=True)
        x = self._columns(rn)
        self.state, alarm = _ph_advance(self.state, x, self._delta, self._h, 0.0, 1.0)
        self.last_zero[(self.state == 0.0) & ~np.isnan(x)[:, None]] = k
        return alarm

    def run(self, k: NDArray[np.int64], rn: NDArray[np.float64]
            ) -> tuple[PageHinkleyResult, int]:
        """Rows of samples k (N,), residuals rn (N, m): the batch result over the (N, columns)
        statistics and ``done``, the rows before the first alarm row (N without one). The state
        advances over those rows only: the alarm row is left for ``step``."""
        x = self._columns(rn)
        ph = page_hinkley_batch(x, self._delta, self._h, state=self.state)
        # The first alarm row: the first nonzero of the flat (row-major) alarms (argmax stops
        # there; a reduction along the short axis costs a pass per row).
        flat = ph.alarms.reshape(-1) != 0
        first = int(flat.argmax())
        done = first // self.columns if flat[first] else len(rn)
        if done > 0:
            valid = ~np.isnan(x[:done])
            cols = np.arange(self.columns)
            for d, traj in enumerate((ph.g_up[:done], ph.g_down[:done])):
                zero = ((traj == 0.0) & valid)[::-1]
                back = np.argmax(zero, axis=0)  # rows from the end to each one's last zero
                any_zero = zero[back, cols]
                self.last_zero[any_zero, d] = k[done - 1 - back[any_zero]]
            self.state = np.stack([ph.g_up[done - 1], ph.g_down[done - 1]], axis=1)
        return ph, done

    def change_point(self, alarm: NDArray[np.int8]) -> int:
        """The earliest sample after which an alarming statistic last was zero, plus one."""
        alarming = np.flatnonzero(alarm)
        col = np.where(alarm[alarming] > 0, 0, 1)
        return int(np.min(self.last_zero[alarming, col])) + 1


class DetectorBacked:
    """The `thresholds` and `statistics` of a diagnoser (canfdi.core.protocol) that detects
    with a `ChangePointDetector` held as ``self.detector``."""

    detector: ChangePointDetector

    @property
    def thresholds(self) -> NDArray[np.float64]:
        """(m,) Page-Hinkley thresholds in noise stds: the detector's (settable, e.g. scaled by
        a sensitivity check)."""
        return self.detector.h

    @thresholds.setter
    def thresholds(self, value: ArrayLike) -> None:
        self.detector.h = np.asarray(value, dtype=float).reshape(self.detector.m)

    @property
    def statistics(self) -> NDArray[np.float64]:
        """(m,) the larger Page-Hinkley statistic of each residual."""
        return self.detector.statistics


def onset_candidates(change_point: int, k: int, first: int, before: int,
                     at_most: int, keep: str = "latest") -> list[int]:
    """Fault onsets to try after an alarm at k: noise may lift the statistic a little before
    the fault, so from ``before`` samples ahead of the change point up to the alarm itself,
    none before ``first`` (the oldest sample kept), ``at_most`` of them ([k] when none is
    left): the latest (``keep="latest"``), or half from the earliest and half from the
    latest (``"ends"``, for a caller that keeps the samples back to the change point: a small
    fault is dated by the change point long before its alarm, and a large one by its alarm,
    when noise had lifted a statistic before it).

    >>> onset_candidates(100, 150, 0, 3, 4), onset_candidates(100, 150, 0, 3, 4, "ends")
    ([147, 148, 149, 150], [97, 98, 149, 150])
    """
    onsets = [kf for kf in range(change_point - before, k + 1) if kf >= first]
    if keep == "ends" and len(onsets) > at_most:
        head = at_most // 2
        return onsets[:head] + onsets[len(onsets) - (at_most - head):]
    return onsets[-at_most:] or [k]


class PageHinkley:
    """Streaming two-sided Page-Hinkley test with a known reference mean.

    Unlike self-resetting implementations with a running mean, the reference ``mu0`` is
    fixed and nothing is reset on an alarm: the statistics keep running (so a persistent
    change stays in alarm) until the caller calls `reset`.

    Parameters
    ----------
    delta : float or array_like, shape (m,)
        Drift, half the smallest change to detect, in units of sigma, >= 0.
    h : float or array_like, shape (m,)
        Alarm threshold in units of sigma, > 0.
    mu0 : float or array_like, shape (m,), optional
        Known fault-free mean of each residual.
    sigma : float or array_like, shape (m,), optional
        Known fault-free standard deviation of each residual, > 0.
    n_residuals : int, optional
        Number m of residuals monitored together.
    """

    def __init__(
        self,
        delta: ArrayLike,
        h: ArrayLike,
        mu0: ArrayLike = 0.0,
        sigma: ArrayLike = 1.0,
        n_residuals: int = 1,
    ) -> None:
        if int(n_residuals) != n_residuals or n_residuals < 1:
            raise ValueError(f"n_residuals: must be a positive integer, got {n_residuals!r}")
        m = int(n_residuals)
        self.n_residuals = m
        self.delta = _per_residual(delta, m, "delta", nonnegative=True)
        self.h = _per_residual(h, m, "h", positive=True)
        self.mu0 = _per_residual(mu0, m, "mu0")
        self.sigma = _per_residual(sigma, m, "sigma", positive=True)
        self._state = np.zeros((m, 2))
        self._latched = np.zeros(m, dtype=np.int8)

    @property
    def statistics(self) -> NDArray[np.float64]:
        """ndarray, shape (m, 2): current (g+, g-) per residual (a copy)."""
        return self._state.copy()

    @property
    def alarm_state(self) -> NDArray[np.int8]:
        """ndarray of int8, shape (m,): direction of the first alarm since the last reset.

        0 where the residual has not alarmed; it stays set even if the statistic later
        falls back under h, until `reset` clears it.
        """
        return self._latched.copy()

    def update(self, x_row: ArrayLike) -> NDArray[np.int8]:
        """Feed one sample.

        Parameters
        ----------
        x_row : array_like, shape (m,)
            Residuals at this sample.

        Returns
        -------
        ndarray of int8, shape (m,)
            +1 (upward change), -1 (downward change) or 0 per residual.
        """
        row = check_shape("x_row", np.atleast_1d(x_row), (self.n_residuals,), dtype=np.float64)
        _check_finite(row, "x", missing_ok=True)
        self._state, alarm = _ph_advance(self._state, row, self.delta, self.h, self.mu0,
                                         self.sigma)
        self._latched = np.where(self._latched == 0, alarm, self._latched).astype(np.int8)
        return alarm

    def reset(self, indices: ArrayLike | None = None) -> None:
        """Zero the statistics and the alarm state.

        Parameters
        ----------
        indices : array_like of int, shape (k,), optional
            Residuals to reset; all of them by default.
        """
        if indices is None:
            self._state[:] = 0.0
            self._latched[:] = 0
            return
        idx = np.atleast_1d(np.asarray(indices))
        if idx.ndim != 1 or (idx.size and not np.issubdtype(idx.dtype, np.integer)):
            raise ValueError("indices: expected a 1-D array of integers")
        if idx.size and (idx.min() < -self.n_residuals or idx.max() >= self.n_residuals):
            raise ValueError(f"indices: out of range for {self.n_residuals} residuals")
        self._state[idx] = 0.0
        self._latched[idx] = 0



"""Residual evaluation: the two-sided Page-Hinkley (CUSUM) test.

The two-sided Page-Hinkley stopping rule (Basseville & Nikiforov 1993, "Detection of Abrupt
Changes", Sections 2.2 and 5.2) accumulates small persistent deviations that a per-sample
threshold would miss. It comes as a batch function over a whole record (`page_hinkley_batch`,
cumulative sums) and as the streaming detector the diagnosers run (`ChangePointDetector`, which
also dates the change); both share the same arithmetic and leave the same state. Choosing the
thresholds (Siegmund's approximation of the run length, calibration on fault-free residuals) is
canfdi.core.calibrate.

References
----------
M. Basseville and I. V. Nikiforov, *Detection of Abrupt Changes: Theory and Application*,
Prentice Hall, 1993.
D. Siegmund, *Sequential Analysis: Tests and Confidence Intervals*, Springer, 1985.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from canfdi.core._check import check_shape

__all__ = [
    "ChangePointBlock",
    "ChangePointDetector",
    "DetectorBacked",
    "PageHinkleyResult",
    "change_point_block",
    "onset_candidates",
    "page_hinkley_batch",
]

# Cumulative sums are restarted at least this often so that their magnitude (which drifts by
# -delta per sample) cannot eat the precision of g = S_k - min_j S_j on long records.
_MAX_BLOCK = 4096
_MIN_WINDOW = 16



# --------------------------------------------------------------------------------------
# records
# --------------------------------------------------------------------------------------


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

    Examples
    --------
    >>> res = page_hinkley_batch(np.array([[1.0], [3.0], [3.0]]), delta=0.5, h=4.0)
    >>> res.g_up[:, 0], res.alarms[:, 0], res.state
    (array([0.5, 3. , 5.5]), array([0, 0, 1], dtype=int8), array([[5.5, 0. ]]))
    """

    g_up: NDArray[np.float64]
    g_down: NDArray[np.float64]
    alarms: NDArray[np.int8]
    state: NDArray[np.float64]


# --------------------------------------------------------------------------------------
# argument checks
# --------------------------------------------------------------------------------------


def _as_2d(x: ArrayLike, name: str, missing_ok: bool = False) -> NDArray[np.float64]:
    arr = check_shape(name, x, ("N", "m"), dtype=np.float64)
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
    # the increments are formed exactly as in _ph_advance so both agree to rounding
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


def _ph_advance(st: NDArray[np.float64], u: NDArray[np.float64], d: NDArray[np.float64],
                hh: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.int8]]:
    """One sample of the two-sided test on checked arrays: (m, 2) state (g+, g-), (m,)
    normalised residuals u (NaN: missing, the statistics hold), drifts d and thresholds hh; the
    new state and the (m,) alarm signs. The detector's per-sample path: its parameters were
    checked once, at construction."""
    up, down = _increments(u, d)
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

    Same arithmetic as ``g+ = max(0, g+ + u - delta)``, ``g- = max(0, g- - u - delta)`` with
    u = (x - mu0) / sigma applied sample by sample (a residual is in alarm while either
    statistic is >= h, the larger one naming the direction), vectorised with
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
        as a streaming user zeroing its statistics after each alarm would get; every alarm
        is then a single sample. If False (default) the statistics keep running, so a
        persistent change keeps the residual in alarm.

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


@dataclass(frozen=True)
class ChangePointBlock:
    """What `change_point_block` gives: the rows before the first alarm row (``done``, the
    block's length without one), the statistics g_up and g_down (rows, c) of those rows and
    of the alarm row (rows = done + 1 with an alarm, else done), the alarm row's signs
    ``alarm`` (c,) (zeros without one), and the state and last zeros after the done rows.

    Examples
    --------
    >>> blk = change_point_block(np.arange(3), np.array([[1.0], [3.0], [3.0]]), np.array([0.5]),
    ...                          np.array([4.0]), np.zeros((1, 2)), np.full((1, 2), -1))
    >>> blk.done, blk.g_up[:, 0], blk.alarm, blk.state
    (2, array([0.5, 3. , 5.5]), array([1], dtype=int8), array([[3., 0.]]))
    """

    done: int
    g_up: NDArray[np.float64]
    g_down: NDArray[np.float64]
    alarm: NDArray[np.int8]
    state: NDArray[np.float64]
    last_zero: NDArray[np.int64]


def change_point_block(k: NDArray[np.int64], x: NDArray[np.float64], delta: NDArray[np.float64],
                       h: NDArray[np.float64], state: NDArray[np.float64],
                       last_zero: NDArray[np.int64]) -> ChangePointBlock:
    """Two-sided Page-Hinkley over rows k (N,), x (N, c) (NaN missing) to the first alarm row,
    with drifts delta and thresholds h (c,), from state (c, 2) and last zeros (c, 2) (the last
    sample each statistic was zero after a present value): `ChangePointBlock`. The numpy
    reference of the kernels' detector block (canfdi.core.kernel): like the C one it takes
    arrays its caller checked (`ChangePointDetector.update_block`: x finite or NaN, the
    parameters at construction) and page_hinkley_batch's arithmetic without its checks; inputs
    are not modified."""
    ph = _run_plain(x, delta, h, state)
    width = x.shape[1]
    # The first alarm row: the first nonzero of the flat (row-major) alarms (argmax stops
    # there; a reduction along the short axis costs a pass per row).
    flat = ph.alarms.reshape(-1) != 0
    first = int(flat.argmax()) if flat.size else 0
    done = first // width if flat.size and flat[first] else len(x)
    last_zero = last_zero.copy()
    new_state = state.copy()
    if done > 0:
        valid = ~np.isnan(x[:done])
        cols = np.arange(width)
        for d, traj in enumerate((ph.g_up[:done], ph.g_down[:done])):
            zero = ((traj == 0.0) & valid)[::-1]
            back = np.argmax(zero, axis=0)  # rows from the end to each one's last zero
            any_zero = zero[back, cols]
            last_zero[any_zero, d] = k[done - 1 - back[any_zero]]
        new_state = np.stack([ph.g_up[done - 1], ph.g_down[done - 1]], axis=1)
    rows = min(done + 1, len(x))
    alarm = ph.alarms[done] if done < len(x) else np.zeros(width, dtype=np.int8)
    return ChangePointBlock(done, ph.g_up[:rows], ph.g_down[:rows], alarm, new_state,
                            last_zero)


class ChangePointDetector:
    """Two-sided Page-Hinkley per residual that also dates the change: for each statistic it
    keeps the last sample where it was zero after a (non-missing) residual, so an alarm's change
    point is the sample after that. The streaming form (`update`) and the block form
    (`update_block`) leave the same state. A diagnoser resets it after each decision.

    Beside the residuals it can run the same test on projections of them (``projection``):
    column c of the statistics is then residual row @ projection[:, c], with its own drift
    and threshold (canfdi.methods.parity.signatures: one CUSUM per fault signature and drift).
    A projection of a row with a missing residual is missing. Nothing is reset on an alarm:
    the caller decides, with `reset`.

    Parameters
    ----------
    m : int
        Number of residuals.
    delta : float
        Drift of the residuals' statistics, half the smallest change to detect (noise stds).
    h : array_like, shape (m,)
        The residuals' thresholds (noise stds), > 0.
    projection : array_like, shape (m, c), optional
        Extra columns: the residual row's projections.
    drifts, h_projected : array_like, shape (c,), optional
        The projections' drifts and thresholds.

    Examples
    --------
    >>> det = ChangePointDetector(2, 0.5, [5.0, 5.0], projection=np.array([[1.0], [1.0]]),
    ...                           drifts=[0.5], h_projected=[6.0])
    >>> [det.update(k, np.array([1.2, 1.2])).tolist() for k in range(4)]
    [[0, 0, 0], [0, 0, 0], [0, 0, 0], [0, 0, 1]]
    >>> det.change_point(det.update(4, np.array([1.2, 1.2])))
    0
    >>> det.statistics
    array([3.5, 3.5])
    >>> det.reset(4)
    >>> det.statistics
    array([0., 0.])
    """

    def __init__(self, m: int, delta: float, h: ArrayLike,
                 projection: ArrayLike | None = None, drifts: ArrayLike = (),
                 h_projected: ArrayLike = ()) -> None:
        self.m = m
        self.projection = (None if projection is None
                           else check_shape("projection", projection, (m, "c")))
        c = 0 if self.projection is None else self.projection.shape[1]
        self._width = m + c
        self._delta = np.concatenate([np.full(m, float(delta)),
                                      np.asarray(drifts, dtype=float).reshape(c)])
        self._h = np.concatenate([np.asarray(h, dtype=float).reshape(m),
                                  np.asarray(h_projected, dtype=float).reshape(c)])
        # The block form's kernel (canfdi.core.kernel): the numpy reference unless set.
        self.block: Callable[..., ChangePointBlock] = change_point_block
        self.reset()

    @property
    def h(self) -> NDArray[np.float64]:
        """(m,) the residuals' thresholds (settable; the projections' stay)."""
        return self._h[: self.m]

    @h.setter
    def h(self, value: ArrayLike) -> None:
        self._h = np.concatenate([np.asarray(value, dtype=float).reshape(self.m),
                                  self._h[self.m:]])

    def reset(self, k: int = -1) -> None:
        """Zero the statistics; a change point cannot predate sample k."""
        self._state = np.zeros((self._width, 2))
        self._last_zero = np.full((self._width, 2), k, dtype=np.int64)

    @property
    def statistics(self) -> NDArray[np.float64]:
        """(m,) the larger statistic of each residual."""
        return self._state[: self.m].max(axis=1)

    def _columns(self, rn: NDArray[np.float64]) -> NDArray[np.float64]:
        """rn (..., m) -> (..., m + c): the residuals, then their projections."""
        if self.projection is None:
            return rn
        return np.concatenate([rn, rn @ self.projection], axis=-1)

    def update(self, k: int, rn: NDArray[np.float64]) -> NDArray[np.int8]:
        """Sample k's normalised residuals (m,) (NaN = missing); the (m + c,) alarm signs
        (+1 upward change, -1 downward, 0 none)."""
        # The checks of page_hinkley_batch's parameters were made once, at construction:
        # this runs once per sample on the live path.
        _check_finite(rn, "x", missing_ok=True)
        x = self._columns(rn)
        self._state, alarm = _ph_advance(self._state, x, self._delta, self._h)
        self._last_zero[(self._state == 0.0) & ~np.isnan(x)[:, None]] = k
        return alarm

    def update_block(self, k: NDArray[np.int64], rn: NDArray[np.float64]
                     ) -> ChangePointBlock:
        """Rows of samples k (N,), residuals rn (N, m): the `ChangePointBlock` of the (N, m + c)
        statistics' columns. The state advances over the rows before the first alarm row
        only (``done``): the alarm row is left for `update`."""
        x = np.ascontiguousarray(self._columns(rn), dtype=np.float64)
        _check_finite(x, "x", missing_ok=True)
        blk = self.block(np.ascontiguousarray(k, dtype=np.int64), x, self._delta, self._h,
                         self._state, self._last_zero)
        self._state, self._last_zero = blk.state, blk.last_zero
        return blk

    def change_point(self, alarm: NDArray[np.int8]) -> int:
        """The earliest sample after which an alarming statistic last was zero, plus one."""
        alarming = np.flatnonzero(alarm)
        col = np.where(alarm[alarming] > 0, 0, 1)
        return int(np.min(self._last_zero[alarming, col])) + 1


class DetectorBacked:
    """The `thresholds` and `statistics` of a diagnoser (canfdi.core.protocol) that detects
    with a `ChangePointDetector` held (private) as ``self._detector``.

    Examples
    --------
    >>> class Watcher(DetectorBacked):
    ...     def __init__(self):
    ...         self._detector = ChangePointDetector(2, 0.5, [5.0, 8.0])
    >>> w = Watcher()
    >>> w.thresholds = 2 * w.thresholds
    >>> w.thresholds, w.statistics
    (array([10., 16.]), array([0., 0.]))
    """

    _detector: ChangePointDetector

    @property
    def thresholds(self) -> NDArray[np.float64]:
        """(m,) Page-Hinkley thresholds in noise stds: the detector's (settable, e.g. scaled by
        a sensitivity check)."""
        return self._detector.h

    @thresholds.setter
    def thresholds(self, value: ArrayLike) -> None:
        self._detector.h = np.asarray(value, dtype=float).reshape(self._detector.m)

    @property
    def statistics(self) -> NDArray[np.float64]:
        """(m,) the larger Page-Hinkley statistic of each residual."""
        return self._detector.statistics

    def use_kernel(self, kernel: Any) -> None:
        """Run the detector's block form on ``kernel`` (canfdi.core.kernel.Kernel)."""
        kernel.install(detectors=(self._detector,))


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

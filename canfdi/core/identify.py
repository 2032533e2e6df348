"""Least squares, the one copy: recursive least squares in information form (Chan, Hua & Zhang
2006, section IV, eqs. 30-32), step, batch and one-shot.

Once a fault is detected, its size is estimated by fitting a model linear in the fault's
parameters to the residuals: ``r(k) = phi(k) theta + n(k)`` with ``m`` residual rows and ``d``
parameters per sample (an actuator's ``theta = [eta - 1, lambda]``, eq. 29; a sensor bias
vector, eq. 41; an output-error path's step amplitude, the output-error paper). Every fit a method
does goes
through this module.

The recursion of eqs. 30-32 with ``P`` reset to ``P0 = I / prior_precision`` at the alarm is the
same estimator as accumulating the information

    J_k = J_0 + sum_i phi_i^T phi_i,    h_k = J_0 theta_0 + sum_i phi_i^T r_i,
    theta_k = J_k^{-1} h_k,             P_k = J_k^{-1},

with ``J_0 = prior_precision I``; the residual cost ``sum_i |r_i - phi_i theta_k|^2`` (plus the
prior's term) comes from the same sums, ``c_k = rr_k - theta_k . h_k``. That form serves the
diagnosers best (thousands of hypotheses and onsets fitted at once by broadcasting, a solve only
when a decision is due) and the report (a whole trajectory by cumulative sums), so it is the one
kept; tests/unit/core/test_identify.py checks it against eqs. 30-32 written out.

The functions work on `RlsState` the way ``scipy.signal.lfilter(b, a, x, zi) -> (y, zf)`` works on
its state:

* `rls_init` starts (or, at an alarm, restarts: the covariance reset) an estimator;
* `rls_update` absorbs one sample's rows (a NaN residual is a missing row: no equation);
* `rls_solve` gives the estimate, its covariance and the cost;
* `rls_batch` absorbs N samples at once and gives the whole trajectory, with the innovations
  ``r - phi theta_prev``: the same numbers as N calls of `rls_update` and `rls_solve` (to
  rounding);
* `least_squares` is the one-shot fit of a batch (SVD, for badly conditioned regressors such as
  the Steiglitz-McBride iteration of canfdi.methods.output_error).

Every state may carry leading batch dimensions (one estimator per hypothesis and onset, say):
``J`` (..., d, d), ``h`` (..., d).

Examples
--------
>>> import numpy as np
>>> rng = np.random.default_rng(0)
>>> phi = rng.normal(size=(500, 1, 2))
>>> r = phi @ np.array([1.0, -2.0])
>>> result = rls_batch(rls_init(2), phi, r)
>>> np.round(result.theta[-1], 6)
array([ 1., -2.])
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from canfdi.core._check import check_shape

__all__ = [
    "InformationSums",
    "LeastSquaresFit",
    "RlsBatchResult",
    "RlsSolution",
    "RlsState",
    "chi2_sigma",
    "least_squares",
    "rls_batch",
    "rls_increments",
    "rls_init",
    "rls_solve",
    "rls_update",
]

FloatArray = NDArray[np.float64]


def chi2_sigma(d: int, sigma: float = 3.0) -> float:
    """The chi-square quantile of d degrees of freedom at the two-sided ``sigma`` level (a
    d-parameter estimate differs from a value significantly when its squared Mahalanobis
    distance exceeds it: sigma^2 for d = 1; the 3-sigma tail is 0.0027).

    >>> round(chi2_sigma(1), 3), round(chi2_sigma(2), 2), round(chi2_sigma(1, 4.0), 3)
    (9.0, 11.83, 16.0)
    """
    # scipy.special: 30 ms to import where scipy.stats takes 0.6 s; chdtri is chi2.isf.
    from scipy import special
    return float(special.chdtri(d, special.erfc(sigma / np.sqrt(2.0))))

DEFAULT_PRIOR_PRECISION = 1e-8
"""``J_0 = 1e-8 I``: ``P_0 = 1e8 I``, "know nothing" for parameters of any sensible size."""


@dataclass(frozen=True, eq=False)
class RlsState:
    """The information an estimator has absorbed (possibly one per leading batch index).

    Attributes
    ----------
    J : ndarray, shape (..., d, d)
        Information matrix ``J_0 + sum phi^T phi`` (the inverse of the covariance ``P``).
    h : ndarray, shape (..., d)
        Information vector ``J_0 theta_0 + sum phi^T r``.
    rr : ndarray, shape broadcastable to (...)
        ``theta_0 . J_0 theta_0 + sum |r|^2``: with ``h`` and ``J`` it gives the cost.
    n : int
        Samples (time steps) absorbed since `rls_init`.
    n_eq : int
        Residual rows absorbed (missing rows not counted): the degrees of freedom of the cost.

    Examples
    --------
    >>> state = rls_update(rls_init(2), np.array([[1.0, 0.0], [0.0, 2.0]]), [3.0, np.nan])
    >>> state.d, state.n, state.n_eq, state.h
    (2, 1, 1, array([3., 0.]))
    """

    J: FloatArray
    h: FloatArray
    rr: FloatArray
    n: int = 0
    n_eq: int = 0

    @property
    def d(self) -> int:
        """Number of parameters."""
        return int(self.h.shape[-1])


@dataclass(frozen=True, eq=False)
class RlsSolution:
    """`rls_solve`'s result.

    theta : (..., d) estimates; P : (..., d, d) their covariance up to the noise variance
    (``J^{-1}``); cost : (...) residual sum of squares at theta (prior term included);
    dof : residual rows minus parameters (at least 1), to scale P by ``cost / dof``.

    Examples
    --------
    >>> state = rls_init(1, prior_precision=1e-12)
    >>> for x, r in ((1.0, 2.1), (2.0, 3.9), (3.0, 6.0)):
    ...     state = rls_update(state, [[x]], [r])
    >>> sol = rls_solve(state)
    >>> round(float(sol.theta[0]), 4), sol.dof, round(float(sol.cost), 4)
    (1.9929, 2, 0.0193)
    """

    theta: FloatArray
    P: FloatArray
    cost: FloatArray
    dof: int

    @property
    def variances(self) -> FloatArray:
        """(..., d) the estimates' variances: ``diag(P) cost / dof``."""
        scale = np.maximum(np.asarray(self.cost, dtype=float) / self.dof, 1e-300)
        return np.diagonal(self.P, axis1=-2, axis2=-1) * scale[..., None]


@dataclass(frozen=True, eq=False)
class RlsBatchResult:
    """What `rls_batch` produced for N samples.

    theta : (N, ..., d) estimate after each sample; variances : (N, ..., d) ``diag(P)`` after
    each sample (up to the noise variance); P : (N, d, d) the covariance itself (``J^{-1}``,
    for a sandwich); cost : (N, ...) residual cost after each sample;
    innovations : (N, ..., m) a-priori residuals ``r_k - phi_k theta_{k-1}`` (NaN for missing
    rows); state : the state after the last sample, to pass to the next call.

    Examples
    --------
    >>> result = rls_batch(rls_init(1), np.ones((3, 1, 1)), [2.0, 2.0, np.nan])
    >>> np.round(result.theta[:, 0], 6), np.round(result.innovations[:, 0], 6)
    (array([2., 2., 2.]), array([ 2.,  0., nan]))
    >>> result.state.n_eq
    2
    """

    theta: FloatArray
    variances: FloatArray
    cost: FloatArray
    innovations: FloatArray
    state: RlsState
    P: FloatArray


def rls_init(d: int, prior_precision: float = DEFAULT_PRIOR_PRECISION,
             theta0: ArrayLike | None = None, shape: tuple[int, ...] = ()) -> RlsState:
    """Start (or restart) an estimator: ``P = I / prior_precision`` around ``theta0``.

    Calling it again on a running estimator is the covariance reset of eqs. 30-32: the samples
    after it decide, so an abrupt change of the parameters is followed within about ``d``
    samples.

    Parameters
    ----------
    d : number of parameters, >= 1.
    prior_precision : ``1 / P_0``, > 0 (small: know nothing).
    theta0 : ``(d,)`` or ``(*shape, d)`` prior estimate; zeros by default.
    shape : leading batch shape (one estimator per index).
    """
    if isinstance(d, bool) or not isinstance(d, int | np.integer) or d < 1:
        raise ValueError(f"d: expected an integer >= 1, got {d!r}")
    prior = float(prior_precision)
    if not (np.isfinite(prior) and prior > 0.0):
        raise ValueError(f"prior_precision: expected a finite number > 0, got {prior_precision!r}")
    J = np.broadcast_to(np.eye(d) * prior, (*shape, d, d)).copy()
    if theta0 is None:
        return RlsState(J=J, h=np.zeros((*shape, d)), rr=np.zeros(shape))
    theta = np.broadcast_to(np.asarray(theta0, dtype=float), (*shape, d))
    check_shape("theta0", theta, (*shape, d), finite=True)
    h = theta * prior
    return RlsState(J=J, h=h.copy(), rr=np.einsum("...i,...i->...", theta, h))


def _rows(phi: ArrayLike, r: ArrayLike, d: int) -> tuple[FloatArray, FloatArray, FloatArray]:
    """phi (..., m, d) and r (..., m) with missing rows zeroed, and the valid-row mask."""
    phi_a = np.asarray(phi, dtype=float)
    if phi_a.ndim < 2 or phi_a.shape[-1] != d:
        raise ValueError(f"phi: expected shape (..., m, {d}), got {phi_a.shape}")
    r_a = np.asarray(r, dtype=float)
    if r_a.ndim == 0:
        r_a = r_a.reshape(1)
    if r_a.shape[-1] != phi_a.shape[-2]:
        raise ValueError(f"r: expected shape (..., {phi_a.shape[-2]}), got {r_a.shape}")
    valid = ~np.isnan(r_a)
    if valid.all():
        return phi_a, r_a, valid
    # A missing residual (its window read a lost value) gives no equation.
    return phi_a * valid[..., None], np.where(valid, r_a, 0.0), valid


@dataclass(frozen=True, eq=False)
class InformationSums:
    """What samples add to estimators in information form (one per leading batch index), and
    to the middle of their sandwich covariance: `rls_increments`, or a diagnosis' regressors
    and sums at once (canfdi.methods.parity.hypotheses.information_increments, or the C
    kernel's cfdi_info_block).

    J : (..., d, d) sum phi^T phi; h : (..., d) sum phi^T r; rr : () sum r^2; n_eq : the
    residual rows absorbed (missing ones not counted); meat : (..., d, d) sum phi^T Gamma phi
    (zeros where no Gamma is given).

    Examples
    --------
    >>> sums = rls_increments(np.array([[1.0, 0.0], [0.0, 2.0]]), [3.0, np.nan], 2)
    >>> sums.h.tolist(), float(sums.rr), sums.n_eq  # the missing row gives no equation
    ([3.0, 0.0], 9.0, 1)
    >>> state = sums.added_to(rls_init(2), samples=1)
    >>> state.n, state.n_eq, state.h.tolist()
    (1, 1, [3.0, 0.0])
    """

    J: FloatArray
    h: FloatArray
    rr: FloatArray
    n_eq: int
    meat: FloatArray

    def added_to(self, state: RlsState, samples: int) -> RlsState:
        """``state`` with these sums absorbed (``samples`` time steps of them)."""
        return RlsState(J=state.J + self.J, h=state.h + self.h, rr=state.rr + self.rr,
                        n=state.n + samples, n_eq=state.n_eq + self.n_eq)


def rls_increments(phi: ArrayLike, r: ArrayLike, d: int) -> InformationSums:
    """The sums `rls_update` adds for rows ``r = phi theta + noise``: phi (..., m, d), r (m,)
    or (..., m), NaN a missing row (no equation); no sandwich middle (``meat`` zeros)."""
    phi_a, r_a, valid = _rows(phi, r, d)
    J = np.einsum("...mi,...mj->...ij", phi_a, phi_a)
    return InformationSums(J=J, h=np.einsum("...mi,...m->...i", phi_a, r_a),
                           rr=np.einsum("...m,...m->...", r_a, r_a), n_eq=int(valid.sum()),
                           meat=np.zeros_like(J))


def rls_update(state: RlsState, phi: ArrayLike, r: ArrayLike, samples: int = 1) -> RlsState:
    """Absorb one sample: ``m`` residual rows ``r = phi theta + noise`` (or ``samples`` of
    them at once, their rows stacked: the information form is a sum, so one update of the
    stack is that many updates in a row).

    Parameters
    ----------
    state : the estimator(s), batch shape (...).
    phi : (..., m, d) regressor rows (broadcast against the state's batch shape).
    r : (m,) or (..., m) residuals; NaN marks a missing row (no equation).
    samples : how many samples the rows are.

    Returns
    -------
    RlsState with the sample absorbed (a new state; the input is not modified).
    """
    return rls_increments(phi, r, state.d).added_to(state, samples)


def rls_solve(state: RlsState) -> RlsSolution:
    """The estimate of every estimator of the state, its covariance and its cost.

    Raises numpy.linalg.LinAlgError when an information matrix is singular (a zero prior
    precision with too few equations).
    """
    theta = np.linalg.solve(state.J, state.h[..., None])[..., 0]
    cost = state.rr - np.einsum("...i,...i->...", theta, state.h)
    return RlsSolution(theta=theta, P=np.linalg.inv(state.J), cost=cost,
                       dof=max(state.n_eq - state.d, 1))


def rls_batch(state: RlsState, Phi: ArrayLike, R: ArrayLike) -> RlsBatchResult:
    """Absorb N samples at once and give the trajectory: N calls of `rls_update` (and
    `rls_solve` after each) in one pass (cumulative sums of the information, one batched
    solve).

    Parameters
    ----------
    state : the estimator before the first sample (no batch dimensions).
    Phi : (N, m, d) regressors; R : (N, m) residuals, NaN for missing rows ((N,) when m = 1).

    Returns
    -------
    RlsBatchResult: theta, variances (diag P), cost, innovations, and the final state.
    """
    d = state.d
    if state.h.shape != (d,):
        raise ValueError(f"state: rls_batch takes one estimator, got batch shape "
                         f"{state.h.shape[:-1]}")
    Phi_a = check_shape("Phi", Phi, ("N", "m", d), dtype=float)
    n, m, _ = Phi_a.shape
    R_a = np.asarray(R, dtype=float)
    if R_a.ndim == 1 and m == 1:
        R_a = R_a[:, None]
    R_a = check_shape("R", R_a, (n, m))
    phi_v, r_v, valid = _rows(Phi_a, R_a, d)
    J = state.J + np.cumsum(np.einsum("nmi,nmj->nij", phi_v, phi_v), axis=0)
    h = state.h + np.cumsum(np.einsum("nmi,nm->ni", phi_v, r_v), axis=0)
    rr = state.rr + np.cumsum(np.einsum("nm,nm->n", r_v, r_v))
    n_eq = state.n_eq + np.cumsum(valid.sum(axis=1))
    theta = np.linalg.solve(J, h[..., None])[..., 0]
    P = np.linalg.inv(J)
    cost = rr - np.einsum("ni,ni->n", theta, h)
    prev = np.concatenate([rls_solve(state).theta[None], theta[:-1]]) if n else theta
    innovations = np.where(valid, R_a - np.einsum("nmi,ni->nm", Phi_a, prev), np.nan)
    final = (RlsState(J=J[-1], h=h[-1], rr=rr[-1], n=state.n + n, n_eq=int(n_eq[-1]))
             if n else state)
    return RlsBatchResult(theta=theta, variances=np.diagonal(P, axis1=1, axis2=2).copy(),
                          cost=cost, innovations=innovations, state=final, P=P)


@dataclass(frozen=True, eq=False)
class LeastSquaresFit:
    """`least_squares`'s result: theta (d,) or (d, c), cost (the weighted residual sum of
    squares, float or (c,)), dof = rows - rank (at least 1), rank, and the weighted regressors
    the unscaled covariance ``(X^T W X)^+`` (d, d) is computed from on demand.

    Examples
    --------
    >>> fit = least_squares(np.array([[1.0], [1.0], [1.0]]), [1.0, 2.0, np.nan])
    >>> fit.theta, fit.cost, fit.dof, fit.covariance
    (array([1.5]), 0.5, 1, array([[0.5]]))
    """

    theta: FloatArray
    cost: float | FloatArray
    dof: int
    rank: int
    weighted_regressors: FloatArray

    @property
    def covariance(self) -> FloatArray:
        """(d, d) ``(X^T W X)^+``: the estimates' covariance up to the noise variance."""
        Xw = self.weighted_regressors
        return np.linalg.pinv(Xw.T @ Xw)


def least_squares(X: ArrayLike, y: ArrayLike, weights: ArrayLike | None = None) -> LeastSquaresFit:
    """One-shot weighted least squares ``min sum w_i (y_i - X_i theta)^2`` (by SVD).

    Parameters
    ----------
    X : (N, d) regressors; y : (N,) or (N, c) data (c right-hand sides share X); weights : (N,)
    non-negative row weights (default 1). Rows with a NaN in y or X are left out.

    Returns
    -------
    LeastSquaresFit; theta is (d,) or (d, c), cost a float or (c,).
    """
    X_a = check_shape("X", X, ("N", "d"), dtype=float)
    y_a = np.asarray(y, dtype=float)
    if y_a.shape[:1] != X_a.shape[:1] or y_a.ndim not in (1, 2):
        raise ValueError(f"y: expected shape ({X_a.shape[0]},) or ({X_a.shape[0]}, c), got "
                         f"{y_a.shape}")
    keep = ~np.isnan(X_a).any(axis=1) & ~np.isnan(y_a.reshape(len(y_a), -1)).any(axis=1)
    w = np.ones(len(X_a)) if weights is None else check_shape("weights", weights,
                                                              (len(X_a),), dtype=float)
    sw = np.sqrt(np.where(keep, w, 0.0))
    Xw = np.where(keep[:, None], X_a, 0.0) * sw[:, None]
    yw = np.where(keep.reshape(-1, *([1] * (y_a.ndim - 1))), y_a, 0.0) * sw.reshape(
        -1, *([1] * (y_a.ndim - 1)))
    theta, _, rank, _ = np.linalg.lstsq(Xw, yw, rcond=None)
    resid = yw - Xw @ theta
    cost = (resid**2).sum(axis=0)
    return LeastSquaresFit(theta=theta, cost=float(cost) if np.ndim(cost) == 0 else cost,
                           dof=max(int(keep.sum()) - int(rank), 1), rank=int(rank),
                           weighted_regressors=Xw)

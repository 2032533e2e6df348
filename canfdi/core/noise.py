"""The measurement noise of a drive, estimated from healthy data through its parity space.

Over a window of s+1 samples, Y(k) = H0 x(k-s) + Hc U(k) + Hw W(k) + Xi(k) (Chan et al. 2006 eq. 3),
Xi the stacked sensor noise. Every row v of a basis V of the left null space of [H0, Hw]
gives a residual r = v^T (Y - Hc U) = v^T Xi that neither the state nor the unknown inputs
reach: whatever the drive does, r is the sensor noise seen through v. With white noise of
covariance R, the residuals' autocovariances are linear in R,

    E[r(k) r(k+tau)^T] = sum_{l=tau}^{s} V_l R V_{l-tau}^T,   V_l the (d, q) block of sample l,

so R follows from the sample autocovariances at lags 0..s by linear least squares (diagonal R:
non-negative; full R: projected onto the positive semi-definite cone). The inputs are taken as
known (commands), as the model takes them; process noise, and a model whose B or A is off,
leak into r and inflate the estimate (the calibration's model check says where).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from canfdi.core.model import StateSpace
from canfdi.core.parity import left_null_space, parity_matrices

__all__ = ["NoiseEstimate", "estimate_measurement_noise", "parity_space_residuals"]


@dataclass(frozen=True)
class NoiseEstimate:
    """Sensor noise estimated from healthy data.

    std : (q,) standard deviation of each sensor's noise (NaN where not identifiable).
    covariance : (q, q) the estimated R (diagonal unless a full estimate was asked for).
    identifiable : (q,) whether the data determine the sensor's noise alone.
    seen : (q,) whether any parity relation reads the sensor (False: the prior times the scale
        the others show).
    std_error : (q,) approximate standard error of ``std`` (from windows of the record).
    windows : number of complete windows used; s : window order.

    Examples
    --------
    >>> from canfdi.core.model import StateSpace
    >>> model = StateSpace(A=[[0.9]], B=[[1.0]], C=[[1.0], [1.0]], dt=0.01)
    >>> rng = np.random.default_rng(0)
    >>> U = rng.standard_normal((5000, 1))
    >>> x = np.zeros(5000)
    >>> for k in range(4999):
    ...     x[k + 1] = 0.9 * x[k] + U[k, 0]
    >>> Z = x[:, None] + rng.standard_normal((5000, 2)) * [0.01, 0.03]
    >>> est = estimate_measurement_noise(model, 1, U, Z, prior_std=np.array([0.02, 0.02]))
    >>> np.round(est.std, 3), est.identifiable, est.windows
    (array([0.01, 0.03]), array([ True,  True]), 4999)
    """

    std: np.ndarray
    covariance: np.ndarray
    identifiable: np.ndarray
    seen: np.ndarray
    std_error: np.ndarray
    windows: int
    s: int


def parity_space_residuals(model: StateSpace, s: int, U: np.ndarray, Z: np.ndarray
                           ) -> tuple[np.ndarray, np.ndarray]:
    """The full parity space's residuals of a record.

    U : (N, p) commands; Z : (N, q) measurements on consecutive samples (NaN where lost).

    Returns (r, V): r (N - s, d) one row per complete window (NaN where a window holds a lost
    value), V (d, s+1, q) the parity vectors by sample of the window.
    """
    P = parity_matrices(model, s)
    basis = left_null_space(np.hstack([P.H0, P.Hw]))  # ((s+1) q, d)
    Vt = basis.T  # (d, (s+1) q)
    coef_z = Vt.reshape(-1, s + 1, model.q)
    coef_u = -(Vt @ P.Hc).reshape(-1, s + 1, model.p)
    if len(Z) <= s:
        return np.zeros((0, Vt.shape[0])), coef_z
    wz = sliding_window_view(Z, (s + 1, model.q))[:, 0]  # (N - s, s+1, q)
    wu = sliding_window_view(U, (s + 1, model.p))[:, 0]
    r = np.einsum("nlq,dlq->nd", wz, coef_z) + np.einsum("nlp,dlp->nd", wu, coef_u)
    return r, coef_z


def _lag_covariances(r: np.ndarray, lags: int) -> np.ndarray:
    """(lags+1, d, d) sample autocovariances E[r(k) r(k+tau)^T] over rows without NaN pairs."""
    d = r.shape[1]
    out = np.zeros((lags + 1, d, d))
    for tau in range(lags + 1):
        a, b = r[: len(r) - tau], r[tau:]
        ok = ~(np.isnan(a).any(axis=1) | np.isnan(b).any(axis=1))
        if ok.sum() > 1:
            out[tau] = a[ok].T @ b[ok] / ok.sum()
    return out


def _basis(q: int, full: bool) -> list[np.ndarray]:
    """Symmetric (q, q) basis matrices of R: its diagonal, then (full) each off-diagonal pair."""
    out = []
    for i in range(q):
        e = np.zeros((q, q))
        e[i, i] = 1.0
        out.append(e)
    if full:
        for i in range(q):
            for j in range(i + 1, q):
                e = np.zeros((q, q))
                e[i, j] = e[j, i] = 1.0
                out.append(e)
    return out


def _design(coef_z: np.ndarray, basis: list[np.ndarray]) -> np.ndarray:
    """(lags * d * d, len(basis)): each basis matrix's contribution to every lag covariance."""
    s1 = coef_z.shape[1]
    cols = []
    for E in basis:
        blocks = []
        for tau in range(s1):
            G = sum(coef_z[:, l] @ E @ coef_z[:, l - tau].T for l in range(tau, s1))
            blocks.append(np.ravel(G))
        cols.append(np.concatenate(blocks))
    return np.column_stack(cols)


def _estimable(G: np.ndarray, rtol: float = 1e-8) -> np.ndarray:
    """(columns,) whether each parameter is estimable: its unit vector lies in G's row space
    (no combination of the others' equations can stand in for it)."""
    scale = np.linalg.norm(G, axis=0)
    live = scale > rtol * max(float(scale.max()), 1e-300)
    out = np.zeros(G.shape[1], dtype=bool)
    if not live.any():
        return out
    Gn = G[:, live] / scale[live]
    # vt is all that is needed: the full U of a tall matrix would be rows x rows.
    _, sv, vt = np.linalg.svd(Gn, full_matrices=Gn.shape[0] < Gn.shape[1])
    rank = int((sv > rtol * sv[0]).sum())
    null = vt[rank:].T  # (live, dim): directions the equations cannot see
    out[np.flatnonzero(live)] = np.linalg.norm(null, axis=1) < 1e-6 if null.size else True
    return out


def estimate_measurement_noise(model: StateSpace, s: int, U: np.ndarray, Z: np.ndarray,
                               prior_std: np.ndarray, *, full: bool = False) -> NoiseEstimate:
    """Sensor noise of a healthy record through the full parity space of window order s.

    U : (N, p) commands; Z : (N, q) measurements on consecutive samples (NaN where lost).
    prior_std : (q,) the noise the config states: where the data see only a combination of
        sensors (i_a and i_f + i_a only as their difference, say) the combination is split in
        the prior's proportions, and a sensor no parity relation sees keeps its prior times the
        scale the others show. ``identifiable`` says which is which.
    full : estimate R's off-diagonal entries too (sensors that share noise).
    """
    q = model.q
    r, coef_z = parity_space_residuals(model, s, np.asarray(U, float), np.asarray(Z, float))
    ok = ~np.isnan(r).any(axis=1)
    windows = int(ok.sum())
    if windows < 10 * (s + 1):
        raise ValueError(f"{windows} complete windows of {s + 1} samples: too few to estimate "
                         f"the noise (at least {10 * (s + 1)})")
    r = r - r[ok].mean(axis=0)  # an offset is a model matter, not noise
    prior_var = np.asarray(prior_std, dtype=float).reshape(q) ** 2
    basis = _basis(q, full)
    G = _design(coef_z, basis)
    estimable = _estimable(G[:, :q])
    reach = np.linalg.norm(G[:, :q], axis=0)
    seen = reach > 1e-8 * reach.max()
    theta = _fit(G, np.ravel(_lag_covariances(r, s)), prior_var, seen, full)
    R = sum(t * E for t, E in zip(theta, basis, strict=True))
    w, vecs = np.linalg.eigh(R)
    R = (vecs * np.maximum(w, 0.0)) @ vecs.T  # the nearest covariance
    std = np.sqrt(np.maximum(np.diag(R), 0.0))
    # Standard error: the spread of the estimate over ten consecutive parts of the record.
    spread = []
    for rows in np.array_split(np.flatnonzero(ok), 10):
        sub = np.full_like(r, np.nan)
        sub[rows] = r[rows]
        th = _fit(G[:, :q], np.ravel(_lag_covariances(sub, s)), prior_var, seen, False)
        spread.append(np.sqrt(np.maximum(th, 0.0)))
    std_error = np.std(np.array(spread), axis=0, ddof=1) / np.sqrt(10)
    return NoiseEstimate(std=std, covariance=R, identifiable=estimable, seen=seen,
                         std_error=std_error,
                         windows=windows, s=s)


def _fit(G: np.ndarray, target: np.ndarray, prior_var: np.ndarray, seen: np.ndarray,
         full: bool) -> np.ndarray:
    """Variances (and covariances) from the lag covariances: the data decide what they can,
    the prior's proportions the rest (a weak pull towards the prior times the data's overall
    scale, which moves no estimable parameter measurably)."""
    q = len(prior_var)
    diag = G[:, :q]
    scale_fit = diag[:, seen] @ prior_var[seen]
    denom = float(scale_fit @ scale_fit)
    scale = float(scale_fit @ target) / denom if denom > 0 else 1.0
    anchor = max(scale, 0.0) * prior_var
    weight = 1e-4 * np.sqrt(denom) / max(float(np.linalg.norm(prior_var)), 1e-300)
    cols = G.shape[1]
    pull = np.zeros((q, cols))
    pull[:, :q] = np.eye(q) * weight
    A = np.vstack([G, pull])
    b = np.concatenate([target, weight * anchor])
    if full:
        return np.linalg.lstsq(A, b, rcond=None)[0]
    from scipy.optimize import nnls  # here: ~0.2 s to import, on every daemon's start

    return nnls(A, b)[0]

"""How good is an identified model, on data left out of its fit, and may it be used at all.

* `nrmse`: the fit per output as MATLAB's ``compare`` reports it,
  100 (1 - ||y - y_hat|| / ||y - mean(y)||) %: 100 is exact, 0 no better than the mean.
* `simulate` (the model driven by the commands alone, from a state fitted to the first
  samples) and `predict` (one step ahead, by the steady-state Kalman predictor): the two fits.
  The predictor takes each unknown input as a random walk (`with_unknown_inputs`), so it
  follows a load's level as the drive's own observer would; the simulation cannot (the
  unknown inputs are unknown: it runs with none).
* `whiteness` and `input_correlation` of the one-step errors: the autocorrelation at lags
  1..L and the cross-correlation with each input at lags 0..L, against the 99 % band
  2.58 / sqrt(N) of a white error independent of the inputs (Ljung, "System
  Identification", 2nd ed., section 16.6).
* `persistence`: whether the commands excite the drive (an input that is constant, or whose
  stacked windows of L samples span fewer than L p directions, cannot identify L-th order
  dynamics).
* `stability` and `minimality`: the eigenvalues, and the modes the outputs do not see or
  nothing drives (Popov-Belevitch-Hautus tests).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from scipy.linalg import solve_discrete_are

from canfdi.core.identify import least_squares
from canfdi.core.model import StateSpace

__all__ = [
    "initial_state",
    "input_correlation",
    "kalman_gain",
    "minimality",
    "nrmse",
    "persistence",
    "predict",
    "robust_std",
    "simulate",
    "stability",
    "whiteness",
    "with_unknown_inputs",
]

STABLE_TOL = 1e-3
"""An eigenvalue of modulus above 1 + this is unstable (1 within it: an integrator)."""
MINIMAL_RTOL = 1e-7
"""A PBH test whose smallest singular value is below this fraction of the largest fails."""
PE_RTOL = 1e-8
"""Stacked input windows whose covariance has an eigenvalue below this fraction of the
largest are not persistently exciting."""


def nrmse(Y: np.ndarray, Yhat: np.ndarray) -> np.ndarray:
    """(q,) 100 (1 - ||y - y_hat|| / ||y - mean y||) per output over the rows with no NaN
    (NaN for an output that does not vary)."""
    ok = ~(np.isnan(Y).any(axis=1) | np.isnan(Yhat).any(axis=1))
    y, yh = Y[ok], Yhat[ok]
    spread = np.linalg.norm(y - y.mean(axis=0), axis=0)
    err = np.linalg.norm(y - yh, axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = 100.0 * (1.0 - err / spread)
    return np.where(spread > 0, out, np.nan)


def robust_std(R: np.ndarray) -> np.ndarray:
    """(n,) each column's standard deviation from its finite entries' median absolute
    deviation (x 1.4826, exact for Gaussian data): a few load steps or outliers do not count.
    NaN for a column with none."""
    out = np.empty(R.shape[1])
    for i in range(R.shape[1]):
        col = R[np.isfinite(R[:, i]), i]
        out[i] = 1.4826 * np.median(np.abs(col - np.median(col))) if col.size else np.nan
    return out


def with_unknown_inputs(model: StateSpace) -> StateSpace:
    """The model with its unknown inputs as states that stay put unless pushed (a random
    walk: w(k+1) = w(k)): [x; w] with A = [[A, F], [0, I]], C = [C, 0]. A predictor of it
    learns the load's level from the outputs, as the drive's own observer would."""
    n, r = model.n, model.r
    if r == 0:
        return model
    A = np.block([[model.A, model.F], [np.zeros((r, n)), np.eye(r)]])
    B = np.vstack([model.B, np.zeros((r, model.p))])
    C = np.hstack([model.C, np.zeros((model.q, r))])
    return StateSpace(A=A, B=B, C=C, D=model.D, dt=model.dt)


def kalman_gain(model: StateSpace, R: np.ndarray, unknown_scale: float = 3.0,
                unknown_inputs: int = 0) -> np.ndarray:
    """(n, q) steady-state one-step predictor gain with measurement noise diag(R). The last
    ``unknown_inputs`` states (`with_unknown_inputs`) get process noise whose step moves the
    outputs it reaches by ``unknown_scale`` noise standard deviations; every state gets a
    trace (so the Riccati equation is well posed)."""
    A, C = model.A, model.C
    n = A.shape[0]
    Rm = np.diag(np.maximum(np.asarray(R, float), 1e-300))
    Q = np.zeros((n, n))
    for i in range(n - unknown_inputs, n):
        hit = C @ A[:, i]  # what a step of this unknown input does to the next outputs
        scale = float(np.max((hit**2) / np.diag(Rm))) if np.any(hit) else 0.0
        if scale > 0:
            Q[i, i] = unknown_scale**2 / scale
    Cp = np.linalg.pinv(C)
    trace = np.diag(Cp @ Rm @ Cp.T)
    Q += 1e-6 * np.diag(np.where(trace > 0, trace, 1e-12)) + 1e-12 * np.eye(n)
    P = solve_discrete_are(A.T, C.T, Q, Rm)
    return A @ P @ C.T @ np.linalg.inv(C @ P @ C.T + Rm)


def initial_state(model: StateSpace, U: np.ndarray, Y: np.ndarray, count: int) -> np.ndarray:
    """(n,) the state at sample 0 that best explains the first ``count`` samples (least
    squares on y(k) - sim(k) = C A^k x0)."""
    A, B, C, D = model.A, model.B, model.C, model.D
    n = A.shape[0]
    count = min(count, len(Y))
    zero = simulate(model, U[:count], np.zeros(n))
    rows, targets = [], []
    Ak = np.eye(n)
    for k in range(count):
        if not np.isnan(Y[k]).any():
            rows.append(C @ Ak)
            targets.append(Y[k] - zero[k])
        Ak = A @ Ak
    del B, D
    if not rows:
        return np.zeros(n)
    return least_squares(np.vstack(rows), np.concatenate(targets)).theta


def simulate(model: StateSpace, U: np.ndarray, x0: np.ndarray) -> np.ndarray:
    """(N, q) outputs of the model driven by U (N, p) from x0 (n,) (no unknown input)."""
    A, B, C, D = model.A, model.B, model.C, model.D
    x = np.asarray(x0, dtype=float).copy()
    out = np.empty((len(U), C.shape[0]))
    for k in range(len(U)):
        out[k] = C @ x + D @ U[k]
        x = A @ x + B @ U[k]
    return out


def predict(model: StateSpace, K: np.ndarray, U: np.ndarray, Y: np.ndarray, x0: np.ndarray
            ) -> np.ndarray:
    """(N, q) one-step predictions y_hat(k | k-1) of the Kalman predictor with gain K (n, q);
    a lost sample (NaN row) updates nothing."""
    A, B, C, D = model.A, model.B, model.C, model.D
    x = np.asarray(x0, dtype=float).copy()
    out = np.empty((len(U), C.shape[0]))
    for k in range(len(U)):
        yh = C @ x + D @ U[k]
        out[k] = yh
        x = A @ x + B @ U[k]
        if not np.isnan(Y[k]).any():
            x = x + K @ (Y[k] - yh)
    return out


def _corr(a: np.ndarray, b: np.ndarray, lag: int) -> float:
    """Correlation of a(k) with b(k - lag) over rows where both are present."""
    if lag:
        a, b = a[lag:], b[:-lag]
    ok = ~(np.isnan(a) | np.isnan(b))
    if ok.sum() < 3:
        return float("nan")
    x, y = a[ok] - a[ok].mean(), b[ok] - b[ok].mean()
    den = np.sqrt((x @ x) * (y @ y))
    return float(x @ y / den) if den > 0 else 0.0


def whiteness(E: np.ndarray, lags: int = 25) -> list[dict]:
    """Per column of E (N, m): the largest |autocorrelation| at lags 1..lags, how many lags
    leave the 99 % band of a white sequence, and the band."""
    out = []
    for j in range(E.shape[1]):
        e = E[:, j]
        n_ok = int(np.sum(~np.isnan(e)))
        band = 2.58 / np.sqrt(max(n_ok, 1))
        rho = np.array([_corr(e, e, lag) for lag in range(1, lags + 1)])
        out.append({"max": float(np.nanmax(np.abs(rho))) if rho.size else 0.0,
                    "outside": int(np.sum(np.abs(rho) > band)), "lags": lags,
                    "band": float(band)})
    return out


def input_correlation(E: np.ndarray, U: np.ndarray, lags: int = 25) -> list[dict]:
    """Per column of E: for each input, the largest |correlation| of e(k) with u(k - lag) at
    lags 0..lags, and how many lags leave the 99 % band."""
    out = []
    for j in range(E.shape[1]):
        e = E[:, j]
        band = 2.58 / np.sqrt(max(int(np.sum(~np.isnan(e))), 1))
        per = []
        for i in range(U.shape[1]):
            rho = np.array([_corr(e, U[:, i], lag) for lag in range(lags + 1)])
            per.append({"max": float(np.nanmax(np.abs(rho))),
                        "outside": int(np.sum(np.abs(rho) > band))})
        out.append({"band": float(band), "inputs": per})
    return out


def persistence(records: Sequence[np.ndarray], order: int) -> tuple[np.ndarray, float]:
    """(each input's standard deviation (p,), the smallest over the largest eigenvalue of the
    covariance of stacked input windows of ``order`` samples): near zero, the commands do not
    excite dynamics of that order."""
    wins = []
    for U in records:
        if len(U) >= order:
            wins.append(sliding_window_view(U, (order, U.shape[1]))[:, 0].reshape(
                -1, order * U.shape[1]))
    if not wins:
        return np.zeros(records[0].shape[1]), 0.0
    W = np.vstack(wins)
    stds = np.vstack(records).std(axis=0)
    scale = np.where(stds > 0, stds, 1.0)
    W = W / np.tile(scale, order)
    ev = np.linalg.eigvalsh(np.cov(W.T).reshape(W.shape[1], W.shape[1]))
    return stds, float(max(ev[0], 0.0) / ev[-1]) if ev[-1] > 0 else 0.0


def stability(model: StateSpace, exempt: Sequence[int] = ()) -> tuple[np.ndarray, list[float]]:
    """(eigenvalues, moduli above 1 + STABLE_TOL that the data fix) of A without the
    ``exempt`` states (the constant state's 1 is no instability).

    A mode the unknown inputs reach (PBH: its left eigenvector w has w^H F != 0) is left out
    of the moduli: A + F L describes the same data for any L and moves that mode anywhere, so
    its modulus is the fit's choice, not the drive's (a rigid rotor's velocity, whose load is
    the unknown input, comes out at 1.0004 or 1.0013 by the log's length)."""
    keep = [i for i in range(model.n) if i not in exempt]
    A = model.A[np.ix_(keep, keep)]
    ev, left = np.linalg.eig(A.T)
    F = model.F[keep]
    reach = np.abs(left.conj().T @ F).max(axis=1, initial=0.0) if F.size else np.zeros(len(ev))
    scale = np.linalg.norm(left, axis=0) * max(np.linalg.norm(F), 1e-300)
    moved = reach > MINIMAL_RTOL * scale
    return ev, [float(abs(v)) for v, m in zip(ev, moved, strict=True)
                if abs(v) > 1 + STABLE_TOL and not m]


def minimality(model: StateSpace, exempt: Sequence[int] = ()) -> dict[str, list[complex]]:
    """The modes of A (without the ``exempt`` states) that the outputs do not see
    ("unobservable") or that neither the inputs nor the unknown inputs drive
    ("uncontrollable"), by the PBH rank tests."""
    keep = [i for i in range(model.n) if i not in exempt]
    A = model.A[np.ix_(keep, keep)]
    C = model.C[:, keep]
    BF = np.hstack([model.B, model.F])[keep]
    n = len(keep)
    out: dict[str, list[complex]] = {"unobservable": [], "uncontrollable": []}
    scale = max(np.linalg.norm(A, 2), 1.0)
    for lam in np.linalg.eigvals(A):
        obs = np.linalg.svd(np.vstack([A - lam * np.eye(n), C]), compute_uv=False)
        if obs[-1] < MINIMAL_RTOL * max(obs[0], scale):
            out["unobservable"].append(complex(lam))
        con = np.linalg.svd(np.hstack([A - lam * np.eye(n), BF]), compute_uv=False)
        if con[min(n, len(con)) - 1] < MINIMAL_RTOL * max(con[0], scale):
            out["uncontrollable"].append(complex(lam))
    return out

"""A drive's model with its unknown inputs, learned from healthy data whose outputs show the state.

The monitor needs (A, B, C, F): the parity residuals are decoupled from the state and from the
unmeasured inputs w that enter through F (a load torque, friction, the nonlinear terms of
Chan et al. 2006's motor). Only the part of the model that F does not reach matters to them: with
x(k+1) = A x + B u + F w, any A + F L, B + F M describe the same data (w absorbs L x + M u),
so the residuals, which see N^T x(k+1) - N^T A x(k) - N^T B u(k) for N^T F = 0, depend on
F's span and on the rows N^T [A B] alone. This module learns exactly those from data.

When the outputs show the state (the usual drive: currents, speed, position, a setpoint echo;
as many independent outputs as states, the redundant ones tied by static relations), the state
is taken as n of the measured outputs (``state_outputs``: in config order, those the earlier
ones do not explain), so C has an identity block and the model's rows keep the meaning of the
signals. Then (the "equation error with the unknown inputs
eliminated" fit):

1. every row of x(k+1) = A x(k) + B u(k) + c is fitted by least squares, corrected for the
   measurement noise in the regressors (bias-compensated least squares, with the sensors'
   noise R: the regressor x(k) is measured, not known);
2. F is the r-dimensional direction that explains most of the rows' error beyond what the
   measurement noise does: the top eigenvectors of the error's mean (the operating point's
   offset) and autocovariances from lag 2 on, which the noise (v(k+1) - A v(k), correlated
   over one lag) does not reach, so that no error in the noise's estimate tilts F;
3. F's entries that the data cannot tell from zero are set to zero, one row at a time, by a
   likelihood-ratio test on the whitened error the rows orthogonal to F keep (a row no unknown
   input reaches is then exactly such a row, and twin sensors stay exact twins);
4. the rows orthogonal to F (N^T x) are refitted in levels, where the unknown inputs are gone,
   and their coefficients that are not significant (|t| < ``prune_t``) are set to zero; the
   rows along F are fitted on first differences (a load that steps and drifts cancels but at
   its steps), which gives the model its physical meaning for simulation (or, where that is
   unstable, taken from the levels fit).

An intercept left in the rows orthogonal to F (an offset the unknown inputs do not explain)
or in a static relation adds a constant state (x_c(k+1) = x_c(k), its output column the
offsets): the residuals are decoupled from any initial state, so from the operating point too.

References: the bias-compensated least squares of errors-in-variables regression (Söderström,
"Errors-in-variables methods in system identification", Automatica 43, 2007); the parity
relations' invariance under w (Chow and Willsky, IEEE TAC 29, 1984; Chan et al. 2006).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from canfdi.core._check import check_shape
from canfdi.core.identify import least_squares

__all__ = [
    "MeasuredStateFit",
    "Record",
    "fit_measured_state",
    "row_excess",
    "select_state_outputs",
    "visible_order",
]

PRUNE_T = 3.0
"""A coefficient of a row orthogonal to F with |t| below this is set to zero."""
INTERCEPT_T = 4.0
"""An intercept with |t| above this needs a constant state."""
STABLE_MARGIN = 1e-3
"""A model whose eigenvalue exceeds 1 by more than this is unstable (1 within: an
integrator)."""
VISIBLE = 3.0
"""An output direction whose variance is this many times its noise variance shows a state."""


@dataclass(frozen=True)
class Record:
    """One healthy record on a regular grid: U (N, p) commands (never NaN), Y (N, q)
    measurements (a NaN row: a lost sample).

    Examples
    --------
    >>> rec = Record(U=np.zeros((4, 1)), Y=np.array([[0.0], [np.nan], [0.1], [0.2]]))
    >>> rec.U.shape, int(np.isnan(rec.Y).any(axis=1).sum())  # one lost sample
    ((4, 1), 1)
    """

    U: np.ndarray
    Y: np.ndarray


@dataclass(frozen=True)
class MeasuredStateFit:
    """The model learned with its unknown inputs.

    A (n, n), B (n, p), C (q, n), F (n, r): discrete, the state being the outputs
    ``state_outputs`` (plus a constant last state when ``constant_state``).
    noise_rows : (n,) each row's error variance over its predicted noise variance (1: the row
        is explained to the noise).
    f_rows : rows (of the measured state) that an unknown input reaches.
    pruned : (row label, regressor label) coefficients set to zero.
    samples : pairs (k, k+1) used.
    eigenvalues : the generalized eigenvalues of the rows' error against the noise (the first
        r are the unknown inputs; those near 1 are noise).

    Examples
    --------
    >>> rng = np.random.default_rng(3)
    >>> U, w = rng.standard_normal((4000, 1)), np.cumsum(0.05 * rng.standard_normal(4000))
    >>> X = np.zeros((4000, 2))
    >>> for k in range(3999):  # w, a slow unmeasured load, acts on the second state only
    ...     X[k + 1] = [0.9 * X[k, 0] + U[k, 0], 0.5 * X[k, 0] + 0.8 * X[k, 1] + w[k]]
    >>> Y = X + 0.01 * rng.standard_normal(X.shape)
    >>> fit = fit_measured_state([Record(U, Y)], np.full(2, 1e-4), 2, 1)
    >>> np.round(np.abs(fit.F[:2, 0]), 2), fit.samples  # F: along the second state
    (array([0., 1.]), 3999)
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    F: np.ndarray
    state_outputs: tuple[int, ...]
    constant_state: bool
    noise_rows: np.ndarray
    f_rows: tuple[int, ...]
    pruned: list[tuple[str, str]] = field(default_factory=list)
    samples: int = 0
    eigenvalues: np.ndarray = field(default_factory=lambda: np.zeros(0))
    offsets: np.ndarray = field(default_factory=lambda: np.zeros(0))
    f_rows_from: str = "none"


def _whitened_covariance(records: Sequence[Record], R: np.ndarray) -> np.ndarray:
    """(q, q) covariance of the outputs, each divided by its noise std (rows with a NaN
    left out)."""
    Y = np.vstack([r.Y for r in records])
    Y = Y[~np.isnan(Y).any(axis=1)]
    if len(Y) < 2:
        raise ValueError("fewer than 2 complete samples")
    W = Y / np.sqrt(R)
    return np.cov(W.T).reshape(len(R), len(R))


def visible_order(records: Sequence[Record], R: np.ndarray, threshold: float = VISIBLE
                  ) -> tuple[int, np.ndarray]:
    """(n, eigenvalues): how many output directions vary at least ``threshold`` times their
    noise variance (the state the outputs show), and the eigenvalues (descending) of the
    noise-whitened output covariance."""
    ev = np.linalg.eigvalsh(_whitened_covariance(records, R))[::-1]
    return int(np.sum(ev > threshold)), ev


def select_state_outputs(records: Sequence[Record], R: np.ndarray, n: int) -> tuple[int, ...]:
    """The n outputs taken as the state: in the config's order, each output that the ones
    already taken do not explain (its variance left after their least-squares fit is more
    than VISIBLE times its noise); an output they explain (the DC motor's i_f + i_a after i_f
    and i_a) is a static relation. The order decides among outputs that explain one another,
    so the choice does not hang on rounding; if fewer than n qualify, the least explained of
    the rest fill up."""
    Y = np.vstack([r.Y for r in records])
    Y = Y[~np.isnan(Y).any(axis=1)]
    Y = (Y - Y.mean(axis=0)) / np.sqrt(R)  # in noise units
    chosen: list[int] = []
    left = np.zeros(Y.shape[1])
    for j in range(Y.shape[1]):
        if len(chosen) == n:
            break
        X = Y[:, chosen]
        rest = Y[:, j] - X @ least_squares(X, Y[:, j]).theta if chosen else Y[:, j]
        left[j] = float(np.mean(rest**2))
        if left[j] > VISIBLE:
            chosen.append(j)
    for j in np.argsort(-left, kind="stable"):
        if len(chosen) == n:
            break
        if int(j) not in chosen:
            chosen.append(int(j))
    return tuple(sorted(chosen))


def _pairs(records: Sequence[Record], sel: Sequence[int], diff: bool = False
           ) -> tuple[np.ndarray, ...]:
    """(x(k), u(k), x(k+1)) for every k whose samples are present, and with ``diff`` their
    first differences (k-1, k, k+1 all present)."""
    xs0, us0, xs1 = [], [], []
    for rec in records:
        X = rec.Y[:, list(sel)]
        ok = ~np.isnan(X).any(axis=1)
        if diff:
            keep = ok[:-2] & ok[1:-1] & ok[2:]
            xs0.append((X[1:-1] - X[:-2])[keep])
            us0.append((rec.U[1:-1] - rec.U[:-2])[keep])
            xs1.append((X[2:] - X[1:-1])[keep])
        else:
            keep = ok[:-1] & ok[1:]
            xs0.append(X[:-1][keep])
            us0.append(rec.U[:-1][keep])
            xs1.append(X[1:][keep])
    return np.vstack(xs0), np.vstack(us0), np.vstack(xs1)


def _bcls(Phi: np.ndarray, T: np.ndarray, noise: np.ndarray, target_noise: np.ndarray,
          cross: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bias-compensated least squares T = Phi Theta + E, the columns of Phi carrying
    measurement noise of covariance ``noise`` (d, d: zero for exact regressors), correlated
    with the targets' noise by ``cross`` (d, m): E[noise of Phi x noise of T] (first
    differences share a sample: -R).

    Returns Theta (d, m), E (N, m), and the standard errors (d, m) of Theta.
    """
    N, d = Phi.shape
    G = Phi.T @ Phi - N * noise
    Ginv = np.linalg.inv(G)
    Theta = Ginv @ (Phi.T @ T - (0.0 if cross is None else N * cross))
    E = T - Phi @ Theta
    var = np.maximum(np.mean(E**2, axis=0), target_noise)
    se = np.sqrt(np.outer(np.maximum(np.diag(Ginv), 0.0), var) * N / max(N - d, 1))
    return Theta, E, se


def _regressor_noise(R_sel: np.ndarray, p: int, extra: int) -> np.ndarray:
    n = len(R_sel)
    out = np.zeros((n + p + extra, n + p + extra))
    out[:n, :n] = np.diag(R_sel)
    return out


def row_excess(records: Sequence[Record], R: np.ndarray, sel: Sequence[int]) -> np.ndarray:
    """(n,) each state row's one-step error variance over what the measurement noise alone
    gives it: row j fitted by itself, x_j(k+1) = a_j x(k) + b_j u(k) + c_j (bias-compensated),
    its error variance over R_j + sum_i a_ji^2 R_i. About 1 for a row no unknown input
    reaches; more where one does (or where the row is not linear)."""
    x0, u0, x1 = _pairs(records, sel)
    M, n = x0.shape
    p = u0.shape[1]
    R_sel = np.asarray(R, dtype=float)[list(sel)]
    Phi = np.hstack([x0, u0, np.ones((M, 1))])
    Theta, E, _ = _bcls(Phi, x1, _regressor_noise(R_sel, p, 1), R_sel)
    A = Theta[:n].T
    predicted = R_sel + (A**2) @ R_sel
    return np.mean((E - E.mean(axis=0))**2, axis=0) / predicted


def _directions(M2: np.ndarray, Sn: np.ndarray, r: int, rows: Sequence[int]
                ) -> tuple[np.ndarray, np.ndarray]:
    """F (n, r) within the axes ``rows``: the r dominant directions of the one-step errors'
    second moment M2 (n, n), measured in the noise's metric Sn, and all the eigenvalues
    (descending)."""
    n = len(M2)
    L = np.linalg.cholesky(Sn)
    Li = np.linalg.inv(L)
    Mt = Li @ M2 @ Li.T  # in noise units
    ev = np.sort(np.linalg.eigvalsh(Mt))[::-1]
    if r == 0:
        return np.zeros((n, 0)), ev
    Q, _ = np.linalg.qr(Li @ np.eye(n)[:, list(rows)])
    w, V = np.linalg.eigh(Q.T @ Mt @ Q)
    idx = np.argsort(-w, kind="stable")[:r]
    F = L @ (Q @ V[:, idx])
    F[[i for i in range(n) if i not in rows]] = 0.0
    if len(rows) == r:  # the rows themselves: F is their axes exactly
        F = np.eye(n)[:, list(rows)]
    for c in range(F.shape[1]):  # a readable scale: largest entry 1
        k = int(np.argmax(np.abs(F[:, c])))
        F[:, c] /= F[k, c]
    return F, ev


def _difference_rows(dx0: np.ndarray, du0: np.ndarray, dx1: np.ndarray, Fp: np.ndarray,
                     R_sel: np.ndarray) -> np.ndarray:
    """((n + p), r): the rows along F, F^+ [A B], fitted on first differences (a load that
    steps and drifts cancels but at its steps): the differenced regressors carry noise of
    variance 2 R and share a sample with the differenced target (covariance -R)."""
    n, p = dx0.shape[1], du0.shape[1]
    noise = _regressor_noise(2 * R_sel, p, 0)
    cross = np.zeros((n + p, Fp.shape[0]))
    cross[:n] = -np.diag(R_sel) @ Fp.T
    theta, _, _ = _bcls(np.hstack([dx0, du0]), dx1 @ Fp.T, noise, np.ones(Fp.shape[0]), cross)
    return theta


def _row_basis(F: np.ndarray, f_rows: Sequence[int]) -> np.ndarray:
    """(n, n - r) rows orthogonal to F: the axes F does not reach, then the complement of F
    within the axes it does."""
    n, r = F.shape
    others = [i for i in range(n) if i not in f_rows]
    cols = [np.eye(n)[:, i] for i in others]
    if f_rows and len(f_rows) > r:
        Fs = F[list(f_rows)]
        _, _, Vt = np.linalg.svd(Fs.T)
        comp = Vt[np.linalg.matrix_rank(Fs):].T  # (|S|, |S| - r)
        for c in range(comp.shape[1]):
            v = np.zeros(n)
            v[list(f_rows)] = comp[:, c]
            k = int(np.argmax(np.abs(v)))
            cols.append(v / v[k])
    return np.array(cols).T if cols else np.zeros((n, 0))


def _pruned_row(Phi: np.ndarray, t: np.ndarray, noise: np.ndarray, target_noise: float,
                prunable: int, prune_t: float) -> tuple[np.ndarray, list[int]]:
    """One row's coefficients (d,), its insignificant ones among the first ``prunable``
    columns set to zero one at a time (the least significant first, ties to the lower
    column), and the columns zeroed. A coefficient goes only while the ones gone, together,
    leave the row's error where it was (an F test at 1 %): with collinear regressors (slow
    states) each may look insignificant alone and all of them matter."""
    d = Phi.shape[1]
    n_rows = len(Phi)
    active = list(range(d))
    zeroed: list[int] = []

    def rss(cols: list[int]) -> float:
        # The error left by the bias-compensated fit on these columns, with their noise
        # taken out as the fit takes it out (t't - b' G^-1 b, G = Phi'Phi - N noise): what
        # ordinary least squares would leave is not comparable (its attenuated coefficients
        # need any slow regressor as an offset).
        if not cols:
            return float(t @ t)
        X = Phi[:, cols]
        G = X.T @ X - n_rows * noise[np.ix_(cols, cols)]
        b = X.T @ t
        return float(t @ t - b @ np.linalg.solve(G, b))

    rss_full = rss(active)
    while active:
        theta, _, se = _bcls(Phi[:, active], t[:, None], noise[np.ix_(active, active)],
                             np.array([target_noise]))
        tstat = np.abs(theta[:, 0]) / np.maximum(se[:, 0], 1e-300)
        candidates = [i for i, col in enumerate(active) if col < prunable]
        if not candidates:
            break
        worst = min(candidates, key=lambda i: (tstat[i], active[i]))
        if tstat[worst] >= prune_t:
            break
        trial = [c for j, c in enumerate(active) if j != worst]
        k = len(zeroed) + 1
        stat = ((rss(trial) - rss_full) / k) / max(rss_full / max(n_rows - d, 1), 1e-300)
        from scipy.stats import f as f_dist  # here: scipy.stats takes ~0.2 s to import

        if stat > f_dist.ppf(0.99, k, max(n_rows - d, 1)):
            break
        zeroed.append(active.pop(worst))
    full = np.zeros(d)
    if active:
        theta, _, _ = _bcls(Phi[:, active], t[:, None], noise[np.ix_(active, active)],
                            np.array([target_noise]))
        full[active] = theta[:, 0]
    return full, sorted(zeroed)


def fit_measured_state(records: Sequence[Record], R: np.ndarray, n: int, r: int, *,
                       state_outputs: Sequence[int] | None = None,
                       f_rows: Sequence[int] | None = None, prune_t: float = PRUNE_T,
                       input_names: Sequence[str] | None = None,
                       output_names: Sequence[str] | None = None) -> MeasuredStateFit:
    """Learn (A, B, C, F) with r unknown inputs when the outputs show the n states.

    Parameters
    ----------
    records : the healthy records (several logs; NaN rows are lost samples).
    R : (q,) each output's measurement noise variance (> 0: a noiseless echo gets its
        resolution's).
    n : states (at most q). r : unknown inputs (< n).
    state_outputs : the n outputs taken as the state (default: `select_state_outputs`).
    f_rows : the state rows the unknown inputs may reach (their entries of F; None: every
        row, F's directions free). From `row_excess`: the rows whose error the noise does not
        explain. With exactly r rows, F is their axes.

    Returns
    -------
    MeasuredStateFit.

    Raises
    ------
    ValueError : n > q, r >= n, or too few samples.
    """
    p = records[0].U.shape[1]
    q = records[0].Y.shape[1]
    R = check_shape("R", R, (q,), dtype=float)
    if not 1 <= n <= q:
        raise ValueError(f"the outputs show the state only when n <= q: n = {n}, q = {q}")
    if not 0 <= r < n:
        raise ValueError(f"unknown inputs: expected 0 <= r < n = {n}, got {r}")
    names_u = list(input_names or [f"u{i}" for i in range(p)])
    names_y = list(output_names or [f"y{j}" for j in range(q)])
    sel = tuple(state_outputs) if state_outputs is not None else select_state_outputs(
        records, R, n)
    x0, u0, x1 = _pairs(records, sel)
    M = len(x0)
    if M < 20 * (n + p + 1):
        raise ValueError(f"{M} pairs of consecutive samples: too few for {n} states and {p} "
                         f"inputs (at least {20 * (n + p + 1)})")
    R_sel = R[list(sel)]
    one = np.ones((M, 1))
    Phi = np.hstack([x0, u0, one])
    noise = _regressor_noise(R_sel, p, 1)
    Theta, _, _ = _bcls(Phi, x1, noise, R_sel)
    A, B, c = Theta[:n].T, Theta[n:n + p].T, Theta[-1]
    rows = tuple(range(n)) if f_rows is None else tuple(sorted(f_rows))
    if r and len(rows) < r:
        raise ValueError(f"{r} unknown inputs cannot reach only {len(rows)} rows")
    dx0, du0, dx1 = _pairs(records, sel, diff=True)
    # Every row fitted freely in levels leaves exactly F times the part of w that the
    # regressors do not explain (plus noise): the same projection acts on every row, so the
    # rows' errors (the intercept, w's mean, left in) point along F. A combined model whose
    # rows along F come from differences would bias that direction.
    E0 = x1 - x0 @ A.T - u0 @ B.T
    Sn = np.diag(R_sel) + A @ np.diag(R_sel) @ A.T
    F, ev = _directions(E0.T @ E0 / M, Sn, r, rows)
    # The rows orthogonal to F, refitted in levels, insignificant coefficients set to zero.
    Nb = _row_basis(F, rows) if r else np.eye(n)
    labels_x = [names_y[j] for j in sel]
    pruned: list[tuple[str, str]] = []
    rows_N = []
    noise_x = _regressor_noise(R_sel, p, 0)
    Phi0 = np.hstack([x0, u0])
    intercepts = []
    for i in range(Nb.shape[1]):
        t = x1 @ Nb[:, i]
        tn = float(Nb[:, i] @ (R_sel * Nb[:, i]))
        theta, zeroed = _pruned_row(Phi0, t, noise_x, tn, n + p, prune_t)
        row_label = _row_label(Nb[:, i], labels_x)
        pruned += [(row_label, (labels_x + names_u)[z]) for z in zeroed]
        rows_N.append(theta)
        # Is an intercept left? (an offset the unknown inputs do not explain)
        keep = [j for j in range(n + p) if j not in zeroed]
        Phi_i = np.hstack([Phi0[:, keep], one])
        th_i, _, se_i = _bcls(Phi_i, t[:, None], _regressor_noise(R_sel, p, 1)[
            np.ix_([*keep, n + p], [*keep, n + p])], np.array([tn]))
        intercepts.append((th_i[-1, 0], th_i[-1, 0] / max(se_i[-1, 0], 1e-300)))
    rows_N = np.array(rows_N).reshape(Nb.shape[1], n + p)
    f_from = "none"
    if r:
        # The rows along F: on first differences (the load's level cancels: the physical
        # model); where that gives an unstable model (in closed loop the differenced
        # command carries the noise back), the levels fit's rows, stable but with the load's
        # correlation folded in. The parity residuals see neither (F absorbs them).
        Fp = np.linalg.pinv(F)
        Mrows = np.vstack([Nb.T, Fp])
        full = np.linalg.solve(Mrows, np.vstack([rows_N, _difference_rows(
            dx0, du0, dx1, Fp, R_sel).T]))
        f_from = "differences"
        if np.max(np.abs(np.linalg.eigvals(full[:, :n]))) > 1 + STABLE_MARGIN:
            levels = Fp @ np.hstack([A, B])
            full = np.linalg.solve(Mrows, np.vstack([rows_N, levels]))
            f_from = "levels"
    else:
        full = rows_N
    A, B = full[:, :n], full[:, n:]
    # Static relations: the outputs that are not state coordinates.
    C = np.zeros((q, n))
    C[list(sel), range(n)] = 1.0
    out_offsets = np.zeros(q)
    X_all = [rec.Y[:, list(sel)] for rec in records]
    for j in [j for j in range(q) if j not in sel]:
        xs = np.vstack(X_all)
        ys = np.vstack([rec.Y[:, j:j + 1] for rec in records])[:, 0]
        ok = ~np.isnan(xs).any(axis=1) & ~np.isnan(ys)
        theta, zeroed = _pruned_row(xs[ok], ys[ok], np.diag(R_sel), float(R[j]), n, prune_t)
        pruned += [(names_y[j], labels_x[z]) for z in zeroed]
        C[j] = theta
        keep = [i for i in range(n) if i not in zeroed]
        Phi_j = np.hstack([xs[ok][:, keep], np.ones((int(ok.sum()), 1))])
        noise_j = np.zeros((len(keep) + 1, len(keep) + 1))
        noise_j[:len(keep), :len(keep)] = np.diag(R_sel[keep])
        th_j, _, se_j = _bcls(Phi_j, ys[ok][:, None], noise_j, np.array([R[j]]))
        if abs(th_j[-1, 0]) > INTERCEPT_T * se_j[-1, 0]:
            out_offsets[j] = th_j[-1, 0]
            C[j, keep] = th_j[:-1, 0]
    need_constant = any(abs(tv) > INTERCEPT_T for _, tv in intercepts) or bool(
        np.any(out_offsets))
    # Each row's error against its predicted noise (1: explained to the noise).
    E_final = x1 - x0 @ A.T - u0 @ B.T
    E_final = E_final - E_final.mean(axis=0)
    Sn = np.diag(R_sel) + A @ np.diag(R_sel) @ A.T
    noise_rows = np.mean(E_final**2, axis=0) / np.diag(Sn)
    offsets = np.zeros(0)
    if need_constant:
        cN = np.array([iv for iv, _ in intercepts])
        if r:
            Fp = np.linalg.pinv(F)
            cF = np.mean(x1 @ Fp.T - np.hstack([x0, u0]) @ np.vstack([A.T, B.T]) @ Fp.T,
                         axis=0)
            c = np.linalg.solve(np.vstack([Nb.T, Fp]), np.concatenate([cN, cF]))
        else:
            c = cN
        A = np.block([[A, c[:, None]], [np.zeros((1, n)), np.ones((1, 1))]])
        B = np.vstack([B, np.zeros((1, p))])
        C = np.hstack([C, out_offsets[:, None]])
        F = np.vstack([F, np.zeros((1, F.shape[1]))])
        offsets = np.concatenate([c, out_offsets])
    return MeasuredStateFit(A=A, B=B, C=C, F=F, state_outputs=sel,
                            constant_state=need_constant, noise_rows=noise_rows,
                            f_rows=rows if r else (), pruned=pruned, samples=M,
                            eigenvalues=ev, f_rows_from=f_from,
                            offsets=offsets)


def _row_label(v: np.ndarray, labels: Sequence[str]) -> str:
    nz = np.flatnonzero(np.abs(v) > 1e-12)
    if len(nz) == 1:
        return labels[int(nz[0])]
    return " ".join(f"{v[i]:+.3g} {labels[i]}" for i in nz)

"""Subspace identification of (A, B, C, D) from records with lost samples, open or closed loop.

PBSID (Chiuso 2007, "The role of vector autoregressive modeling in predictor-based subspace
identification", Automatica 43; van der Veen et al. 2013): a vector ARX model of the one-step
predictor over a past window, whose coefficients give the state as a linear function of past
data; consistent in closed loop (a master closing a speed loop through the bus makes the input
depend on past noise), up to the predictor's decay within the past window. Open-loop methods
such as PO-MOESP (Verhaegen 1994) are biased there (tests/unit/core/test_sysid.py shows it), and
drives are usually recorded in closed loop. The order comes from the canonical correlations
between the future outputs and the past (CVA weighting, Larimore 1990): a state carries a
correlation near 1, noise correlations of order sqrt(dims / samples); the count of
correlations above ``ORDER_FLOOR`` times the noise floor (the median of the trailing ones) is
the order.

Records are lists of (U (N, p), Y (N, q)) on regular sample grids; a NaN row of Y is a lost
sample, and no window that holds one is used; several records (logs) are stacked window by
window. The constant operating point is removed as the windows' mean (the estimates are of
deviations); `input_matrices` estimates B, D, the initial states and the offsets by least
squares once A and C are known.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from canfdi.core.identify import least_squares

__all__ = [
    "ORDER_FLOOR",
    "SubspaceModel",
    "canonical_correlations",
    "input_matrices",
    "order_from_correlations",
    "pbsid",
]

ORDER_FLOOR = 4.0
"""A canonical correlation above this many times the noise floor marks a state."""


@dataclass(frozen=True)
class SubspaceModel:
    """x(k+1) = A x + B u + K e, y = C x + D u + e (K, Sigma_e: PBSID's innovation form; zeros
    when the method gives none). offsets : (q,) output offset of the operating point,
    ``u0`` (p,) its input; the model holds for the deviations y - y0, u - u0.

    Examples
    --------
    >>> rng = np.random.default_rng(1)
    >>> U = rng.standard_normal((3000, 1))
    >>> x, Y = 0.0, np.empty((3000, 1))
    >>> for k in range(3000):
    ...     Y[k] = x + 0.01 * rng.standard_normal()
    ...     x = 0.8 * x + U[k, 0]
    >>> model, _ = pbsid([(U, Y)], 1, 10, 5)
    >>> model.method, np.round(model.A, 2), np.round(model.C @ model.B, 2)
    ('PBSID', array([[0.8]]), array([[1.]]))
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    K: np.ndarray
    sigma_e: np.ndarray
    y0: np.ndarray
    u0: np.ndarray
    method: str


def _record_windows(U: np.ndarray, Y: np.ndarray, length: int
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One record's windows of ``length`` consecutive samples: (W, length, p), (W, length, q)
    and (W,) which hold no lost sample."""
    wu = sliding_window_view(U, (length, U.shape[1]))[:, 0]
    wy = sliding_window_view(Y, (length, Y.shape[1]))[:, 0]
    return wu, wy, ~np.isnan(wy).any(axis=(1, 2)) & ~np.isnan(wu).any(axis=(1, 2))


def _windows(records: Sequence[tuple[np.ndarray, np.ndarray]], length: int
             ) -> tuple[np.ndarray, np.ndarray]:
    """(M, length, p), (M, length, q): every window of ``length`` consecutive samples with no
    lost one, over all records."""
    us, ys = [], []
    for U, Y in records:
        if len(Y) < length:
            continue
        wu, wy, ok = _record_windows(U, Y, length)
        us.append(wu[ok])
        ys.append(wy[ok])
    p = records[0][0].shape[1]
    q = records[0][1].shape[1]
    if not us:
        return np.zeros((0, length, p)), np.zeros((0, length, q))
    return np.concatenate(us), np.concatenate(ys)


def _past_future(records, past: int, future: int):
    wu, wy = _windows(records, past + future)
    M = len(wu)
    Up = wu[:, :past].reshape(M, -1)
    Yp = wy[:, :past].reshape(M, -1)
    Uf = wu[:, past:].reshape(M, -1)
    Yf = wy[:, past:].reshape(M, -1)
    return Up, Yp, Uf, Yf


def _lq_blocks(records, past: int, future: int):
    """The LQ factor blocks of [Uf; Zp; Yf] (data as rows: R of the QR of the stacked
    columns), means removed: L22-block basis of the past, L32, L33."""
    Up, Yp, Uf, Yf = _past_future(records, past, future)
    if len(Up) < 2 * (Up.shape[1] + Yp.shape[1] + Uf.shape[1] + Yf.shape[1]):
        raise ValueError(f"{len(Up)} windows of {past + future} samples without a lost one: "
                         f"too few for a past of {past} and a future of {future}")
    H = np.hstack([Uf, Up, Yp, Yf])
    H = H - H.mean(axis=0)
    Rm = np.linalg.qr(H, mode="r")
    L = Rm.T
    a = Uf.shape[1]
    b = Up.shape[1] + Yp.shape[1]
    return L[a + b:, a:a + b], L[a + b:, a + b:], len(H)


def canonical_correlations(records: Sequence[tuple[np.ndarray, np.ndarray]], past: int,
                           future: int) -> np.ndarray:
    """Canonical correlations between the future outputs and the past inputs and outputs,
    the future inputs projected out (CVA weighting), descending."""
    L32, L33, _ = _lq_blocks(records, past, future)
    W = L32 @ L32.T + L33 @ L33.T
    w, V = np.linalg.eigh(W)
    w = np.maximum(w, w.max() * 1e-14)
    Wih = (V / np.sqrt(w)) @ V.T
    return np.linalg.svd(Wih @ L32, compute_uv=False)


def order_from_correlations(rho: np.ndarray, nmax: int) -> tuple[int, float]:
    """(order, noise floor): the correlations above ``ORDER_FLOOR`` times the floor (the
    median of those beyond nmax), and above 0.1."""
    tail = rho[nmax:2 * nmax] if len(rho) > nmax else rho[-1:]
    floor = float(np.median(tail))
    n = int(np.sum(rho[:nmax] > max(ORDER_FLOOR * floor, 0.1)))
    return max(n, 1), floor


def _state_response(A: np.ndarray, U: np.ndarray) -> np.ndarray:
    """(N, n, n p): for x(k+1) = A x(k) + B u(k) from x(0) = 0, the state's derivative with
    respect to vec(B) (column-major) at every k."""
    N, p = U.shape
    n = A.shape[0]
    out = np.zeros((N, n, n * p))
    S = np.zeros((n, n * p))
    eye = np.eye(n)
    for k in range(N):
        out[k] = S
        S = A @ S + np.kron(U[k], eye)
    return out


def input_matrices(records: Sequence[tuple[np.ndarray, np.ndarray]], A: np.ndarray,
                   C: np.ndarray, feedthrough: bool = False
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[np.ndarray]]:
    """(B, D, y0, initial states) by least squares once A and C are known:
    y(k) = C A^k x0 + sum_j<k C A^(k-1-j) B u(j) + D u(k) + y0 is linear in all of them (one
    x0 per record; y0 the operating point's output offset). Lost samples are missing
    equations."""
    n, q = A.shape[0], C.shape[0]
    p = records[0][0].shape[1]
    blocks, targets = [], []
    n_rec = len(records)
    for r, (U, Y) in enumerate(records):
        N = len(U)
        Sx = _state_response(A, U)
        ok = ~np.isnan(Y).any(axis=1)
        cols = [np.einsum("qn,knd->kqd", C, Sx)]
        if feedthrough:
            cols.append(np.einsum("kp,qr->kqpr", U, np.eye(q)).reshape(N, q, p * q))
        powers = np.empty((N, n, n))
        Ak = np.eye(n)
        for k in range(N):
            powers[k] = Ak
            Ak = A @ Ak
        x0 = np.zeros((N, q, n * n_rec))
        x0[:, :, r * n:(r + 1) * n] = np.einsum("qn,knm->kqm", C, powers)
        cols.append(x0)
        cols.append(np.broadcast_to(np.eye(q), (N, q, q)))
        block = np.concatenate(cols, axis=2)[ok]
        blocks.append(block.reshape(-1, block.shape[2]))
        targets.append(Y[ok].reshape(-1))
    theta = least_squares(np.vstack(blocks), np.concatenate(targets)).theta
    i = n * p
    B = theta[:i].reshape(p, n).T
    D = np.zeros((q, p))
    if feedthrough:
        D = theta[i:i + q * p].reshape(p, q).T
        i += q * p
    x0s = [theta[i + r * n:i + (r + 1) * n] for r in range(n_rec)]
    i += n * n_rec
    return B, D, theta[i:i + q], x0s


def pbsid(records: Sequence[tuple[np.ndarray, np.ndarray]], n: int | None, past: int,
          future: int, nmax: int = 10, feedthrough: bool = False
          ) -> tuple[SubspaceModel, np.ndarray]:
    """PBSID: (model in innovation form, singular values of the predicted future outputs
    whitened by the innovation covariance). ``n`` None: chosen from those singular values
    by `order_from_correlations`' rule on their normalised values. Without ``feedthrough``
    D = 0: in closed loop u(k) depends on e(k) through the controller, and a D fitted beside
    it would take the controller's gain for the plant's."""
    p = records[0][0].shape[1]
    q = records[0][1].shape[1]
    wu, wy = _windows(records, past + 1)
    M = len(wu)
    if M < 5 * past * (p + q):
        raise ValueError(f"{M} windows of {past + 1} samples without a lost one: too few for "
                         f"a past of {past} ({past * (p + q)} regressors)")
    u0 = wu[:, past].mean(axis=0)
    y0 = wy[:, past].mean(axis=0)
    z = np.concatenate([wu - u0, wy - y0], axis=2)
    Zp = z[:, :past][:, ::-1].reshape(M, -1)  # z(k-1), ..., z(k-past)
    Yk = wy[:, past] - y0
    X = Zp
    Theta = least_squares(X, Yk).theta
    E = Yk - X @ Theta
    Se = E.T @ E / M
    w, V = np.linalg.eigh(Se)
    Sih = (V / np.sqrt(np.maximum(w, w.max() * 1e-14))) @ V.T
    Xi = Theta.T  # (q, past (p + q))
    m = p + q
    blocks = [Xi[:, j * m:(j + 1) * m] for j in range(past)]
    zero = np.zeros((q, m))
    H = np.vstack([np.hstack(blocks[i:] + [zero] * i) for i in range(future)])
    P = (np.kron(np.eye(future), Sih) @ H) @ Zp.T / np.sqrt(M)
    _, S, Vt = np.linalg.svd(P, full_matrices=False)
    if n is None:
        rho = S / (1.0 + S)
        n, _ = order_from_correlations(rho, nmax)
    # The state sequence: its first n principal directions, scaled.
    Xs = (np.sqrt(S[:n])[:, None] * Vt[:n]) * np.sqrt(M)  # (n, M)
    # Consecutive windows of one record follow each other: pair k with k+1 where both exist.
    # Rebuild the pairing from the windows' order: windows of one record are consecutive in
    # time when no lost sample sits between them, which the stacked order keeps.
    U_k = wu[:, past] - u0
    Xn = Xs.T
    if feedthrough:
        CD = least_squares(np.hstack([Xn, U_k]), Yk).theta
        C, D = CD[:n].T, CD[n:].T
    else:
        C = least_squares(Xn, Yk).theta.T
        D = np.zeros((q, p))
    e = Yk - Xn @ C.T - U_k @ D.T
    nxt = _successors(records, past + 1)
    a, b = nxt[:, 0], nxt[:, 1]
    reg = np.hstack([Xn[a], U_k[a], e[a]])
    ABK = least_squares(reg, Xn[b]).theta
    A = ABK[:n].T
    B = ABK[n:n + p].T
    K = ABK[n + p:].T
    sigma_e = e.T @ e / len(e)
    model = SubspaceModel(A=A, B=B, C=C, D=D, K=K, sigma_e=sigma_e, y0=y0, u0=u0,
                          method="PBSID")
    return model, S


def _successors(records, length: int) -> np.ndarray:
    """(P, 2) indices (i, j) into the stacked windows of `_windows` such that window j starts
    one sample after window i in the same record."""
    pairs = []
    offset = 0
    for U, Y in records:
        if len(Y) < length:
            continue
        _, _, ok = _record_windows(U, Y, length)
        idx = np.cumsum(ok) - 1 + offset
        starts = np.flatnonzero(ok[:-1] & ok[1:])
        pairs.append(np.column_stack([idx[starts], idx[starts + 1]]))
        offset += int(ok.sum())
    return np.vstack(pairs) if pairs else np.zeros((0, 2), dtype=int)

"""A drive's state-space model, its unknown inputs and its noise, learned from healthy records.

`identify_state_space` chooses the way the data allow (the path is reported):

* **measured state** (canfdi.core.unknown_inputs), with unknown inputs (r > 0): when the
  outputs show the state (the noise-whitened output covariance has n directions well above
  the noise, n <= q). The state is n of the outputs; F and the rows it does not reach are
  learned as that module says. Unknown inputs absorb what a linear model of the visible
  state cannot explain (a load, friction, the nonlinear terms), so n is the visible order.
  When no row's error exceeds its noise, the data show no unknown input: r becomes 0 (said).
* **subspace** (canfdi.core.subspace, PBSID, consistent in closed loop): without unknown
  inputs (it uses every horizon of the data, not one step, and pins slow dynamics better;
  the order from the canonical correlations), or when the data hold more states than the
  outputs show. With unknown inputs there, F is taken as the r dominant directions of the
  state innovation K Sigma_e K^T, measured in what it does to the next outputs (whitened by
  the noise): the least exact of the ways, said in the report.

The measurement noise R is learned along (the fits need it: the regressors are measured, and
F is what the noise does not explain): a first guess from a vector ARX model's one-step error
(`first_noise_guess`), then, in rounds, through the
parity space of the model found so far (canfdi.core.noise, as `canfdi calibrate` does), never
below each output's resolution (``floor_std``: a setpoint's echo is exact up to float32).

An input delay d >= 1 (u(k) first reaches x(k + d)) adds d - 1 states holding the past
inputs.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from canfdi.core.identify import least_squares
from canfdi.core.model import StateSpace
from canfdi.core.noise import estimate_measurement_noise
from canfdi.core.subspace import (
    canonical_correlations,
    input_matrices,
    order_from_correlations,
    pbsid,
)
from canfdi.core.unknown_inputs import (
    Record,
    fit_measured_state,
    row_excess,
    select_state_outputs,
    visible_order,
)
from canfdi.core.validation import robust_std

__all__ = [
    "EXCESS",
    "IdentifiedModel",
    "first_noise_guess",
    "identify_state_space",
    "parity_noise",
    "realise_paths",
    "regular_grid",
    "stack_records",
]

EXCESS = 0.10
"""A state row whose one-step error exceeds its noise's by more than this fraction is reached
by an unknown input (or is not linear)."""
MAX_ORDER = 12
OFFSET = 0.5
"""An output offset (of a subspace model) above this many noise stds gets a constant
state."""
NOISE_ROUNDS = 3


@dataclass(frozen=True)
class IdentifiedModel:
    """What `identify_state_space` learned.

    model : discrete StateSpace (A, B, C, D, F, dt). state_names : a name per state (an
    output's for a measured state, "x1".. for a subspace state, "1" for the constant state,
    "u(k-1)".. for delayed inputs). path : "measured state" or "subspace (PBSID)".
    order : states before the constant and delay states; order_evidence : the numbers the
    order was read from. noise_std : (q,) the noise found. unknown_inputs : F's columns.
    notes : what the user should know (fewer unknown inputs than asked, ...).
    details : the path's own figures (row excess, pruned coefficients, ...).

    Examples
    --------
    >>> from canfdi.core.unknown_inputs import Record
    >>> rng = np.random.default_rng(2)
    >>> U = rng.standard_normal((3000, 1))
    >>> x, Y = 0.0, np.empty((3000, 1))
    >>> for k in range(3000):
    ...     Y[k] = x + 0.01 * rng.standard_normal()
    ...     x = 0.8 * x + U[k, 0]
    >>> found = identify_state_space([Record(U, Y)], 0.01, prior_std=np.array([0.01]))
    >>> found.path, found.order, found.state_names
    ('subspace (PBSID)', 1, ['x1'])
    >>> np.round(found.model.A, 2), np.round(found.noise_std, 3)
    (array([[0.8]]), array([0.01]))
    """

    model: StateSpace
    state_names: list[str]
    path: str
    order: int
    order_evidence: dict
    noise_std: np.ndarray
    unknown_inputs: int
    notes: list[str] = field(default_factory=list)
    details: dict = field(default_factory=dict)


def regular_grid(k: np.ndarray, U: np.ndarray, Z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The samples k (N,), U (N, p), Z (N, q) on their regular grid k0..k1: (Ug (n, p) with
    lost commands held, Zg (n, q) with lost samples as NaN rows)."""
    n = int(k[-1] - k[0] + 1)
    Ug = np.full((n, U.shape[1]), np.nan)
    Zg = np.full((n, Z.shape[1]), np.nan)
    Ug[k - k[0]] = U
    Zg[k - k[0]] = Z
    for i in range(Ug.shape[1]):
        col = Ug[:, i]
        idx = np.where(~np.isnan(col), np.arange(n), 0)
        np.maximum.accumulate(idx, out=idx)
        Ug[:, i] = col[idx]
        first = np.flatnonzero(~np.isnan(col))
        Ug[: first[0] if len(first) else n, i] = np.nanmean(col) if len(first) else 0.0
    return Ug, Zg


def stack_records(records: Sequence[Record], gap: int) -> tuple[np.ndarray, np.ndarray]:
    """(U, Y) of the records end to end with ``gap`` lost samples between two (so that no
    window of gap samples straddles them)."""
    p = records[0].U.shape[1]
    q = records[0].Y.shape[1]
    us, ys = [], []
    for i, rec in enumerate(records):
        if i:
            us.append(np.zeros((gap, p)))
            ys.append(np.full((gap, q), np.nan))
        us.append(rec.U)
        ys.append(rec.Y)
    return np.vstack(us), np.vstack(ys)


def first_noise_guess(records: Sequence[Record], order: int = 4) -> np.ndarray:
    """(q,) a first guess of each output's noise variance, before any model: the one-step
    error of a vector ARX model of ``order`` lags (outputs and inputs), robustly (the median
    absolute deviation, so that a few load steps do not count), divided by 1 + the sum of
    the squares of the output's own lag coefficients (white noise v on the output enters its
    own error as v(k) - sum a_i v(k-i)). Within about 10 % on the shipped drives; the parity
    space's estimate refines it."""
    q = records[0].Y.shape[1]
    regs, targets = [], []
    for rec in records:
        Y, U = rec.Y, rec.U
        N = len(Y)
        if N <= order + 1:
            continue
        cols = [Y[order - 1 - i:N - 1 - i] for i in range(order)]
        cols += [U[order - 1 - i:N - 1 - i] for i in range(order)]
        reg = np.hstack([*cols, np.ones((N - order, 1))])
        target = Y[order:]
        ok = ~(np.isnan(reg).any(axis=1) | np.isnan(target).any(axis=1))
        regs.append(reg[ok])
        targets.append(target[ok])
    X = np.vstack(regs) if regs else np.zeros((0, 1))
    if len(X) < 10 * X.shape[1]:
        raise ValueError(f"{len(X)} runs of {order + 1} consecutive samples: too few for a "
                         "first look at the noise")
    T = np.vstack(targets)
    theta = least_squares(X, T).theta
    E = T - X @ theta
    own = np.array([sum(theta[i * q + j, j] ** 2 for i in range(order)) for j in range(q)])
    return robust_std(E) ** 2 / (1.0 + own)


def _delayed(records: Sequence[Record], delay: int) -> list[Record]:
    """Each record with u shifted so that x(k+1) depends on u(k - delay + 1) (the first
    delay - 1 samples dropped)."""
    if delay <= 1:
        return list(records)
    d = delay - 1
    return [Record(rec.U[:-d], rec.Y[d:]) for rec in records if len(rec.Y) > d]


def _with_delay(A, B, C, F, delay: int):
    """The model with delay - 1 states holding u(k-1), ..., u(k-delay+1) (the records were
    shifted by `_delayed`: B acted on the oldest)."""
    if delay <= 1:
        return A, B, C, F
    n, p = B.shape
    d = delay - 1
    m = n + d * p
    Aa = np.zeros((m, m))
    Aa[:n, :n] = A
    Aa[:n, n + (d - 1) * p:] = B  # the oldest held input drives x
    for i in range(1, d):  # shift the chain: slot i takes slot i - 1
        Aa[n + i * p:n + (i + 1) * p, n + (i - 1) * p:n + i * p] = np.eye(p)
    Ba = np.zeros((m, p))
    Ba[n:n + p] = np.eye(p)
    Ca = np.hstack([C, np.zeros((C.shape[0], d * p))])
    Fa = np.vstack([F, np.zeros((d * p, F.shape[1]))])
    return Aa, Ba, Ca, Fa


def parity_noise(model: StateSpace, records: Sequence[Record], window: int,
                 prior_std: np.ndarray) -> np.ndarray:
    """(q,) each output's noise std through the parity space of ``model`` over windows of
    ``window`` + 1 samples of the records (end to end, no window across two), as `canfdi
    calibrate` learns it (canfdi.core.noise); ``prior_std`` (q,) where the data cannot tell
    and for splitting what they see only together. Raises ValueError when nothing can be
    estimated."""
    U, Y = stack_records(records, window + 1)
    est = estimate_measurement_noise(model, window, U, Y, prior_std)
    return np.where(np.isfinite(est.std), est.std, prior_std)


def _noise_round(A, B, C, F, dt, records, prior_var, floor_var, window) -> np.ndarray:
    """R (q,) through the parity space of (A, B, C, F), at least the floor; the outputs the
    data see only together are split in the proportions of ``prior_var`` (the first guess,
    never a previous round's split, which would only repeat itself)."""
    model = StateSpace(A=A, B=B, C=C, F=F, dt=dt)
    return np.maximum(parity_noise(model, records, window, np.sqrt(prior_var)) ** 2, floor_var)


def identify_state_space(records: Sequence[Record], dt: float, *, unknown_inputs: int = 0,
                         order: int | None = None, delay: int = 1,
                         prior_std: np.ndarray | None = None,
                         floor_std: np.ndarray | None = None,
                         input_names: Sequence[str] | None = None,
                         output_names: Sequence[str] | None = None,
                         progress=lambda msg: None) -> IdentifiedModel:
    """Learn (A, B, C, F) and the noise from healthy records (the module docstring).

    Parameters
    ----------
    records : Record list (U (N, p) never NaN, Y (N, q) NaN rows for lost samples).
    dt : sample period (s). unknown_inputs : r, the number of unmeasured inputs.
    order : the state dimension (None: from the data). delay : input delay d >= 1.
    prior_std : (q,) the config's noise, if it states one (a better first guess).
    floor_std : (q,) each output's resolution (the noise never goes below it).

    Raises
    ------
    ValueError : what cannot be done, in words (too few samples, r >= n, ...).
    """
    p = records[0].U.shape[1]
    q = records[0].Y.shape[1]
    names_u = list(input_names or [f"u{i + 1}" for i in range(p)])
    names_y = list(output_names or [f"y{j + 1}" for j in range(q)])
    floor_var = np.zeros(q) if floor_std is None else np.asarray(floor_std, float) ** 2
    floor_var = np.maximum(floor_var, 1e-300)
    if not 1 <= delay <= 10:
        raise ValueError(f"delay: expected 1 to 10 samples, got {delay}")
    recs = _delayed(records, delay)
    r = int(unknown_inputs)
    guess = first_noise_guess(recs)
    if prior_std is not None:
        guess = np.asarray(prior_std, float) ** 2
    R = np.maximum(guess, floor_var)
    n_vis, eig = visible_order(recs, R)
    notes: list[str] = []
    evidence: dict = {"visible_order": n_vis,
                      "output_eigenvalues": [float(v) for v in eig]}
    if r > 0 and n_vis >= 1 and (order is None or order <= min(q, n_vis)):
        # Do the data show an unknown input at all? Rows (of the state the outputs show)
        # whose one-step error exceeds the noise: none, and the drive is linear in what it is
        # commanded (the VTOL's airspeed variation is a linear feedback, say).
        n_try = n_vis if order is None else int(order)
        excess = row_excess(recs, R, select_state_outputs(recs, R, n_try))
        if not np.any(excess > 1 + EXCESS):
            notes.append(f"no state row shows an error beyond its noise (the largest is "
                         f"{excess.max():.3f} times it): the data show no unknown input, and "
                         f"the model is learned without the {r} asked for")
            r = 0
    n_ss = None
    if order is None and r == 0:
        progress("estimating the order (canonical correlations of the future and the past)")
        past = _horizon(recs, p, q)
        rho = canonical_correlations([(x.U, x.Y) for x in recs], past, past)
        n_ss, floor = order_from_correlations(rho, MAX_ORDER)
        evidence.update(canonical_correlations=[float(v) for v in rho[:2 * MAX_ORDER]],
                        correlation_floor=floor, subspace_order=n_ss)
    if order is not None:
        n = int(order)
        measured = r > 0 and n <= min(q, n_vis)
    elif r > 0:
        n = n_vis
        measured = True
    else:
        # No unknown input: the subspace fit, which uses every horizon of the data rather
        # than one step, pins slow dynamics better.
        n = max(n_ss or n_vis, 1)
        measured = False
    if n < 1:
        raise ValueError("the outputs show no state above their noise: the log does not "
                         "excite the drive")
    if r >= n:
        raise ValueError(f"{r} unknown inputs need more than {n} states (the data show {n}): "
                         "lower unknown_inputs or set order")
    if measured:
        return _measured(recs, dt, n, r, R, floor_var, delay, names_u, names_y, evidence,
                         notes, progress)
    if r > 0:
        notes.append(f"the outputs show {n_vis} states but the model needs {n}: the unknown "
                     "inputs' directions come from the subspace fit's state innovation, the "
                     "least exact way")
    return _subspace(recs, dt, n, r, R, floor_var, delay, names_u, names_y, evidence, notes,
                     progress)


def _horizon(records: Sequence[Record], p: int, q: int) -> int:
    """Past and future window of the subspace fits: long enough for the slow modes a 10 ms
    drive shows, short enough for the data (at least 20 windows per regressor)."""
    samples = sum(len(x.Y) for x in records)
    return int(max(5, min(30, samples // (40 * (p + q)))))


def _measured(recs, dt, n, r, R, floor_var, delay, names_u, names_y, evidence, notes,
              progress) -> IdentifiedModel:
    window = min(max(n, 2), 10)
    first = R.copy()
    sel = select_state_outputs(recs, R, n)
    f_rows: tuple[int, ...] = ()
    fit = None
    for round_ in range(NOISE_ROUNDS):
        progress(f"fitting {n} measured states with {r} unknown input(s), round "
                 f"{round_ + 1} of {NOISE_ROUNDS}")
        if r:
            # The rows an unknown input reaches: those whose error exceeds the noise. The
            # first guess errs high, which keeps a row the inputs do not reach clear of the
            # threshold; later rounds refine with the noise the parity space gives.
            excess = row_excess(recs, R, sel)
            rows = tuple(int(i) for i in np.flatnonzero(excess > 1 + EXCESS))
            if len(rows) >= r:
                f_rows = rows
            elif len(f_rows) < r:
                f_rows = tuple(int(i) for i in np.argsort(-excess, kind="stable")[:r])
        fit = fit_measured_state(recs, R, n, r, state_outputs=sel,
                                 f_rows=f_rows if r else None, input_names=names_u,
                                 output_names=names_y)
        A, B, C, F = _with_delay(fit.A, fit.B, fit.C, fit.F, delay)
        try:
            R = _noise_round(A, B, C, F, dt, recs, first, floor_var, window)
        except ValueError as exc:
            notes.append(f"the noise could not be learned through the parity space ({exc}); "
                         "the first guess is kept")
            break
    assert fit is not None
    excess = row_excess(recs, R, sel)
    A, B, C, F = _with_delay(fit.A, fit.B, fit.C, fit.F, delay)
    names = [names_y[j] for j in fit.state_outputs]
    if fit.constant_state:
        names.append("1")
    names += [f"{u}(k-{i})" for i in range(1, delay) for u in names_u]
    details = {"state_outputs": [names_y[j] for j in fit.state_outputs],
               "rows_reached": [names_y[fit.state_outputs[i]] for i in fit.f_rows],
               "row_excess": {names_y[fit.state_outputs[i]]: float(excess[i])
                              for i in range(n)},
               "pruned": [f"{row} <- {reg}" for row, reg in fit.pruned],
               "constant_state": fit.constant_state,
               "rows_along_f_from": fit.f_rows_from,
               "unknown_input_eigenvalues": [float(v) for v in fit.eigenvalues],
               "pairs": fit.samples}
    model = StateSpace(A=A, B=B, C=C, F=F, dt=dt)
    return IdentifiedModel(model=model, state_names=names, path="measured state", order=n,
                           order_evidence=evidence, noise_std=np.sqrt(R),
                           unknown_inputs=F.shape[1], notes=notes, details=details)


def _subspace(recs, dt, n, r, R, floor_var, delay, names_u, names_y, evidence, notes,
              progress) -> IdentifiedModel:
    p = recs[0].U.shape[1]
    q = recs[0].Y.shape[1]
    past = _horizon(recs, p, q)
    progress(f"subspace fit (PBSID) of order {n}, past window {past}")
    sub, sv = pbsid([(x.U, x.Y) for x in recs], n, past, max(past // 2, n + 1))
    A, B, C = sub.A, sub.B, sub.C
    # B again, with the output offset and each record's initial state, by least squares on
    # the raw signals once A and C are known (the predictor's B is for deviations from the
    # data's mean, which a slow excitation leaves off the steady state): the offset that is
    # left is the drive's, not the fit's. White measurement noise keeps it consistent in
    # closed loop too (the regressors are the commands' past).
    c = np.zeros(n)
    if not np.any(np.isclose(np.abs(np.linalg.eigvals(A)), 1.0, atol=1e-3)):
        B, _, d, _ = input_matrices([(x.U, x.Y) for x in recs], A, C)
    else:  # an integrator: the constant input stays a state input
        c, d = -B @ sub.u0, sub.y0 + np.zeros(q)
    noise = np.sqrt(np.maximum(R, floor_var))
    # An offset left, of half the noise or more, would sit in the residuals: a
    # constant state takes it out (it costs a decoupling dimension, so not for less).
    significant = bool(np.any(np.abs(d) > OFFSET * noise) or np.any(c != 0))
    F = np.zeros((n, 0))
    if r:
        F = _innovation_directions(A, C, sub.K, sub.sigma_e, R, r, past)
    names = [f"x{i + 1}" for i in range(n)]
    if significant:
        A = np.block([[A, c[:, None]], [np.zeros((1, n)), np.ones((1, 1))]])
        B = np.vstack([B, np.zeros((1, p))])
        C = np.hstack([C, d[:, None]])
        F = np.vstack([F, np.zeros((1, F.shape[1]))])
        names.append("1")
    A, B, C, F = _with_delay(A, B, C, F, delay)
    names += [f"{u}(k-{i})" for i in range(1, delay) for u in names_u]
    window = min(max(n, 2), 10)
    try:
        R = _noise_round(A, B, C, F, dt, recs, R.copy(), floor_var, window)
    except ValueError as exc:
        notes.append(f"the noise could not be learned through the parity space ({exc})")
    evidence["predictor_singular_values"] = [float(v) for v in sv[:2 * MAX_ORDER]]
    model = StateSpace(A=A, B=B, C=C, F=F, dt=dt)
    return IdentifiedModel(model=model, state_names=names, path="subspace (PBSID)", order=n,
                           order_evidence=evidence, noise_std=np.sqrt(R),
                           unknown_inputs=F.shape[1], notes=notes,
                           details={"past_window": past, "constant_state": bool(significant)})


def _innovation_directions(A, C, K, sigma_e, R, r, horizon) -> np.ndarray:
    """F (n, r): the dominant directions of the state innovation K Sigma_e K^T, measured by
    what a state disturbance does to the next ``horizon`` outputs whitened by the noise."""
    n = A.shape[0]
    Wi = 1.0 / np.sqrt(R)
    blocks, Ak = [], np.eye(n)
    for _ in range(horizon):
        blocks.append((C @ Ak) * Wi[:, None])
        Ak = A @ Ak
    G = np.vstack(blocks)  # whitened observability
    Gram = G.T @ G
    w, V = np.linalg.eigh(Gram)
    w = np.maximum(w, w.max() * 1e-12)
    half = (V * np.sqrt(w)) @ V.T
    half_inv = (V / np.sqrt(w)) @ V.T
    Q = K @ sigma_e @ K.T
    ev, U = np.linalg.eigh(half @ Q @ half)
    idx = np.argsort(-ev, kind="stable")[:r]
    F = half_inv @ U[:, idx]
    for c in range(F.shape[1]):
        k = int(np.argmax(np.abs(F[:, c])))
        F[:, c] /= F[k, c]
    return F


def realise_paths(paths: Sequence[tuple[int, int, Sequence[float], Sequence[float], int]],
                  p: int, q: int, offsets: np.ndarray, noise: np.ndarray, dt: float
                  ) -> tuple[StateSpace, list[str]]:
    """(model, state names): output-error paths y_j += B(q)/F(q) q^-d u_i (each
    (output, input, b, f, delay)) realised block by block (scipy's controllable form of each
    transfer function), the blocks side by side: a path the data do not show is an exact
    zero, which a subspace fit's dense basis cannot keep. ``offsets`` (q,): each output's
    level at zero input; one of more than OFFSET noise stds gets a constant state."""
    import warnings

    from scipy.signal import BadCoefficients, tf2ss

    blocks = []
    for j, i, b, f, d in paths:
        num = np.concatenate([np.zeros(d), np.asarray(b, float)])
        den = np.concatenate([[1.0], np.asarray(f, float)])
        size = max(len(num), len(den))
        num = np.pad(num, (0, size - len(num)))
        den = np.pad(den, (0, size - len(den)))
        with warnings.catch_warnings():  # the delay's leading zeros: no loss, said anyway
            warnings.simplefilter("ignore", BadCoefficients)
            Ab, Bb, Cb, Db = tf2ss(num, den)
        blocks.append((j, i, Ab, Bb[:, 0], Cb[0], float(Db[0, 0])))
    n = sum(len(Ab) for _, _, Ab, _, _, _ in blocks)
    A, B, C, D = np.zeros((n, n)), np.zeros((n, p)), np.zeros((q, n)), np.zeros((q, p))
    names, at = [], 0
    for j, i, Ab, Bb, Cb, Db in blocks:
        m = len(Ab)
        A[at:at + m, at:at + m] = Ab
        B[at:at + m, i] = Bb
        C[j, at:at + m] = Cb
        D[j, i] += Db
        names += [f"y{j + 1}<-u{i + 1}.{k + 1}" for k in range(m)]
        at += m
    offsets = np.asarray(offsets, float)
    if np.any(np.abs(offsets) > OFFSET * np.asarray(noise, float)):
        A = np.block([[A, np.zeros((n, 1))], [np.zeros((1, n)), np.ones((1, 1))]])
        B = np.vstack([B, np.zeros((1, p))])
        C = np.hstack([C, offsets[:, None]])
        names.append("1")
    return StateSpace(A=A, B=B, C=C, D=D, dt=dt), names

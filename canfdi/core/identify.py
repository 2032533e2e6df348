"""Fault identification by recursive least squares (Chan, Hua & Zhang 2006, section IV).

Once a fully decoupled residual has isolated a fault, its size is estimated by fitting a
linear fault model to the residual, which is linear in the unknown fault parameters:

* actuator ``i`` (eqs. 24-29): ``u_i = eta_i * u_ic + lambda_i`` gives the scalar regression
  ``r_i(k) = phi_i(k) theta_i + n(k)`` with ``phi_i = [v_i^T Hc Uc(k), v_i^T Hc E]`` and
  ``theta_i = [eta_i - 1, lambda_i]``;
* sensors (eqs. 34-41): ``z = y + f`` gives the vector regression
  ``r(k) = V I* f + n(k)`` with one row per sensor-insensitive residual and ``theta = f``.

Both are solved by the recursive least-squares update of eqs. 30-32, generalised here to
``m`` residual rows at once and to a forgetting factor ``lam`` in ``(0, 1]`` so that a
fault that changes after it has been identified is still tracked. The update comes in
two equivalent forms, in the style of ``scipy.signal.lfilter(b, a, x, zi) -> (y, zf)``:

* :func:`rls_step` absorbs one sample and returns the new :class:`RlsState`;
* :func:`rls_batch` absorbs ``N`` samples at once, vectorised in information form, and
  gives the same numbers as ``N`` calls of :func:`rls_step` (to rounding).

:class:`RecursiveLeastSquares` is a thin streaming wrapper around the two.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.signal import lfilter

__all__ = [
    "RecursiveLeastSquares",
    "RlsBatchResult",
    "RlsState",
    "actuator_estimate",
    "actuator_regressor",
    "rls_batch",
    "rls_init",
    "rls_step",
    "sensor_regressor",
]

FloatArray = NDArray[np.float64]

# Smallest block the batch form retries with after the trace bound forced it onto the
# sequential step: small enough not to waste much when the bound keeps triggering, large
# enough that the per-call overhead of the vectorised pass is amortised.
_MIN_WINDOW = 256


def _shape_error(name: str, expected: str, got: tuple[int, ...]) -> ValueError:
    return ValueError(f"{name} must have shape {expected}, got {got}")


def _readonly(a: FloatArray) -> FloatArray:
    a.flags.writeable = False
    return a


@dataclass(frozen=True, eq=False)
class RlsState:
    """State of a recursive least-squares estimator.

    The arrays are copied and made read-only on construction, so a state can be kept
    (e.g. as a checkpoint) and fed to :func:`rls_step` or :func:`rls_batch` again later.

    Attributes
    ----------
    theta : ndarray, shape (d,)
        Current parameter estimate.
    P : ndarray, shape (d, d)
        Current error covariance (symmetric positive definite); ``diag(P)`` are the
        variances of the estimates up to the noise variance.
    n : int
        Number of samples (time steps, not residual rows) absorbed since the last
        :func:`rls_init`.
    """

    theta: FloatArray
    P: FloatArray
    n: int = 0

    def __post_init__(self) -> None:
        theta = np.array(self.theta, dtype=float)
        if theta.ndim != 1 or theta.shape[0] == 0:
            raise _shape_error("theta", "(d,) with d >= 1", theta.shape)
        d = theta.shape[0]
        P = np.array(self.P, dtype=float)
        if P.shape != (d, d):
            raise _shape_error("P", f"(d, d) = ({d}, {d})", P.shape)
        if not (np.all(np.isfinite(theta)) and np.all(np.isfinite(P))):
            raise ValueError("theta and P must be finite")
        n = int(self.n)
        if n < 0:
            raise ValueError(f"n must be >= 0, got {n}")
        object.__setattr__(self, "theta", _readonly(theta))
        object.__setattr__(self, "P", _readonly(P))
        object.__setattr__(self, "n", n)

    @property
    def d(self) -> int:
        """Number of parameters."""
        return int(self.theta.shape[0])


def _make_state(theta: FloatArray, P: FloatArray, n: int) -> RlsState:
    # Internal results are already validated float arrays; skipping __post_init__ keeps the
    # per-sample cost of the streaming path down.
    state = object.__new__(RlsState)
    object.__setattr__(state, "theta", _readonly(np.array(theta, dtype=float)))
    object.__setattr__(state, "P", _readonly(np.array(P, dtype=float)))
    object.__setattr__(state, "n", int(n))
    return state


@dataclass(frozen=True, eq=False)
class RlsBatchResult:
    """What :func:`rls_batch` produced for ``N`` samples of ``m`` rows and ``d`` parameters.

    Attributes
    ----------
    theta : ndarray, shape (N, d)
        Estimate after each sample.
    variances : ndarray, shape (N, d)
        ``diag(P)`` after each sample: the variances of the estimates (up to the noise
        variance).
    innovations : ndarray, shape (N, m)
        A-priori residuals ``r_k - phi_k theta_{k-1}``.
    state : RlsState
        State after the last sample; pass it to the next call to process in chunks.
    fallback_samples : int
        How many samples went through the sequential step because the trace bound was
        active (0 when the whole batch was done in information form).
    """

    theta: FloatArray
    variances: FloatArray
    innovations: FloatArray
    state: RlsState
    fallback_samples: int


def _check_hyper(forgetting: float, trace_max: float) -> tuple[float, float]:
    lam = float(forgetting)
    if not 0.0 < lam <= 1.0:
        raise ValueError(f"forgetting must be in (0, 1], got {forgetting!r}")
    tmax = float(trace_max)
    if not tmax > 0.0:
        raise ValueError(f"trace_max must be > 0 (inf disables the bound), got {trace_max!r}")
    return lam, tmax


def _check_p0(p0: float) -> float:
    p = float(p0)
    if not (np.isfinite(p) and p > 0.0):
        raise ValueError(f"p0 must be finite and > 0, got {p0!r}")
    return p


def rls_init(d: int, p0: float = 1e4, theta0: ArrayLike | None = None) -> RlsState:
    """Start (or restart) an estimator with ``P = p0 * I``.

    Calling it again on a running estimator is the covariance reset: with a large ``P``
    the next few samples dominate, so an abrupt change of the fault parameters is
    followed within about ``d`` samples even with ``forgetting = 1``.

    Parameters
    ----------
    d : int
        Number of parameters, >= 1.
    p0 : float
        Initial variance of every parameter; large means "know nothing".
    theta0 : array_like, shape (d,), optional
        Initial estimate (e.g. the current one, on a reset); zeros by default.

    Returns
    -------
    RlsState
        ``theta`` shape (d,), ``P`` shape (d, d), ``n = 0``.
    """
    if isinstance(d, bool) or not isinstance(d, int | np.integer) or d < 1:
        raise ValueError(f"d must be an integer >= 1, got {d!r}")
    p = _check_p0(p0)
    if theta0 is None:
        theta = np.zeros(d)
    else:
        theta = np.array(theta0, dtype=float)
        if theta.shape != (d,):
            raise _shape_error("theta0", f"(d,) = ({d},)", theta.shape)
        if not np.all(np.isfinite(theta)):
            raise ValueError("theta0 must be finite")
    return RlsState(theta=theta, P=p * np.eye(d), n=0)


def _check_rows(phi: ArrayLike, r: ArrayLike, d: int) -> tuple[FloatArray, FloatArray]:
    phi_a = np.asarray(phi, dtype=float)
    if phi_a.ndim != 2 or phi_a.shape[1] != d or phi_a.shape[0] == 0:
        raise _shape_error("phi", f"(m, d) = (m, {d}) with m >= 1", phi_a.shape)
    m = phi_a.shape[0]
    r_a = np.asarray(r, dtype=float)
    if r_a.ndim == 0 and m == 1:
        r_a = r_a.reshape(1)
    if r_a.shape != (m,):
        raise _shape_error("r", f"(m,) = ({m},)", r_a.shape)
    if not (np.all(np.isfinite(phi_a)) and np.all(np.isfinite(r_a))):
        raise ValueError("phi and r must be finite")
    return phi_a, r_a


def _step(
    theta: FloatArray,
    P: FloatArray,
    phi: FloatArray,
    r: FloatArray,
    lam: float,
    trace_max: float,
) -> tuple[FloatArray, FloatArray, FloatArray, bool]:
    """Unchecked eqs. 30-32 with forgetting; returns (theta, P, innovation, clipped)."""
    PphiT = P @ phi.T
    S = phi @ PphiT
    m = S.shape[0]
    if m == 1:
        # A 1x1 solve costs several times a division, and m == 1 is the actuator case
        # that runs once per sample per actuator.
        K = PphiT / (lam + S[0, 0])
    else:
        S = S + lam * np.eye(m)
        # S is symmetric, so P phi^T S^{-1} = (S^{-1} phi P^T)^T: one solve, no inverse.
        K = np.linalg.solve(S, PphiT.T).T
    e = r - phi @ theta
    theta = theta + K @ e
    P = (P - K @ (phi @ P)) / lam
    # The textbook update loses symmetry by rounding and, divided by lam < 1 every step,
    # the antisymmetric part grows until P is no longer a covariance.
    P = 0.5 * (P + P.T)
    tr = float(P.trace())
    clipped = tr > trace_max
    if clipped:
        # Without excitation P grows like lam^-k (estimator wind-up); one burst of data
        # after that would throw the estimate around, so P is kept bounded.
        P = P * (trace_max / tr)
    return theta, P, e, clipped


def rls_step(
    state: RlsState,
    phi: ArrayLike,
    r: ArrayLike,
    forgetting: float = 1.0,
    trace_max: float = 1e8,
) -> tuple[RlsState, FloatArray]:
    """Absorb one sample of ``m`` residual rows (eqs. 30-32 with forgetting).

    ``K = P phi^T (lam I + phi P phi^T)^{-1}``, ``theta += K (r - phi theta)``,
    ``P = (P - K phi P) / lam``, symmetrised, and scaled down to ``trace(P) == trace_max``
    whenever it would exceed it.

    Parameters
    ----------
    state : RlsState
        State before the sample; ``theta`` shape (d,), ``P`` shape (d, d).
    phi : array_like, shape (m, d)
        Regressor rows: ``m = 1`` for an actuator (eq. 29, see
        :func:`actuator_regressor`), ``m = q`` for the sensors (eq. 41, see
        :func:`sensor_regressor`).
    r : array_like, shape (m,)
        Residuals; a scalar is accepted when ``m == 1``.
    forgetting : float
        Forgetting factor ``lam`` in (0, 1]; 1 weights all samples equally, smaller
        values track changing parameters with a memory of about ``1 / (1 - lam)`` samples.
    trace_max : float
        Upper bound on ``trace(P)`` (``inf`` disables it).

    Returns
    -------
    state : RlsState
        State after the sample, ``n`` incremented by one.
    innovation : ndarray, shape (m,)
        A-priori residual ``r - phi theta_prev``.

    Raises
    ------
    ValueError
        If ``phi`` or ``r`` has the wrong shape or is not finite, or a hyper-parameter is
        out of range.
    """
    lam, tmax = _check_hyper(forgetting, trace_max)
    phi_a, r_a = _check_rows(phi, r, state.d)
    theta, P, e, _ = _step(state.theta, state.P, phi_a, r_a, lam, tmax)
    return _make_state(theta, P, state.n + 1), e


def _check_batch(Phi: ArrayLike, R: ArrayLike, d: int) -> tuple[FloatArray, FloatArray]:
    Phi_a = np.asarray(Phi, dtype=float)
    if Phi_a.ndim != 3 or Phi_a.shape[2] != d or Phi_a.shape[1] == 0:
        raise _shape_error("Phi", f"(N, m, d) = (N, m, {d}) with m >= 1", Phi_a.shape)
    N, m, _ = Phi_a.shape
    R_a = np.asarray(R, dtype=float)
    if R_a.ndim == 1 and m == 1:
        R_a = R_a.reshape(-1, 1)
    if R_a.shape != (N, m):
        raise _shape_error("R", f"(N, m) = ({N}, {m})", R_a.shape)
    if not (np.all(np.isfinite(Phi_a)) and np.all(np.isfinite(R_a))):
        raise ValueError("Phi and R must be finite")
    return Phi_a, R_a


def _solve_prefix(M: FloatArray, rhs: FloatArray) -> tuple[int, FloatArray]:
    """Batched ``solve(M, rhs)`` over a prefix, halved until no ``M_k`` in it is
    numerically singular; returns ``(length, solution)``."""
    L = M.shape[0]
    while L > 0:
        try:
            return L, np.linalg.solve(M[:L], rhs[:L])
        except np.linalg.LinAlgError:
            # A numerically singular M_k means an unexcited direction whose variance is far
            # beyond any trace bound, so the sample is clipped anyway and only the prefix
            # before it is needed.
            L //= 2
    return 0, rhs[:0]


def _batch_segment(
    theta0: FloatArray,
    P0: FloatArray,
    Phi: FloatArray,
    R: FloatArray,
    lam: float,
    trace_max: float,
) -> tuple[int, bool, FloatArray, FloatArray, FloatArray, FloatArray]:
    """Information-form pass up to (excluding) the first sample the trace bound would clip.

    Returns ``(k, triggered, theta (k, d), variances (k, d), innovations (k, m), P_k)``;
    ``triggered`` is False when the pass stopped early only because an ``M_k`` was
    numerically singular, so that the caller resumes in information form rather than with
    the sequential step.
    """
    L, m, d = Phi.shape
    nothing = (np.empty((0, d)), np.empty((0, d)), np.empty((0, m)), P0)
    # The recursion runs in whitened coordinates theta = theta0 + C beta with P0 = C C^T,
    # where the prior on beta is the identity: J_k = C^{-T} M_k C^{-1} and h_k = C^{-T} g_k
    # with M_0 = I, g_0 = 0. Inverting P0 instead would lose most digits once P0 is
    # ill-conditioned (wound up in one direction, well known in another), which is what
    # forgetting with poor excitation produces; and theta0 never passes through a solve.
    try:
        w, U = np.linalg.eigh(0.5 * (P0 + P0.T))
    except np.linalg.LinAlgError:
        return (0, True, *nothing)
    C = U * np.sqrt(np.clip(w, 0.0, None))
    Psi = Phi @ C
    den = [1.0, -lam]
    # M_k = lam M_{k-1} + psi_k^T psi_k and g_k = lam g_{k-1} + psi_k^T (r_k - phi_k theta0)
    # are first-order IIR filters run along time.
    eye = np.eye(d)
    M, _ = lfilter([1.0], den, np.einsum("kmi,kmj->kij", Psi, Psi), axis=0, zi=lam * eye[None])
    e0 = R - Phi @ theta0
    g = lfilter([1.0], den, np.einsum("kmi,km->ki", Psi, e0), axis=0)
    rhs = np.concatenate([g[:, :, None], np.broadcast_to(C.T, (L, d, d))], axis=2)
    solved, sol = _solve_prefix(M, rhs)
    X = C @ sol
    P = X[:, :, 1:]
    # "not <=" also stops at a non-finite or non-positive trace (a solve gone wrong),
    # leaving that sample to the sequential step.
    tr = np.trace(P, axis1=1, axis2=2)
    bad = ~((tr <= trace_max) & (tr > 0.0))
    if bad.any():
        k, triggered = int(np.argmax(bad)), True
    else:
        k, triggered = solved, solved == 0
    if k == 0:
        return (0, triggered, *nothing)
    theta = theta0 + X[:k, :, 0]
    prev = np.concatenate([theta0[None, :], theta[:-1]], axis=0)
    innov = R[:k] - np.einsum("kmi,ki->km", Phi[:k], prev)
    var = np.diagonal(P[:k], axis1=1, axis2=2).copy()
    P_last = 0.5 * (P[k - 1] + P[k - 1].T)
    return k, triggered, theta, var, innov, P_last


def rls_batch(
    state: RlsState,
    Phi: ArrayLike,
    R: ArrayLike,
    forgetting: float = 1.0,
    trace_max: float = 1e8,
) -> RlsBatchResult:
    """Absorb ``N`` samples at once; the same result as ``N`` calls of :func:`rls_step`.

    While the trace bound is inactive the update is exactly the information form
    ``J_k = lam J_{k-1} + phi_k^T phi_k``, ``h_k = lam h_{k-1} + phi_k^T r_k``,
    ``theta_k = J_k^{-1} h_k`` with ``J_0 = P_0^{-1}``, ``h_0 = J_0 theta_0``; the
    exponentially weighted sums are computed with :func:`scipy.signal.lfilter` and the
    solves batched (in coordinates whitened by ``P_0 = C C^T``, so that ``P_0`` is never
    inverted: ``J_k = C^{-T} M_k C^{-1}`` with ``M_0 = I``). From the first sample where
    ``trace(P_k)`` would exceed ``trace_max``, the samples go through the sequential step
    until the bound is inactive again, then the vectorised pass resumes. Chunking does not
    change the result: pass ``result.state`` to the next call.

    Parameters
    ----------
    state : RlsState
        State before the first sample; ``theta`` shape (d,), ``P`` shape (d, d).
    Phi : array_like, shape (N, m, d)
        Regressor rows of every sample (``N`` may be 0).
    R : array_like, shape (N, m)
        Residuals of every sample; shape (N,) is accepted when ``m == 1``.
    forgetting : float
        Forgetting factor ``lam`` in (0, 1].
    trace_max : float
        Upper bound on ``trace(P)`` (``inf`` disables it).

    Returns
    -------
    RlsBatchResult
        ``theta`` (N, d), ``variances`` (N, d), ``innovations`` (N, m), the final
        ``state`` (``n`` advanced by ``N``) and ``fallback_samples``.

    Raises
    ------
    ValueError
        If ``Phi`` or ``R`` has the wrong shape or is not finite, or a hyper-parameter is
        out of range.
    """
    lam, tmax = _check_hyper(forgetting, trace_max)
    d = state.d
    Phi_a, R_a = _check_batch(Phi, R, d)
    N, m, _ = Phi_a.shape
    theta_out = np.empty((N, d))
    var_out = np.empty((N, d))
    innov_out = np.empty((N, m))
    theta: FloatArray = np.array(state.theta)
    P: FloatArray = np.array(state.P)
    k = 0
    window = N
    fallback = 0
    while k < N:
        stop = min(N, k + window)
        done, triggered, th, var, inn, P_seg = _batch_segment(
            theta, P, Phi_a[k:stop], R_a[k:stop], lam, tmax
        )
        if done:
            theta_out[k : k + done] = th
            var_out[k : k + done] = var
            innov_out[k : k + done] = inn
            theta, P = th[-1], P_seg
        k += done
        if k == stop:
            window *= 2
            continue
        # Retry with a block about twice as long as the one that succeeded, so that a
        # bound that keeps triggering costs O(N) overall rather than O(N^2).
        window = max(_MIN_WINDOW, 2 * done)
        if not triggered:
            continue
        while k < N:
            theta, P, e, clipped = _step(theta, P, Phi_a[k], R_a[k], lam, tmax)
            theta_out[k] = theta
            var_out[k] = np.diag(P)
            innov_out[k] = e
            k += 1
            fallback += 1
            if not clipped:
                break
    return RlsBatchResult(
        theta=theta_out,
        variances=var_out,
        innovations=innov_out,
        state=_make_state(theta, P, state.n + N),
        fallback_samples=fallback,
    )


def actuator_regressor(g: ArrayLike, Uc: ArrayLike) -> FloatArray:
    """Regressor of the actuator fault model (eqs. 27-29).

    With ``U = eta Uc + lambda E`` the actuator-``i`` residual is
    ``r = (eta - 1) g . Uc + lambda sum(g)``, i.e. ``r = phi theta`` with
    ``phi = [g . Uc, sum(g)]`` and ``theta = [eta - 1, lambda]``; ``sum(g)`` is
    ``v_i^T Hc E`` because ``v_i`` annihilates the other actuators' columns (eq. 10).

    Parameters
    ----------
    g : array_like, shape (s+1,)
        ``v_i^T Hc`` restricted to actuator ``i``'s columns, oldest sample first.
    Uc : array_like, shape (s+1,) or (N, s+1)
        Window ``[u_ic(k-s), ..., u_ic(k)]`` of actuator ``i``'s commanded input, or one
        window per row for a batch (e.g. from
        ``numpy.lib.stride_tricks.sliding_window_view(u_ic, s + 1)``).

    Returns
    -------
    ndarray, shape (1, 2) or (N, 1, 2)
        ``phi`` for :func:`rls_step`, or ``Phi`` for :func:`rls_batch`.
    """
    g_a = np.asarray(g, dtype=float)
    if g_a.ndim != 1 or g_a.shape[0] == 0:
        raise _shape_error("g", "(s+1,)", g_a.shape)
    w = g_a.shape[0]
    U = np.asarray(Uc, dtype=float)
    if U.ndim not in (1, 2) or U.shape[-1] != w:
        raise _shape_error("Uc", f"(s+1,) or (N, s+1) with s+1 = {w}", U.shape)
    gu = U @ g_a
    phi = np.stack([gu, np.full_like(gu, g_a.sum())], axis=-1)
    return phi[..., None, :]


def actuator_estimate(theta: ArrayLike) -> tuple[FloatArray | float, FloatArray | float]:
    """Fault-model parameters from an actuator estimate ``theta = [eta - 1, lambda]``.

    Parameters
    ----------
    theta : array_like, shape (2,) or (N, 2)
        One estimate or a trajectory (e.g. ``RlsBatchResult.theta``).

    Returns
    -------
    eta : float or ndarray, shape (N,)
        Scaling factor (1 for a healthy actuator).
    lam : float or ndarray, shape (N,)
        Bias (0 for a healthy actuator).
    """
    t = np.asarray(theta, dtype=float)
    if t.ndim not in (1, 2) or t.shape[-1] != 2:
        raise _shape_error("theta", "(2,) or (N, 2)", t.shape)
    # ``+ 0.0`` makes a copy for a trajectory and a plain scalar for a single estimate.
    return t[..., 0] + 1.0, t[..., 1] + 0.0


def sensor_regressor(V: ArrayLike, q: int, s: int) -> FloatArray:
    """Regressor of the sensor fault model (eqs. 36-41): ``phi = V I*``.

    ``I* = [I_q; I_q; ...; I_q]`` stacks ``s+1`` identities, so ``V I*`` sums the ``s+1``
    column blocks of ``V``; with ``theta = f`` the residuals are ``r = phi f``.

    Parameters
    ----------
    V : array_like, shape (m, (s+1) q)
        Parity row vectors ``v_i^T`` stacked, columns ordered like
        ``Z = [z(k-s); ...; z(k)]``.
    q : int
        Number of sensors, >= 1.
    s : int
        Order of the parity space, >= 0.

    Returns
    -------
    ndarray, shape (m, q)
        ``phi`` for :func:`rls_step` (constant in time; broadcast to (N, m, q) for
        :func:`rls_batch`).
    """
    for name, val, lo in (("q", q, 1), ("s", s, 0)):
        if isinstance(val, bool) or not isinstance(val, int | np.integer) or val < lo:
            raise ValueError(f"{name} must be an integer >= {lo}, got {val!r}")
    V_a = np.asarray(V, dtype=float)
    cols = (s + 1) * q
    if V_a.ndim != 2 or V_a.shape[1] != cols or V_a.shape[0] == 0:
        raise _shape_error("V", f"(m, (s+1) q) = (m, {cols}) with m >= 1", V_a.shape)
    return V_a.reshape(V_a.shape[0], s + 1, q).sum(axis=1)


class RecursiveLeastSquares:
    """Streaming recursive least squares: a thin wrapper around :func:`rls_step`.

    Parameters
    ----------
    n_params : int
        Number of parameters ``d`` (2 for an actuator, ``q`` for the sensors).
    forgetting : float
        Forgetting factor in (0, 1].
    p0 : float
        Initial (and reset) variance of every parameter.
    trace_max : float
        Upper bound on ``trace(P)`` against wind-up (``inf`` disables it).
    """

    def __init__(
        self,
        n_params: int,
        forgetting: float = 1.0,
        p0: float = 1e4,
        trace_max: float = 1e8,
    ) -> None:
        _check_hyper(forgetting, trace_max)
        self.n_params = n_params
        self.forgetting = forgetting
        self.p0 = p0
        self.trace_max = trace_max
        self._state = rls_init(n_params, p0)

    def reset(self, theta0: ArrayLike | None = None) -> None:
        """Covariance reset: ``P = p0 I`` and ``theta = theta0`` (shape (d,), zeros if None)."""
        self._state = rls_init(self.n_params, self.p0, theta0)

    def update(self, phi: ArrayLike, r: ArrayLike) -> FloatArray:
        """Absorb one sample; ``phi`` shape (m, d), ``r`` shape (m,).

        Returns
        -------
        ndarray, shape (m,)
            The innovation ``r - phi theta_prev``.
        """
        self._state, e = rls_step(self._state, phi, r, self.forgetting, self.trace_max)
        return e

    def update_batch(self, Phi: ArrayLike, R: ArrayLike) -> RlsBatchResult:
        """Absorb ``N`` samples at once; ``Phi`` shape (N, m, d), ``R`` shape (N, m)."""
        result = rls_batch(self._state, Phi, R, self.forgetting, self.trace_max)
        self._state = result.state
        return result

    @property
    def state(self) -> RlsState:
        """The current :class:`RlsState` (immutable)."""
        return self._state

    @property
    def theta(self) -> FloatArray:
        """Current estimate, shape (d,)."""
        return self._state.theta

    @property
    def covariance(self) -> FloatArray:
        """Current error covariance ``P``, shape (d, d)."""
        return self._state.P

    @property
    def variances(self) -> FloatArray:
        """``diag(P)``, shape (d,): the variances of the estimates."""
        return np.diag(self._state.P).copy()

    @property
    def n_samples(self) -> int:
        """Samples absorbed since the last reset."""
        return self._state.n

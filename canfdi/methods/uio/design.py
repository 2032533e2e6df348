"""Unknown-input decoupled residuals of Hwang, Chang and Hsu (Hwang, Chang, Hsu), in discrete time.

Design (all on the zero-order-hold model x(k+1) = A x + B u + E d + K f, y = C x + G f; E is the
model's F, discretised with the inputs as ``StateSpace.discretize`` does):

1. Decoupling (eqs 6-11). With rank(CE) = rank(E) = r < m, (CE)^+ = ((CE)^T CE)^-1 (CE)^T
   (eq 7), T = E (CE)^+, Pi = I - T C, and z = Pi x obeys, free of d (Pi E = 0)::

       z(k+1) = Abar z + Bbar u + Abar T y + (Kbar - Abar T G) f,   Abar = Pi A, Bbar = Pi B,
       H y    = C z + H G f,                                        H = I - CE (CE)^+

   (eq 11 with q in place of s: the discrete form replaces y' by y(k+1), which is exact here).
2. Basic residual (eqs 12-14). e = H y - C zhat from the observer
   zhat(k+1) = Abar zhat + Bbar u + Abar T y + L (H y - C zhat). In continuous time the paper
   forms e = Ly y - Lu u, whose poles are those of Abar (unstable for this aircraft), and lets
   the dynamic weighting W(s) cancel them. Here the observer gain L is *deadbeat* (all poles of
   Abar - L C at the origin, or within ``DEADBEAT_EPS`` of it when C has fewer independent rows
   than states): that is the basic residual premultiplied by the left coprime factor
   M(q) = I - C (qI - Abar + LC)^-1 L, a polynomial in q^-1. So e is a finite-window (FIR)
   function of the last S+1 samples, and a value lost on the bus makes only the residuals
   whose window reads it missing, exactly; all the residual dynamics are then set by W.
3. Actuator fault identification filter (FIDF, Section 2.3). With K = B, G = 0 the fault map
   is Lf(q) = C (qI - Ao)^-1 Kbar, Ao = Abar - L C. When its first Markov parameter
   M1 = C Kbar = H C B has full column rank p (then Lf has full column rank), W0 = M1^+ and
   the exact inverse of W0 Lf (a relative-degree-one system) gives fhat(k-1) = f(k-1): the
   fault map of the chain is the identity times a delay. The dynamic weighting
   W(q) = Hf(q) (W0 Lf(q))^-1 W0 with Hf(q) = diag((1 - a) / (q - a)), the ZOH of the paper's
   2 / (s + 2) for pole -2 (a = exp(-2 dt)), makes residual j a low-passed estimate of
   actuator j's fault alone: the diagonal fault-to-residual map of the paper's Fig. 2.
4. GRGS (Fig. 1): generator i is the same construction on all sensors but i (C and G without
   row i); its residual is the scalar w_i^T e_i, w_i the direction of e_i most sensitive to
   the other sensors' biases at steady state, low-passed by (1 - a_s) / (1 - a_s q^-1). A
   fault on sensor j moves every residual but j: column j of Hf(0) (zero diagonal) is its
   direction, the flag psi(t) = sqrt(sum r_i^2 / m) (eq 23a) tells a fault, and the fault
   angles theta_i(t) = arccos(<r, Hf_i> / |r| |Hf_i|) (eq 23b) tell which: the smallest.

Deviations from the paper: discrete time throughout (the paper notes its derivation holds with
z in place of s); W is realised as deadbeat front end + first-order low-pass instead of the
paper's hand-chosen rational weights (their coefficients are partly illegible in the
extraction); the rank test for the diagonal map uses the first Markov parameter (sufficient for
full column rank of Lf). The ZOH of E d is exact only for d held over a period: the plant's
d = [0 0.5 0 2] x varies within it, which leaves an O(dt^2) leak the tests bound.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

__all__ = [
    "DEADBEAT_EPS",
    "Decoupling",
    "Fir",
    "UioDesign",
    "deadbeat_gain",
    "decouple",
    "design_uio",
    "fault_angles",
    "flag_function",
    "lowpass_coefficient",
    "observer_residual",
]

# Poles placed at the origin where C cannot make Abar - LC nilpotent through place_poles (which
# takes a pole at most rank(C) times): the rest go here, so the residual's memory still dies
# out within a few samples (EPS^k) and the FIR truncation is at round-off.
DEADBEAT_EPS = 1e-4


@dataclass(frozen=True)
class Decoupling:
    """The unknown-input free model of eqs 6-11 (discrete).

    CEp : (r, m) (CE)^+; T : (n, m) E (CE)^+; Pi : (n, n) I - T C; Abar : (n, n) Pi A;
    Bbar : (n, p) Pi B; H : (m, m) I - CE (CE)^+ (projector onto range(CE)^perp).

    Examples
    --------
    >>> A = np.array([[0.9, 0.0], [0.1, 0.95]])
    >>> B, E = np.array([[0.1], [0.0]]), np.array([[0.0], [1.0]])  # E: an unmeasured load on x2
    >>> C = np.array([[1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
    >>> dec = decouple(A, B, C, E)
    >>> np.round(dec.H @ C @ E, 12), np.round(dec.Pi @ E, 12)  # d reaches neither H y nor Pi x
    (array([[0.],
           [0.],
           [0.]]), array([[0.],
           [0.]]))
    """

    CEp: np.ndarray
    T: np.ndarray
    Pi: np.ndarray
    Abar: np.ndarray
    Bbar: np.ndarray
    H: np.ndarray


def decouple(A: np.ndarray, B: np.ndarray, C: np.ndarray, E: np.ndarray) -> Decoupling:
    """(CE)^+ decoupling of the unknown input d (eqs 6-11).

    Parameters
    ----------
    A : (n, n); B : (n, p); C : (m, n); E : (n, r) discrete-time matrices.

    Raises
    ------
    ValueError when rank(CE) != rank(E) (d is not decouplable: the states it drives are not
    measured) or m <= rank(E) (no redundancy left).
    """
    A, B, C, E = (np.asarray(M, dtype=float) for M in (A, B, C, E))
    n, m = A.shape[0], C.shape[0]
    if E.shape[1] == 0:
        E = np.zeros((n, 0))
    CE = C @ E
    r = np.linalg.matrix_rank(E) if E.size else 0
    if E.size and np.linalg.matrix_rank(CE) != r:
        raise ValueError(f"rank(CE) = {np.linalg.matrix_rank(CE)} != rank(E) = {r}: the "
                         "unknown input cannot be decoupled")
    if m <= r:
        raise ValueError(f"m = {m} outputs for rank(E) = {r} unknown inputs: no redundancy")
    # (CE)^T CE is invertible when CE has full column rank (eq 7); pinv covers rank(E) < r.
    CEp = np.linalg.pinv(CE) if E.size else np.zeros((0, m))
    T = E @ CEp
    Pi = np.eye(n) - T @ C
    return Decoupling(CEp=CEp, T=T, Pi=Pi, Abar=Pi @ A, Bbar=Pi @ B, H=np.eye(m) - CE @ CEp)


def deadbeat_gain(Abar: np.ndarray, C: np.ndarray) -> np.ndarray:
    """(n, m) observer gain L with Abar - L C nilpotent (or all poles within DEADBEAT_EPS).

    With C of full column rank, L = Abar C^+ gives Abar - L C = 0 exactly (window 1).
    """
    n = Abar.shape[0]
    rank = np.linalg.matrix_rank(C)
    if rank == n:
        return Abar @ np.linalg.pinv(C)
    poles = [0.0] * rank + [DEADBEAT_EPS * (i + 1) for i in range(n - rank)]
    try:
        from scipy.signal import place_poles  # here: scipy.signal takes ~0.6 s to import

        return place_poles(Abar.T, C.T, poles).gain_matrix.T
    except ValueError as exc:
        raise ValueError(f"no deadbeat observer for (Abar, C): {exc}") from None


@dataclass(frozen=True)
class Lti:
    """x(k+1) = A x + B v, out(k) = C x + D v: A (ns, ns), B (ns, nin), C (nout, ns), D.

    Examples
    --------
    >>> gain = Lti(A=np.array([[0.5]]), B=np.array([[1.0]]), C=np.array([[1.0]]),
    ...            D=np.array([[0.0]]))
    >>> gain.markov(4).ravel()
    array([0.  , 1.  , 0.5 , 0.25])
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray

    def markov(self, count: int) -> np.ndarray:
        """(count, nout, nin) impulse response D, CB, CAB, ..."""
        out = [self.D]
        M = self.B
        for _ in range(count - 1):
            out.append(self.C @ M)
            M = self.A @ M
        return np.array(out)


def series(first: Lti, second: Lti) -> Lti:
    """``second`` driven by the output of ``first``."""
    n1, n2 = first.A.shape[0], second.A.shape[0]
    A = np.block([[first.A, np.zeros((n1, n2))], [second.B @ first.C, second.A]])
    B = np.vstack([first.B, second.B @ first.D])
    C = np.hstack([second.D @ first.C, second.C])
    return Lti(A, B, C, second.D @ first.D)


def observer_residual(dec: Decoupling, C: np.ndarray, L: np.ndarray) -> Lti:
    """The basic residual e = H y - C zhat (eq 14 through the observer), input v = [y; u]."""
    m = C.shape[0]
    p = dec.Bbar.shape[1]
    Ao = dec.Abar - L @ C
    Bo = np.hstack([dec.Abar @ dec.T + L @ dec.H, dec.Bbar])
    return Lti(Ao, Bo, -C, np.hstack([dec.H, np.zeros((m, p))]))


def lowpass_coefficient(pole: float, dt: float) -> float:
    """a = exp(pole dt): the ZOH of -pole / (s - pole), i.e. (1 - a) / (q - a)."""
    return float(np.exp(pole * dt))


@dataclass(frozen=True)
class Fir:
    """Outputs o(k) = sum_l coef[l]^T v(k - S + l), v = [y; u] (m + p,), o (n_out,).

    coef : (S+1, m+p, n_out), oldest lag first; entries at round-off are exactly zero, so an
    output never reads (nor goes missing for) a channel it was decoupled from.

    Examples
    --------
    >>> smooth = Fir(coef=np.full((2, 1, 1), 0.5))  # the mean of the last two samples
    >>> smooth.S, smooth.dc, smooth.batch(np.array([[1.0], [3.0], [np.nan], [5.0]])).ravel()
    (1, array([[1.]]), array([ 2., nan, nan]))
    """

    coef: np.ndarray

    @property
    def S(self) -> int:
        return self.coef.shape[0] - 1

    @property
    def dc(self) -> np.ndarray:
        """(n_out, m+p) steady-state gain."""
        return self.coef.sum(axis=0).T

    def batch(self, v: np.ndarray) -> np.ndarray:
        """(N - S, n_out) outputs of every full window of v (N, m+p); NaN where one reads a
        missing value."""
        S = self.S
        n = len(v) - S
        if n <= 0:
            return np.zeros((0, self.coef.shape[2]))
        missing = np.isnan(v)
        x = np.where(missing, 0.0, v)
        uses = (self.coef != 0).astype(float)
        out = x[:n] @ self.coef[0]
        bad = missing[:n] @ uses[0]
        for lag in range(1, S + 1):
            out += x[lag: lag + n] @ self.coef[lag]
            bad += missing[lag: lag + n] @ uses[lag]
        out[bad > 0] = np.nan
        return out


def _fir(lti: Lti, max_taps: int = 64, tol: float = 1e-12) -> Fir:
    """The (finite) impulse response of a deadbeat chain as a Fir."""
    h = lti.markov(max_taps)  # (taps, nout, nin)
    scale = max(np.abs(h).max(), 1e-300)
    alive = np.flatnonzero(np.abs(h).reshape(len(h), -1).max(axis=1) > tol * scale)
    taps = int(alive[-1]) + 1 if len(alive) else 1
    if taps == max_taps:
        raise ValueError("the residual generator has no finite memory (not deadbeat)")
    h = h[:taps].copy()
    h[np.abs(h) <= tol * scale] = 0.0
    return Fir(np.ascontiguousarray(h[::-1].transpose(0, 2, 1)))


@dataclass(frozen=True)
class UioDesign:
    """The FIDF and the GRGS bank of a model, as one FIR front end and first-order weights.

    Front end outputs o(k) (p + m,): fhat(k-1) (the FIDF inverse, p) then the GRGS scalars
    (m); residuals r(k) = a r(k-1) + (1 - a) o(k) per output (unity DC gain).

    fir : the front end, input v = [y; u]. a : (p+m,) low-pass coefficients.
    fault_dc : (p+m, p+m) steady-state response of o (and r) to a unit actuator bias
        (columns 0..p-1) and a unit sensor bias (columns p..p+m-1).
    Hf0 : (m, m) the GRGS part for sensor biases: the paper's Hf(0) (zero diagonal).
    W0 : (p, m) the FIDF's left inverse of M1 = H C B.
    noise_std : (p+m,) std of r for the measurement noise; front_std : (p+m,) of o;
    long_run_std : (p+m,) sqrt of the long-run variance of o (and r) (sum of autocovariances).
    front_cov, long_run_cov : (p+m, p+m) the same as covariances across the outputs (their
        diagonals the squares of front_std and long_run_std): an estimate that combines the
        outputs varies as these say, not as if they were independent.

    Examples
    --------
    >>> A = np.array([[0.9, 0.0], [0.1, 0.95]])
    >>> B, E = np.array([[0.1], [0.0]]), np.array([[0.0], [1.0]])  # E: an unmeasured load on x2
    >>> C = np.array([[1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
    >>> design = design_uio(A, B, C, E, 0.01, measurement_std=np.full(3, 0.01), input_names=["u"],
    ...                     output_names=["y0", "y1", "y2"])
    >>> design.names, (design.p, design.m), design.fir.S
    (['fidf:u', 'grgs:y0', 'grgs:y1', 'grgs:y2'], (1, 3), 1)
    >>> np.round(design.fault_dc, 2)  # each column: one unit fault's steady residuals
    array([[ 1.  ,  0.67, -0.33,  0.33],
           [-0.07,  0.  ,  0.07, -0.07],
           [ 0.1 ,  0.1 ,  0.  ,  0.  ],
           [ 0.1 ,  0.1 ,  0.  ,  0.  ]])
    """

    p: int
    m: int
    dt: float
    fir: Fir
    a: np.ndarray
    fault_dc: np.ndarray
    Hf0: np.ndarray
    W0: np.ndarray
    grgs_rows: np.ndarray
    noise_std: np.ndarray
    front_std: np.ndarray
    long_run_std: np.ndarray
    front_cov: np.ndarray
    long_run_cov: np.ndarray
    names: list[str] = field(default_factory=list)

    def scaled(self, factor: np.ndarray) -> UioDesign:
        """This design with each output's noise ``factor`` (p+m,) times as large."""
        f = np.broadcast_to(np.asarray(factor, dtype=float), self.noise_std.shape)
        ff = np.outer(f, f)
        return replace(self, noise_std=self.noise_std * f, front_std=self.front_std * f,
                       long_run_std=self.long_run_std * f, front_cov=self.front_cov * ff,
                       long_run_cov=self.long_run_cov * ff)


def _grgs_scheme(A, B, C, E, i: int) -> tuple[Lti, np.ndarray]:
    """Generator i of the GRGS: every sensor but i; returns its (m-1)-output residual system
    on the full input [y; u] (column i unused) and the (m-1, m) steady gain to sensor biases."""
    m, p = C.shape[0], B.shape[1]
    keep = [j for j in range(m) if j != i]
    Ci = C[keep]
    dec = decouple(A, B, Ci, E)
    L = deadbeat_gain(dec.Abar, Ci)
    sub = observer_residual(dec, Ci, L)
    # Embed: input [y (m); u (p)], the generator reads y without y_i.
    select = np.zeros((m - 1 + p, m + p))
    select[np.arange(m - 1), keep] = 1.0
    select[m - 1:, m:] = np.eye(p)
    return Lti(sub.A, sub.B @ select, sub.C, sub.D @ select)


def design_uio(A: np.ndarray, B: np.ndarray, C: np.ndarray, E: np.ndarray, dt: float,
               actuator_pole: float = -2.0, sensor_pole: float = -2.0,
               measurement_std: np.ndarray | None = None,
               input_names: list[str] | None = None,
               output_names: list[str] | None = None) -> UioDesign:
    """The FIDF (actuators) and GRGS (sensors) of a discrete model.

    Parameters
    ----------
    A (n, n), B (n, p), C (m, n), E (n, r): the discrete model (E: unknown-input direction).
    dt : sample period (s); actuator_pole, sensor_pole : continuous poles (1/s, < 0) of the
        first-order weights (the paper's Hf(s) = 2 / (s + 2) for -2).
    measurement_std : (m,) sensor noise stds (for the residual noise levels); ones if None.

    Raises
    ------
    ValueError when d cannot be decoupled or M1 = H C B lacks full column rank (no diagonal
    actuator map).
    """
    A, B, C, E = (np.asarray(M, dtype=float) for M in (A, B, C, E))
    m, p = C.shape[0], B.shape[1]
    sig = np.ones(m) if measurement_std is None else np.asarray(measurement_std, float)
    input_names = input_names or [f"u{j + 1}" for j in range(p)]
    output_names = output_names or [f"y{j + 1}" for j in range(m)]
    # FIDF: basic residual on all sensors, then the exact inverse of W0 Lf (relative degree 1).
    dec = decouple(A, B, C, E)
    L = deadbeat_gain(dec.Abar, C)
    basic = observer_residual(dec, C, L)
    Kbar = dec.Bbar  # K = B, G = 0
    M1 = C @ Kbar
    if np.linalg.matrix_rank(M1, tol=1e-9 * max(np.abs(M1).max(), 1e-300)) < p:
        raise ValueError("H C B has no full column rank: no diagonal actuator fault map")
    W0 = np.linalg.pinv(M1)
    Ao = basic.A
    # Input e(k), output fhat(k-1), state ez_hat(k-1) (see the module docstring, item 3).
    inverse = Lti(Ao - Kbar @ W0 @ C @ Ao, Kbar @ W0, -W0 @ C @ Ao, W0)
    fidf = _fir(series(basic, inverse))
    # GRGS: scheme i sees all sensors but i; its scalar residual is w_i^T e_i.
    rows, scalars = [], []
    for i in range(m):
        scheme = _fir(_grgs_scheme(A, B, C, E, i))
        dc_y = scheme.dc[:, :m]  # (m-1, m): steady response to each sensor bias
        U, _, _ = np.linalg.svd(dc_y)
        w = U[:, 0]
        # Sign: the residual of the first seen sensor's positive bias is positive.
        j0 = next(j for j in range(m) if j != i)
        if w @ dc_y[:, j0] < 0:
            w = -w
        rows.append(w)
        scalars.append(scheme.coef @ w)  # (S_i+1, m+p)
    S = max(fidf.S, *(c.shape[0] - 1 for c in scalars))
    coef = np.zeros((S + 1, m + p, p + m))
    coef[S - fidf.S:, :, :p] = fidf.coef
    for i, c in enumerate(scalars):
        coef[S + 1 - c.shape[0]:, :, p + i] = c
    fir = Fir(coef)
    dc = fir.dc
    # A sensor bias b_j adds b_j to y_j; an actuator bias adds lambda_j to the plant's input,
    # which the residual sees as the command lacking it: -dc of u_j (F_y P + F_u = 0).
    fault_dc = np.hstack([-dc[:, m:], dc[:, :m]])
    a = np.array([lowpass_coefficient(actuator_pole, dt)] * p
                 + [lowpass_coefficient(sensor_pole, dt)] * m)
    front_std, noise_std, long_run, front_cov, long_run_cov = _noise(
        _lag_covariances(coef, sig, m), a)
    names = [f"fidf:{n}" for n in input_names] + [f"grgs:{n}" for n in output_names]
    return UioDesign(p=p, m=m, dt=dt, fir=fir, a=a, fault_dc=fault_dc,
                     Hf0=fault_dc[p:, p:], W0=W0, grgs_rows=np.array(rows),
                     noise_std=noise_std, front_std=front_std, long_run_std=long_run,
                     names=names, front_cov=front_cov, long_run_cov=long_run_cov)


def _lag_covariances(coef: np.ndarray, sig: np.ndarray, m: int) -> np.ndarray:
    """(S+1, n_out, n_out) the front end o's autocovariances for white sensor noise: o is a
    moving average of the noise, G(tau) = sum_l M_l^T S M_{l+tau}."""
    Mz = coef[:, :m, :]  # (S+1, m, n_out)
    var = sig**2
    S1 = Mz.shape[0]
    return np.array([np.einsum("lco,c,lcq->oq", Mz[: S1 - t], var, Mz[t:])
                     for t in range(S1)])


def _noise(gamma: np.ndarray, a: np.ndarray
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """From the autocovariances G (S+1, n_out, n_out) (`_lag_covariances`): the stds of the
    front end o, of the low-passed r, and the long-run stds; then o's covariance at one sample
    and its long-run covariance, G(0) + sum_tau (G(tau) + G(tau)^T). A first-order low-pass
    gives var r = (1-a)^2 / (1-a^2) sum_tau G_ii(tau) a^|tau|.
    """
    diag = np.diagonal(gamma, axis1=1, axis2=2)  # (S+1, n_out)
    S1 = len(gamma)
    front = np.sqrt(diag[0])
    weights = a[None, :] ** np.arange(S1)[:, None]
    acc = diag[0] + 2.0 * (diag[1:] * weights[1:]).sum(axis=0)
    low = np.sqrt((1 - a) ** 2 / (1 - a**2) * acc)
    long_run = np.sqrt(np.maximum(diag[0] + 2.0 * diag[1:].sum(axis=0), 0.0))
    lagged = gamma[1:].sum(axis=0)
    return front, low, long_run, gamma[0], gamma[0] + lagged + lagged.T


def flag_function(r: np.ndarray) -> np.ndarray:
    """psi = sqrt(sum_i r_i^2 / m) (eq 23a); r (..., m) -> (...)."""
    r = np.asarray(r, dtype=float)
    return np.sqrt(np.mean(r**2, axis=-1))


def fault_angles(r: np.ndarray, directions: np.ndarray, signed: bool = True) -> np.ndarray:
    """theta_i = arccos(<r, D_i> / |r| |D_i|) in radians (eq 23b).

    r : (..., m) residual vectors; directions : (m, c) one fault direction per column
    (Hf(0)). signed=False gives the angle to the line through D_i (a bias of either sign:
    the paper's unit faults are positive, a -1.0 bias points the other way). Returns (..., c);
    NaN where r = 0.
    """
    r = np.asarray(r, dtype=float)
    D = np.asarray(directions, dtype=float)
    norm = np.linalg.norm(r, axis=-1, keepdims=True) * np.linalg.norm(D, axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        c = (r @ D) / norm
    if not signed:
        c = np.abs(c)
    return np.arccos(np.clip(c, -1.0, 1.0))

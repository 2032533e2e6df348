"""Windowed parity matrices and fully decoupled parity vectors (Chan et al. 2006, Sections II-III).

Over a window of s+1 samples the outputs obey eq. (2)::

    Y(k) = H0 x(k-s) + Hc U(k) + Hw W(k) + Hpsi Psi(k)

with Y(k) = [y(k-s); ...; y(k)] and likewise U, W, Psi. A parity row v (length (s+1) q) with
v^T H0 = 0 gives a residual r(k) = v^T (Z(k) - Hc Uc(k)) (eq. 5) that does not depend on the state.

* Actuator i (eq. 13, Theorem 1, Theorem 3): v^T [H0 Hw Hpsi Hci] = 0 and v^T Hc != 0, where Hci
  is Hc without actuator i's columns: the residual sees actuator i only.
* Sensor i (eq. 20, Theorem 2): v^T [H0i Hwi Hpsii] = 0 with C, D and G stripped of row i and the
  entries of v on sensor i's rows zero: the residual is blind to sensor i and sees the others.

Among all admissible vectors we keep the unit vector that maximises the fault's gain (||v^T M||
with M = Hc's columns of actuator i, or I* for sensors): the top left singular vector of N^T M for
an orthonormal basis N of the admissible space.

Hpsi: Chan et al. 2006 prints Hpsi = [G; G; ...; G], which decouples psi only if it is constant
over the
window. We use the block diagonal I_(s+1) (x) G, which decouples an arbitrary psi(k); it is the
stricter condition and equals the paper's when G = 0 (the DC motor).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import null_space

from canfdi.core.model import StateSpace

__all__ = [
    "NOISE_SPREAD",
    "RANK_RTOL",
    "ParityMatrices",
    "ParityVector",
    "actuator_columns",
    "block_toeplitz",
    "design_actuator",
    "design_sensor",
    "identity_stack",
    "left_null_space",
    "parity_matrices",
    "sensor_rows",
    "smallest_window",
    "window_noise_covariance",
]

#: Singular values below RANK_RTOL times the largest count as zero. A returned vector therefore
#: satisfies its decoupling equations to RANK_RTOL relative to the 2-norm of the constraint matrix.
RANK_RTOL = 1e-11
#: A gain below GAIN_RTOL times the scale of the fault's matrix counts as no gain at all.
GAIN_RTOL = 1e-8


def block_toeplitz(first: np.ndarray, markov: list[np.ndarray]) -> np.ndarray:
    """Lower block-triangular Toeplitz matrix.

    Parameters
    ----------
    first : (q, m) block on the diagonal.
    markov : s blocks (q, m); block (i, j) for i > j is markov[i - j - 1].

    Returns
    -------
    ((s+1) q, (s+1) m) matrix.
    """
    s = len(markov)
    q, m = first.shape
    out = np.zeros(((s + 1) * q, (s + 1) * m))
    blocks = [first, *markov]
    for i in range(s + 1):
        for j in range(i + 1):
            out[i * q : (i + 1) * q, j * m : (j + 1) * m] = blocks[i - j]
    return out


def _powers_times(C: np.ndarray, A: np.ndarray, X: np.ndarray, count: int) -> list[np.ndarray]:
    """[C X, C A X, ..., C A^(count-1) X]."""
    out, AX = [], X
    for _ in range(count):
        out.append(C @ AX)
        AX = A @ AX
    return out


@dataclass(frozen=True)
class ParityMatrices:
    """The windowed matrices of eq. (3) for window order s.

    Attributes
    ----------
    s : window order (the window holds s+1 samples).
    H0 : ((s+1) q, n) = [C; CA; ...; CA^s].
    Hc : ((s+1) q, (s+1) p) input Toeplitz, D on the diagonal (zero in Chan et al. 2006).
    Hw : ((s+1) q, (s+1) r) state unknown input Toeplitz, zero diagonal.
    Hpsi : ((s+1) q, (s+1) r1) block diagonal of G.

    Examples
    --------
    >>> from canfdi.core.model import StateSpace
    >>> model = StateSpace(A=[[0.9]], B=[[1.0]], C=[[1.0]], dt=0.01)
    >>> pm = parity_matrices(model, 1)
    >>> pm.H0, pm.Hc
    (array([[1. ],
           [0.9]]), array([[0., 0.],
           [1., 0.]]))
    """

    s: int
    H0: np.ndarray
    Hc: np.ndarray
    Hw: np.ndarray
    Hpsi: np.ndarray


def parity_matrices(model: StateSpace, s: int, C: np.ndarray | None = None,
                    D: np.ndarray | None = None, G: np.ndarray | None = None) -> ParityMatrices:
    """H0, Hc, Hw, Hpsi of eq. (3) for a discrete model, optionally with C, D, G replaced.

    Passing C, D, G with sensor i's row zeroed gives H0i, Hci, Hwi, Hpsii of Section III-B.
    """
    if model.continuous:
        raise ValueError("parity matrices need a discrete model: call model.discretize() first")
    if s < 0:
        raise ValueError(f"s: window order must be >= 0, got {s}")
    C = model.C if C is None else C
    D = model.D if D is None else D
    G = model.G if G is None else G
    A = model.A
    H0 = np.vstack([C @ np.linalg.matrix_power(A, k) for k in range(s + 1)])
    Hc = block_toeplitz(D, _powers_times(C, A, model.B, s))
    Hw = block_toeplitz(np.zeros((C.shape[0], model.r)), _powers_times(C, A, model.F, s))
    Hpsi = np.kron(np.eye(s + 1), G)
    return ParityMatrices(s=s, H0=H0, Hc=Hc, Hw=Hw, Hpsi=Hpsi)


def actuator_columns(p: int, s: int, i: int) -> np.ndarray:
    """Column indices of actuator i in Hc (one per sample of the window), shape (s+1,)."""
    return np.arange(s + 1) * p + i


def sensor_rows(q: int, s: int, i: int) -> np.ndarray:
    """Row indices of sensor i in a stacked window Y(k), shape (s+1,)."""
    return np.arange(s + 1) * q + i


def identity_stack(q: int, s: int) -> np.ndarray:
    """I* of eq. (36): s+1 identities stacked, shape ((s+1) q, q)."""
    return np.tile(np.eye(q), (s + 1, 1))


def left_null_space(M: np.ndarray, rtol: float = RANK_RTOL) -> np.ndarray:
    """Orthonormal basis of {v : v^T M = 0}, shape (rows, dim)."""
    if M.shape[1] == 0 or not np.any(M):
        return np.eye(M.shape[0])
    return null_space(M.T, rcond=rtol)


@dataclass(frozen=True)
class ParityVector:
    """One designed residual.

    Attributes
    ----------
    kind : "actuator" or "sensor".
    index : 0-based actuator or sensor index.
    s : window order.
    exists : a vector satisfying the decoupling equations with a nonzero fault gain was found.
    vector : ((s+1) q,) unit parity row v, or None.
    gain : the gain row v^T M: (s+1,) for an actuator (v^T Hc on its columns), (q,) for a sensor
        residual (v^T I*, zero at its own sensor).
    sensitivity : ||gain||, the quantity maximised.
    null_dim : dimension of the admissible space (before the gain condition).
    rank : rank of the constraint matrix H*.
    rows : number of rows of H*, (s+1) q for actuators, (s+1)(q-1) for sensors.
    decoupling_residual : ||v^T H*|| / ||H*||_2, the relative violation of the decoupling equations.
    reason : why no vector exists, or None.

    Examples
    --------
    >>> from canfdi.core.model import StateSpace
    >>> model = StateSpace(A=[[0.9]], B=[[1.0]], C=[[1.0], [1.0]], dt=0.01)
    >>> v = design_sensor(model, 0, 1)  # blind to y0, over a window of two samples
    >>> v.kind, v.exists, v.s, np.round(np.abs(v.gain), 4)
    ('sensor', True, 1, array([0.    , 0.0743]))
    """

    kind: str
    index: int
    s: int
    exists: bool
    vector: np.ndarray | None
    gain: np.ndarray | None
    sensitivity: float
    null_dim: int
    rank: int
    rows: int
    decoupling_residual: float | None
    reason: str | None


def _best_vector(N: np.ndarray, M: np.ndarray, weights: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray, float]:
    """Unit v = N a maximising ||v^T M||; returns (v, v^T M, ||v^T M||).

    ``weights`` ((rows,) noise std of each window row; M's columns already in units of their
    fault's noise): maximise ||v^T M|| / sqrt(v^T diag(weights^2) v) instead, the fault seen
    per unit of the residual's own noise (then scaled to unit norm). With every row equally
    noisy the two are the same vector."""
    if weights is not None:
        B = N.T @ (N * weights[:, None] ** 2)
        L = np.linalg.cholesky(B + 1e-300 * np.eye(len(B)))
        Li = np.linalg.inv(L)
        U, _, _ = np.linalg.svd(Li @ (N.T @ M), full_matrices=False)
        v = N @ (Li.T @ U[:, 0])
        v = v / np.linalg.norm(v)
        v, gain = _sign_fixed(v, v @ M)
        return v, gain, float(np.linalg.norm(gain))
    S = N.T @ M
    U, sig, _ = np.linalg.svd(S, full_matrices=False)
    v = N @ U[:, 0]
    v, gain = _sign_fixed(v, v @ M)
    return v, gain, float(sig[0])


def _sign_fixed(v: np.ndarray, gain: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(v, gain) or (-v, -gain): the sign that makes the largest gain entry positive, and of
    entries equal to it up to rounding (a fault pair the residual sees alike, such as the DC
    motor's i_a and i_f + i_a in the residual blind to i_f) the first in index order: the
    same design on any BLAS, which an argmax over a tie is not.

    >>> v, gain = _sign_fixed(np.array([1.0, 2.0]), np.array([0.0, -0.3, 0.3 + 1e-16]))
    >>> v.tolist(), np.round(gain, 6).tolist()
    ([-1.0, -2.0], [-0.0, 0.3, -0.3])
    """
    mag = np.abs(gain)
    if mag.size == 0 or not mag.max() > 0.0:
        return v, gain
    first = int(np.flatnonzero(mag >= (1.0 - 1e-9) * mag.max())[0])
    return (-v, -gain) if gain[first] < 0 else (v, gain)


def _balanced(N: np.ndarray, M: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """M's columns (faults, in units of their noise) each divided by the most any vector of
    span(N) can see of it per unit of its own noise: the residual then sees every fault it
    can, rather than the one that dwarfs the others (a float32 echo next to a current)."""
    B = N.T @ (N * weights[:, None] ** 2)
    S = N.T @ M
    best = np.sqrt(np.maximum(np.einsum("ij,ij->j", S, np.linalg.solve(B, S)), 0.0))
    top = best.max() if best.size else 0.0
    return np.where(best > GAIN_RTOL * max(top, 1e-300), M / np.where(best > 0, best, 1.0),
                    0.0)


def _every_fault(N: np.ndarray, Mb: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Unit v = N a of least noise that sees every fault of the balanced Mb alike: Mb's
    seen columns all get a gain of 1 in size (least squares where they cannot), their signs
    those of the best vector's gains. A vector that maximised the sum of the squared gains
    would take one relation when two see different faults equally well (a tie that rounding
    would break); this one takes both."""
    B = N.T @ (N * weights[:, None] ** 2)
    S = N.T @ Mb
    seen = np.flatnonzero(np.linalg.norm(S, axis=0) > 0)
    if seen.size == 0:
        return _best_vector(N, Mb, weights)[0]
    top, _, _ = _best_vector(N, Mb, weights)
    signs = np.where(top @ Mb[:, seen] < 0, -1.0, 1.0)
    Ss = S[:, seen]
    BiS = np.linalg.solve(B, Ss)
    a = BiS @ (np.linalg.pinv(Ss.T @ BiS, rcond=1e-10) @ signs)
    v = N @ a
    norm = np.linalg.norm(v)
    if norm == 0:
        return top
    v = v / norm
    gain = v @ Mb
    if gain[np.argmax(np.abs(gain))] < 0:
        v = -v
    return v


def _constraint_residual(v: np.ndarray, H: np.ndarray) -> float:
    if H.shape[1] == 0:
        return 0.0
    scale = np.linalg.norm(H, 2)
    return float(np.linalg.norm(v @ H) / scale) if scale > 0 else 0.0


def _from_space(kind: str, i: int, s: int, N: np.ndarray, M: np.ndarray, H_check: np.ndarray,
                rows: int, gain_floor: float, no_space: str, no_gain: str,
                weights: np.ndarray | None = None, fault_scale: np.ndarray | None = None
                ) -> ParityVector:
    """The best vector of the admissible space N for the fault matrix M, or why there is none
    (``weights``, ``fault_scale``: the noise-weighted choice of `_best_vector`; the gain
    reported is v^T M in the faults' own units)."""
    rank = rows - N.shape[1]
    common = dict(kind=kind, index=i, s=s, null_dim=N.shape[1], rank=rank, rows=rows)
    none = dict(exists=False, vector=None, gain=None, sensitivity=0.0, decoupling_residual=None)
    if N.shape[1] == 0:
        return ParityVector(reason=no_space.format(rank=rank, rows=rows, s=s), **none, **common)
    if weights is None:
        v, gain, sens = _best_vector(N, M)
    else:
        if fault_scale is None:
            v, _, _ = _best_vector(N, M, weights)
        else:
            v = _every_fault(N, _balanced(N, M * fault_scale, weights), weights)
        gain = v @ M
        sens = float(np.linalg.norm(gain))
    if sens <= gain_floor:
        return ParityVector(reason=no_gain.format(dim=N.shape[1], s=s), **none, **common)
    return ParityVector(exists=True, vector=v, gain=gain, sensitivity=sens,
                        decoupling_residual=_constraint_residual(v, H_check), reason=None,
                        **common)


NOISE_SPREAD = 10.0
"""Sensors whose noise standard deviations differ by more than this factor get vectors chosen
per unit of noise (`design_actuator`, `design_sensor`); closer ones keep the paper's choice."""


def _weights(noise_std: np.ndarray | None, q: int, s: int) -> np.ndarray | None:
    """Each window row's noise std, when the sensors' noise differs by more than
    NOISE_SPREAD (else None: the paper's unweighted choice)."""
    if noise_std is None:
        return None
    std = np.broadcast_to(np.asarray(noise_std, dtype=float), (q,))
    if np.all(std > 0) and std.max() <= std.min() * NOISE_SPREAD:
        return None
    return np.tile(np.maximum(std, 1e-300), s + 1)


def design_actuator(model: StateSpace, i: int, s: int, noise_std: np.ndarray | None = None
                    ) -> ParityVector:
    """Fully decoupled parity vector for actuator i at window order s (eq. 13, Theorem 3).

    noise_std : (q,) the sensors' noise; when they differ by more than NOISE_SPREAD, the
    vector is the one that sees the actuator best per unit of its own noise (a drive whose
    sensors range from a float32 echo to a noisy current would otherwise get the vector of
    the largest raw gain)."""
    if not 0 <= i < model.p:
        raise ValueError(f"i: actuator index must be in [0, {model.p}), got {i}")
    pm = parity_matrices(model, s)
    cols = actuator_columns(model.p, s, i)
    Hstar = np.hstack([pm.H0, pm.Hw, pm.Hpsi, np.delete(pm.Hc, cols, axis=1)])
    M = pm.Hc[:, cols]
    return _from_space(
        "actuator", i, s, left_null_space(Hstar), M, Hstar, Hstar.shape[0],
        gain_floor=GAIN_RTOL * max(np.linalg.norm(M, 2), 1e-300),
        weights=_weights(noise_std, model.q, s),
        no_space=("Theorem 1: [H0 Hw Hpsi Hci] has rank {rank} = its {rows} rows at s={s}, so "
                  "no nonzero v decouples state, unknown inputs and other actuators"),
        no_gain=("Theorem 3: all {dim} decoupled vectors at s={s} have v^T Hc = 0: the "
                 "actuator's effect on the window is hidden by the decoupling"),
    )


def design_sensor(model: StateSpace, i: int, s: int, noise_std: np.ndarray | None = None
                  ) -> ParityVector:
    """Fully decoupled parity vector blind to sensor i at window order s (eq. 20, Theorem 2).

    noise_std : (q,) the sensors' noise; when they differ by more than NOISE_SPREAD, the
    vector that sees the other sensors' biases best, each bias counted in its sensor's noise
    stds, relative to the most any admissible vector sees of it, per unit of the residual's
    own noise: it sees every other sensor it can, as the scheme wants."""
    if not 0 <= i < model.q:
        raise ValueError(f"i: sensor index must be in [0, {model.q}), got {i}")
    rows_i = sensor_rows(model.q, s, i)
    pm = parity_matrices(model, s)
    Hfull = np.hstack([pm.H0, pm.Hw, pm.Hpsi])
    # Starred matrices of Theorem 2: sensor i's rows removed (they are zero once C_i, G_i are used).
    Hstar = np.delete(Hfull, rows_i, axis=0)
    N_red = left_null_space(Hstar)
    # Embed back into the full window with zeros on sensor i's rows.
    N = np.zeros(((s + 1) * model.q, N_red.shape[1]))
    N[np.delete(np.arange((s + 1) * model.q), rows_i)] = N_red
    weights = _weights(noise_std, model.q, s)
    return _from_space(
        "sensor", i, s, N, identity_stack(model.q, s), Hfull, Hstar.shape[0],
        gain_floor=GAIN_RTOL, weights=weights,
        fault_scale=None if weights is None else weights[:model.q],
        no_space=(f"Theorem 2: [H0i Hwi Hpsii] without sensor {i}'s rows has rank {{rank}} = "
                  "its {rows} rows at s={s}: the other sensors hold no redundancy free of the "
                  "state and unknown inputs"),
        no_gain=("decoupled vectors exist at s={s} but none responds to a constant bias on any "
                 "sensor (v^T I* = 0)"),
    )


def smallest_window(design, model: StateSpace, i: int, s_max: int) -> ParityVector:
    """The design at the smallest s in [0, s_max] that admits a vector (Theorems 1-3).

    ``design`` is design_actuator or design_sensor. When no s admits one, the result at s_max
    is returned, with its reason.
    """
    result = None
    for s in range(s_max + 1):
        result = design(model, i, s)
        if result.exists:
            return result
    assert result is not None
    return result


def window_noise_covariance(model: StateSpace, s: int, measurement_std: np.ndarray,
                            process_std: np.ndarray) -> np.ndarray:
    """Covariance of the stacked window Y(k) due to white measurement and process noise.

    Parameters
    ----------
    measurement_std : (q,) standard deviation of each sensor's noise xi(k).
    process_std : (n,) standard deviation of each state's noise varsigma(k).

    Returns
    -------
    ((s+1) q, (s+1) q) covariance; a residual v has noise variance v^T Sigma v.
    """
    meas = np.asarray(measurement_std, dtype=float).reshape(model.q)
    proc = np.asarray(process_std, dtype=float).reshape(model.n)
    Sigma = np.kron(np.eye(s + 1), np.diag(meas**2))
    if np.any(proc):
        # Process noise enters x(k+1), so it reaches the window like an unknown input with F = I.
        Hx = block_toeplitz(np.zeros((model.q, model.n)),
                            _powers_times(model.C, model.A, np.eye(model.n), s))
        Sigma = Sigma + Hx @ np.kron(np.eye(s + 1), np.diag(proc**2)) @ Hx.T
    return Sigma

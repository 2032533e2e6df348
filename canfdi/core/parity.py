"""Windowed parity matrices and fully decoupled parity vectors (seed 001, Sections II-III).

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

Hpsi: seed 001 prints Hpsi = [G; G; ...; G], which decouples psi only if it is constant over the
window. We use the block diagonal I_(s+1) (x) G, which decouples an arbitrary psi(k); it is the
stricter condition and equals the paper's when G = 0 (the DC motor).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import null_space

from canfdi.core.model import StateSpace

__all__ = [
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
    Hc : ((s+1) q, (s+1) p) input Toeplitz, D on the diagonal (zero in seed 001).
    Hw : ((s+1) q, (s+1) r) state unknown input Toeplitz, zero diagonal.
    Hpsi : ((s+1) q, (s+1) r1) block diagonal of G.
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


def _best_vector(N: np.ndarray, M: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Unit v = N a maximising ||v^T M||; returns (v, v^T M, ||v^T M||)."""
    S = N.T @ M
    U, sig, _ = np.linalg.svd(S, full_matrices=False)
    v = N @ U[:, 0]
    gain = v @ M
    # Fix the sign so the largest gain entry is positive: designs are then reproducible.
    if gain[np.argmax(np.abs(gain))] < 0:
        v, gain = -v, -gain
    return v, gain, float(sig[0])


def _constraint_residual(v: np.ndarray, H: np.ndarray) -> float:
    if H.shape[1] == 0:
        return 0.0
    scale = np.linalg.norm(H, 2)
    return float(np.linalg.norm(v @ H) / scale) if scale > 0 else 0.0


def _from_space(kind: str, i: int, s: int, N: np.ndarray, M: np.ndarray, H_check: np.ndarray,
                rows: int, gain_floor: float, no_space: str, no_gain: str) -> ParityVector:
    """The best vector of the admissible space N for the fault matrix M, or why there is none."""
    rank = rows - N.shape[1]
    common = dict(kind=kind, index=i, s=s, null_dim=N.shape[1], rank=rank, rows=rows)
    none = dict(exists=False, vector=None, gain=None, sensitivity=0.0, decoupling_residual=None)
    if N.shape[1] == 0:
        return ParityVector(reason=no_space.format(rank=rank, rows=rows, s=s), **none, **common)
    v, gain, sens = _best_vector(N, M)
    if sens <= gain_floor:
        return ParityVector(reason=no_gain.format(dim=N.shape[1], s=s), **none, **common)
    return ParityVector(exists=True, vector=v, gain=gain, sensitivity=sens,
                        decoupling_residual=_constraint_residual(v, H_check), reason=None,
                        **common)


def design_actuator(model: StateSpace, i: int, s: int) -> ParityVector:
    """Fully decoupled parity vector for actuator i at window order s (eq. 13, Theorem 3)."""
    if not 0 <= i < model.p:
        raise ValueError(f"i: actuator index must be in [0, {model.p}), got {i}")
    pm = parity_matrices(model, s)
    cols = actuator_columns(model.p, s, i)
    Hstar = np.hstack([pm.H0, pm.Hw, pm.Hpsi, np.delete(pm.Hc, cols, axis=1)])
    M = pm.Hc[:, cols]
    return _from_space(
        "actuator", i, s, left_null_space(Hstar), M, Hstar, Hstar.shape[0],
        gain_floor=GAIN_RTOL * max(np.linalg.norm(M, 2), 1e-300),
        no_space=("Theorem 1: [H0 Hw Hpsi Hci] has rank {rank} = its {rows} rows at s={s}, so "
                  "no nonzero v decouples state, unknown inputs and other actuators"),
        no_gain=("Theorem 3: all {dim} decoupled vectors at s={s} have v^T Hc = 0: the "
                 "actuator's effect on the window is hidden by the decoupling"),
    )


def design_sensor(model: StateSpace, i: int, s: int) -> ParityVector:
    """Fully decoupled parity vector blind to sensor i at window order s (eq. 20, Theorem 2)."""
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
    return _from_space(
        "sensor", i, s, N, identity_stack(model.q, s), Hfull, Hstar.shape[0],
        gain_floor=GAIN_RTOL,
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

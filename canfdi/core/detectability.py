"""Fault detectability as a system property (Nyberg and Nielsen, the ULPE scheme).

For one fault entering as ``sigma x = A x + B u + E v + K f`` and ``y = C x + D u + J v + L f``
(sigma = d/dt or the shift q), with the disturbances v decoupled:

* the state is split (Kalman decomposition) into x, reachable from [u v], and z, reachable only
  from the fault; R = [C; CA; ...; CA^rho] splits into R_x and R_z;
* Theorem 2: the fault is detectable iff N^T P != 0, N a basis of the left null space of [R_x H];
* Theorem 3: it is strongly detectable (nonzero steady-state response to a constant fault) iff
  N^T (P v - R_z A_z^-1 K_z) != 0 (continuous, v = [1 0 ... 0]) or
  N^T (P v + R_z (I - A_z)^-1 K_z) != 0 (discrete, v = [1 ... 1]);
* rho = n is enough for both.

In canfdi the disturbances are the model's unknown inputs: v = [w; psi], E = [F 0], J = [0 G].
An actuator fault j has K = B_j, L = D_j; a sensor fault j has K = 0, L = e_j.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import orth

from canfdi.core.model import StateSpace
from canfdi.core.parity import RANK_RTOL, block_toeplitz, left_null_space

__all__ = ["Detectability", "fault_detectability", "fault_directions", "model_detectability"]

#: A response below this fraction of the fault's own matrix scale counts as zero.
RESPONSE_RTOL = 1e-8


def _reachable(A: np.ndarray, X: np.ndarray) -> np.ndarray:
    """Orthonormal basis of the reachable subspace of (A, X), shape (n, dim)."""
    n = A.shape[0]
    if X.shape[1] == 0 or not np.any(X):
        return np.zeros((n, 0))
    blocks, AX = [], X
    for _ in range(n):
        blocks.append(AX)
        AX = A @ AX
    ctrb = np.hstack(blocks)
    U, sig, _ = np.linalg.svd(ctrb, full_matrices=False)
    return U[:, sig > RANK_RTOL * sig[0]]


def _complement(T1: np.ndarray, Xc: np.ndarray) -> np.ndarray:
    """Orthonormal basis of span(T1) minus span(Xc) (Xc is a subspace of T1)."""
    if T1.shape[1] == 0:
        return T1
    proj = T1 - Xc @ (Xc.T @ T1)
    if not np.any(np.abs(proj) > RANK_RTOL):
        return np.zeros((T1.shape[0], 0))
    Z = orth(proj, rcond=1e-9)
    return Z


@dataclass(frozen=True)
class Detectability:
    """Detectability of one fault with the unknown inputs decoupled.

    Attributes
    ----------
    detectable : Theorem 2 holds.
    strongly_detectable : Theorem 3 holds (False when its precondition fails; see reason).
    response : ||N^T P||, the largest gain of any normalised parity function.
    steady_response : ||N^T (P v +/- R_z ...)||, the steady-state counterpart.
    direct_steady_response : ||N^T P v||, the steady state a Chow-Willsky scheme would predict
        by ignoring the fault-only dynamics z (Example 3 shows it can be nonzero when the
        true steady response is zero).
    rho : the parity order used (n).
    n_z : number of states reachable only from the fault.
    reason : why the fault is not (strongly) detectable, or None.

    Examples
    --------
    >>> from canfdi.core.model import StateSpace
    >>> model = StateSpace(A=[[0.9]], B=[[1.0]], C=[[1.0], [1.0]], dt=0.01)
    >>> [(kind, j, d.detectable, d.n_z) for kind, j, d in model_detectability(model)]
    [('actuator', 0, True, 0), ('sensor', 0, True, 0), ('sensor', 1, True, 0)]
    """

    detectable: bool
    strongly_detectable: bool
    response: float
    steady_response: float
    direct_steady_response: float
    rho: int
    n_z: int
    reason: str | None


def fault_detectability(
    A: np.ndarray, B: np.ndarray, C: np.ndarray, D: np.ndarray, E: np.ndarray, J: np.ndarray,
    K: np.ndarray, L: np.ndarray, continuous: bool, rho: int | None = None,
) -> Detectability:
    """Theorems 2 and 3 of Nyberg and Nielsen for one fault.

    Parameters
    ----------
    A : (n, n); B : (n, k) known inputs; C : (m, n); D : (m, k).
    E : (n, kd), J : (m, kd) disturbance (decoupled) distributions.
    K : (n,) or (n, 1), L : (m,) or (m, 1) fault distributions.
    continuous : selects the continuous or the discrete form of Theorem 3.
    rho : parity order, n by default (sufficient by the theorems).
    """
    n, m = A.shape[0], C.shape[0]
    K = np.asarray(K, dtype=float).reshape(n, 1)
    L = np.asarray(L, dtype=float).reshape(m, 1)
    rho = n if rho is None else rho
    # Modes not reachable from anything stay at rest; drop them, then split x / z.
    T1 = _reachable(A, np.hstack([B, E, K]))
    Xc = _reachable(A, np.hstack([B, E]))
    Z = _complement(T1, Xc)
    R = np.vstack([C @ np.linalg.matrix_power(A, k) for k in range(rho + 1)])
    Rx, Rz = R @ Xc, R @ Z
    H = block_toeplitz(J, [C @ np.linalg.matrix_power(A, k) @ E for k in range(rho)])
    P = block_toeplitz(L, [C @ np.linalg.matrix_power(A, k) @ K for k in range(rho)])
    N = left_null_space(np.hstack([Rx, H]))
    scale = max(np.linalg.norm(P, 2), np.linalg.norm(K), 1e-300)
    response = float(np.linalg.norm(N.T @ P, 2)) if N.shape[1] else 0.0
    detectable = response > RESPONSE_RTOL * scale
    if continuous:
        v = np.zeros((rho + 1, 1))
        v[0] = 1.0
    else:
        v = np.ones((rho + 1, 1))
    reason = None
    steady = 0.0
    direct = float(np.linalg.norm(N.T @ P @ v)) if N.shape[1] else 0.0
    strong = False
    Az, Kz = Z.T @ A @ Z, Z.T @ K
    stable = (np.all(np.linalg.eigvals(Az).real < 0) if continuous
              else np.all(np.abs(np.linalg.eigvals(Az)) < 1)) if Z.shape[1] else True
    if not detectable:
        reason = ("Theorem 2: N^T P = 0 at rho = n: every parity function decoupled from the "
                  "unknown inputs is blind to this fault")
    elif not stable:
        reason = ("Theorem 3 does not apply: the dynamics reachable only from the fault are not "
                  "asymptotically stable")
    else:
        if Z.shape[1]:
            zss = -np.linalg.solve(Az, Kz) if continuous else np.linalg.solve(np.eye(len(Az)) - Az,
                                                                              Kz)
            steady_vec = P @ v + Rz @ zss
        else:
            steady_vec = P @ v
        steady = float(np.linalg.norm(N.T @ steady_vec)) if N.shape[1] else 0.0
        strong = steady > RESPONSE_RTOL * scale
        if not strong:
            reason = ("Theorem 3: detectable, but the steady-state response to a constant fault "
                      "is zero in every decoupled parity function (a constant fault is "
                      "indistinguishable from a change of state or unknown input)")
    return Detectability(detectable=bool(detectable), strongly_detectable=bool(strong),
                         response=response, steady_response=steady,
                         direct_steady_response=direct, rho=rho, n_z=Z.shape[1],
                         reason=reason)


def fault_directions(model: StateSpace) -> list[tuple[str, int, np.ndarray, np.ndarray]]:
    """(kind, index, K, L) for every actuator and sensor fault of the model."""
    out = []
    for j in range(model.p):
        out.append(("actuator", j, model.B[:, j], model.D[:, j]))
    for j in range(model.q):
        L = np.zeros(model.q)
        L[j] = 1.0
        out.append(("sensor", j, np.zeros(model.n), L))
    return out


def model_detectability(model: StateSpace) -> list[tuple[str, int, Detectability]]:
    """Detectability of every actuator and sensor fault, the unknown inputs w, psi decoupled.

    The model's own time domain is used (continuous form for a continuous model).
    """
    E = np.hstack([model.F, np.zeros((model.n, model.r1))])
    J = np.hstack([np.zeros((model.q, model.r)), model.G])
    return [
        (kind, j, fault_detectability(model.A, model.B, model.C, model.D, E, J, K, L,
                                      continuous=model.continuous))
        for kind, j, K, L in fault_directions(model)
    ]

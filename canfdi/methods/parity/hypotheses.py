"""The parity method's fault hypotheses and their regressors (Chan et al. 2006 eqs. 24-29, 34-41).

Every hypothesis predicts the residuals linearly in its parameters from the fault onset k_f on,
through the bank's signatures (canfdi.core.residuals): a sensor bias through ``Gz[j]``, an
actuator's ``u = eta u_c + lambda`` through ``Gu[j]`` (``(eta - 1) u_c`` and ``lambda``). The
diagnoser fits every hypothesis at several onsets at once with these regressors; `canfdi report`
recomputes an accepted fault's estimate history with the same ones.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from canfdi.core.identify import InformationSums, rls_increments
from canfdi.core.residuals import ResidualBank

__all__ = ["COLUMN_SOURCES", "Hypothesis", "block_regressors", "independent_sensors",
           "information_increments", "noise_units", "proportional", "regressor_columns",
           "regressors", "row_regressors", "steady_response"]

COLUMN_SOURCES = {"none": 0, "sensor": 1, "scale": 2, "bias": 3}
"""What a regressor column is made of (`regressor_columns`; the C core's CFDI_COL_*): nothing
(beyond a hypothesis' parameters), a sensor's bias signature Gz[j], an actuator's signature
Gu[j] times its command (eta - 1), or Gu[j] alone (lambda)."""


@dataclass(frozen=True)
class Hypothesis:
    """One fault hypothesis.

    target : "actuator" (u = eta u_c + lambda, eq. 24), "actuator_bias" (the same with eta = 1:
        a bias alone, one parameter), "sensor", or "sensors" (biases on several sensors at
        once: Chan et al. 2006 eq. 41, over a largest set of sensors whose signatures are linearly
        independent).
    index, name : the channel (for "sensors": the first member).
    members : the sensor indices of a "sensors" hypothesis.

    Examples
    --------
    >>> h = Hypothesis("actuator", 0, "V")
    >>> h.label, h.n_params, Hypothesis("sensors", 1, "i_a", members=(1, 2)).n_params
    ('actuator:V', 2, 2)
    """

    target: str
    index: int
    name: str
    members: tuple[int, ...] = ()

    @property
    def label(self) -> str:
        return f"{self.target}:{self.name}"

    @property
    def n_params(self) -> int:
        return {"actuator": 2, "actuator_bias": 1, "sensor": 1}.get(self.target,
                                                                     len(self.members))


def steady_response(bank: ResidualBank, target: str, j: int) -> np.ndarray:
    """(m,) the steady change of the normalised residuals (the noise the bank uses) under a
    unit constant fault: sensor j's bias (``target`` "sensor"), or actuator j's lambda."""
    G = bank.Gz if target == "sensor" else bank.Gu
    return G[j].sum(axis=-1) / bank.sigma


def noise_units(bank: ResidualBank, h: Hypothesis, u_mean: float | np.ndarray | None = None,
                projection: np.ndarray | None = None) -> np.ndarray:
    """(n_params,) each parameter's noise unit: the size whose steady change in the statistic
    most sensitive to it is one noise standard deviation: a residual (normalised with the
    noise the bank uses: the configured one, widened where the watchdog found more), or one of
    the detector's signature projections (``projection`` (m, c), canfdi.methods.parity.
    signatures: unit variance). inf where nothing sees it. An actuator's eta - 1 moves its
    command by (eta - 1) u: its unit is lambda's over the command's mean size ``u_mean`` (inf
    without one; an array of them (...) gives (..., 2)).

    A fault known to within a small part of its noise units leaves, once compensated, a change
    far below what detection sees, however large the fault.
    """
    def unit(target: str, j: int) -> float:
        mu = steady_response(bank, target, j)
        gain = float(np.max(np.abs(mu)))
        if projection is not None and projection.size:
            gain = max(gain, float(np.max(np.abs(mu @ projection))))
        return 1.0 / gain if gain > 0.0 else np.inf

    if h.target == "sensors":
        return np.array([unit("sensor", j) for j in h.members])
    if h.target == "sensor":
        return np.array([unit("sensor", h.index)])
    lam = unit("actuator", h.index)
    if h.target == "actuator_bias":
        return np.array([lam])
    u = np.asarray(0.0 if u_mean is None else u_mean, dtype=float)
    eta = np.divide(lam, u, out=np.full(u.shape, np.inf), where=u > 0.0)
    return np.stack([eta, np.full(u.shape, lam)], axis=-1)


def proportional(a: np.ndarray, b: np.ndarray, tol: float = 1e-9) -> bool:
    """Whether two signatures are multiples of each other (and nonzero)."""
    na, nb = float(np.linalg.norm(a)), float(np.linalg.norm(b))
    if na == 0.0 or nb == 0.0:
        return False
    return abs(float(a @ b)) >= (1.0 - tol) * na * nb


def independent_sensors(bank: ResidualBank, sensors: list[int]) -> list[int]:
    """A largest subset of ``sensors``, in index order, whose signatures are linearly
    independent."""
    chosen: list[int] = []
    basis = np.zeros((0, bank.Gz[0].size))
    for j in sensors:
        trial = np.vstack([basis, bank.Gz[j].ravel()])
        if np.linalg.matrix_rank(trial, tol=1e-9 * np.abs(trial).max()) > len(chosen):
            chosen.append(j)
            basis = trial
    return chosen


def regressors(bank: ResidualBank, hypotheses: list[Hypothesis], d: int, k: int,
               onsets: np.ndarray, u_window: np.ndarray) -> np.ndarray:
    """(H, K, m, d) normalised regressors of every hypothesis and onset at sample k
    (`block_regressors` of one sample).

    Parameters
    ----------
    bank : the residual bank (window S).
    hypotheses : (H,) the hypotheses; d : parameters of the largest (columns beyond a
        hypothesis' own are zero).
    k : the sample; onsets : (K,) candidate fault onsets.
    u_window : (S+1, p) the (compensated) commands of samples k-S..k; NaN (lost) is taken as
        0, since a lost command only enters residuals that are missing anyway.
    """
    return block_regressors(bank, hypotheses, d, np.array([k]), onsets,
                            np.asarray(u_window)[None])[0]


def block_regressors(bank: ResidualBank, hypotheses: list[Hypothesis], d: int, k: np.ndarray,
                     onsets: np.ndarray, u_windows: np.ndarray) -> np.ndarray:
    """(N, H, K, m, d) normalised regressors of every hypothesis and onset at samples k (N,),
    u_windows (N, S+1, p) the commands of each sample's window (as in `regressors`)."""
    S = bank.S
    positions = np.asarray(k)[:, None] - S + np.arange(S + 1)  # (N, S+1)
    mask = (positions[:, None, :] >= np.asarray(onsets)[None, :, None]).astype(float)
    # Every sensor's and actuator's signature under every onset at once (einsum rather than a
    # Python loop over hypotheses: this runs for each sample of a diagnosis).
    zs = np.einsum("jms,nks->njkm", bank.Gz, mask)  # (N, q, K, m)
    u = np.nan_to_num(u_windows)  # (N, S+1, p)
    ua = np.einsum("jms,nks,nsj->njkm", bank.Gu, mask, u)  # (N, p, K, m)
    ub = np.einsum("jms,nks->njkm", bank.Gu, mask)
    out = np.zeros((len(positions), len(hypotheses), len(onsets), bank.m, d))
    for h_i, h in enumerate(hypotheses):
        if h.target == "sensor":
            out[:, h_i, :, :, 0] = zs[:, h.index]
        elif h.target == "sensors":
            for c, j in enumerate(h.members):
                out[:, h_i, :, :, c] = zs[:, j]
        elif h.target == "actuator_bias":
            out[:, h_i, :, :, 0] = ub[:, h.index]
        else:
            out[:, h_i, :, :, 0] = ua[:, h.index]
            out[:, h_i, :, :, 1] = ub[:, h.index]
    return out / bank.sigma[None, None, None, :, None]


def regressor_columns(hypotheses: list[Hypothesis], d: int) -> np.ndarray:
    """(H, d, 2) int32: for each hypothesis and parameter, what `block_regressors` makes its
    column of (a `COLUMN_SOURCES` code) and from which channel: the table the C kernel's
    cfdi_info_block computes the regressors by.

    Examples
    --------
    >>> hyps = [Hypothesis("actuator", 0, "V"), Hypothesis("sensor", 2, "y2")]
    >>> regressor_columns(hyps, 2).tolist()  # (scale, V), (bias, V); (sensor, y2), none
    [[[2, 0], [3, 0]], [[1, 2], [0, 0]]]
    """
    out = np.zeros((len(hypotheses), d, 2), dtype=np.int32)
    for h_i, h in enumerate(hypotheses):
        if h.target == "sensor":
            cols = [("sensor", h.index)]
        elif h.target == "sensors":
            cols = [("sensor", j) for j in h.members]
        elif h.target == "actuator_bias":
            cols = [("bias", h.index)]
        else:
            cols = [("scale", h.index), ("bias", h.index)]
        for c, (source, channel) in enumerate(cols):
            out[h_i, c] = (COLUMN_SOURCES[source], channel)
    return out


def information_increments(bank: ResidualBank, hypotheses: list[Hypothesis],
                           columns: np.ndarray, d: int, onsets: np.ndarray, k: np.ndarray,
                           u_windows: np.ndarray, rn: np.ndarray, gamma: np.ndarray
                           ) -> InformationSums:
    """What N samples add to a diagnosis' fits (the numpy reference of the C kernel's
    cfdi_info_block, which reads ``columns``, `regressor_columns`, where this reads
    ``hypotheses``): every hypothesis' regressors at every onset (`block_regressors`), their
    information and vector over the residuals present (`rls_increments`, batch shape (H, K)),
    and the sandwich's middle sum phi^T Gamma phi.

    Parameters
    ----------
    k : (N,) samples; u_windows : (N, S+1, p) their commands' windows; rn : (N, m) normalised
        residuals, NaN: no equation; gamma : (m, m) the residuals' long-run covariance.
    """
    del columns  # the C kernel's form of ``hypotheses``
    phi = block_regressors(bank, hypotheses, d, k, onsets, u_windows)  # (N, H, K, m, d)
    rows = phi * (~np.isnan(rn))[:, None, None, :, None]
    meat = np.einsum("nhkmd,nhkme->hkde", rows, gamma @ rows)
    n, H, K, m, dd = phi.shape
    stacked = np.moveaxis(phi, 0, 2).reshape(H, K, n * m, dd)
    sums = rls_increments(stacked, rn.reshape(n * m), dd)
    return InformationSums(J=sums.J, h=sums.h, rr=sums.rr, n_eq=sums.n_eq, meat=meat)


def row_regressors(bank: ResidualBank, hypotheses: list[Hypothesis], onsets: list[int],
                   k: np.ndarray, u_windows: np.ndarray, sigma: np.ndarray | None = None
                   ) -> np.ndarray:
    """(N, m, D) normalised regressors of several hypotheses at once, each at its own onset,
    for N samples: the columns of `regressors` side by side (D = the hypotheses' parameters
    in all), one row block per sample. What a fit of several faults together (the accepted
    ones, refined as data come in) needs over a stretch of samples in one pass.

    Parameters
    ----------
    hypotheses : single-channel hypotheses ("actuator", "actuator_bias", "sensor");
    onsets : their fault onsets.
    k : (N,) samples; u_windows : (N, S+1, p) the (compensated) commands of samples k-S..k of
        each, NaN taken as 0 (as in `regressors`).
    sigma : (m,) or (N, m) the residuals' noise each sample was normalised by; None: the
        bank's now.
    """
    k = np.asarray(k, dtype=np.int64)
    S = bank.S
    positions = k[:, None] - S + np.arange(S + 1)[None, :]  # (N, S+1)
    u = np.nan_to_num(np.asarray(u_windows, dtype=float))
    cols = []
    for h, onset in zip(hypotheses, onsets, strict=True):
        mask = (positions >= onset).astype(float)
        if h.target == "sensor":
            cols.append(np.einsum("ms,ns->nm", bank.Gz[h.index], mask))
        elif h.target in ("actuator", "actuator_bias"):
            if h.target == "actuator":
                cols.append(np.einsum("ms,ns,ns->nm", bank.Gu[h.index], mask, u[:, :, h.index]))
            cols.append(np.einsum("ms,ns->nm", bank.Gu[h.index], mask))
        else:
            raise ValueError(f"hypotheses: {h.label} is not a single channel")
    out = np.stack(cols, axis=-1) if cols else np.zeros((len(k), bank.m, 0))
    sigma = bank.sigma if sigma is None else np.asarray(sigma, dtype=float)
    return out / np.broadcast_to(sigma, (len(k), bank.m))[:, :, None]

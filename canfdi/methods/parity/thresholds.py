"""Page-Hinkley thresholds of the parity residuals, calibrated on simulated fault-free residuals.

Parity residuals over a window are correlated in time, so the white-noise (Siegmund) threshold
is too low; `calibrate_thresholds` calibrates each on fault-free residuals generated from the
config's noise model and bounds it by Siegmund's on the residual's long-run variance.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from canfdi.core.calibrate import calibrate_threshold, threshold_for_long_run_variance
from canfdi.core.memo import digest, remembered
from canfdi.core.residuals import ResidualBank

if TYPE_CHECKING:
    from canfdi.methods.parity.signatures import SignatureColumns

__all__ = [
    "calibrate_thresholds", "instant_covariance", "lagged_covariance", "lagged_middle",
    "long_run_covariance", "noise_factors",
]


def calibrate_thresholds(bank: ResidualBank, measurement_std: np.ndarray,
                         process_std: np.ndarray | None, model, drift: float,
                         interval: float, n: int = 100_000, seed: int = 0,
                         signatures: SignatureColumns | None = None) -> np.ndarray:
    """Page-Hinkley thresholds (m,) in noise-std units for a false-alarm interval (samples);
    with ``signatures`` (canfdi.methods.parity.signatures), (m + c,): the residuals', then
    each projection's at its own drift, for ``signatures.rungs`` times the interval.

    Parity residuals over a window are correlated in time, so the white-noise formula is wrong;
    the thresholds are calibrated on ``n`` fault-free residuals generated from the model's noise
    (seeded, so the design is reproducible) at two false-alarm intervals the record can show
    (n/20 and n/200), and extrapolated log-linearly to ``interval``, as the run length of the
    test grows exponentially with its threshold. Never below the white-noise (Siegmund) value.
    Results are remembered (canfdi.core.memo: for the process, and in the store the shell
    installed): the same design calibrates once.
    """
    m = bank.m
    if signatures is None:
        project, drifts, intervals = np.eye(m), np.full(m, float(drift)), np.full(m, interval)
    else:
        project = np.hstack([np.eye(m), signatures.projection])
        drifts = np.concatenate([np.full(m, float(drift)), signatures.drifts])
        intervals = np.concatenate([np.full(m, float(interval)),
                                    np.full(signatures.count, interval * signatures.rungs)])
    key = digest(CALIBRATION, bank.M, bank.sigma, np.asarray(measurement_std, dtype=float),
                 None if process_std is None else np.asarray(process_std, dtype=float),
                 model.A, model.C, project, drifts, intervals, n, seed)
    return remembered(key, lambda: _calibrate(bank, measurement_std, process_std, model, project,
                                              drifts, intervals, n, seed), (project.shape[1],))


CALIBRATION = "parity thresholds 2"
"""Names the calibration below in the digest of its results: change it with the algorithm,
so that results remembered by an older one are not used."""


def _calibrate(bank: ResidualBank, measurement_std: np.ndarray, process_std: np.ndarray | None,
               model, project: np.ndarray, drift: np.ndarray, interval: np.ndarray, n: int,
               seed: int) -> np.ndarray:
    """Thresholds of the columns rn @ project (m, c) at drifts and intervals (c,)."""
    rng = np.random.default_rng(seed)
    length = n + bank.S
    x = np.zeros((length, bank.q + bank.p))
    x[:, : bank.q] = rng.standard_normal((length, bank.q)) * measurement_std
    if process_std is not None and np.any(process_std):
        state = np.zeros(model.n)
        noise = rng.standard_normal((length, model.n)) * process_std
        for k in range(length):
            x[k, : bank.q] += model.C @ state
            state = model.A @ state + noise[k]
    rn = (bank.batch(x) / bank.sigma) @ project
    arl_hi, arl_lo = n / 20.0, n / 200.0
    # Thresholds are tens of noise stds: 0.02 is far below what matters.
    h_hi = np.asarray(calibrate_threshold(rn, drift, arl_hi, tol=0.02), dtype=float)
    h_lo = np.asarray(calibrate_threshold(rn, drift, arl_lo, tol=0.02), dtype=float)
    slope = np.maximum(h_hi - h_lo, 0.0) / np.log(arl_hi / arl_lo)
    h = h_hi + slope * np.log(np.maximum(interval, arl_hi) / arl_hi)
    # Far beyond the record the extrapolation runs low for strongly correlated residuals (the
    # 10^7-sample soak found s:omega_r, a 5-sample moving sum, alarming every ~1.3e6 samples
    # at a 1e7 target): bound it by Siegmund's threshold on the long-run variance (which is
    # never below the white-noise one).
    long_run = _long_run_variance(bank, measurement_std, process_std, rn, project)
    bound = [threshold_for_long_run_variance(float(d), float(t), [lr])[0]
             for d, t, lr in zip(drift, interval, long_run, strict=True)]
    return np.maximum(h, bound)


def _long_run_variance(bank: ResidualBank, measurement_std: np.ndarray,
                       process_std: np.ndarray | None, rn: np.ndarray,
                       project: np.ndarray | None = None) -> np.ndarray:
    """(c,) long-run variance (sum of all autocovariances) of each column rn @ project of the
    normalised residuals.

    For white measurement noise it is exact: r_i = sum_l sum_c M_i[l, c] x_c(k - S + l), so
    sum_tau cov(tau) = sum_c var(x_c) (sum_l M_i[l, c])^2. Process noise adds slowly decaying
    correlation the formula does not see: with process noise, batch means over the
    calibration record (blocks of 50 windows) estimate it too, and the larger value is used.
    """
    project = np.eye(bank.m) if project is None else project
    exact = np.einsum("ic,ij,jc->c", project, long_run_covariance(bank, measurement_std),
                      project)
    block = 50 * (bank.S + 1)
    n_blocks = len(rn) // block
    if process_std is None or not np.any(process_std) or n_blocks < 20:
        return exact
    means = rn[: n_blocks * block].reshape(n_blocks, block, -1).mean(axis=1)
    return np.maximum(exact, means.var(axis=0, ddof=1) * block)


def _noise_coefficients(bank: ResidualBank, measurement_std: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """(m, S+1, q) each residual's coefficients on the measurements of its window
    (r_i = sum_l sum_c M_i[l, c] x_c(k - S + l)) and (q,) their noise variances."""
    coef = bank.M.reshape(bank.m, bank.S + 1, -1)[:, :, : bank.q]
    return coef, np.asarray(measurement_std, dtype=float) ** 2 * np.ones(bank.q)


def long_run_covariance(bank: ResidualBank, measurement_std: np.ndarray) -> np.ndarray:
    """(m, m) long-run covariance (sum over all lags) of the normalised residuals under white
    measurement noise: r_i = sum_l sum_c M_i[l, c] x_c(k - S + l), so the sum of r over a
    stretch moves as sum_c var(x_c) (sum_l M_i[l, c]) (sum_l M_j[l, c]) per sample. What a sum
    of residuals (a bias fitted over many samples) really varies by: the white, independent
    residuals that least squares assumes would give the identity. Process noise adds
    correlation this does not count."""
    coef, var = _noise_coefficients(bank, measurement_std)
    gain = coef.sum(axis=1) / bank.sigma[:, None]  # (m, q)
    return (gain * var[None, :]) @ gain.T


def noise_factors(bank: ResidualBank, measurement_std: np.ndarray) -> np.ndarray:
    """(S+1, q, m) N[l, c, a]: normalised residual a's coefficient on measurement c at lag l
    of its window, times c's noise standard deviation. The normalised residuals are
    r(k) = sum_l N[l]^T e(k - S + l) of white unit noise e, which is what their
    autocovariances (`lagged_covariance`) and the C core's lag-by-lag middle
    (canfdi/_c/lagged.h: a sum of squares over measurement times) are made of."""
    coef, var = _noise_coefficients(bank, measurement_std)
    c = coef / bank.sigma[:, None, None]  # (m, S+1, q)
    return np.transpose(c, (1, 2, 0)) * np.sqrt(var)[None, :, None]


def lagged_covariance(bank: ResidualBank, measurement_std: np.ndarray) -> np.ndarray:
    """(S+1, m, m) autocovariances C[lag] = E[r(k) r(k - lag)^T] of the normalised residuals
    under white measurement noise, lag 0..S (none beyond: a window holds S+1 samples). A fit
    whose regressors change within S samples (a fault's transient) varies as these say; the
    long-run covariance, C[0] + sum_lag (C[lag] + C[lag]^T), holds for steady ones only.

    >>> from canfdi.core.design import design_bank
    >>> from canfdi.core.model import StateSpace
    >>> bank = ResidualBank(design_bank(StateSpace(A=[[0.9]], B=[[1.0]], C=[[1.0], [1.0]]),
    ...                                 ["u"], ["y0", "y1"]))
    >>> C = lagged_covariance(bank, np.ones(2))
    >>> total = C[0] + (C[1:] + np.swapaxes(C[1:], 1, 2)).sum(axis=0)
    >>> bool(np.allclose(total, long_run_covariance(bank, np.ones(2))))
    True
    """
    N = noise_factors(bank, measurement_std)
    width = bank.S + 1
    # r_i(k) holds e(k - S + l) with N[l, :, i]; r_j(k - lag) holds it with N[l + lag, :, j].
    return np.stack([np.einsum("lci,lcj->ij", N[: width - lag], N[lag:])
                     for lag in range(width)])


def lagged_middle(rows: np.ndarray, k: np.ndarray, lagged: np.ndarray) -> np.ndarray:
    """(d, d) sum_i sum_j rows_i^T C[k_i - k_j] rows_j over the pairs of samples within S of
    each other (C[-lag] = C[lag]^T): the middle of the sandwich covariance of least squares on
    residuals correlated as ``lagged`` says, lag by lag.

    rows : (N, m, d) the regressors of samples ``k`` (N,), strictly increasing (gaps allowed);
    lagged : (S+1, m, m) the residuals' autocovariances (`lagged_covariance`).

    >>> rng = np.random.default_rng(0)
    >>> rows, k, C = rng.normal(size=(6, 2, 1)), np.array([0, 1, 2, 5, 6, 9]), rng.normal(
    ...     size=(3, 2, 2))
    >>> brute = sum(rows[i].T @ (C[k[i] - k[j]] if k[i] >= k[j] else C[k[j] - k[i]].T)
    ...             @ rows[j] for i in range(6) for j in range(6) if abs(k[i] - k[j]) <= 2)
    >>> bool(np.allclose(lagged_middle(rows, k, C), brute))
    True
    """
    rows = np.asarray(rows, dtype=float)
    k = np.asarray(k, dtype=np.int64)
    out = np.einsum("nmd,nme->de", rows, lagged[0] @ rows)
    for lag in range(1, lagged.shape[0]):
        j = np.searchsorted(k, k - lag)
        i = np.flatnonzero((j < k.size) & (k[np.minimum(j, k.size - 1)] == k - lag))
        if i.size:
            cross = np.einsum("nmd,nme->de", rows[i], lagged[lag] @ rows[j[i]])
            out += cross + cross.T
    return out


def instant_covariance(bank: ResidualBank, measurement_std: np.ndarray) -> np.ndarray:
    """(m, m) covariance of the normalised residuals at one sample under white measurement
    noise (the same coefficients, lag by lag)."""
    coef, var = _noise_coefficients(bank, measurement_std)
    flat = (coef / bank.sigma[:, None, None]).reshape(bank.m, -1)
    return (flat * np.tile(var, bank.S + 1)[None, :]) @ flat.T

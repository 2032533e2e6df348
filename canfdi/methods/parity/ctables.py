"""The parity diagnoser's tables for the C drive loop (`canfdi codegen`; canfdi/_c/drive.h's
cfdi_diag_tables): what a diagnosis, its events' variances (canfdi/_c/lagged.h) and the
accepted faults' tracking (canfdi/_c/track.h) read, each computed by the function the Python
diagnoser runs with, so the two compute the same thing.
"""

from __future__ import annotations

import numpy as np

from canfdi.core.identify import chi2_sigma
from canfdi.core.records import OWN_FAULT_SIGMA
from canfdi.core.residuals import ResidualBank
from canfdi.methods.parity.hypotheses import (
    COLUMN_SOURCES,
    Hypothesis,
    noise_units,
    steady_response,
)
from canfdi.methods.parity.tracking import FIRST_CHECK, steady_ratio

__all__ = ["lagged_columns", "lagged_steady", "own_fault_chi2", "tracking_tables"]


def lagged_columns(columns: np.ndarray, n_params: np.ndarray) -> dict[str, np.ndarray]:
    """The regressor columns the hypotheses use, and the pairs of them their fits' middles
    read (lagged.h's cfdi_lagged_tables).

    Parameters
    ----------
    columns : (H, d, 2) each hypothesis' columns (hypotheses.regressor_columns).
    n_params : (H,) each one's parameters.

    Returns
    -------
    {"cols": (NC, 2) each distinct column's source and channel, in order of first use;
     "hyp_cols": (H, d) each parameter's column, -1 beyond; "pairs": (NP, 2) the distinct
     pairs (a <= b); "hyp_pairs": (H, d, d) each parameter pair's, -1 beyond} (int32).

    >>> cols = np.array([[[2, 0], [3, 0]], [[1, 1], [0, 0]], [[3, 0], [0, 0]]])
    >>> t = lagged_columns(cols, np.array([2, 1, 1]))
    >>> t["cols"].tolist(), t["hyp_cols"].tolist(), t["pairs"].tolist()
    ([[2, 0], [3, 0], [1, 1]], [[0, 1], [2, -1], [1, -1]], [[0, 0], [0, 1], [1, 1], [2, 2]])
    """
    H, d, _ = columns.shape
    cols: list[tuple[int, int]] = []
    hyp_cols = np.full((H, d), -1, dtype=np.int32)
    for h in range(H):
        for a in range(int(n_params[h])):
            key = (int(columns[h, a, 0]), int(columns[h, a, 1]))
            if key[0] == COLUMN_SOURCES["none"]:
                raise ValueError(f"hypothesis {h}: parameter {a} has no column")
            if key not in cols:
                cols.append(key)
            hyp_cols[h, a] = cols.index(key)
    pairs: list[tuple[int, int]] = []
    hyp_pairs = np.full((H, d, d), -1, dtype=np.int32)
    for h in range(H):
        n = int(n_params[h])
        for a in range(n):
            for b in range(n):
                key = tuple(sorted((int(hyp_cols[h, a]), int(hyp_cols[h, b]))))
                if key not in pairs:
                    pairs.append(key)
                hyp_pairs[h, a, b] = pairs.index(key)
    order = sorted(range(len(pairs)), key=lambda i: pairs[i])
    rank = np.empty(len(pairs), dtype=np.int32)
    rank[order] = np.arange(len(pairs), dtype=np.int32)
    hyp_pairs = np.where(hyp_pairs >= 0, rank[np.maximum(hyp_pairs, 0)], -1).astype(np.int32)
    return {"cols": np.array(cols, dtype=np.int32).reshape(-1, 2), "hyp_cols": hyp_cols,
            "pairs": np.array([pairs[i] for i in order], dtype=np.int32).reshape(-1, 2),
            "hyp_pairs": hyp_pairs}


def lagged_steady(bank: ResidualBank, cols: np.ndarray, noise: np.ndarray) -> np.ndarray:
    """(S+1, q, NC) what each column's steady regressor adds, residual by residual through the
    noise factors (thresholds.noise_factors, (S+1, q, m)), to the measurement times of a sample
    whose residuals are all there (lagged.h's psi): N[l]^T times the column, a sensor's bias or
    an actuator's lambda over the whole window (hypotheses.steady_response); 0 for a scale's
    column, which moves with the commands."""
    out = np.zeros((noise.shape[0], noise.shape[1], len(cols)))
    for c, (source, channel) in enumerate(np.asarray(cols).tolist()):
        if source == COLUMN_SOURCES["scale"]:
            continue
        target = "sensor" if source == COLUMN_SOURCES["sensor"] else "actuator"
        column = steady_response(bank, target, int(channel))
        out[:, :, c] = np.einsum("lca,a->lc", noise, column)
    return out


def tracking_tables(bank: ResidualBank, gamma: np.ndarray, hypotheses: list[Hypothesis],
                    precise: float, projection: np.ndarray | None = None) -> dict:
    """What the C loop's tracker of accepted faults reads (track.h's cfdi_track_tables):
    each channel's steady ratio (tracking.steady_ratio) and noise unit (hypotheses.noise_units:
    an actuator's lambda's, a sensor's bias'), inputs then outputs; the most parameters it
    tracks at once (two an actuator, one a sensor, over the channels a hypothesis names), the
    chi-square quantiles up to them, when tracking ends (``precise``) and its first
    checkpoint."""
    p, q = bank.p, bank.q
    ratio = np.ones(p + q)
    unit = np.full(p + q, np.inf)
    for j in range(p):
        ratio[j] = steady_ratio(bank, gamma, "actuator", j)
        unit[j] = noise_units(bank, Hypothesis("actuator_bias", j, ""), None, projection)[0]
    for j in range(q):
        ratio[p + j] = steady_ratio(bank, gamma, "sensor", j)
        unit[p + j] = noise_units(bank, Hypothesis("sensor", j, ""), None, projection)[0]
    actuators = {h.index for h in hypotheses if h.target in ("actuator", "actuator_bias")}
    sensors = {h.index for h in hypotheses if h.target == "sensor"}
    sensors |= {j for h in hypotheses if h.target == "sensors" for j in h.members}
    T = 2 * len(actuators) + len(sensors)
    return {"ratio": ratio, "unit": unit, "max_params": T,
            "chi2": np.array([0.0] + [chi2_sigma(n) for n in range(1, T + 1)]),
            "precise": float(precise), "first_check": FIRST_CHECK,
            "channels": len(actuators) + len(sensors)}


def own_fault_chi2() -> np.ndarray:
    """(3,) chi2_sigma(d, OWN_FAULT_SIGMA) for d = 0, 1, 2: when a diagnosis on a compensated
    channel is a fault of its own (records._own_fault)."""
    return np.array([0.0, chi2_sigma(1, OWN_FAULT_SIGMA), chi2_sigma(2, OWN_FAULT_SIGMA)])

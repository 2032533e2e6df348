"""One CUSUM per fault signature: the residuals combined as each fault moves them.

Page-Hinkley on each residual alone detects a fault with the information of its most sensitive
residual. A constant fault f moves all the normalised residuals at once, by f mu (mu: their
steady response to a unit fault, the bank's signatures summed over the window), and the
log-likelihood ratio of that change is a CUSUM on one projection of the residuals (Willsky and
Jones' GLR, Basseville and Nikiforov Section 7.2, with the direction known and the size not):

    s_k = w^T r_k,   w proportional to (Omega + a Sigma_0)^+ mu,   var(s_k) = 1,

Omega the residuals' long-run covariance (what a steady change is judged against over many
samples), Sigma_0 their covariance at one sample (what it is judged against over few), a = 0.1
keeping w finite where Omega is singular (parity residuals share their sensors' noise: Omega has
the rank of the sensors). The size is unknown, so each projection runs under a ladder of drifts,
each the optimum for a change of twice it (within 21 % of the optimum delay between rungs a
factor 2 apart). Faults whose signatures are proportional share one projection.

Each column's threshold is calibrated like the residuals' (canfdi.methods.parity.thresholds),
for ``len(drifts)`` times the false-alarm interval: one signature's ladder alarms about as
rarely as one residual.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from canfdi.core.residuals import ResidualBank
from canfdi.methods.parity.hypotheses import proportional, steady_response
from canfdi.methods.parity.thresholds import instant_covariance, long_run_covariance

__all__ = ["DRIFTS", "SignatureColumns", "signature_columns"]

DRIFTS = (0.25, 0.5, 1.0, 2.0)
"""The drift ladder (noise stds of the projection): changes of 0.5 to 4 per sample. Larger
ones Page-Hinkley on the residuals catches within a sample or two; a rung at 4 acts as a
threshold near 6 noise stds on one sample, and a single outlier of the real plant (5.3 stds
on a:V in run 66 of the DC motor evaluation) set it off."""

_REGULARISE = 0.1


@dataclass(frozen=True)
class SignatureColumns:
    """The projections the detector runs beside the residuals.

    projection : (m, c) column c = the weights of its signature; drifts : (c,); names : (c,)
    "cusum:<channels>"; residuals : per column, the residuals its signature moves (what a
    detection by it names); rungs : drifts per signature (the false-alarm budget's factor).

    Examples
    --------
    >>> from canfdi.core.design import design_bank
    >>> from canfdi.core.model import StateSpace
    >>> from canfdi.core.residuals import ResidualBank
    >>> model = StateSpace(A=[[0.9]], B=[[1.0]], C=[[1.0], [1.0]], dt=0.01)
    >>> bank = ResidualBank(design_bank(model, ["u"], ["y0", "y1"]))
    >>> cols = signature_columns(bank, np.array([0.01, 0.01]), ["u"], ["y0", "y1"], drifts=(0.5,))
    >>> cols.count, cols.names, cols.projection.shape
    (3, ('cusum:u', 'cusum:y0', 'cusum:y1'), (3, 3))
    """

    projection: np.ndarray
    drifts: np.ndarray
    names: tuple[str, ...]
    residuals: tuple[tuple[int, ...], ...]
    rungs: int

    @property
    def count(self) -> int:
        return int(self.projection.shape[1])


def signature_columns(bank: ResidualBank, measurement_std: np.ndarray,
                      input_names: list[str], output_names: list[str],
                      drifts: tuple[float, ...] = DRIFTS) -> SignatureColumns | None:
    """The signature CUSUMs' columns (module docstring); None without drifts or signature.

    One signature per actuator (its bias: lambda) and per sensor some residual responds to;
    proportional ones merge (their channels joined by "/").
    """
    if not drifts:
        return None
    omega = long_run_covariance(bank, measurement_std)
    sigma0 = instant_covariance(bank, measurement_std)
    weight = np.linalg.pinv(omega + _REGULARISE * sigma0, rcond=1e-10, hermitian=True)
    found: list[tuple[np.ndarray, list[str]]] = []
    for target, names in (("actuator", input_names), ("sensor", output_names)):
        for j, name in enumerate(names):
            mu = steady_response(bank, target, j)
            if not np.any(mu):
                continue
            for seen, labels in found:
                if proportional(seen, mu):
                    labels.append(name)
                    break
            else:
                found.append((mu, [name]))
    if not found:
        return None
    cols, labels, moved = [], [], []
    for mu, names in found:
        w = weight @ mu
        var = float(w @ sigma0 @ w)
        if not var > 0.0:
            continue
        w = w / np.sqrt(var)
        w = w if w @ mu >= 0 else -w  # a positive fault moves s up: a rule, not rounding
        # Another BLAS's pseudo-inverse differs in the last bits, which a threshold's
        # calibration on a record could turn into a different threshold: weights on a grid.
        w = np.round(w, 12)
        cols.append(w)
        labels.append("cusum:" + "/".join(names))
        moved.append(tuple(int(i) for i in np.flatnonzero(mu)))
    if not cols:
        return None
    rungs = len(drifts)
    projection = np.repeat(np.stack(cols, axis=1), rungs, axis=1)
    return SignatureColumns(projection=projection,
                            drifts=np.tile(np.asarray(drifts, dtype=float), len(cols)),
                            names=tuple(n for n in labels for _ in range(rungs)),
                            residuals=tuple(r for r in moved for _ in range(rungs)), rungs=rungs)

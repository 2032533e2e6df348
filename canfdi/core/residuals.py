"""Parity residuals of a designed bank as one FIR filter over the last S+1 samples.

Every residual of the bank is r_i(k) = v_i^T (Z(k) - Hc Uc(k)) over its own window s_i. With
x(k) = [z(k); u(k)] (q + p values) and S = max_i s_i, all residuals of a sample are one product

    r(k) = M w(k),   w(k) = [x(k-S); ...; x(k)]  ((S+1)(q+p),)

where row i of M holds v_i on the z entries and -v_i^T Hc on the u entries of the last s_i+1
samples (zeros on older ones). The streaming path keeps a ring of S+1 samples; the batch path
applies the same M to a whole record as S+1 shifted products (equal to round-off; tested).

Missing data. A value lost on the bus (a dropped frame: NaN in x) or a whole missing sample
(`ResidualBank.skip`) makes missing exactly the residuals that use it, i.e. whose row of M is
nonzero at that entry; the others are still exact. Each residual needs only its own s_i + 1
samples, so after a restart the short-window residuals resume first. Missing residuals are NaN.

Fault signatures for the diagnoser: a sensor bias b on z_j from sample k_f adds
b * sum_l Gz_j[:, l] [k-S+l >= k_f]; an actuator fault u_j = eta u_cj + lambda from k_f adds
sum_l Gu_j[:, l] ((eta - 1) u_cj(k-S+l) + lambda) [k-S+l >= k_f], with Gz_j = M's z_j columns and
Gu_j = -(M's u_j columns) = v^T Hc on actuator j.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from canfdi.core.design import Design
from canfdi.core.parity import parity_matrices

__all__ = ["ResidualBank", "fir_rows"]


class ResidualBank:
    """The residuals of a Design, streaming and batch.

    Attributes
    ----------
    names : (m,) residual names ("a:V", "s:i_f", ...).
    sigma : (m,) noise standard deviation of each residual (from the design's noise model).
    S : longest window order; a residual needs S+1 consecutive samples.
    M : (m, (S+1)(q+p)) the FIR matrix.
    Gz : (q, m, S+1) sensor signatures; Gu : (p, m, S+1) actuator signatures.

    Examples
    --------
    >>> from canfdi.core.design import design_bank
    >>> from canfdi.core.model import StateSpace
    >>> model = StateSpace(A=[[0.9]], B=[[1.0]], C=[[1.0], [1.0]], dt=0.01)
    >>> bank = ResidualBank(design_bank(model, ["u"], ["y0", "y1"]))
    >>> bank.names, bank.S
    (['a:u', 's:y0', 's:y1'], 1)
    >>> bank.update(np.array([1.0, 1.0]), np.array([0.0])) is None  # the window is filling
    True
    >>> r = bank.update(np.array([0.9, 1.4]), np.array([0.0]))  # y1 reads 0.5 too high
    >>> np.round(np.abs(r) / np.abs(r).max(), 3)  # s:y1, the residual blind to y1, stays 0
    array([0.707, 1.   , 0.   ])
    """

    def __init__(self, design: Design) -> None:
        model = design.model
        q, p = model.q, model.p
        rows, names, sigma, windows = [], [], [], []
        for res in design.actuators + design.sensors:
            if res.vector.exists:
                rows.append(res.vector)
                names.append(res.name)
                sigma.append(res.noise_std)
                windows.append(res.vector.s)
        if not rows:
            raise ValueError("the design has no residual: nothing can be monitored")
        self.q, self.p = q, p
        self.S = max(windows)
        self.names = names
        self.sigma = np.array(sigma)
        self.kinds = [pv.kind for pv in rows]
        self.indices = [pv.index for pv in rows]
        m, S, width = len(rows), self.S, q + p
        coef = np.zeros((m, S + 1, width))
        for i, pv in enumerate(rows):
            s = pv.s
            Hc = parity_matrices(model, s).Hc
            vz = pv.vector.reshape(s + 1, q)
            vu = -(pv.vector @ Hc).reshape(s + 1, p)
            coef[i, S - s :, :q] = vz
            coef[i, S - s :, q:] = vu
        # Entries at round-off (1e-17 where the design decoupled a channel) are zero: then a
        # residual never reads a channel it was decoupled from, lost or not.
        scale = np.abs(coef).reshape(m, -1).max(axis=1)
        coef[np.abs(coef) <= 1e-12 * scale[:, None, None]] = 0.0
        self.M = coef.reshape(m, (S + 1) * width)
        self.blocks = np.ascontiguousarray(coef.transpose(1, 2, 0))  # (S+1, q+p, m)
        # Which entries each residual reads: a missing one there makes the residual missing.
        uses = (coef != 0).astype(float)
        self._uses = uses.reshape(m, (S + 1) * width)
        self.uses = np.ascontiguousarray(uses.transpose(1, 2, 0))  # (S+1, q+p, m), 0 or 1
        # The block form's kernel (canfdi.core.kernel): the numpy reference unless set.
        self.fir_rows: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray] = fir_rows
        self.Gz = np.ascontiguousarray(coef[:, :, :q].transpose(2, 0, 1))
        self.Gu = np.ascontiguousarray(-coef[:, :, q:].transpose(2, 0, 1))
        self._ring = np.full((S + 1, width), np.nan)

    @property
    def m(self) -> int:
        return len(self.names)

    def restart(self) -> None:
        """Forget the window (after a long gap): each residual resumes after s_i+1 samples."""
        self._ring[:] = np.nan

    def skip(self, count: int) -> None:
        """``count`` samples are missing entirely: push them as missing values."""
        if count > self.S:
            self.restart()
        elif count > 0:
            self._ring[:-count] = self._ring[count:].copy()
            self._ring[-count:] = np.nan

    @property
    def window(self) -> np.ndarray:
        """(S+1, q+p) the current window, oldest first; NaN where a value is missing."""
        return self._ring

    @property
    def tail(self) -> np.ndarray:
        """(S, q+p) the window's last S samples: prepended to a record, its first sample's
        residuals are the ones `update` would give."""
        return self._ring[1:]

    def load(self, x: np.ndarray) -> None:
        """Replace the window by the last S+1 rows of x ((n, q+p), compensated samples);
        fewer rows leave the older positions missing."""
        n = min(len(x), self.S + 1)
        self._ring[:] = np.nan
        if n:
            self._ring[self.S + 1 - n :] = x[len(x) - n :]

    def update(self, z: np.ndarray, u: np.ndarray) -> np.ndarray | None:
        """Push one sample ((q,), (p,); NaN = missing); (m,) residuals, NaN where missing, or
        None when every residual is missing."""
        ring = self._ring
        ring[:-1] = ring[1:]
        ring[-1, : self.q] = z
        ring[-1, self.q :] = u
        w = ring.reshape(-1)
        missing = np.isnan(w)
        if not missing.any():
            return self.M @ w
        r = self.M @ np.where(missing, 0.0, w)
        r[self._uses @ missing > 0] = np.nan
        return None if np.isnan(r).all() else r

    def batch(self, x: np.ndarray) -> np.ndarray:
        """Residuals of every full window of a record.

        Parameters
        ----------
        x : (N, q+p) consecutive samples [z, u]; NaN marks a missing value.

        Returns
        -------
        (N - S, m): row j is r at sample j + S; NaN where a residual reads a missing value.
        """
        if len(x) <= self.S:
            return np.zeros((0, self.m))
        return self.fir_rows(x, self.blocks, self.uses)


def fir_rows(x: np.ndarray, blocks: np.ndarray, uses: np.ndarray) -> np.ndarray:
    """(N - S, m) the residuals of every full window of x (N, q+p), NaN missing: row j is
    sum_l x(j + l) blocks[l], NaN where a residual reads a missing value (uses (S+1, q+p, m),
    1 where it reads an entry). The numpy reference of the kernels' block form
    (canfdi.core.kernel); N > S."""
    missing = np.isnan(x)
    if missing.any():
        out = _fir(np.where(missing, 0.0, x), blocks)
        out[_fir(missing.astype(float), uses) > 0] = np.nan
        return out
    return _fir(x, blocks)


def _fir(x: np.ndarray, blocks: np.ndarray) -> np.ndarray:
    # M w(k) split by window position: sum over l of x(k - S + l) M_l^T, S+1 thin products
    # over the whole record instead of copying every window into a ((S+1)(q+p))-wide row.
    S = len(blocks) - 1
    n = len(x) - S
    out = x[:n] @ blocks[0]
    for lag in range(1, S + 1):
        out += x[lag: lag + n] @ blocks[lag]
    return out

"""Parity residuals of a designed bank as one FIR filter over the last S+1 samples.

Every residual of the bank is r_i(k) = v_i^T (Z(k) - Hc Uc(k)) over its own window s_i. With
x(k) = [z(k); u(k)] (q + p values) and S = max_i s_i, all residuals of a sample are one product

    r(k) = M w(k),   w(k) = [x(k-S); ...; x(k)]  ((S+1)(q+p),)

where row i of M holds v_i on the z entries and -v_i^T Hc on the u entries of the last s_i+1
samples (zeros on older ones). The streaming path keeps a ring of S+1 samples; the batch path
applies the same M to a whole record as S+1 shifted products (equal to round-off; tested).

Fault signatures for the diagnoser: a sensor bias b on z_j from sample k_f adds
b * sum_l Gz_j[:, l] [k-S+l >= k_f]; an actuator fault u_j = eta u_cj + lambda from k_f adds
sum_l Gu_j[:, l] ((eta - 1) u_cj(k-S+l) + lambda) [k-S+l >= k_f], with Gz_j = M's z_j columns and
Gu_j = -(M's u_j columns) = v^T Hc on actuator j.
"""

from __future__ import annotations

import numpy as np

from canfdi.core.design import Design
from canfdi.core.parity import parity_matrices

__all__ = ["ResidualBank"]


class ResidualBank:
    """The residuals of a Design, streaming and batch.

    Attributes
    ----------
    names : (m,) residual names ("a:V", "s:i_f", ...).
    sigma : (m,) noise standard deviation of each residual (from the design's noise model).
    S : longest window order; a residual needs S+1 consecutive samples.
    M : (m, (S+1)(q+p)) the FIR matrix.
    Gz : (q, m, S+1) sensor signatures; Gu : (p, m, S+1) actuator signatures.
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
        self.M = coef.reshape(m, (S + 1) * width)
        self._blocks_T = np.ascontiguousarray(coef.transpose(1, 2, 0))  # (S+1, q+p, m)
        self.Gz = np.ascontiguousarray(coef[:, :, :q].transpose(2, 0, 1))
        self.Gu = np.ascontiguousarray(-coef[:, :, q:].transpose(2, 0, 1))
        self._ring = np.zeros((S + 1, width))
        self._fill = 0

    @property
    def m(self) -> int:
        return len(self.names)

    def restart(self) -> None:
        """Forget the window (after a gap): residuals resume after S+1 new samples."""
        self._fill = 0

    @property
    def window(self) -> np.ndarray | None:
        """(S+1, q+p) the current window, oldest first, or None while it is filling."""
        return self._ring if self._fill > self.S else None

    def load(self, x: np.ndarray) -> None:
        """Replace the window by the last S+1 rows of x ((n, q+p), compensated samples)."""
        n = min(len(x), self.S + 1)
        self._ring[self.S + 1 - n :] = x[len(x) - n :]
        self._fill = n

    def update(self, z: np.ndarray, u: np.ndarray) -> np.ndarray | None:
        """Push one sample; (m,) residuals, or None while the window fills."""
        ring = self._ring
        ring[:-1] = ring[1:]
        ring[-1, : self.q] = z
        ring[-1, self.q :] = u
        self._fill += 1
        if self._fill <= self.S:
            return None
        return self.M @ ring.reshape(-1)

    def batch(self, x: np.ndarray) -> np.ndarray:
        """Residuals of every full window of a record.

        Parameters
        ----------
        x : (N, q+p) consecutive samples [z, u].

        Returns
        -------
        (N - S, m): row j is r at sample j + S.
        """
        if len(x) <= self.S:
            return np.zeros((0, self.m))
        # M w(k) split by window position: sum over l of x(k - S + l) M_l^T, S+1 thin products
        # over the whole record instead of copying every window into a ((S+1)(q+p))-wide row.
        n = len(x) - self.S
        blocks = self._blocks_T
        out = x[: n] @ blocks[0]
        for lag in range(1, self.S + 1):
            out += x[lag : lag + n] @ blocks[lag]
        return out

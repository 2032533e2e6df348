"""A fourth diagnosis method, for tests only: what adding a method takes (one package, one
registry line), and a method the conformance suite runs on that no one tuned for it.

``tiny``: the parity residual bank of the config (canfdi.core.residuals), a plain threshold on
each normalised residual, and on an alarm a sensor bias fitted to the next ``samples`` residual
rows by the one least squares (each sensor's signature, the best cost wins). The accepted bias
is compensated from the alarm on and the window restarts.

Config section::

    tiny: {threshold: 8.0, samples: 30}
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from canfdi.core.blockrun import run_block
from canfdi.core.design import design_bank
from canfdi.core.identify import least_squares
from canfdi.core.protocol import DIAGNOSE, MONITOR
from canfdi.core.records import BlockResult, Compensation, FaultEvent, Sample, compensate
from canfdi.core.residuals import ResidualBank
from canfdi.core.settings import MonitorConfig, Option, parse_options
from canfdi.methods import Method


@dataclass(frozen=True)
class TinyOptions:
    threshold: float = 8.0
    samples: int = 30


@dataclass(frozen=True)
class _Diagnosis:
    k_d: int
    t_d: int
    rows: list[np.ndarray] = field(default_factory=list)


class TinyDiagnoser:
    """Threshold on parity residuals, sensor-bias fit, compensation (streaming only)."""

    def __init__(self, bank: ResidualBank, options: TinyOptions, output_names: list[str]) -> None:
        self.bank = bank
        self.options = options
        self.output_names = list(output_names)
        self._h = np.full(bank.m, options.threshold)
        self.reset()

    def reset(self) -> None:
        self._scale = np.ones(self.bank.m)
        self.mode = MONITOR
        self.events: list[FaultEvent] = []
        self.compensation: list[Compensation] = []
        self.last_residuals: np.ndarray | None = None
        self.last_normalized: np.ndarray | None = None
        self._stat = np.zeros(self.bank.m)
        self._diag: _Diagnosis | None = None
        self._last_k: int | None = None
        self.bank.restart()

    @property
    def residual_names(self) -> list[str]:
        return list(self.bank.names)

    @property
    def thresholds(self) -> np.ndarray:
        return self._h

    @thresholds.setter
    def thresholds(self, value: np.ndarray) -> None:
        self._h = np.asarray(value, dtype=float).reshape(self.bank.m)

    @property
    def statistics(self) -> np.ndarray:
        return self._stat.copy()

    @property
    def noise_scale(self) -> np.ndarray:
        return self._scale.copy()

    @noise_scale.setter
    def noise_scale(self, value: np.ndarray) -> None:
        self._scale = np.broadcast_to(np.asarray(value, dtype=float), (self.bank.m,)).copy()

    def update(self, sample: Sample) -> list[FaultEvent]:
        k = int(sample.k)
        if self._last_k is not None and k != self._last_k + 1:
            self.bank.restart()
        self._last_k = k
        Z, U = compensate(self.compensation, np.array([k]), np.asarray(sample.z)[None, :],
                          np.asarray(sample.u)[None, :])
        r = self.bank.update(Z[0], U[0])
        if r is None:
            self.last_residuals = self.last_normalized = None
            return []
        rn = r / (self.bank.sigma * self._scale)
        self.last_residuals, self.last_normalized = r, rn
        seen = ~np.isnan(rn)
        self._stat[seen] = np.abs(rn[seen])
        if self.mode == MONITOR:
            alarm = np.flatnonzero(self._stat >= self._h)
            if not len(alarm):
                return []
            self.mode = DIAGNOSE
            self._diag = _Diagnosis(k, sample.timestamp_ns, [rn])
            event = FaultEvent(kind="detected", sample=k, timestamp_ns=sample.timestamp_ns,
                               detected_sample=k, onset_sample=k,
                               residuals=tuple(self.bank.names[i] for i in alarm))
            self.events.append(event)
            return [event]
        self._diag.rows.append(rn)
        if len(self._diag.rows) < self.options.samples:
            return []
        return self._decide(k, sample.timestamp_ns)

    def _decide(self, k: int, t: int) -> list[FaultEvent]:
        d = self._diag
        R = np.array(d.rows)  # (N, m), NaN where missing
        fits = []
        for j in range(self.bank.q):
            # Residual rows respond to a bias on sensor j with its signature's sum over the
            # window (the bias is on every sample of the window since the alarm).
            x = self.bank.Gz[j].sum(axis=1) / (self.bank.sigma * self._scale)
            X = np.broadcast_to(x, R.shape).reshape(-1, 1)
            fits.append(least_squares(X, R.reshape(-1)) if x.any() else None)
        costs = [np.inf if f is None else f.cost for f in fits]
        best = int(np.argmin(costs))
        self.mode = MONITOR
        self._stat[:] = 0.0
        self.bank.restart()
        if not np.isfinite(costs[best]):
            event = FaultEvent(kind="unexplained", sample=k, timestamp_ns=t,
                               detected_sample=d.k_d)
        else:
            fit = fits[best]
            bias = float(fit.theta[0])
            variance = float(fit.cost / fit.dof * fit.covariance[0, 0])
            self.compensation.append(Compensation("sensor", best, d.k_d, bias=bias))
            event = FaultEvent(kind="accepted", sample=k, timestamp_ns=t, target="sensor",
                               index=best, name=self.output_names[best],
                               estimates={"bias": bias}, variances={"bias": variance},
                               onset_sample=d.k_d, detected_sample=d.k_d, accepted_sample=k)
        self._diag = None
        self.events.append(event)
        return [event]

    def update_block(self, k: np.ndarray, t_ns: np.ndarray, U: np.ndarray, Z: np.ndarray,
                     gap: np.ndarray | None = None) -> BlockResult:
        return run_block(self, k, t_ns, U, Z, gap)


_SPEC = {"threshold": Option(float, 1.0, 100.0), "samples": Option(int, 2, 10_000)}


def parse_tiny(section: Mapping[str, Any] | None, config: MonitorConfig) -> TinyOptions:
    return TinyOptions(**parse_options(section, _SPEC, "tiny"))


def build(config: MonitorConfig) -> TinyDiagnoser:
    design = design_bank(config.model, config.inputs, config.outputs, config.design)
    return TinyDiagnoser(ResidualBank(design), config.method_options, config.outputs)


METHOD = Method(name="tiny", summary="test-only: threshold on parity residuals, sensor biases",
                section="tiny", parse_options=parse_tiny, build=build,
                fault_kinds=("sensor_bias",), statistic=("|r|/σ", "|r|/σ"))

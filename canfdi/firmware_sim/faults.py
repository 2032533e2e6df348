"""Actuator and sensor faults (Chan et al. 2006 eqs. 23-24 and 34) injected on a schedule.

Actuator i (eq. 24):   u_i = eta u_ci + lambda          kind "scale_bias" (scale, bias or both)
                       u_i = value                      kind "stuck" (value held at onset if absent)
Sensor j (eq. 34 and the usual catalogue):
                       z_j = y_j + bias                 kind "bias"
                       z_j = y_j + rate (t - onset)     kind "drift" (a ramp)
                       z_j = value                      kind "stuck" (held at onset if absent)
                       z_j = scale y_j                  kind "scale"
                       z_j = y_j + N(0, std^2)          kind "noise" (extra noise)

Each fault is active on onset <= t < end (end absent: never repaired). Several faults, on the
same or on different channels, compose in the order they are listed.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

__all__ = ["ACTUATOR_KINDS", "SENSOR_KINDS", "Fault", "FaultInjector", "onset_sample"]

ACTUATOR_KINDS = ("scale_bias", "stuck")
SENSOR_KINDS = ("bias", "drift", "stuck", "scale", "noise")


def onset_sample(t: float, dt: float) -> int:
    """First sample index k with k dt >= t (robust to float round-off)."""
    return max(0, math.ceil(t / dt - 1e-9))


@dataclass(frozen=True)
class Fault:
    """One scheduled fault.

    target : "actuator" or "sensor"; index : 0-based channel; kind : see the module docstring.
    onset, end : seconds (end None: permanent).
    eta, lam : actuator scale and bias; bias, rate, scale, std : sensor parameters;
    value : stuck value (None: the value at onset is held).
    """

    target: str
    index: int
    kind: str
    onset: float
    end: float | None = None
    eta: float = 1.0
    lam: float = 0.0
    bias: float = 0.0
    rate: float = 0.0
    scale: float = 1.0
    std: float = 0.0
    value: float | None = None

    def truth(self, dt: float, names: list[str] | tuple[str, ...]) -> dict:
        """JSON-ready description, with the onset/end sample indices and the channel name."""
        out = {k: v for k, v in asdict(self).items() if v is not None}
        out["lambda"] = out.pop("lam")
        out["name"] = names[self.index]
        out["onset_sample"] = onset_sample(self.onset, dt)
        out["end_sample"] = None if self.end is None else onset_sample(self.end, dt)
        keep = {
            ("actuator", "scale_bias"): ("eta", "lambda"),
            ("actuator", "stuck"): ("value",),
            ("sensor", "bias"): ("bias",),
            ("sensor", "drift"): ("rate",),
            ("sensor", "stuck"): ("value",),
            ("sensor", "scale"): ("scale",),
            ("sensor", "noise"): ("std",),
        }[(self.target, self.kind)]
        for key in ("eta", "lambda", "bias", "rate", "scale", "std", "value"):
            if key not in keep:
                out.pop(key, None)
        return out


class FaultInjector:
    """Applies a fault schedule sample by sample.

    Parameters
    ----------
    faults : the schedule.
    dt : sample period (s).
    rng : generator for the "noise" kind (the scenario's, so runs are reproducible).
    """

    def __init__(self, faults: list[Fault], dt: float, rng: np.random.Generator) -> None:
        self.faults = list(faults)
        self.dt = dt
        self.rng = rng
        self._start = [onset_sample(f.onset, dt) for f in self.faults]
        self._stop = [None if f.end is None else onset_sample(f.end, dt) for f in self.faults]
        self._held: dict[int, float] = {}

    def _active(self, i: int, k: int) -> bool:
        stop = self._stop[i]
        return k >= self._start[i] and (stop is None or k < stop)

    def actuators(self, k: int, u_c: np.ndarray) -> np.ndarray:
        """(p,) applied input at sample k from the (p,) command."""
        u = np.array(u_c, dtype=float)
        for i, f in enumerate(self.faults):
            if f.target != "actuator" or not self._active(i, k):
                continue
            if f.kind == "scale_bias":
                u[f.index] = f.eta * u[f.index] + f.lam
            else:  # stuck
                held = self._held.setdefault(i, u[f.index] if f.value is None else f.value)
                u[f.index] = held
        return u

    def sensors(self, k: int, y: np.ndarray) -> np.ndarray:
        """(q,) measured outputs at sample k from the (q,) true (noisy) outputs."""
        z = np.array(y, dtype=float)
        for i, f in enumerate(self.faults):
            if f.target != "sensor" or not self._active(i, k):
                continue
            j = f.index
            if f.kind == "bias":
                z[j] += f.bias
            elif f.kind == "drift":
                z[j] += f.rate * (k - self._start[i]) * self.dt
            elif f.kind == "stuck":
                z[j] = self._held.setdefault(i, z[j] if f.value is None else f.value)
            elif f.kind == "scale":
                z[j] *= f.scale
            else:  # noise
                z[j] += f.std * self.rng.standard_normal()
        return z

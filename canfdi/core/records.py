"""Records passed between the layers: frozen, numbers only, integer-nanosecond timestamps."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["FaultEvent", "Sample"]


@dataclass(frozen=True)
class Sample:
    """One control period's decoded values.

    k : unwrapped sample index (the drive's alive counter k mod 256, unwrapped).
    timestamp_ns : arrival time of the frame that completed the sample (ns since the epoch).
    u : (p,) commanded inputs u_c(k), in the model's input order.
    z : (q,) measured outputs z(k), in the model's output order.
    gap : samples lost or broken just before this one (0 when the previous sample was k-1);
        the diagnoser restarts its data windows after a gap.
    """

    k: int
    timestamp_ns: int
    u: np.ndarray
    z: np.ndarray
    gap: int = 0


@dataclass(frozen=True)
class FaultEvent:
    """Something the diagnoser concluded at sample ``sample``.

    kind : "detected" (a residual changed), "accepted" (a fault isolated and identified, folded
        into the compensation), or "unexplained" (no hypothesis fitted within max_samples).
    target : "actuator" or "sensor" for accepted faults, None otherwise.
    index, name : 0-based channel and its name (accepted faults).
    estimates : {"eta", "lambda"} for actuators, {"bias"} for sensors.
    variances : the estimates' variances, same keys.
    onset_sample : estimated fault onset k_f; detected_sample : k_d; accepted_sample : k_a.
    candidates : for a fault whose residual signature other channels share, every
        (target, index, name, estimates) that explains the data equally well.
    residuals : names of the residuals in alarm (detected events).
    """

    kind: str
    sample: int
    timestamp_ns: int
    target: str | None = None
    index: int | None = None
    name: str | None = None
    estimates: dict[str, float] = field(default_factory=dict)
    variances: dict[str, float] = field(default_factory=dict)
    onset_sample: int | None = None
    detected_sample: int | None = None
    accepted_sample: int | None = None
    candidates: tuple[dict, ...] = ()
    residuals: tuple[str, ...] = ()

    def as_dict(self) -> dict:
        """JSON-ready form."""
        out = {k: getattr(self, k) for k in self.__dataclass_fields__}
        out["candidates"] = list(self.candidates)
        out["residuals"] = list(self.residuals)
        return out

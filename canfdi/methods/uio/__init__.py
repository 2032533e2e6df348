"""The uio method (Hwang, Chang and Hsu): unknown-input decoupling through (CE)^+, the diagonal
actuator
fault identification filter and the generalized residual generator scheme (GRGS), with
isolation by fault angles.

Its own config section is ``uio:`` (canfdi.methods.uio.config). Faults are additive: actuator
and sensor biases. Detection is a threshold on the weighted residuals, not Page-Hinkley
(docs/methods/uio.md says why).
"""

from __future__ import annotations

from canfdi.methods import Method
from canfdi.methods.uio.config import SCHEMA, build, parse_uio_options
from canfdi.methods.uio.diagnoser import UioDiagnoser, UioSettings

__all__ = ["METHOD", "UioDiagnoser", "UioSettings"]

METHOD = Method(
    name="uio",
    summary="unknown-input decoupling, FIDF and GRGS with fault angles (Hwang, Chang and Hsu)",
    section="uio",
    parse_options=parse_uio_options,
    build=build,
    fault_kinds=("actuator_bias", "sensor_bias"),
    statistic=("|r|/σ", "threshold-test statistic |r|/σ"),
    schema=SCHEMA,
)

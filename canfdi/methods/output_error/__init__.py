"""The output_error method (the output-error paper): output-error residuals of identified
input-output models,
Page-Hinkley detection, isolation by identifying the residual's step response (the gamma and
kappa tests), and the reset of Section 3.3.

Its own config section is ``output_error:`` (canfdi.methods.output_error.config; `canfdi
identify` writes it from a fault-free log). Faults are additive: actuator and sensor biases.
"""

from __future__ import annotations

from canfdi.methods import Method
from canfdi.methods.output_error.config import (
    SCHEMA,
    SECTION,
    OeOptions,
    build,
    output_error_section,
    parse_output_error,
    with_noise,
)
from canfdi.methods.output_error.diagnoser import OeSettings, OutputErrorDiagnoser
from canfdi.methods.output_error.fit import fit_section

__all__ = ["METHOD", "OeOptions", "OeSettings", "OutputErrorDiagnoser", "output_error_section"]

METHOD = Method(
    name="output_error",
    summary="output-error residuals of identified OE models, step-response isolation "
            "(the output-error paper)",
    section=SECTION,
    parse_options=parse_output_error,
    build=build,
    fault_kinds=("actuator_bias", "sensor_bias"),
    with_noise=with_noise,
    fit_models=fit_section,
    schema=SCHEMA,
)

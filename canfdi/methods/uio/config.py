"""The uio method (Hwang, Chang and Hsu): build the UioDiagnoser a monitor config describes.

The config's ``uio:`` section (all optional)::

    uio:
      actuator_pole: -2.0      # 1/s, pole of the FIDF weights Hf(s) = -pole / (s - pole)
      sensor_pole: -2.0        # 1/s, pole of the GRGS weights
      angle_threshold: 5.0     # degrees: a fault direction within it is a match
      min_samples: 30          # samples after the alarm before a decision
      max_samples: 400         # ... before "unexplained"
      settle_rel_std: 0.02     # accept when the estimate's standard error is below this part
      onset_lookback: 50       # samples before the alarm kept for the onset fit

The false-alarm interval comes from the shared ``detection:`` section (drift is unused: the
alarm is a threshold on the weighted residuals, canfdi.methods.uio.diagnoser), the
measurement noise from ``noise:``. The model (continuous with dt, or discrete) is discretised
with a zero-order hold (StateSpace.discretize), the unknown-input direction E being its F.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from canfdi.core.settings import ConfigError, MonitorConfig, Option, options_schema, parse_options
from canfdi.methods.uio.design import design_uio
from canfdi.methods.uio.diagnoser import UioDiagnoser, UioSettings, uio_thresholds

__all__ = ["SCHEMA", "build", "parse_uio_options"]

_SPEC = {
    "actuator_pole": Option(float, -1e6, 0.0, open_lo=True, open_hi=True),
    "sensor_pole": Option(float, -1e6, 0.0, open_lo=True, open_hi=True),
    "angle_threshold": Option(float, 0.0, 90.0, open_lo=True, open_hi=True),
    "min_samples": Option(int, 1, 10**6),
    "max_samples": Option(int, 1, 10**6),
    "settle_rel_std": Option(float, 0.0, 1.0, open_lo=True, open_hi=True),
    "onset_lookback": Option(int, 1, 10**5),
}
SCHEMA = options_schema(_SPEC, defaults=UioSettings)
"""The ``uio:`` section's JSON Schema (the method's ``schema``)."""


def parse_uio_options(options: Mapping[str, Any] | None, config: MonitorConfig | None = None
                      ) -> dict:
    """Validate the ``uio:`` mapping; ConfigError("uio.<field>", ...) on bad input."""
    out = parse_options(options, _SPEC, "uio")
    lo_n = out.get("min_samples", UioSettings.min_samples)
    if out.get("max_samples", UioSettings.max_samples) < lo_n:
        raise ConfigError("uio.max_samples", f"must be >= min_samples ({lo_n})")
    return out


def build(config: MonitorConfig) -> UioDiagnoser:
    """Design, calibrate and build the Hwang, Chang and Hsu diagnoser of a config (method: uio)."""
    opts = config.method_options or {}
    model = config.model.discretize()
    if model.r == 0:
        raise ConfigError("model.F", "the uio method needs the unknown-input direction F (E)")
    if np.any(model.D) or model.r1:
        raise ConfigError("model", "the uio method takes no D nor G (output unknown input)")
    dt = model.dt or 1.0
    meas = (config.design.measurement_std if config.design.measurement_std is not None
            else np.ones(model.q))
    try:
        design = design_uio(model.A, model.B, model.C, model.F, dt,
                            actuator_pole=opts.get("actuator_pole", -2.0),
                            sensor_pole=opts.get("sensor_pole", -2.0),
                            measurement_std=meas, input_names=config.inputs,
                            output_names=config.outputs)
    except ValueError as exc:
        raise ConfigError("model", f"no uio design: {exc}") from None
    det = config.detection
    settings = UioSettings(false_alarm_interval=det.false_alarm_interval,
                           **{k: v for k, v in opts.items() if k not in ("actuator_pole",
                                                                         "sensor_pole")})
    thresholds = uio_thresholds(design.p + design.m, det.false_alarm_interval)
    return UioDiagnoser(design, settings, thresholds, config.inputs, config.outputs)

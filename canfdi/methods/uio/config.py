"""The uio method (seed 004): build the UioDiagnoser a monitor config describes.

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

import numpy as np

from canfdi.config import ConfigError, MonitorConfig
from canfdi.methods.uio.design import design_uio
from canfdi.methods.uio.diagnoser import UioDiagnoser, UioSettings, uio_thresholds

__all__ = ["build_uio_diagnoser", "parse_uio_options"]

# field -> (type, low, high): floats in the open interval, integers in the closed one.
_SPEC = {
    "actuator_pole": (float, -1e6, 0.0),
    "sensor_pole": (float, -1e6, 0.0),
    "angle_threshold": (float, 0.0, 90.0),
    "min_samples": (int, 1, 10**6),
    "max_samples": (int, 1, 10**6),
    "settle_rel_std": (float, 0.0, 1.0),
    "onset_lookback": (int, 1, 10**5),
}


def parse_uio_options(options: object) -> dict:
    """Validate the ``uio:`` mapping; ConfigError("uio.<field>", ...) on bad input."""
    if options is None:
        return {}
    if not isinstance(options, dict):
        raise ConfigError("uio", f"expected a mapping, got {type(options).__name__}")
    out: dict = {}
    for key, value in options.items():
        field = f"uio.{key}"
        if key not in _SPEC:
            raise ConfigError(field, f"unknown key (allowed: {', '.join(sorted(_SPEC))})")
        kind, lo, hi = _SPEC[key]
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ConfigError(field, f"expected a number, got {value!r}")
        if kind is int and not isinstance(value, int):
            raise ConfigError(field, f"expected an integer, got {value!r}")
        inside = lo < value < hi if kind is float else lo <= value <= hi
        if not np.isfinite(value) or not inside:
            shape = "({}, {})" if kind is float else "[{}, {}]"
            raise ConfigError(field, f"must be in {shape.format(lo, hi)}, got {value!r}")
        out[key] = kind(value)
    lo_n = out.get("min_samples", UioSettings.min_samples)
    if out.get("max_samples", UioSettings.max_samples) < lo_n:
        raise ConfigError("uio.max_samples", f"must be >= min_samples ({lo_n})")
    return out


def build_uio_diagnoser(config: MonitorConfig) -> UioDiagnoser:
    """Design, calibrate and build the seed 004 diagnoser of a config (method: uio)."""
    opts = parse_uio_options(config.method_options)
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

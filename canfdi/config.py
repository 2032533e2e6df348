"""Monitor configuration: YAML in, frozen dataclasses out.

Every error names the offending field as a dotted path (``design.sensor_window``) so the CLI can
print one line and exit with status 2. Unknown keys are errors too: a typo must not silently fall
back to a default.

Layout::

    name: dc_motor                 # free text
    description: ...               # optional
    method: parity                 # parity (seed 001) | output_error (seed 003) | uio (seed 004)
    model: {time, dt, A, B, C, D, F, G}          # see canfdi.core.model.StateSpace.from_dict
    signals:
      inputs: [V]                  # p names, the actuators
      outputs: [i_f, i_a, ...]     # q names, the sensors
      unknown_inputs: [phi1, phi2] # optional, r names (w)
      unknown_outputs: []          # optional, r1 names (psi)
    noise:                         # optional, standard deviations
      measurement: 0.01            # scalar or q values
      process: 0.0                 # scalar or n values
    design:                        # optional
      actuator_window: auto        # auto (smallest admissible) or an integer s >= 0
      sensor_window: auto
      max_window: 10
    bus:                           # optional; how `canfdi run` and `capture` reach the drive
      interface: virtual           # any python-can interface (socketcan, pcan, ...)
      channel: canfdi
      bitrate: null                # bit/s, passed to interfaces that take one
      dbc: motor_drive             # a file of dbc/ by name, or a path (needed to run)
      status_period: 1.0           # seconds between FDI_STATUS frames
    detection:                     # optional; Page-Hinkley on each normalised residual
      drift: 0.5                   # delta, in residual noise standard deviations
      false_alarm_interval: 1.0e7  # samples between false alarms per residual (calibration)
    identification:                # optional; the parity method's (canfdi.methods.parity)
      min_samples: 200
      max_samples: 2000
      settle_rel_std: 0.01
      isolation_margin: 50.0
      max_fit_variance: 4.0        # accept only fits leaving about noise (a spike: no)
    output_error: {...}            # the output_error method's own section
    uio: {...}                     # the uio method's own section
    recording:                     # optional; MCAP logs of `canfdi run`
      directory: logs
      rotate_mib: 256
      rotate_minutes: 60

The model's input and output names are the DBC signal names of the drive's commands and
measurements (dbc/README.md); each must be in exactly one message sent by DRIVE.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from canfdi import methods
from canfdi.core.design import DesignOptions
from canfdi.core.model import ModelError, StateSpace
from canfdi.core.settings import (
    BusConfig,
    ConfigError,
    DetectionConfig,
    IdentificationConfig,
    MonitorConfig,
    Option,
    RecordingConfig,
    parse_options,
    section,
)

__all__ = [
    "BusConfig",
    "ConfigError",
    "DetectionConfig",
    "IdentificationConfig",
    "MonitorConfig",
    "RecordingConfig",
    "load_config",
    "parse_config",
    "read_yaml",
]

# The sections every config may have; each method adds its own (canfdi.methods).
_COMMON_KEYS = ("name", "description", "method", "model", "signals", "noise", "design", "bus",
                "detection", "identification", "recording")
_BUS = {"interface": Option(str), "channel": Option(str), "bitrate": Option(int, 1),
        "dbc": Option(str), "status_period": Option(float, 0.01, 3600.0)}
_DETECTION = {"drift": Option(float, 0.0, 100.0),
              "false_alarm_interval": Option(float, 10.0, 1e15)}
_IDENTIFICATION = {"min_samples": Option(int, 1, 10**7), "max_samples": Option(int, 1, 10**7),
                   "settle_rel_std": Option(float, 1e-9, 1.0),
                   "isolation_margin": Option(float, 0.0, 1e12),
                   "max_fit_variance": Option(float, 1.0, 1e12)}
_RECORDING = {"directory": Option(str), "rotate_mib": Option(float, 0.01, 1e7),
              "rotate_minutes": Option(float, 0.01, 1e7)}


def _names(value: Any, field: str, count: int | None) -> list[str]:
    if value is None:
        value = []
    if not isinstance(value, list) or not all(isinstance(v, str) and v for v in value):
        raise ConfigError(field, "expected a list of non-empty names")
    if len(set(value)) != len(value):
        raise ConfigError(field, "names must be unique")
    if count is not None and len(value) != count:
        raise ConfigError(field, f"expected {count} names to match the model, got {len(value)}")
    return list(value)


def _stds(value: Any, field: str, size: int, default: float | None) -> np.ndarray | None:
    if value is None:
        return None if default is None else np.full(size, default)
    arr = np.array(value, dtype=float) if not isinstance(value, bool) else None
    if arr is None or arr.ndim > 1:
        raise ConfigError(field, f"expected a number or a list of {size} numbers")
    arr = np.full(size, float(arr)) if arr.ndim == 0 else arr
    if arr.shape != (size,):
        raise ConfigError(field, f"expected {size} values, got {arr.shape[0]}")
    if not np.all(np.isfinite(arr)) or np.any(arr < 0):
        raise ConfigError(field, "standard deviations must be finite and >= 0")
    return arr


def _window(value: Any, field: str) -> int | None:
    if value is None or value == "auto":
        return None
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise ConfigError(field, f"expected 'auto' or an integer >= 0, got {value!r}")
    return value


def parse_config(data: Any, path: Path | None = None) -> MonitorConfig:
    """Validate a loaded YAML document and build a MonitorConfig (the method's own section
    parsed by its registry entry)."""
    if not isinstance(data, dict):
        raise ConfigError("(top level)", "expected a mapping")
    method = methods.get(data.get("method", methods.DEFAULT))
    own = {m.section for m in map(methods.get, methods.names()) if m.section}
    parse_options(data, {}, "", extra=(*_COMMON_KEYS, *own))
    try:
        model = StateSpace.from_dict(section(data, "model", required=True))
    except ModelError as exc:
        raise ConfigError(exc.field, str(exc).split(": ", 1)[1]) from None

    signals = section(data, "signals", required=True)
    parse_options(signals, {}, "signals",
                  extra=("inputs", "outputs", "unknown_inputs", "unknown_outputs"))
    inputs = _names(signals.get("inputs"), "signals.inputs", model.p)
    outputs = _names(signals.get("outputs"), "signals.outputs", model.q)
    unknown_inputs = _names(signals.get("unknown_inputs"), "signals.unknown_inputs",
                            model.r if "unknown_inputs" in signals else None)
    unknown_outputs = _names(signals.get("unknown_outputs"), "signals.unknown_outputs",
                             model.r1 if "unknown_outputs" in signals else None)

    noise = section(data, "noise")
    parse_options(noise, {}, "noise", extra=("measurement", "process"))
    meas = _stds(noise.get("measurement"), "noise.measurement", model.q, None)
    proc = _stds(noise.get("process"), "noise.process", model.n, None)
    if meas is not None and proc is not None and not np.any(meas) and not np.any(proc):
        raise ConfigError("noise", "all standard deviations are zero: no threshold can be derived")

    design = section(data, "design")
    max_window = parse_options(design, {"max_window": Option(int, 0, 50)}, "design",
                               extra=("actuator_window", "sensor_window")).get("max_window", 10)
    options = DesignOptions(
        actuator_window=_window(design.get("actuator_window"), "design.actuator_window"),
        sensor_window=_window(design.get("sensor_window"), "design.sensor_window"),
        max_window=max_window, measurement_std=meas, process_std=proc,
    )
    bus = BusConfig(**parse_options(data.get("bus"), _BUS, "bus"))
    detection = DetectionConfig(**parse_options(data.get("detection"), _DETECTION, "detection"))
    identification = IdentificationConfig(**parse_options(data.get("identification"),
                                                          _IDENTIFICATION, "identification"))
    if identification.max_samples < identification.min_samples:
        raise ConfigError("identification.max_samples",
                          f"must be >= min_samples ({identification.min_samples})")
    recording = RecordingConfig(**parse_options(data.get("recording"), _RECORDING, "recording"))
    name = data.get("name", path.stem if path else "model")
    if not isinstance(name, str) or not name:
        raise ConfigError("name", "expected a non-empty string")
    description = data.get("description", "")
    if not isinstance(description, str):
        raise ConfigError("description", "expected a string")
    config = MonitorConfig(name=name, description=description, model=model, inputs=inputs,
                           outputs=outputs, unknown_inputs=unknown_inputs,
                           unknown_outputs=unknown_outputs, design=options, bus=bus,
                           detection=detection, identification=identification,
                           recording=recording, path=path, method=method.name)
    raw = data.get(method.section) if method.section else None
    return dataclasses.replace(config, method_options=method.parse_options(raw, config))


def read_yaml(path: Path, error: type[ValueError], field: str) -> Any:
    """A YAML file's document; ``error(field, message)`` for a missing, unreadable or invalid
    file (the position of a YAML error included)."""
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise error(field, f"file not found: {path}") from None
    except OSError as exc:
        raise error(field, f"cannot read {path}: {exc.strerror}") from None
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = getattr(exc, "problem", exc)
        raise error(field, f"invalid YAML{where}: {problem}") from None


def load_config(path: str | Path) -> MonitorConfig:
    """Read and validate a YAML monitor config; raises ConfigError naming the field."""
    path = Path(path)
    return parse_config(read_yaml(path, ConfigError, "config"), path)

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
    identification:                # optional; see canfdi.methods.parity.diagnoser.DiagnoserSettings
      min_samples: 200
      max_samples: 2000
      settle_rel_std: 0.01
      isolation_margin: 50.0
      max_fit_variance: 4.0        # accept only fits leaving about noise (a spike: no)
    output_error: {...}            # the output_error method's section (canfdi.methods.output_error.config)
    uio: {...}                     # the uio method's section (canfdi.methods.uio.config)
    recording:                     # optional; MCAP logs of `canfdi run`
      directory: logs
      rotate_mib: 256
      rotate_minutes: 60

The model's input and output names are the DBC signal names of the drive's commands and
measurements (dbc/README.md); each must be in exactly one message sent by DRIVE.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from canfdi.core.design import DesignOptions
from canfdi.core.model import ModelError, StateSpace

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


class ConfigError(ValueError):
    """A configuration problem; ``field`` is the dotted path of the offending key."""

    def __init__(self, field: str, message: str) -> None:
        super().__init__(f"{field}: {message}")
        self.field = field


# The diagnosis methods (seed 001 parity, seed 003 output error, seed 004 unknown-input
# decoupling); each non-parity method reads its own section, named after it.
METHODS = ("parity", "output_error", "uio")
_TOP_KEYS = {"name", "description", "method", "model", "signals", "noise", "design", "bus",
             "detection", "identification", "recording", "output_error", "uio"}


@dataclass(frozen=True)
class BusConfig:
    """Where the drive's frames are: python-can arguments and the DBC file."""

    interface: str = "virtual"
    channel: str = "canfdi"
    bitrate: int | None = None
    dbc: str | None = None
    status_period: float = 1.0


@dataclass(frozen=True)
class DetectionConfig:
    """Page-Hinkley settings: drift delta (noise stds) and the false-alarm interval (samples)."""

    drift: float = 0.5
    false_alarm_interval: float = 1.0e7


@dataclass(frozen=True)
class IdentificationConfig:
    """When a hypothesis is accepted (see canfdi.methods.parity.diagnoser)."""

    min_samples: int = 200
    max_samples: int = 2000
    settle_rel_std: float = 0.01
    isolation_margin: float = 50.0
    max_fit_variance: float = 4.0


@dataclass(frozen=True)
class RecordingConfig:
    """MCAP logging of `canfdi run`."""

    directory: str = "logs"
    rotate_mib: float = 256.0
    rotate_minutes: float = 60.0


@dataclass(frozen=True)
class MonitorConfig:
    """A parsed monitor configuration."""

    name: str
    description: str
    model: StateSpace
    inputs: list[str]
    outputs: list[str]
    unknown_inputs: list[str]
    unknown_outputs: list[str]
    design: DesignOptions
    bus: BusConfig = BusConfig()
    detection: DetectionConfig = DetectionConfig()
    identification: IdentificationConfig = IdentificationConfig()
    recording: RecordingConfig = RecordingConfig()
    path: Path | None = None
    method: str = "parity"
    method_options: dict = field(default_factory=dict)


def _check_keys(data: dict, allowed: set[str], where: str) -> None:
    for key in data:
        if key not in allowed:
            raise ConfigError(f"{where}.{key}" if where else str(key),
                              f"unknown key (allowed: {', '.join(sorted(allowed))})")


def _section(data: dict, key: str, required: bool = False) -> dict:
    value = data.get(key)
    if value is None:
        if required:
            raise ConfigError(key, "missing section")
        return {}
    if not isinstance(value, dict):
        raise ConfigError(key, f"expected a mapping, got {type(value).__name__}")
    return value


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
    """Validate a loaded YAML document and build a MonitorConfig."""
    if not isinstance(data, dict):
        raise ConfigError("(top level)", "expected a mapping")
    _check_keys(data, _TOP_KEYS, "")
    try:
        model = StateSpace.from_dict(_section(data, "model", required=True))
    except ModelError as exc:
        raise ConfigError(exc.field, str(exc).split(": ", 1)[1]) from None

    signals = _section(data, "signals", required=True)
    _check_keys(signals, {"inputs", "outputs", "unknown_inputs", "unknown_outputs"}, "signals")
    inputs = _names(signals.get("inputs"), "signals.inputs", model.p)
    outputs = _names(signals.get("outputs"), "signals.outputs", model.q)
    unknown_inputs = _names(signals.get("unknown_inputs"), "signals.unknown_inputs",
                            model.r if "unknown_inputs" in signals else None)
    unknown_outputs = _names(signals.get("unknown_outputs"), "signals.unknown_outputs",
                             model.r1 if "unknown_outputs" in signals else None)

    noise = _section(data, "noise")
    _check_keys(noise, {"measurement", "process"}, "noise")
    meas = _stds(noise.get("measurement"), "noise.measurement", model.q, None)
    proc = _stds(noise.get("process"), "noise.process", model.n, None)
    if meas is not None and proc is not None and not np.any(meas) and not np.any(proc):
        raise ConfigError("noise", "all standard deviations are zero: no threshold can be derived")

    design = _section(data, "design")
    _check_keys(design, {"actuator_window", "sensor_window", "max_window"}, "design")
    max_window = design.get("max_window", 10)
    if isinstance(max_window, bool) or not isinstance(max_window, int) or not 0 <= max_window <= 50:
        raise ConfigError("design.max_window",
                          f"expected an integer in [0, 50], got {max_window!r}")
    options = DesignOptions(
        actuator_window=_window(design.get("actuator_window"), "design.actuator_window"),
        sensor_window=_window(design.get("sensor_window"), "design.sensor_window"),
        max_window=max_window, measurement_std=meas, process_std=proc,
    )
    bus = _dataclass_section(data, "bus", BusConfig, {
        "interface": (str, None), "channel": (str, None), "bitrate": (int, (1, None)),
        "dbc": (str, None), "status_period": (float, (0.01, 3600.0)),
    })
    detection = _dataclass_section(data, "detection", DetectionConfig, {
        "drift": (float, (0.0, 100.0)), "false_alarm_interval": (float, (10.0, 1e15)),
    })
    identification = _dataclass_section(data, "identification", IdentificationConfig, {
        "min_samples": (int, (1, 10**7)), "max_samples": (int, (1, 10**7)),
        "settle_rel_std": (float, (1e-9, 1.0)), "isolation_margin": (float, (0.0, 1e12)),
        "max_fit_variance": (float, (1.0, 1e12)),
    })
    if identification.max_samples < identification.min_samples:
        raise ConfigError("identification.max_samples",
                          f"must be >= min_samples ({identification.min_samples})")
    recording = _dataclass_section(data, "recording", RecordingConfig, {
        "directory": (str, None), "rotate_mib": (float, (0.01, 1e7)),
        "rotate_minutes": (float, (0.01, 1e7)),
    })
    name = data.get("name", path.stem if path else "model")
    if not isinstance(name, str) or not name:
        raise ConfigError("name", "expected a non-empty string")
    description = data.get("description", "")
    if not isinstance(description, str):
        raise ConfigError("description", "expected a string")
    method = data.get("method", "parity")
    if method not in METHODS:
        raise ConfigError("method", f"expected one of {', '.join(METHODS)}, got {method!r}")
    # The method's own section stays a mapping here: its module validates it (naming fields
    # "<method>.<key>") when the diagnoser is built.
    method_options = _section(data, method) if method != "parity" else {}
    return MonitorConfig(name=name, description=description, model=model, inputs=inputs,
                         outputs=outputs, unknown_inputs=unknown_inputs,
                         unknown_outputs=unknown_outputs, design=options, bus=bus,
                         detection=detection, identification=identification,
                         recording=recording, path=path, method=method,
                         method_options=method_options)


def _dataclass_section(data: dict, key: str, cls, spec: dict):
    """Parse an optional flat section into ``cls``; spec maps field -> (type, (lo, hi) or None).

    Ranges are inclusive; None as a bound means unbounded. Integers are accepted for floats.
    """
    section = _section(data, key)
    _check_keys(section, set(spec), key)
    values = {}
    for name, (kind, bounds) in spec.items():
        if name not in section or section[name] is None:
            continue
        value = section[name]
        field = f"{key}.{name}"
        if kind is str:
            if not isinstance(value, str) or not value:
                raise ConfigError(field, f"expected a non-empty string, got {value!r}")
        elif kind is int:
            if isinstance(value, bool) or not isinstance(value, int):
                raise ConfigError(field, f"expected an integer, got {value!r}")
        else:
            if isinstance(value, str):
                # PyYAML (YAML 1.1) reads 1.0e7 without a sign in the exponent as a string.
                try:
                    value = float(value)
                except ValueError:
                    raise ConfigError(field, f"expected a number, got {value!r}") from None
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise ConfigError(field, f"expected a number, got {value!r}")
            value = float(value)
        if bounds is not None:
            lo, hi = bounds
            if (lo is not None and value < lo) or (hi is not None and value > hi):
                raise ConfigError(field, f"must be in [{lo}, {hi if hi is not None else 'inf'}]"
                                         f", got {value!r}")
        values[name] = value
    return cls(**values)


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

"""Monitor configuration: YAML in, frozen dataclasses out.

Every error names the offending field as a dotted path (``design.sensor_window``) so the CLI can
print one line and exit with status 2. Unknown keys are errors too: a typo must not silently fall
back to a default.

Layout::

    name: dc_motor                 # free text
    description: ...               # optional
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
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from canfdi.core.design import DesignOptions
from canfdi.core.model import ModelError, StateSpace

__all__ = ["ConfigError", "MonitorConfig", "load_config", "parse_config"]


class ConfigError(ValueError):
    """A configuration problem; ``field`` is the dotted path of the offending key."""

    def __init__(self, field: str, message: str) -> None:
        super().__init__(f"{field}: {message}")
        self.field = field


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
    path: Path | None = None


_TOP_KEYS = {"name", "description", "model", "signals", "noise", "design"}


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
    name = data.get("name", path.stem if path else "model")
    if not isinstance(name, str) or not name:
        raise ConfigError("name", "expected a non-empty string")
    description = data.get("description", "")
    if not isinstance(description, str):
        raise ConfigError("description", "expected a string")
    return MonitorConfig(name=name, description=description, model=model, inputs=inputs,
                         outputs=outputs, unknown_inputs=unknown_inputs,
                         unknown_outputs=unknown_outputs, design=options, path=path)


def load_config(path: str | Path) -> MonitorConfig:
    """Read and validate a YAML monitor config; raises ConfigError naming the field."""
    path = Path(path)
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise ConfigError("config", f"file not found: {path}") from None
    except OSError as exc:
        raise ConfigError("config", f"cannot read {path}: {exc.strerror}") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = getattr(exc, "problem", exc)
        raise ConfigError("config", f"invalid YAML{where}: {problem}") from None
    return parse_config(data, path)

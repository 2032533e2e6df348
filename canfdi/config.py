"""Monitor configuration: YAML in, frozen dataclasses out.

Every error names the offending field as a dotted path (``design.sensor_window``) so the CLI can
print one line and exit with status 2. Unknown keys are errors too: a typo must not silently fall
back to a default.

Layout::

    name: dc_motor                 # free text
    description: ...               # optional
    method: parity                 # parity (Chan et al. 2006) | output_error (the
                                   # output-error paper) | uio (Hwang, Chang and Hsu)
    model: {time, dt, A, B, C, D, F, G}          # see canfdi.core.model.StateSpace.from_dict
      identify:                    # optional: how `canfdi identify` learns A, B, C, F from a
        unknown_inputs: 1          #   healthy log (the matrices may then be left out)
        order: 4                   #   optional: the states (default: from the data)
        delay: 1                   #   optional: samples from a command to its first effect
        template: servo_axis       #   optional: a grey-box template, or {name, roles,
                                   #   parameters, fixed, ...} (canfdi.core.greybox)
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
      signatures: false            # parity: also a CUSUM per fault signature across the
                                   # residuals, at several drifts (faster on small faults; it
                                   # also sees what compensation leaves: docs/methods/parity.md)
    identification:                # optional; the parity method's (canfdi.methods.parity)
      min_samples: 10
      max_samples: 2000
      settle_rel_std: 0.005        # accept once each estimate's std is below this part of it
      settle_noise: 0.2            # or below this many of its noise units (0: relative only)
      isolation_margin: 50.0
      max_fit_variance: 2.25       # accept only fits leaving about noise (a spike or a
                                   # noisier drive: no; the watchdog's factor squared)
      lookback: 256                # with channels compensated, samples before the change
                                   # point a diagnosis fits too (a leftover acts from its
                                   # fault's onset, a new fault from its own)
    output_error: {...}            # the output_error method's own section
    uio: {...}                     # the uio method's own section
    recording:                     # optional; MCAP logs of `canfdi run`
      directory: logs
      rotate_mib: 256
      rotate_minutes: 60
      keep_days: 30                # optional: logs older than this are removed by `canfdi run`
      keep_mib: 10240              # optional: and the oldest while they weigh more than this
      row_encoding: cdr            # optional: samples and residual rows as ROS 2 CDR (default)
                                   # or json (the JSON rows of older logs)
    watchdog:                      # optional; the noise watchdog (canfdi.core.watchdog)
      enabled: true
      factor: 1.5                  # noise std over its calibrated value that is a mismatch
      block: 250                   # samples per block (variance about the block's mean)
      blocks: 2                    # consecutive blocks that must agree (window: 500 samples)

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
from canfdi.bus.clock import CLOCKS
from canfdi.bus.e2e import PROFILES as E2E_PROFILES
from canfdi.bus.nodeid import MAX_EXTENDED_ID, check_template
from canfdi.core.design import DesignOptions
from canfdi.core.model import MAX_DIMENSION, MAX_ENTRY, ModelError, StateSpace
from canfdi.core.settings import (
    NUMBER_AS_TEXT,
    BusConfig,
    ClockConfig,
    ConfigError,
    DetectionConfig,
    DriveConfig,
    E2EConfig,
    IdentificationConfig,
    IdentifySpec,
    MonitorConfig,
    MonitorFramesConfig,
    Option,
    RecordingConfig,
    SignalRef,
    TemplateSpec,
    WatchdogConfig,
    brief,
    options_schema,
    parse_options,
    section,
    unknown_name,
)
from canfdi.io.rowencodings import ROW_ENCODINGS

__all__ = [
    "BusConfig",
    "ConfigError",
    "DetectionConfig",
    "IdentificationConfig",
    "MonitorConfig",
    "NotIdentified",
    "RecordingConfig",
    "WatchdogConfig",
    "config_schema",
    "load_config",
    "parse_config",
    "read_yaml",
]

# The sections every config may have; each method adds its own (canfdi.methods).
_COMMON_KEYS = ("name", "description", "method", "model", "signals", "noise", "design", "bus",
                "detection", "identification", "recording", "watchdog", "drives")
_BUS = {"interface": Option(str), "channel": Option(str), "bitrate": Option(int, 1),
        "dbc": Option(str), "status_period": Option(float, 0.01, 3600.0),
        "transmit": Option(bool), "canopen": Option(bool)}
_BUS_SECTIONS = ("map", "e2e", "clock", "node", "monitor")
_CLOCK = {"kind": Option(str, choices=CLOCKS), "period": Option(float, 1e-6, 3600.0),
          "phase": Option(float, 0.0, 3600.0), "max_age": Option(float, 1e-6, 3600.0)}
_MONITOR = {"dbc": Option(str), "base": Option(int, 0, MAX_EXTENDED_ID)}
MAX_DRIVES = 8  # the Drive signal of the monitor's frames has 3 bits
_DETECTION = {"drift": Option(float, 0.0, 100.0),
              "false_alarm_interval": Option(float, 10.0, 1e15),
              "signatures": Option(bool)}
_IDENTIFICATION = {"min_samples": Option(int, 1, 10**7), "max_samples": Option(int, 1, 10**7),
                   "settle_rel_std": Option(float, 1e-9, 1.0),
                   "settle_noise": Option(float, 0.0, 10.0),
                   "isolation_margin": Option(float, 0.0, 1e12),
                   "max_fit_variance": Option(float, 1.0, 1e12),
                   "lookback": Option(int, 0, 10**7)}
_WATCHDOG = {"enabled": Option(bool), "factor": Option(float, 1.01, 100.0),
             "block": Option(int, 10, 10**6), "blocks": Option(int, 1, 1000)}
_RECORDING = {"directory": Option(str), "rotate_mib": Option(float, 0.01, 1e7),
              "rotate_minutes": Option(float, 0.01, 1e7), "keep_days": Option(float, 0.001, 1e5),
              "keep_mib": Option(float, 1.0, 1e9),
              "row_encoding": Option(str, choices=tuple(sorted(ROW_ENCODINGS)))}
MAX_IDENTIFIED_ORDER = 20
_IDENTIFY = {"unknown_inputs": Option(int, 0, MAX_IDENTIFIED_ORDER - 1),
             "order": Option(int, 1, MAX_IDENTIFIED_ORDER), "delay": Option(int, 1, 10)}
_TEMPLATE = {"name": Option(str)}
_MATRICES = ("A", "B", "C", "D", "F", "G")


class NotIdentified(ConfigError):
    """A config whose model has no matrices yet: `canfdi identify` learns them."""


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
    try:
        arr = np.array(value, dtype=float) if not isinstance(value, bool) else None
    except (TypeError, ValueError):
        arr = None
    if arr is None or arr.ndim > 1:
        raise ConfigError(field, f"expected a number or a list of {size} numbers")
    arr = np.full(size, float(arr)) if arr.ndim == 0 else arr
    if arr.shape != (size,):
        raise ConfigError(field, f"expected {size} values, got {arr.shape[0]}")
    if not np.all(np.isfinite(arr)) or np.any(arr < 0):
        raise ConfigError(field, "standard deviations must be finite and >= 0")
    return arr


MAX_WINDOW = 50
"""The longest parity window a config may ask for (design.max_window's bound too): the
window's matrices grow as its square, and 50 periods is far beyond any fault's need."""


def _window(value: Any, field: str) -> int | None:
    if value is None or value == "auto":
        return None
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= MAX_WINDOW:
        raise ConfigError(field, f"expected 'auto' or an integer from 0 to {MAX_WINDOW}, got "
                                 f"{brief(value)}")
    return value


def _template(value: Any, field: str) -> TemplateSpec:
    """``model.identify.template``: a template's name, or {name, roles, parameters, fixed,
    and the template's settings}; the names are checked against the template registry by
    `canfdi identify` (canfdi.core.greybox), which knows each template's roles."""
    if isinstance(value, str) and value:
        return TemplateSpec(name=value)
    if not isinstance(value, dict):
        raise ConfigError(field, f"expected a template name or {{name, roles, parameters, "
                                 f"fixed}}, got {brief(value)}")
    if "name" not in value:
        raise ConfigError(f"{field}.name", "missing: which template")
    name = Option(str).check(value["name"], f"{field}.name")
    roles = section(value, "roles", field)
    for role, signal in roles.items():
        Option(str).check(signal, f"{field}.roles.{role}")
    params = section(value, "parameters", field)
    starts: dict[str, float] = {}
    fixed: list[str] = []
    for key, entry in params.items():
        where = f"{field}.parameters.{key}"
        if isinstance(entry, dict):
            parse_options(entry, {"value": Option(float, 0.0, None, open_lo=True),
                                  "fixed": Option(bool)}, where)
            if "value" in entry:
                starts[key] = float(entry["value"])
            if entry.get("fixed"):
                if "value" not in entry:
                    raise ConfigError(f"{where}.value", "a fixed parameter needs its value")
                fixed.append(key)
        else:
            starts[key] = Option(float, 0.0, None, open_lo=True).check(entry, where)
    settings = {k: v for k, v in value.items() if k not in ("name", "roles", "parameters")}
    return TemplateSpec(name=name, roles=dict(roles), parameters=starts, fixed=tuple(fixed),
                        settings=settings)


def _identify_spec(model_data: dict) -> IdentifySpec | None:
    raw = model_data.get("identify")
    if raw is None:
        return None
    if not isinstance(raw, dict):
        raise ConfigError("model.identify", f"expected a mapping like {{unknown_inputs: 1}}, "
                                            f"got {brief(raw)}")
    opts = parse_options(raw, _IDENTIFY, "model.identify", extra=("template",))
    template = (_template(raw["template"], "model.identify.template")
                if raw.get("template") is not None else None)
    return IdentifySpec(unknown_inputs=opts.get("unknown_inputs", 0),
                        order=opts.get("order"), delay=opts.get("delay", 1),
                        template=template)


def _model(data: dict, allow_unidentified: bool) -> tuple[StateSpace | None,
                                                          IdentifySpec | None, float | None]:
    """(model or None, identify spec, dt) of the ``model:`` section."""
    raw = section(data, "model", required=True)
    spec = _identify_spec(raw)
    matrices = {k: v for k, v in raw.items() if k != "identify"}
    if spec is not None and not any(k in matrices for k in _MATRICES):
        if not allow_unidentified:
            raise NotIdentified("model", "no matrices yet (model.identify says how to learn "
                                         "them): run `canfdi identify LOG --config FILE -o "
                                         "OUT.yaml` on a healthy log of the drive first")
        dt = matrices.get("dt")
        if dt is not None:
            dt = Option(float, 0.0, 3600.0, open_lo=True).check(dt, "model.dt")
        parse_options(matrices, {}, "model", extra=("dt", "time"))
        return None, spec, dt
    try:
        model = StateSpace.from_dict(matrices)
    except ModelError as exc:
        raise ConfigError(exc.field, str(exc).split(": ", 1)[1]) from None
    return model, spec, model.dt


def parse_config(data: Any, path: Path | None = None, *, allow_unidentified: bool = False
                 ) -> MonitorConfig:
    """Validate a loaded YAML document and build a MonitorConfig (the method's own section
    parsed by its registry entry).

    allow_unidentified : accept a ``model:`` with ``identify:`` and no matrices (for
    `canfdi identify`); the config's ``model`` is then None, and the signals' sizes come from
    their lists. Otherwise such a config is a `NotIdentified` error.
    """
    if not isinstance(data, dict):
        raise ConfigError("(top level)", "expected a mapping")
    method = methods.get(data.get("method", methods.DEFAULT))
    own = {m.section for m in map(methods.get, methods.names()) if m.section}
    parse_options(data, {}, "", extra=(*_COMMON_KEYS, *own))
    model, spec, dt = _model(data, allow_unidentified)

    signals = section(data, "signals", required=True)
    parse_options(signals, {}, "signals",
                  extra=("inputs", "outputs", "unknown_inputs", "unknown_outputs"))
    inputs = _names(signals.get("inputs"), "signals.inputs", model.p if model else None)
    outputs = _names(signals.get("outputs"), "signals.outputs", model.q if model else None)
    if model is None and (not inputs or not outputs):
        raise ConfigError("signals.inputs" if not inputs else "signals.outputs",
                          "a model to identify needs its inputs and outputs named")
    # A template brings its own unknown inputs: their names are checked when it is fitted.
    unknown_count = (model.r if model else None if spec is None or spec.template is not None
                     else spec.unknown_inputs)
    unknown_inputs = _names(signals.get("unknown_inputs"), "signals.unknown_inputs",
                            unknown_count if "unknown_inputs" in signals else None)
    unknown_outputs = _names(signals.get("unknown_outputs"), "signals.unknown_outputs",
                             (model.r1 if model else 0) if "unknown_outputs" in signals
                             else None)

    noise = section(data, "noise")
    parse_options(noise, {}, "noise", extra=("measurement", "process"))
    meas = _stds(noise.get("measurement"), "noise.measurement", len(outputs), None)
    proc = (_stds(noise.get("process"), "noise.process", model.n, None) if model is not None
            else None)
    if meas is not None and proc is not None and not np.any(meas) and not np.any(proc):
        raise ConfigError("noise", "all standard deviations are zero: no threshold can be derived")

    design = section(data, "design")
    max_window = parse_options(design, {"max_window": Option(int, 0, MAX_WINDOW)}, "design",
                               extra=("actuator_window", "sensor_window")).get("max_window", 10)
    options = DesignOptions(
        actuator_window=_window(design.get("actuator_window"), "design.actuator_window"),
        sensor_window=_window(design.get("sensor_window"), "design.sensor_window"),
        max_window=max_window, measurement_std=meas, process_std=proc,
    )
    bus = _bus(section(data, "bus"), inputs + outputs)
    detection = DetectionConfig(**parse_options(data.get("detection"), _DETECTION, "detection"))
    identification = IdentificationConfig(**parse_options(data.get("identification"),
                                                          _IDENTIFICATION, "identification"))
    if identification.max_samples < identification.min_samples:
        raise ConfigError("identification.max_samples",
                          f"must be >= min_samples ({identification.min_samples})")
    recording = RecordingConfig(**parse_options(data.get("recording"), _RECORDING, "recording"))
    watchdog = WatchdogConfig(**parse_options(data.get("watchdog"), _WATCHDOG, "watchdog"))
    name = data.get("name", path.stem if path else "model")
    if not isinstance(name, str) or not name:
        raise ConfigError("name", "expected a non-empty string")
    description = data.get("description", "")
    if not isinstance(description, str):
        raise ConfigError("description", "expected a string")
    drives = _drives(data.get("drives"), bus)
    if dt is None and bus.clock.period is not None:
        dt = bus.clock.period
    config = MonitorConfig(name=name, description=description, model=model, inputs=inputs,
                           outputs=outputs, unknown_inputs=unknown_inputs,
                           unknown_outputs=unknown_outputs, design=options, bus=bus,
                           detection=detection, identification=identification,
                           recording=recording, watchdog=watchdog, path=path,
                           method=method.name, drives=drives, identify=spec, dt=dt)
    raw = data.get(method.section) if method.section else None
    return dataclasses.replace(config, method_options=method.parse_options(raw, config))


def _message_ref(value: Any, field: str) -> str | int:
    """A DBC message named by its name or by its (DBC) ID."""
    if isinstance(value, bool) or not isinstance(value, str | int) or value == "":
        raise ConfigError(field, f"expected a message name or ID, got {brief(value)}")
    if isinstance(value, int) and not 0 <= value <= MAX_EXTENDED_ID:
        raise ConfigError(field, f"expected an ID in [0, 0x{MAX_EXTENDED_ID:X}], got "
                                 f"{brief(value)}")
    return value


def _signal_ref(value: Any, field: str) -> SignalRef:
    if isinstance(value, str):
        message, dot, signal = value.rpartition(".")
        if not dot or not message or not signal:
            raise ConfigError(field, f"expected MESSAGE.SIGNAL or {{message, signal}}, got "
                                     f"{brief(value)}")
        return SignalRef(_message_ref(int(message, 0) if _is_int(message) else message, field),
                         signal)
    if not isinstance(value, dict):
        raise ConfigError(field, f"expected MESSAGE.SIGNAL or {{message, signal}}, got "
                                 f"{brief(value)}")
    parse_options(value, {"signal": Option(str)}, field, extra=("message", "range"))
    if "message" not in value or "signal" not in value:
        raise ConfigError(field, "needs both message and signal")
    return SignalRef(_message_ref(value["message"], f"{field}.message"), value["signal"],
                     _range(value.get("range"), f"{field}.range"))


def _range(value: Any, field: str) -> tuple[float, float] | None:
    """``[low, high]``: finite numbers, low < high."""
    if value is None:
        return None
    if (not isinstance(value, list) or len(value) != 2
            or not all(isinstance(x, int | float) and not isinstance(x, bool)
                       and np.isfinite(x) for x in value) or not value[0] < value[1]):
        raise ConfigError(field, f"expected [low, high], two finite numbers with low < high, "
                                 f"got {brief(value)}")
    return float(value[0]), float(value[1])


def _is_int(text: str) -> bool:
    try:
        int(text, 0)
    except ValueError:
        return False
    return True


def _e2e_spec(value: Any, field: str) -> Any:
    """A profile name or a mapping with ``profile`` (its options are checked against the DBC
    when the bus is compiled: canfdi.bus.e2e)."""
    if isinstance(value, str) and value:
        if value not in E2E_PROFILES:
            raise unknown_name(field, "E2E profile", value, E2E_PROFILES)
        return value
    if isinstance(value, dict):
        name = value.get("profile")
        if name not in E2E_PROFILES:
            raise unknown_name(f"{field}.profile", "E2E profile", name, E2E_PROFILES)
        return dict(value)
    raise ConfigError(field, f"expected a profile name or {{profile, ...options}}, got "
                             f"{brief(value)}")


def _bus(data: dict, names: list[str]) -> BusConfig:
    values = parse_options(data, _BUS, "bus", extra=_BUS_SECTIONS)
    mapping = section(data, "map", "bus")
    for key in mapping:
        if key not in names:
            raise unknown_name(f"bus.map.{key}", "model signal", key, names)
    signal_map = {key: _signal_ref(value, f"bus.map.{key}") for key, value in mapping.items()}
    e2e_data = section(data, "e2e", "bus")
    parse_options(e2e_data, {}, "bus.e2e", extra=("default", "messages"))
    messages = section(e2e_data, "messages", "bus.e2e")
    e2e = E2EConfig(
        default=_e2e_spec(e2e_data.get("default", "canfdi"), "bus.e2e.default"),
        messages={_message_ref(key, f"bus.e2e.messages.{key}"):
                  _e2e_spec(spec, f"bus.e2e.messages.{key}") for key, spec in messages.items()})
    clock_data = section(data, "clock", "bus")
    clock = ClockConfig(**parse_options(clock_data, _CLOCK, "bus.clock", extra=("message",)))
    if "message" in clock_data:
        clock = dataclasses.replace(clock, message=_message_ref(clock_data["message"],
                                                                "bus.clock.message"))
    if clock.kind == "trigger" and clock.message is None:
        raise ConfigError("bus.clock.message", "a trigger clock needs the message that marks "
                                               "each control period (e.g. SYNC)")
    if clock.kind != "trigger" and clock.message is not None:
        raise ConfigError("bus.clock.message", f"only a trigger clock takes a message (this "
                                               f"one is {clock.kind})")
    node = section(data, "node", "bus")
    parse_options(node, {"id": Option(str)}, "bus.node", extra=("shared",))
    node_id = node.get("id")
    if node_id is not None:
        check_template(node_id, "bus.node.id")
    shared = node.get("shared", [])
    if not isinstance(shared, list):
        raise ConfigError("bus.node.shared", f"expected a list of message names or IDs, got "
                                             f"{brief(shared)}")
    node_shared = tuple(_message_ref(ref, f"bus.node.shared[{i}]")
                        for i, ref in enumerate(shared))
    monitor_data = section(data, "monitor", "bus")
    mon = parse_options(monitor_data, _MONITOR, "bus.monitor", extra=("ids", "e2e"))
    ids = section(monitor_data, "ids", "bus.monitor")
    for key, value in ids.items():
        Option(int, 0, MAX_EXTENDED_ID).check(value, f"bus.monitor.ids.{key}")
    if ids and "base" in mon:
        raise ConfigError("bus.monitor.ids", "give base or ids, not both")
    monitor = MonitorFramesConfig(
        **mon, ids=dict(ids),
        e2e=_e2e_spec(monitor_data.get("e2e", "canfdi"), "bus.monitor.e2e"))
    return BusConfig(**values, map=signal_map, e2e=e2e, clock=clock, node_id=node_id,
                     node_shared=node_shared, monitor=monitor,
                     stated=frozenset({"interface", "channel", "bitrate"} & set(values)))


def _drives(value: Any, bus: BusConfig) -> tuple[DriveConfig, ...]:
    if value is None:
        return ()
    if not isinstance(value, list) or not value:
        raise ConfigError("drives", "expected a non-empty list of {name, node}")
    if len(value) > MAX_DRIVES:
        raise ConfigError("drives", f"at most {MAX_DRIVES} drives on one bus (the monitor's "
                                    f"frames name a drive in 3 bits), got {len(value)}")
    drives, seen = [], set()
    for i, entry in enumerate(value):
        where = f"drives[{i}]"
        if not isinstance(entry, dict):
            raise ConfigError(where, "expected a mapping {name, node}")
        opts = parse_options(entry, {"name": Option(str), "node": Option(int, 0, 2**29)}, where)
        if "name" not in opts:
            raise ConfigError(f"{where}.name", "missing: every drive needs a name")
        if opts["name"] in seen:
            raise ConfigError(f"{where}.name", f"{brief(opts['name'])} is named twice")
        seen.add(opts["name"])
        if len(value) > 1 and "node" not in opts:
            raise ConfigError(f"{where}.node", "missing: several drives need a node each")
        drives.append(DriveConfig(opts["name"], opts.get("node")))
    if len(drives) > 1 and bus.node_id is None:
        raise ConfigError("bus.node.id", "several drives need a node-id template (e.g. "
                                         "\"(id & ~0x7F) | node\" for CANopen)")
    if bus.node_id is not None:
        # Every drive's node, now: a template that divides by zero for one of them is a bad
        # config, not a crash when that drive's frames are mapped.
        check_template(bus.node_id, "bus.node.id",
                       nodes=tuple(d.node for d in drives if d.node is not None) or (1,))
    return tuple(drives)


class _UniqueKeyLoader(yaml.SafeLoader):
    """PyYAML's safe loader, refusing a key given twice in one mapping (YAML says keys are
    unique; PyYAML keeps the last silently, so a second ``name:`` pasted at the end of a file
    would win unseen). Keys merged in with ``<<`` may be overridden, as YAML intends."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict:
        seen: set[tuple[str, str]] = set()
        for key_node, _ in node.value:
            if isinstance(key_node, yaml.ScalarNode) and key_node.tag != "tag:yaml.org,2002:merge":
                key = (key_node.tag, key_node.value)
                if key in seen:
                    raise yaml.constructor.ConstructorError(
                        None, None, f"the key {brief(key_node.value)} is given twice",
                        key_node.start_mark)
                seen.add(key)
        return super().construct_mapping(node, deep=deep)


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
        document = yaml.load(text, Loader=_UniqueKeyLoader)  # a SafeLoader
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = " ".join(str(getattr(exc, "problem", None) or exc).split())
        raise error(field, f"invalid YAML{where}: {problem}") from None
    except RecursionError:
        raise error(field, "invalid YAML: nested too deeply") from None
    if _expanded_size(document, MAX_DOCUMENT_VALUES) > MAX_DOCUMENT_VALUES:
        raise error(field, f"the document expands to more than {MAX_DOCUMENT_VALUES:,} values "
                           "(YAML aliases repeated?)")
    return document


MAX_DOCUMENT_VALUES = 1_000_000
"""The most values (scalars, lists and mappings, aliases counted each time they are used) a
YAML file may expand to: a config is a few thousand; an alias repeated within aliases is
exponential, and everything that reads the document would pay for it."""


def _expanded_size(document: Any, limit: int) -> int:
    """Values in the document as if every alias were copied, counted up to just past
    ``limit``."""
    count, stack = 0, [document]
    while stack and count <= limit:
        item = stack.pop()
        count += 1
        if isinstance(item, dict):
            stack.extend(item.keys())
            stack.extend(item.values())
        elif isinstance(item, list):
            stack.extend(item)
    return count


def load_config(path: str | Path, *, allow_unidentified: bool = False) -> MonitorConfig:
    """Read and validate a YAML monitor config; raises ConfigError naming the field
    (`NotIdentified` for a model still to learn, unless ``allow_unidentified``)."""
    path = Path(path)
    return parse_config(read_yaml(path, ConfigError, "config"), path,
                        allow_unidentified=allow_unidentified)


# The JSON Schema of a config (`canfdi schema`): the option tables above, and beside them what
# the parsers of the structured keys accept. What a schema cannot say (sizes that must match
# the model, names that must be in the DBC, a node-id template's arithmetic) stays the
# parser's alone; tests/integration/test_config_schema.py holds the two to agreement.
SCHEMA_ID = "https://canfdi.dev/schema/config.json"
_TEXT = {"type": "string", "minLength": 1}
_ENTRY = {"anyOf": [{"type": "number", "minimum": -MAX_ENTRY, "maximum": MAX_ENTRY},
                    NUMBER_AS_TEXT]}
_MATRIX = {"type": "array", "maxItems": MAX_DIMENSION,
           "items": {"anyOf": [_ENTRY, {"type": "array", "maxItems": MAX_DIMENSION,
                                        "items": _ENTRY}]},
           "title": "matrix", "description": "a list of rows of numbers (a flat list is one row)"}
_NAMES = {"type": ["array", "null"], "items": _TEXT, "uniqueItems": True, "title": "names",
          "description": "unique names, as many as the model has"}
_STD = {"anyOf": [{"type": "number", "minimum": 0}, NUMBER_AS_TEXT]}
_STDS = {"anyOf": [{"type": "null"}, *_STD["anyOf"], {"type": "array", "items": _STD}],
         "title": "standard deviations",
         "description": "one number for all, or one per signal"}
_WINDOW_SCHEMA = {"anyOf": [{"enum": ["auto", None]},
                            {"type": "integer", "minimum": 0, "maximum": MAX_WINDOW}],
                  "title": f"auto or 0 to {MAX_WINDOW}", "default": "auto",
                  "description": "the parity window's order (auto: the smallest admissible)"}
_MESSAGE_REF = {"anyOf": [_TEXT, {"type": "integer", "minimum": 0,
                                  "maximum": MAX_EXTENDED_ID}],
                "title": "message", "description": "a DBC message by name or ID"}
_SIGNAL_REF = {"anyOf": [
    {"type": "string", "pattern": r"^.+\.[^.]+$", "description": "MESSAGE.SIGNAL"},
    {"type": "object", "required": ["message", "signal"], "additionalProperties": False,
     "properties": {"message": _MESSAGE_REF, "signal": _TEXT,
                    "range": {"anyOf": [{"type": "null"},
                                        {"type": "array", "items": {"type": "number"},
                                         "minItems": 2, "maxItems": 2}]}}}],
               "title": "signal", "description": "MESSAGE.SIGNAL or {message, signal, range}"}


def _e2e_schema() -> dict[str, Any]:
    names = sorted(E2E_PROFILES)
    return {"anyOf": [{"enum": names},
                      {"type": "object", "required": ["profile"],
                       "properties": {"profile": {"enum": names}}}],
            "title": "E2E profile",
            "description": "an E2E profile by name, or {profile, ...its options}"}


def _template_schema() -> dict[str, Any]:
    positive = Option(float, 0.0, None, open_lo=True).json_schema()
    parameter = {"anyOf": [positive, options_schema(
        {"value": Option(float, 0.0, None, open_lo=True), "fixed": Option(bool)},
        nullable=False)]}
    return {"anyOf": [{"type": "null"}, _TEXT, {
        "type": "object", "required": ["name"],
        "properties": {"name": Option(str).json_schema(),
                       "roles": {"type": ["object", "null"],
                                 "additionalProperties": Option(str).json_schema()},
                       "parameters": {"type": ["object", "null"],
                                      "additionalProperties": parameter}}}],
        "title": "template",
        "description": "a grey-box template's name, or {name, roles, parameters, ...}"}


def _model_schema() -> dict[str, Any]:
    identify = options_schema(_IDENTIFY, defaults=IdentifySpec,
                              extra={"template": _template_schema()})
    identify["type"] = ["object", "null"]
    matrices = {key: ({"anyOf": [{"type": "null"}, _MATRIX]} if key in "DFG"
                      else {**_MATRIX, "minItems": 1} if key in "AC" else _MATRIX)
                for key in _MATRICES}
    return {"type": "object", "additionalProperties": False,
            "properties": {**matrices, "time": {"enum": ["discrete", "continuous"],
                                                "default": "discrete"},
                           "dt": {"type": ["number", "null"], "exclusiveMinimum": 0},
                           "identify": identify},
            "anyOf": [{"required": ["A", "B", "C"]},
                      {"required": ["identify"], "properties": {"identify": {"type": "object"}},
                       "not": {"anyOf": [{"required": [key]} for key in _MATRICES]}}]}


def _bus_schema() -> dict[str, Any]:
    e2e = _e2e_schema()
    clock = options_schema(_CLOCK, defaults=ClockConfig, extra={"message": _MESSAGE_REF})
    clock["allOf"] = [
        {"if": {"properties": {"kind": {"const": "trigger"}}, "required": ["kind"]},
         "then": {"required": ["message"]}},
        {"if": {"required": ["message"]},
         "then": {"required": ["kind"], "properties": {"kind": {"const": "trigger"}}}}]
    monitor = options_schema(_MONITOR, defaults=MonitorFramesConfig, extra={
        "ids": {"type": ["object", "null"], "additionalProperties": {
            "type": "integer", "minimum": 0, "maximum": MAX_EXTENDED_ID}},
        "e2e": e2e})
    monitor["not"] = {"required": ["base", "ids"],
                      "properties": {"base": {"type": "integer"},
                                     "ids": {"type": "object", "minProperties": 1}}}
    sections = {
        "map": {"type": ["object", "null"], "additionalProperties": _SIGNAL_REF,
                "description": "model signal -> the DBC signal that carries it"},
        "e2e": {"type": ["object", "null"], "additionalProperties": False,
                "properties": {"default": e2e,
                               "messages": {"type": ["object", "null"],
                                            "additionalProperties": e2e}}},
        "clock": clock,
        "node": {"type": ["object", "null"], "additionalProperties": False,
                 "properties": {"id": Option(str).json_schema(),
                                "shared": {"type": "array", "items": _MESSAGE_REF}}},
        "monitor": monitor}
    return options_schema(_BUS, defaults=BusConfig, extra=sections)


def _drives_schema() -> dict[str, Any]:
    drive = options_schema({"name": Option(str), "node": Option(int, 0, 2**29)},
                           nullable=False)
    drive["required"] = ["name"]
    drive["properties"]["name"] = dict(_TEXT)
    return {"type": ["array", "null"], "minItems": 1, "maxItems": MAX_DRIVES, "items": drive,
            "if": {"type": "array", "minItems": 2},
            "then": {"items": {"required": ["name", "node"],
                               "properties": {"node": {"type": "integer"}}}}}


def config_schema() -> dict[str, Any]:
    """The JSON Schema (draft 2020-12) of a monitor config, made from the tables and parsers
    that `parse_config` checks with, and each registered method's own section.

    >>> schema = config_schema()
    >>> schema["required"], schema["properties"]["detection"]["properties"]["drift"]["default"]
    (['model', 'signals'], 0.5)
    """
    registered = [methods.get(name) for name in methods.names()]
    own = {m.section: (dict(m.schema) if m.schema is not None else {"type": ["object", "null"]})
           for m in registered if m.section and m.section not in _COMMON_KEYS}
    signals = {"type": "object", "additionalProperties": False,
               "properties": {key: _NAMES for key in
                              ("inputs", "outputs", "unknown_inputs", "unknown_outputs")}}
    properties: dict[str, Any] = {
        "name": {**_TEXT, "description": "the config's name (default: the file's stem)"},
        "description": {"type": "string"},
        "method": {"enum": sorted(m.name for m in registered), "default": methods.DEFAULT},
        "model": _model_schema(),
        "signals": signals,
        "noise": {"type": ["object", "null"], "additionalProperties": False,
                  "properties": {"measurement": _STDS, "process": _STDS}},
        "design": options_schema({"max_window": Option(int, 0, MAX_WINDOW)},
                                 defaults=DesignOptions,
                                 extra={"actuator_window": _WINDOW_SCHEMA,
                                        "sensor_window": _WINDOW_SCHEMA}),
        "bus": _bus_schema(),
        "detection": options_schema(_DETECTION, defaults=DetectionConfig),
        "identification": options_schema(_IDENTIFICATION, defaults=IdentificationConfig),
        "recording": options_schema(_RECORDING, defaults=RecordingConfig),
        "watchdog": options_schema(_WATCHDOG, defaults=WatchdogConfig),
        "drives": _drives_schema(),
        **own,
    }
    several_need_a_template = {
        "if": {"required": ["drives"], "properties": {"drives": {"type": "array",
                                                                 "minItems": 2}}},
        "then": {"required": ["bus"], "properties": {"bus": {
            "type": "object", "required": ["node"], "properties": {"node": {
                "type": "object", "required": ["id"],
                "properties": {"id": {"type": "string"}}}}}}}}
    return {"$schema": "https://json-schema.org/draft/2020-12/schema", "$id": SCHEMA_ID,
            "title": "canfdi monitor config", "type": "object", "required": ["model", "signals"],
            "properties": properties, "additionalProperties": False,
            **several_need_a_template}

"""A validated monitor configuration as frozen records, and the one option validator.

canfdi.config reads the YAML and builds a `MonitorConfig`; every layer below it (bus, methods)
takes these records, never a mapping of strings. Every config error is a `ConfigError` naming
the dotted field, saying what was expected and, for a name, the nearest names that exist; the
CLI prints it in one line and exits with status 2.

>>> parse_options({"drfit": 0.5}, {"drift": Option(float, 0.0, 100.0)}, "detection")
Traceback (most recent call last):
...
canfdi.core.settings.ConfigError: detection.drfit: unknown key (did you mean drift? allowed: drift)
>>> parse_options({"drift": 200}, {"drift": Option(float, 0.0, 100.0)}, "detection")
Traceback (most recent call last):
...
canfdi.core.settings.ConfigError: detection.drift: expected a number in [0.0, 100.0], got 200
"""

from __future__ import annotations

import difflib
import math
import reprlib
from collections.abc import Iterable, Mapping
from dataclasses import MISSING, dataclass, field, fields
from pathlib import Path
from typing import Any

from canfdi.core.design import DesignOptions
from canfdi.core.model import StateSpace

__all__ = [
    "BusConfig",
    "ClockConfig",
    "ConfigError",
    "DetectionConfig",
    "DriveConfig",
    "E2EConfig",
    "IdentificationConfig",
    "IdentifySpec",
    "MonitorConfig",
    "MonitorFramesConfig",
    "Option",
    "RecordingConfig",
    "SignalRef",
    "TemplateSpec",
    "nearest",
    "options_schema",
    "parse_options",
    "section",
    "unknown_name",
]


_BRIEF = reprlib.Repr()
_BRIEF.maxlevel, _BRIEF.maxlist, _BRIEF.maxtuple, _BRIEF.maxdict = 2, 4, 4, 4
_BRIEF.maxstring, _BRIEF.maxother, _BRIEF.maxlong = 40, 40, 40

MAX_MESSAGE = 400
"""The longest config error line: a value echoed in it is cut (`brief`)."""


def brief(value: object) -> str:
    """A short repr of a config value for an error line: nested lists and mappings cut after
    a few items and two levels, long strings cut (a YAML alias repeated nine times nine
    times is never expanded into the message).

    >>> brief("x" * 100)
    "'xxxxxxxxxxxxxxxxx...xxxxxxxxxxxxxxxxxx'"
    >>> brief([[1, 2, 3, 4, 5, 6]] * 9)
    '[[1, 2, 3, 4, ...], [1, 2, 3, 4, ...], [1, 2, 3, 4, ...], [1, 2, 3, 4, ...], ...]'
    """
    return _BRIEF.repr(value)


NUMBER_AS_TEXT = {"type": "string",
                  "pattern": r"^[-+]?([0-9]+[.]?[0-9]*|[.][0-9]+)([eE][-+]?[0-9]+)?$"}
"""The JSON Schema of a number written as text, which a float option takes too: PyYAML, a
YAML 1.1 reader, reads 1e7 and 1.0e7 (no exponent sign) as strings. It checks such text for
its form only, not for the option's bounds."""


class ConfigError(ValueError):
    """A configuration problem; ``field`` is the dotted path of the offending key. The line
    is cut at `MAX_MESSAGE` characters.

    Examples
    --------
    >>> err = ConfigError("detection.drift", "expected a number > 0, got -1")
    >>> err.field, str(err)
    ('detection.drift', 'detection.drift: expected a number > 0, got -1')
    """

    def __init__(self, field: str, message: str) -> None:
        text = f"{field}: {message}"
        if len(text) > MAX_MESSAGE:
            text = text[: MAX_MESSAGE - 3] + "..."
        super().__init__(text)
        self.field = field


def nearest(name: str, names: Iterable[str], count: int = 3, cutoff: float = 0.6) -> list[str]:
    """The names most like ``name`` (difflib's ratio >= ``cutoff``), best first."""
    return difflib.get_close_matches(str(name), list(names), n=count, cutoff=cutoff)


def unknown_name(field: str, what: str, name: object, names: Iterable[str]) -> ConfigError:
    """The error for a name that is not one of ``names``: the nearest ones, then all."""
    known = sorted(names)
    close = nearest(str(name), known)
    hint = f"did you mean {' or '.join(close)}? " if close else ""
    return ConfigError(field, f"unknown {what} {brief(name)} ({hint}known: {', '.join(known)})")


@dataclass(frozen=True)
class Option:
    """What one option of a config section may be.

    kind : int, float, str or bool. A float accepts an integer, and a string that reads as a
        number (PyYAML, a YAML 1.1 reader, reads 1.0e7 without an exponent sign as a string).
    lo, hi : bounds (None: unbounded); ``open_lo``/``open_hi`` exclude them.
    choices : the allowed values of a str option.

    Examples
    --------
    >>> drift = Option(float, lo=0.0, open_lo=True)
    >>> drift.check(0.5, "detection.drift"), drift.check("1.0e7", "detection.drift")
    (0.5, 10000000.0)
    >>> try:
    ...     drift.check(0, "detection.drift")
    ... except ConfigError as exc:
    ...     print(exc)
    detection.drift: expected a number > 0.0, got 0
    """

    kind: type
    lo: float | None = None
    hi: float | None = None
    open_lo: bool = False
    open_hi: bool = False
    choices: tuple[str, ...] | None = None

    def expected(self) -> str:
        """'a number in [0, 1]', 'an integer >= 1', 'one of a, b', ..."""
        noun = {int: "an integer", float: "a number", str: "a non-empty string",
                bool: "true or false"}[self.kind]
        if self.choices:
            return "one of " + ", ".join(self.choices)
        if self.lo is not None and self.hi is not None:
            return (f"{noun} in {'(' if self.open_lo else '['}{self.lo}, {self.hi}"
                    f"{')' if self.open_hi else ']'}")
        if self.lo is not None:
            return f"{noun} {'>' if self.open_lo else '>='} {self.lo}"
        if self.hi is not None:
            return f"{noun} {'<' if self.open_hi else '<='} {self.hi}"
        return noun

    def json_schema(self) -> dict[str, Any]:
        """The JSON Schema of what `check` accepts (null too: an empty key means the default).

        >>> Option(float, 0.0, 1.0, open_hi=True).json_schema()["anyOf"][0]
        {'type': ['number', 'null'], 'minimum': 0.0, 'exclusiveMaximum': 1.0}
        >>> Option(str, choices=("a", "b")).json_schema()["enum"]
        ['a', 'b', None]
        """
        if self.kind is bool:
            return {"type": ["boolean", "null"]}
        if self.kind is str:
            out: dict[str, Any] = {"type": ["string", "null"], "minLength": 1}
            if self.choices:
                out["enum"] = [*self.choices, None]
            return out
        bounds: dict[str, Any] = {}
        if self.lo is not None:
            bounds["exclusiveMinimum" if self.open_lo else "minimum"] = self.lo
        if self.hi is not None:
            bounds["exclusiveMaximum" if self.open_hi else "maximum"] = self.hi
        if self.kind is int:
            return {"type": ["integer", "null"], **bounds}
        return {"anyOf": [{"type": ["number", "null"], **bounds},
                          NUMBER_AS_TEXT]}

    def check(self, value: Any, field: str) -> Any:
        """The value as ``kind``, or a ConfigError naming ``field``."""
        bad = ConfigError(field, f"expected {self.expected()}, got {brief(value)}")
        if self.kind is bool:
            if not isinstance(value, bool):
                raise bad
            return value
        if self.kind is str:
            if not isinstance(value, str) or not value:
                raise bad
            if self.choices is not None and value not in self.choices:
                raise unknown_name(field, "value", value, self.choices)
            return value
        if self.kind is float and isinstance(value, str):
            try:
                value = float(value)
            except ValueError:
                raise bad from None
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise bad
        if self.kind is int and not isinstance(value, int):
            raise bad
        if not math.isfinite(value):
            raise bad
        if self.lo is not None and (value <= self.lo if self.open_lo else value < self.lo):
            raise bad
        if self.hi is not None and (value >= self.hi if self.open_hi else value > self.hi):
            raise bad
        return self.kind(value)


def section(data: Mapping[str, Any], key: str, where: str = "", required: bool = False
            ) -> dict[str, Any]:
    """The mapping under ``key`` ({} when absent and not required)."""
    field_name = f"{where}.{key}" if where else key
    value = data.get(key)
    if value is None:
        if required:
            raise ConfigError(field_name, "missing section")
        return {}
    if not isinstance(value, Mapping):
        raise ConfigError(field_name, f"expected a mapping, got {type(value).__name__}")
    return dict(value)


def parse_options(data: Any, spec: Mapping[str, Option], where: str, *,
                  extra: Iterable[str] = ()) -> dict[str, Any]:
    """Validate a flat config section against ``spec``.

    Parameters
    ----------
    data : the section (a mapping, or None for an absent one).
    spec : option name -> `Option`.
    where : the section's dotted name, the prefix of every field named in an error.
    extra : further keys allowed here, validated by the caller.

    Returns
    -------
    dict of the options present (None values left out: they mean the default), converted.

    Raises
    ------
    ConfigError
        ``where.key`` for an unknown key (with the nearest allowed ones) or a bad value.
    """
    if data is None:
        return {}
    if not isinstance(data, Mapping):
        raise ConfigError(where, f"expected a mapping, got {type(data).__name__}")
    allowed = set(spec) | set(extra)
    out: dict[str, Any] = {}
    for key, value in data.items():
        field_name = f"{where}.{key}" if where else str(key)
        if key not in allowed:
            close = nearest(str(key), allowed)
            hint = f"did you mean {' or '.join(close)}? " if close else ""
            raise ConfigError(field_name,
                              f"unknown key ({hint}allowed: {', '.join(sorted(allowed))})")
        if key in spec and value is not None:
            out[key] = spec[key].check(value, field_name)
    return out


def options_schema(spec: Mapping[str, Option], *, defaults: Any = None,
                   extra: Mapping[str, Mapping[str, Any]] | None = None,
                   nullable: bool = True) -> dict[str, Any]:
    """The JSON Schema of a section that `parse_options` checks against ``spec``.

    defaults : the dataclass (or instance) whose field defaults are the options' defaults.
    extra : the schemas of the keys the caller validates itself (``parse_options``' extra).
    nullable : an empty section (null) means all defaults, as `section` reads it.

    >>> schema = options_schema({"drift": Option(float, 0.0, 100.0)},
    ...                         defaults=DetectionConfig)
    >>> schema["properties"]["drift"]["default"], schema["additionalProperties"]
    (0.5, False)
    """
    known = {f.name: f.default for f in fields(defaults)} if defaults is not None else {}
    properties: dict[str, Any] = {}
    for key, option in spec.items():
        properties[key] = option.json_schema()
        default = known.get(key, MISSING)
        if default is not MISSING and default is not None:
            properties[key]["default"] = default
    properties.update({key: dict(value) for key, value in (extra or {}).items()})
    return {"type": ["object", "null"] if nullable else "object",
            "properties": properties, "additionalProperties": False}


@dataclass(frozen=True)
class SignalRef:
    """Where the bus carries a model signal: a message of the DBC (its name, or its ID as the
    DBC writes it) and one of its signals; ``range`` (low, high): the values the drive can
    physically send, tighter than the DBC's (a frame outside is "implausible").

    Examples
    --------
    >>> ref = SignalRef("MotorStatus", "ArmatureCurrent", range=(-20.0, 20.0))
    >>> ref.message, ref.range
    ('MotorStatus', (-20.0, 20.0))
    """

    message: str | int
    signal: str
    range: tuple[float, float] | None = None

    def __str__(self) -> str:
        msg = self.message if isinstance(self.message, str) else f"0x{self.message:X}"
        return f"{msg}.{self.signal}"


@dataclass(frozen=True)
class ClockConfig:
    """How one sample per control period is formed (canfdi.bus.clock; docs/bus.md).

    kind : "counter", "trigger" or "grid". message : the trigger message (name or DBC ID).
    period, phase, max_age : seconds (None: the defaults of docs/bus.md, from model.dt).

    Examples
    --------
    >>> ClockConfig().kind, ClockConfig(kind="grid", period=0.01).period
    ('counter', 0.01)
    """

    kind: str = "counter"
    message: str | int | None = None
    period: float | None = None
    phase: float | None = None
    max_age: float | None = None


@dataclass(frozen=True)
class E2EConfig:
    """End-to-end protection per message: a profile spec (a name, or a mapping with
    ``profile`` and its options; canfdi.bus.e2e) for each listed message (name or DBC ID), and
    the default for the others.

    Examples
    --------
    >>> e2e = E2EConfig(default="none", messages={"MotorCommand": "canfdi"})
    >>> e2e.default, dict(e2e.messages)
    ('none', {'MotorCommand': 'canfdi'})
    """

    default: Any = "canfdi"
    messages: Mapping[str | int, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class MonitorFramesConfig:
    """The monitor's own frames: the DBC defining FDI_FAULT, FDI_ESTIMATE, FDI_STATUS (and
    FDI_RESIDUAL), their IDs (``base`` for consecutive ones, or ``ids`` by message name; none:
    the DBC's), their E2E profile.

    Examples
    --------
    >>> frames = MonitorFramesConfig(base=0x700)
    >>> frames.dbc, hex(frames.base), frames.e2e
    ('canfdi_monitor', '0x700', 'canfdi')
    """

    dbc: str = "canfdi_monitor"
    base: int | None = None
    ids: Mapping[str, int] = field(default_factory=dict)
    e2e: Any = "canfdi"


@dataclass(frozen=True)
class BusConfig:
    """Where the drive's frames are and how to read them (docs/bus.md).

    interface, channel, bitrate : python-can arguments. dbc : the drive's DBC (a file or a
    shipped name). status_period : seconds between FDI_STATUS frames. transmit : False for a
    listen-only monitor. canopen : a CANopen bus (the monitor's IDs avoid its function codes).
    map : model signal name -> SignalRef (names not listed: the same-named DBC signal).
    e2e, clock, monitor : see their records. node_id : the node-id template, an expression of
    ``id`` (a message's DBC ID) and ``node`` (None: the DBC's IDs as written). node_shared :
    messages of the bus rather than of a drive (a CANopen SYNC), by name or DBC ID: the template
    leaves their IDs alone and every drive reads them.

    Examples
    --------
    >>> bus = BusConfig(interface="socketcan", channel="can0", stated=frozenset({"interface"}))
    >>> bus.interface, bus.bitrate, bus.clock.kind, bus.monitor.dbc
    ('socketcan', None, 'counter', 'canfdi_monitor')
    """

    interface: str = "virtual"
    channel: str = "canfdi"
    bitrate: int | None = None
    dbc: str | None = None
    status_period: float = 1.0
    transmit: bool = True
    canopen: bool = False
    map: Mapping[str, SignalRef] = field(default_factory=dict)
    e2e: E2EConfig = E2EConfig()
    clock: ClockConfig = ClockConfig()
    node_id: str | None = None
    node_shared: tuple[str | int, ...] = ()
    monitor: MonitorFramesConfig = MonitorFramesConfig()
    stated: frozenset[str] = frozenset()
    """Which of interface, channel and bitrate the config file states (the others may come
    from python-can's own configuration: canfdi.tools.session.bus_factory)."""


@dataclass(frozen=True)
class DriveConfig:
    """One drive on the bus: its name (events and log records carry it) and its node number
    (for ``bus.node_id``; None: the DBC's IDs).

    Examples
    --------
    >>> DriveConfig("left", node=3)
    DriveConfig(name='left', node=3)
    """

    name: str
    node: int | None = None


@dataclass(frozen=True)
class DetectionConfig:
    """Page-Hinkley settings: drift delta (noise stds), the false-alarm interval (samples) and
    whether the parity method also runs a CUSUM per fault signature (``signatures``).

    Examples
    --------
    >>> DetectionConfig(drift=0.25)
    DetectionConfig(drift=0.25, false_alarm_interval=10000000.0, signatures=False)
    """

    drift: float = 0.5
    false_alarm_interval: float = 1.0e7
    signatures: bool = False


@dataclass(frozen=True)
class WatchdogConfig:
    """The noise watchdog of `canfdi run`, replay and demo (canfdi.core.watchdog): each
    residual's noise std in ``blocks`` consecutive blocks of ``block`` samples against its
    calibrated value; a mismatch beyond ``factor`` (or below 1 / factor) is said, never
    diagnosed as a fault.

    Examples
    --------
    >>> w = WatchdogConfig()
    >>> w.enabled, w.block * w.blocks  # samples the watchdog compares at once
    (True, 500)
    """

    enabled: bool = True
    factor: float = 1.5
    block: int = 250
    blocks: int = 2


@dataclass(frozen=True)
class IdentificationConfig:
    """When the parity method accepts a hypothesis (canfdi.methods.parity); its max_samples is
    also `canfdi evaluate`'s default spacing between faults, whatever the method.

    Examples
    --------
    >>> IdentificationConfig(max_samples=4000).max_samples, IdentificationConfig().min_samples
    (4000, 10)
    """

    min_samples: int = 10
    max_samples: int = 2000
    settle_rel_std: float = 0.005
    settle_noise: float = 0.2
    isolation_margin: float = 50.0
    max_fit_variance: float = 2.25
    lookback: int = 256


@dataclass(frozen=True)
class TemplateSpec:
    """A grey-box template for `canfdi identify` (canfdi.core.greybox): its name, the config
    signal that plays each of its roles, start values of its parameters (the datasheet's;
    unset: the template's defaults), the parameters held at their start, and its settings.

    Examples
    --------
    >>> spec = TemplateSpec("dc_motor", roles={"speed": "omega_r"}, fixed=("D",))
    >>> spec.name, dict(spec.roles), spec.fixed
    ('dc_motor', {'speed': 'omega_r'}, ('D',))
    """

    name: str
    roles: Mapping[str, str] = field(default_factory=dict)
    parameters: Mapping[str, float] = field(default_factory=dict)
    fixed: tuple[str, ...] = ()
    settings: Mapping[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class IdentifySpec:
    """How `canfdi identify` learns the model (the config's ``model.identify``).

    unknown_inputs : how many unmeasured inputs act on the drive (a load, friction, an
        unmodelled coupling). order : the state dimension (None: from the data). delay :
        samples from a command to its first effect (>= 1). template : a grey-box template,
        or None for a black-box model.

    Examples
    --------
    >>> spec = IdentifySpec(unknown_inputs=1, template=TemplateSpec("servo_axis"))
    >>> spec.order, spec.delay, spec.template.name
    (None, 1, 'servo_axis')
    """

    unknown_inputs: int = 0
    order: int | None = None
    delay: int = 1
    template: TemplateSpec | None = None


@dataclass(frozen=True)
class RecordingConfig:
    """MCAP logging of `canfdi run`: where, when a segment is rotated, and how long logs are
    kept (canfdi.io.retention; None: no bound of that kind).

    Examples
    --------
    >>> rec = RecordingConfig(directory="/var/log/canfdi", keep_days=30)
    >>> rec.rotate_mib, rec.keep_days, rec.keep_mib
    (256.0, 30, None)
    """

    directory: str = "logs"
    rotate_mib: float = 256.0
    rotate_minutes: float = 60.0
    keep_days: float | None = None
    keep_mib: float | None = None
    row_encoding: str | None = None  # canfdi.io.rowencodings' name; None: the recorder's default


@dataclass(frozen=True)
class MonitorConfig:
    """A parsed monitor configuration (canfdi.config.load_config builds it).

    Attributes
    ----------
    method : the diagnosis method's registered name (canfdi.methods).
    method_options : that method's options, as its registry entry parsed them from its own
        config section (None for a method with no section of its own).
    model : the drive's model; None only in a config read for `canfdi identify` whose
        ``model:`` holds no matrices yet (``identify`` says how to learn them; ``dt`` its
        sample period when known).
    identify : the config's ``model.identify`` (None when it has none).

    Examples
    --------
    >>> from canfdi.core.design import DesignOptions
    >>> from canfdi.core.model import StateSpace
    >>> model = StateSpace(A=[[0.9]], B=[[1.0]], C=[[1.0]], dt=0.01)
    >>> config = MonitorConfig(name="toy", description="", model=model, inputs=["u"], outputs=["y"],
    ...                        unknown_inputs=[], unknown_outputs=[], design=DesignOptions(),
    ...                        method="parity")
    >>> config.drive_list, config.detection.false_alarm_interval
    ((DriveConfig(name='toy', node=None),), 10000000.0)
    """

    name: str
    description: str
    model: StateSpace
    inputs: list[str]
    outputs: list[str]
    unknown_inputs: list[str]
    unknown_outputs: list[str]
    design: DesignOptions
    method: str
    bus: BusConfig = BusConfig()
    detection: DetectionConfig = DetectionConfig()
    identification: IdentificationConfig = IdentificationConfig()
    recording: RecordingConfig = RecordingConfig()
    watchdog: WatchdogConfig = WatchdogConfig()
    path: Path | None = None
    method_options: Any = None
    drives: tuple[DriveConfig, ...] = ()
    identify: IdentifySpec | None = None
    dt: float | None = None

    @classmethod
    def of_bus(cls, name: str, inputs: list[str], outputs: list[str], bus: BusConfig,
               drives: tuple[DriveConfig, ...] = ()) -> MonitorConfig:
        """A config of a bus alone, without a model: what the bus layer reads of one (its
        examples, and a bus compiled before any model is known).

        >>> config = MonitorConfig.of_bus("drive", ["u"], ["y"], BusConfig(dbc="motor_drive"))
        >>> config.model is None, config.bus.dbc, config.drive_list[0].name
        (True, 'motor_drive', 'drive')
        """
        return cls(name=name, description="", model=None, inputs=list(inputs),
                   outputs=list(outputs), unknown_inputs=[], unknown_outputs=[],
                   design=DesignOptions(), method="parity", bus=bus, drives=drives)

    @property
    def drive_list(self) -> tuple[DriveConfig, ...]:
        """The drives on the bus: ``drives``, or one drive named after the config."""
        return self.drives or (DriveConfig(self.name),)

"""The diagnosis methods, by name: the one place that branches on a method's name.

A method is a `Method` record: its config section and how to parse it, how to build its
diagnoser (canfdi.core.protocol.Diagnoser) from a config, and what the tools need to know of it
(its fault model for `canfdi evaluate`, its detection statistic and estimate history for
`canfdi report`). The config's ``method:`` key picks one by name; config validation, the
monitor, evaluate and report ask this registry, never the name.

Built in: ``parity`` (Chan et al. 2006), ``output_error`` (the output-error paper), ``uio`` (Hwang,
Chang and Hsu). Another
package adds one the way python-can finds interfaces, with an entry point::

    [project.entry-points."canfdi.methods"]
    kalman = "my_package.kalman:METHOD"       # a canfdi.methods.Method

or in code with `register`. Each registered method runs through the conformance suite of
tests/methods/.

>>> {"output_error", "parity", "uio"} <= set(names())   # the built-ins, and any registered
True
>>> get("parity").section
'identification'
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from importlib.metadata import entry_points
from typing import Any

import numpy as np

from canfdi.core.protocol import Diagnoser
from canfdi.core.records import FaultEvent
from canfdi.core.settings import MonitorConfig, unknown_name

__all__ = ["DEFAULT", "ENTRY_POINT_GROUP", "FAULT_KINDS", "EstimateHistory", "Method",
           "build_diagnoser", "get", "names", "register"]

ENTRY_POINT_GROUP = "canfdi.methods"
DEFAULT = "parity"
"""The method of a config that names none."""
FAULT_KINDS = ("actuator_bias", "actuator_scale", "sensor_bias")
"""The fault kinds `canfdi evaluate` can inject (a method declares those of its model)."""

log = logging.getLogger("canfdi.methods")


@dataclass(frozen=True)
class EstimateHistory:
    """The running estimates of an accepted fault, recomputed from a log (canfdi report).

    k : (N,) samples from the onset to the acceptance; names : the parameters (e.g. eta,
    lambda); values, std : (N, len(names)); source : how they were computed, for the page.

    Examples
    --------
    >>> history = EstimateHistory(k=np.arange(100, 103), names=["bias"],
    ...                           values=np.array([[0.4], [0.45], [0.5]]),
    ...                           std=np.full((3, 1), 0.05),
    ...                           source="recomputed from the log's residuals")
    >>> history.names, history.values[-1], int(history.k[-1] - history.k[0])
    (['bias'], array([0.5]), 2)
    """

    k: np.ndarray
    names: list[str]
    values: np.ndarray
    std: np.ndarray
    source: str


@dataclass(frozen=True)
class Method:
    """A diagnosis method, as the registry knows it.

    Attributes
    ----------
    name : the config's ``method:`` value.
    summary : one line: what it is and which paper.
    section : the config section holding its own options (None: it has none).
    parse_options : (section mapping or None, config) -> the method's options, validated:
        a ConfigError names ``<section>.<key>`` on bad input. Called when the config is
        loaded; the result is ``config.method_options``.
    build : config -> a Diagnoser (designed and calibrated; may raise ConfigError).
    fault_kinds : the fault kinds of its model, of `FAULT_KINDS`.
    statistic : (short, long) name of its detection statistic, for plots and pages.
    describe : config -> JSON-ready design description for the log's metadata, or None.
    with_noise : (its section as written, sensor noise stds (q,)) -> the section for that
        noise, for a method whose own section holds a noise level (`canfdi calibrate` writes
        it). None: the method reads ``noise.measurement`` only.
    fit_models : (k (N,), U (N, p), Z (N, q) healthy samples, config, the method's fit
        options or None, progress) -> (its config section, a JSON-able report with ``path``
        and ``samples``), for a method whose models are its own rather than the config's
        state space (output_error's OE models): `canfdi identify` fits them and writes the
        section. None: identify learns the state-space model.
    schema : the JSON Schema of its own section (`canfdi schema`), made from the tables its
        parse_options checks with. None: any mapping (or its section is a shared one).
    c_tables : config -> the tables of its residual bank and detectors for the C drive loop
        (`canfdi codegen`, canfdi/_c/drive.h): ``coef`` and ``uses`` (S+1, q+p, m), ``sigma``,
        ``delta`` and ``h`` (m,), ``residual_names``; a ConfigError names what of the config
        the C loop cannot run. None: the method does not run on the C loop.
    estimate_history : (config, log contents, accepted event) -> EstimateHistory or None:
        the estimate's trajectory for `canfdi report`, recomputed from the log (its
        ``residuals``, ``samples``, ``accepted`` events; what it cannot do goes to its
        ``notes``). None: the report shows the accepted value only.

    Examples
    --------
    >>> toy = Method(name="toy", summary="a method that never alarms", section=None,
    ...              parse_options=lambda section, config: None, build=lambda config: None)
    >>> toy.fault_kinds, toy.statistic[0]
    (('actuator_bias', 'sensor_bias'), 'PH statistic g')
    >>> get("parity").section, get("parity").fault_kinds
    ('identification', ('actuator_bias', 'actuator_scale', 'sensor_bias'))
    >>> try:
    ...     Method("bad", "", None, lambda s, c: None, lambda c: None, fault_kinds=("drift",))
    ... except ValueError as exc:
    ...     print(exc)
    method bad: fault_kinds must be some of actuator_bias, ..., got ('drift',)
    """

    name: str
    summary: str
    section: str | None
    parse_options: Callable[[Mapping[str, Any] | None, MonitorConfig], Any]
    build: Callable[[MonitorConfig], Diagnoser]
    fault_kinds: tuple[str, ...] = ("actuator_bias", "sensor_bias")
    statistic: tuple[str, str] = ("PH statistic g", "Page-Hinkley statistic")
    describe: Callable[[MonitorConfig], dict | None] | None = None
    estimate_history: Callable[[MonitorConfig, Any, FaultEvent],
                               EstimateHistory | None] | None = None
    with_noise: Callable[[Mapping[str, Any], Any], dict] | None = None
    fit_models: Callable[[np.ndarray, np.ndarray, np.ndarray, MonitorConfig, Any,
                          Callable[[str], None]], tuple[dict, dict]] | None = None
    schema: Mapping[str, Any] | None = None
    c_tables: Callable[[MonitorConfig], Mapping[str, Any]] | None = None

    def __post_init__(self) -> None:
        unknown = set(self.fault_kinds) - set(FAULT_KINDS)
        if unknown or not self.fault_kinds:
            raise ValueError(f"method {self.name}: fault_kinds must be some of "
                             f"{', '.join(FAULT_KINDS)}, got {self.fault_kinds}")


_REGISTRY: dict[str, Method] = {}
_LOADED = False


def register(method: Method) -> Method:
    """Add a method (or replace one of the same name); returns it."""
    if not isinstance(method, Method):
        raise TypeError(f"register: expected a canfdi.methods.Method, got {type(method)}")
    _REGISTRY[method.name] = method
    return method


def _load() -> None:
    global _LOADED
    if _LOADED:
        return
    _LOADED = True
    from canfdi.methods.output_error import METHOD as output_error
    from canfdi.methods.parity import METHOD as parity
    from canfdi.methods.uio import METHOD as uio

    for method in (parity, output_error, uio):
        _REGISTRY.setdefault(method.name, method)
    for entry in entry_points(group=ENTRY_POINT_GROUP):
        try:
            method = entry.load()
        except Exception as exc:  # a broken plug-in must not take the built-ins down
            log.warning("canfdi.methods: entry point %s (%s) failed to load: %s", entry.name,
                        entry.value, exc)
            continue
        if not isinstance(method, Method) or method.name != entry.name:
            log.warning("canfdi.methods: entry point %s is not a Method named %s", entry.value,
                        entry.name)
            continue
        _REGISTRY.setdefault(method.name, method)


def names() -> list[str]:
    """The registered methods' names."""
    _load()
    return list(_REGISTRY)


def get(name: str) -> Method:
    """The method of that name; a ConfigError on ``method`` (with the nearest names) for an
    unknown one."""
    _load()
    try:
        return _REGISTRY[name]
    except (KeyError, TypeError):
        raise unknown_name("method", "method", name, _REGISTRY) from None


def build_diagnoser(config: MonitorConfig) -> Diagnoser:
    """The diagnoser a config describes: its method's, designed and calibrated."""
    return get(config.method).build(config)

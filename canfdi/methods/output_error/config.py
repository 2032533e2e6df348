"""The output_error method's config section (the output-error paper) and its diagnoser builder.

Layout (``canfdi identify`` writes it from a fault-free log)::

    method: output_error
    output_error:
      models:                          # one entry per (output, input) pair
        - {output: T1, input: u1, b: [0.45], f: [-0.85], delay: 1, gain_std: 0.0003}
          # B(q)/F(q) q^-delay; gain_std: its static gain's std from the fit (default 0: exact)
        - {output: T1, input: u3, path: false}                      # no path (also: unlisted)
      operating_point: {u: [...], y: [...]}   # y_hat = y + sum G (u_c - u)
      residual_std: [...]              # per output; default: the config's noise.measurement
      long_run_variance: [...]         # per output, the residual's long-run / plain variance
      gamma: 0.2                       # decision tests (canfdi.methods.output_error.diagnoser)
      kappa: 0.1
      min_samples: 48                  # L - l0: samples after the alarm before deciding
      max_samples: 400
      pre_samples: 10                  # l0
      onset_before: 3
      max_onsets: 10
      max_fit_variance: 4.0
      check_every: 10
      max_hold: 10
      settle: 0.01
      fit: {...}                       # free-form notes of `canfdi identify` (ignored here)

b are the numerator coefficients b_0.., f the denominator coefficients f_1.. of a monic F
(the 1 implied). Page-Hinkley drift and false-alarm interval come from ``detection:``.

Thresholds: the OE residual of a well identified model is the measurement noise itself, white,
so no simulation is needed to calibrate: Siegmund's threshold for the false-alarm interval,
bounded by the same formula on the residual's long-run variance (measured on the
identification data: model error colours the residual), see canfdi.methods.output_error.diagnoser.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from canfdi.core.settings import (
    NUMBER_AS_TEXT,
    ConfigError,
    MonitorConfig,
    Option,
    brief,
    options_schema,
    parse_options,
    unknown_name,
)
from canfdi.methods.output_error.diagnoser import OeSettings, OutputErrorDiagnoser, oe_thresholds
from canfdi.methods.output_error.model import OeModel, OePair

__all__ = ["SCHEMA", "OeOptions", "build", "output_error_section", "parse_output_error"]

SECTION = "output_error"
_SETTINGS = {
    "gamma": Option(float, 1e-9, 1e6), "kappa": Option(float, 1e-9, 1e6),
    "min_samples": Option(int, 1, 10**6), "max_samples": Option(int, 1, 10**7),
    "pre_samples": Option(int, 0, 10**4), "onset_before": Option(int, 0, 10**4),
    "max_onsets": Option(int, 1, 1000), "max_fit_variance": Option(float, 1.0, 1e12),
    "check_every": Option(int, 1, 10**6), "max_hold": Option(int, 0, 10**6),
    "settle": Option(float, 1e-9, 0.5),
}
# Validated here rather than by the option spec: lists and mappings.
_STRUCTURED = ("models", "operating_point", "residual_std", "long_run_variance", "fit")
_NUMBER = Option(float)
_NUMBERS = {"type": "array", "items": {"anyOf": [{"type": "number"}, NUMBER_AS_TEXT]}}
_PAIR = options_schema({"path": Option(bool), "delay": Option(int, 0, 1000),
                        "gain_std": Option(float, lo=0.0)}, nullable=False,
                       extra={"output": {"type": "string"}, "input": {"type": "string"},
                              "b": _NUMBERS, "f": _NUMBERS})
_PAIR["required"] = ["output", "input"]
SCHEMA = options_schema(_SETTINGS, defaults=OeSettings, nullable=False, extra={
    "models": {"type": "array", "minItems": 1, "items": _PAIR},
    "operating_point": {"type": ["object", "null"], "additionalProperties": False,
                        "properties": {"u": _NUMBERS, "y": _NUMBERS}},
    "residual_std": _NUMBERS, "long_run_variance": _NUMBERS,
    "fit": {"description": "free-form notes of `canfdi identify` (not read)"}})
SCHEMA["required"] = ["models"]
"""The ``output_error:`` section's JSON Schema (the method's ``schema``)."""


@dataclass(frozen=True)
class OeOptions:
    """The parsed output_error section: the identified model, the residuals' fault-free
    standard deviations (q,) and long-run variance ratios (q,), the diagnoser's settings.

    Examples
    --------
    >>> from canfdi.methods.output_error.model import OeModel, OePair
    >>> model = OeModel((OePair(0, 0, (0.1,), (-0.9,)),), u0=[0.0], y0=[0.0])
    >>> options = OeOptions(model, sigma=np.array([0.01]), long_run=np.ones(1),
    ...                     settings=OeSettings())
    >>> options.model.static_gains(), options.settings.max_samples
    (array([[1.]]), 400)
    """

    model: OeModel
    sigma: np.ndarray
    long_run: np.ndarray
    settings: OeSettings


def _number(value: Any, field: str) -> float:
    return _NUMBER.check(value, field)


def _numbers(value: Any, field: str, size: int | None = None) -> list[float]:
    if not isinstance(value, list):
        raise ConfigError(field, f"expected a list of numbers, got {brief(value)}")
    out = [_number(v, f"{field}[{i}]") for i, v in enumerate(value)]
    if size is not None and len(out) != size:
        raise ConfigError(field, f"expected {size} values, got {len(out)}")
    return out


def _pair(entry: Any, where: str, inputs: list[str], outputs: list[str]) -> OePair | None:
    if not isinstance(entry, dict):
        raise ConfigError(where, "expected a mapping {output, input, b, f, delay}")
    opts = parse_options(entry, {"path": Option(bool), "delay": Option(int, 0, 1000),
                                 "gain_std": Option(float, lo=0.0)}, where,
                         extra=("output", "input", "b", "f"))
    path = opts.get("path", True)
    for key, names in (("output", outputs), ("input", inputs)):
        if entry.get(key) not in names:
            raise unknown_name(f"{where}.{key}", key, entry.get(key), names)
    if not path:
        return None
    b = _numbers(entry.get("b"), f"{where}.b")
    if not b:
        raise ConfigError(f"{where}.b", "needs at least one coefficient (or path: false)")
    f = _numbers(entry.get("f", []), f"{where}.f")
    delay = opts.get("delay", 1)
    pair = OePair(output=outputs.index(entry["output"]), input=inputs.index(entry["input"]),
                  b=tuple(b), f=tuple(f), delay=delay, gain_std=opts.get("gain_std", 0.0))
    if f and pair.pole_radius >= 1.0:
        raise ConfigError(f"{where}.f", f"F(q) is not stable (a pole of modulus "
                                        f"{pair.pole_radius:.4g}): an OE model must be")
    return pair


def parse_output_error(section: Mapping[str, Any] | None, config: MonitorConfig) -> OeOptions:
    """The config's output_error section, validated; ConfigError naming the field on bad input."""
    sec = section
    if not isinstance(sec, Mapping) or not sec:
        raise ConfigError(SECTION, "missing section (run `canfdi identify` to write it)")
    values = parse_options(sec, _SETTINGS, SECTION, extra=_STRUCTURED)
    inputs, outputs = config.inputs, config.outputs
    models = sec.get("models")
    if not isinstance(models, list) or not models:
        raise ConfigError(f"{SECTION}.models", "expected a non-empty list of pairs")
    pairs, seen = [], set()
    for n, entry in enumerate(models):
        where = f"{SECTION}.models[{n}]"
        pair = _pair(entry, where, inputs, outputs)
        key = (entry["output"], entry["input"])
        if key in seen:
            raise ConfigError(where, f"pair {key[0]} <- {key[1]} given twice")
        seen.add(key)
        if pair is not None:
            pairs.append(pair)
    if not pairs:
        raise ConfigError(f"{SECTION}.models", "no pair has a path")
    op = sec.get("operating_point") or {}
    if not isinstance(op, dict):
        raise ConfigError(f"{SECTION}.operating_point", "expected a mapping {u: [...], y: [...]}")
    parse_options(op, {}, f"{SECTION}.operating_point", extra=("u", "y"))
    u0 = _numbers(op.get("u", [0.0] * len(inputs)), f"{SECTION}.operating_point.u", len(inputs))
    y0 = _numbers(op.get("y", [0.0] * len(outputs)), f"{SECTION}.operating_point.y",
                  len(outputs))
    model = OeModel(pairs=tuple(pairs), u0=np.array(u0), y0=np.array(y0))
    if "residual_std" in sec:
        sigma = np.array(_numbers(sec["residual_std"], f"{SECTION}.residual_std", len(outputs)))
        field = f"{SECTION}.residual_std"
    else:
        sigma = config.design.measurement_std
        field = "noise.measurement"
        if sigma is None:
            raise ConfigError(f"{SECTION}.residual_std",
                              "needed (or noise.measurement): the residuals' noise level")
    if np.any(np.asarray(sigma) <= 0):
        raise ConfigError(field, "every residual standard deviation must be > 0")
    long_run = np.array(_numbers(sec.get("long_run_variance", [1.0] * len(outputs)),
                                 f"{SECTION}.long_run_variance", len(outputs)))
    if np.any(long_run <= 0):
        raise ConfigError(f"{SECTION}.long_run_variance", "ratios must be > 0")
    settings = OeSettings(drift=config.detection.drift,
                          false_alarm_interval=config.detection.false_alarm_interval, **values)
    if settings.max_samples < settings.min_samples:
        raise ConfigError(f"{SECTION}.max_samples",
                          f"must be >= min_samples ({settings.min_samples})")
    return OeOptions(model=model, sigma=np.asarray(sigma, dtype=float), long_run=long_run,
                     settings=settings)


def build(config: MonitorConfig) -> OutputErrorDiagnoser:
    """The the output-error paper diagnoser the config's output_error section describes."""
    opts: OeOptions = config.method_options
    settings = opts.settings
    thresholds = oe_thresholds(settings.drift, settings.false_alarm_interval, opts.long_run)
    return OutputErrorDiagnoser(opts.model, opts.sigma, thresholds, settings, config.inputs,
                                config.outputs)


def output_error_section(model: OeModel, sigma: np.ndarray, long_run: np.ndarray,
                         inputs: list[str], outputs: list[str],
                         fit: dict | None = None, **settings: Any) -> dict:
    """The YAML-ready output_error section of an identified model (pairs without a path are
    listed with ``path: false``)."""
    entries = []
    have = {(pr.output, pr.input): pr for pr in model.pairs}
    for j, out in enumerate(outputs):
        for i, inp in enumerate(inputs):
            pr = have.get((j, i))
            if pr is None:
                entries.append({"output": out, "input": inp, "path": False})
            else:
                entries.append({"output": out, "input": inp,
                                "b": [float(f"{x:.10g}") for x in pr.b],
                                "f": [float(f"{x:.10g}") for x in pr.f], "delay": pr.delay,
                                "gain_std": float(f"{pr.gain_std:.4g}")})
    sec: dict[str, Any] = {
        "models": entries,
        "operating_point": {"u": [float(f"{x:.10g}") for x in model.u0],
                            "y": [float(f"{x:.10g}") for x in model.y0]},
        "residual_std": [float(f"{x:.6g}") for x in sigma],
        "long_run_variance": [float(f"{max(x, 1.0):.4g}") for x in long_run],
    }
    sec.update(settings)
    if fit:
        sec["fit"] = fit
    return sec


def with_noise(section: Mapping[str, Any], std: ArrayLike) -> dict:
    """The section with ``residual_std`` set to the sensors' noise stds (q,): the OE residual
    of a well identified model is the measurement noise itself."""
    out = dict(section or {})
    out["residual_std"] = [float(f"{x:.6g}") for x in np.asarray(std, dtype=float)]
    return out

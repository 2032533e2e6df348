"""The parity method (Chan et al. 2006): fully decoupled parity residuals, Page-Hinkley detection,
identification of every fault hypothesis by recursive least squares, compensation and reset.

Its options are the config's shared ``detection:`` and ``identification:`` sections and the
``design:`` section (window orders); the residual bank is designed from the config's model
(canfdi.core.design), the thresholds calibrated on simulated fault-free residuals
(`calibrate_thresholds`).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from canfdi.core.design import design_bank, design_to_dict
from canfdi.core.records import FaultEvent
from canfdi.core.residuals import ResidualBank
from canfdi.core.settings import ConfigError, MonitorConfig
from canfdi.methods import EstimateHistory, Method
from canfdi.methods.parity.ctables import lagged_steady
from canfdi.methods.parity.diagnoser import ParityDiagnoser, ParitySettings
from canfdi.methods.parity.history import estimate_history
from canfdi.methods.parity.signatures import DRIFTS, signature_columns
from canfdi.methods.parity.thresholds import (
    calibrate_thresholds,
    lagged_covariance,
    long_run_covariance,
    noise_factors,
)

__all__ = ["METHOD", "ParityDiagnoser", "ParitySettings", "build", "calibrate_thresholds"]


def parse_options(section: Mapping[str, Any] | None, config: MonitorConfig) -> ParitySettings:
    """The diagnoser's settings from the config's detection: and identification: sections
    (canfdi.config validated them)."""
    ident = config.identification
    return ParitySettings(
        drift=config.detection.drift,
        false_alarm_interval=config.detection.false_alarm_interval,
        min_samples=ident.min_samples, max_samples=ident.max_samples,
        settle_rel_std=ident.settle_rel_std, settle_noise=ident.settle_noise,
        isolation_margin=ident.isolation_margin,
        max_fit_variance=ident.max_fit_variance, lookback=ident.lookback,
        signature_drifts=DRIFTS if config.detection.signatures else (),
    )


def _design(config: MonitorConfig):
    return design_bank(config.model, config.inputs, config.outputs, config.design)


def build(config: MonitorConfig) -> ParityDiagnoser:
    """Design the residual bank, calibrate its thresholds, build the diagnoser."""
    design = _design(config)
    bank = ResidualBank(design)
    meas = (config.design.measurement_std if config.design.measurement_std is not None
            else np.ones(design.model.q))
    settings = config.method_options or parse_options(None, config)
    signatures = signature_columns(bank, meas, design.input_names, design.output_names,
                                   settings.signature_drifts)
    thresholds = calibrate_thresholds(bank, meas, config.design.process_std, design.model,
                                      settings.drift, settings.false_alarm_interval,
                                      signatures=signatures)
    return ParityDiagnoser(design, settings, thresholds, long_run_covariance(bank, meas),
                           signatures, lagged_covariance(bank, meas))


def c_tables(config: MonitorConfig) -> dict:
    """The residual bank's and detectors' tables for the C drive loop (canfdi codegen): the
    numbers the diagnoser `build` makes runs with. Its signature CUSUMs are not in C.

    Raises
    ------
    ConfigError
        detection.signatures asked for.
    """
    if config.detection.signatures:
        raise ConfigError("detection.signatures", "the signature CUSUMs stay on the gateway: "
                                                  "set it false for the MCU")
    diagnoser = build(config)
    bank = diagnoser.bank
    meas = (config.design.measurement_std if config.design.measurement_std is not None
            else np.ones(bank.q))
    diag = diagnoser.c_tables()
    noise = noise_factors(bank, meas)
    diag["noise"] = noise
    diag["lagged"]["steady"] = lagged_steady(bank, diag["lagged"]["cols"], noise)
    return {"coef": np.asarray(bank.blocks, dtype=float),
            "uses": np.asarray(bank.uses, dtype=np.uint8),
            "sigma": np.asarray(bank.sigma, dtype=float),
            "delta": np.full(bank.m, float(diagnoser.settings.drift)),
            "h": np.asarray(diagnoser.thresholds, dtype=float).reshape(bank.m),
            "residual_names": tuple(diagnoser.residual_names),
            "diag": diag}


def describe(config: MonitorConfig) -> dict:
    """The design (`canfdi design --json`'s object), for the log's metadata."""
    return design_to_dict(_design(config))


def history(config: MonitorConfig, contents: Any, event: FaultEvent) -> EstimateHistory | None:
    """`canfdi report`'s running estimates of an accepted fault (canfdi.methods.parity.history)."""
    try:
        bank = ResidualBank(_design(config))
    except ValueError as exc:
        contents.notes.append(f"{event.target} {event.name}: the config's design fails "
                              f"({exc}): no trajectory")
        return None
    return estimate_history(bank, contents, event)


METHOD = Method(
    name="parity",
    summary="fully decoupled parity equations, Page-Hinkley, RLS identification (Chan et al. 2006)",
    section="identification",
    parse_options=parse_options,
    build=build,
    fault_kinds=("actuator_bias", "actuator_scale", "sensor_bias"),
    describe=describe,
    estimate_history=history,
    c_tables=c_tables,
)

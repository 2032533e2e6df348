"""A grey-box template fitted for `canfdi identify` (``model.identify.template``): the config's
signals given the template's roles, its datasheet values as the start, some held fixed; the
fit by prediction error (canfdi.core.greybox), then the sensors' noise through the fitted
model's parity space, as the black-box path learns it."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from canfdi.core.greybox import get_template
from canfdi.core.model import StateSpace
from canfdi.core.settings import ConfigError, MonitorConfig, unknown_name
from canfdi.core.sysid import IdentifiedModel, first_noise_guess, parity_noise, stack_records
from canfdi.core.unknown_inputs import Record as FitRecord
from canfdi.tools.calibrate import Record

__all__ = ["fit_with_template"]

FIELD = "model.identify.template"


def _roles(config: MonitorConfig, template) -> dict[str, int]:
    """role -> output column: the config's ``roles``, else an output named as the role."""
    spec = config.identify.template
    names = list(template.outputs)
    roles: dict[str, int] = {}
    for role, signal in spec.roles.items():
        if role not in names:
            raise unknown_name(f"{FIELD}.roles.{role}", f"role of template {template.name}",
                               role, names)
        if signal not in config.outputs:
            raise unknown_name(f"{FIELD}.roles.{role}", "output", signal, config.outputs)
        roles[role] = config.outputs.index(signal)
    for role in names:
        if role not in roles and role in config.outputs:
            roles[role] = config.outputs.index(role)
    missing = [r for r in names if r not in roles and r not in template.optional]
    if missing:
        raise ConfigError(f"{FIELD}.roles", f"template {template.name} needs the output playing "
                                            f"{', '.join(missing)} (roles: {{{missing[0]}: "
                                            "<an output>}})")
    return roles


def fit_with_template(records: Sequence[Record], config: MonitorConfig, dt: float,
                      floor: np.ndarray, progress: Callable[[str], None]
                      ) -> tuple[IdentifiedModel, list[str], dict]:
    """(identified model, unknown-input names, the template's report) from the fit records.

    Raises
    ------
    ConfigError : an unknown template, role, parameter or setting (naming the key).
    """
    spec = config.identify.template
    try:
        template = get_template(spec.name)
    except ValueError as exc:
        raise ConfigError(f"{FIELD}.name", str(exc)) from None
    roles = _roles(config, template)
    known = set(template.parameter_names)
    for name in (*spec.parameters, *spec.fixed):
        if name not in known:
            raise unknown_name(f"{FIELD}.parameters.{name}", f"parameter of {template.name}",
                               name, known)
    fits = [FitRecord(r.U, r.Z) for r in records]
    U, Y = stack_records(fits, 2)
    progress(f"fitting template {template.name} by prediction error")
    try:
        fit = fit_template_checked(template, U, Y, roles, dt, spec, floor)
    except ValueError as exc:
        raise ConfigError(FIELD, str(exc)) from None
    model = _pruned(fit)
    window = min(max(model.n, 2), 10)
    prior = np.sqrt(np.maximum(first_noise_guess(fits), floor**2 + 1e-300))
    notes: list[str] = []
    try:
        noise = np.maximum(parity_noise(model, fits, window, prior), floor)
    except ValueError as exc:
        notes.append(f"the noise could not be learned through the parity space ({exc})")
        noise = prior
    undetermined = fit.undetermined
    if undetermined:
        notes.append("not determined by these data (held at their start): "
                     + ", ".join(undetermined))
    table = fit.parameters_table()
    report = {"name": template.name, "settings": fit.settings,
              "parameters": [dict(row, text=_text(row)) for row in table],
              "samples": fit.samples, "iterations": fit.iterations}
    identified = IdentifiedModel(
        model=model, state_names=[config.outputs[roles[r]] for r in fit.states],
        path=f"template {template.name}",
        order=model.n, order_evidence={"visible_order": model.n, "output_eigenvalues": []},
        noise_std=noise, unknown_inputs=model.r, notes=notes,
        details={"template": template.name})
    return identified, list(fit.unknown_inputs), report


PRUNE_T = 3.0
"""A static relation's coefficient within this many of its standard deviations of zero is
zero (as the black-box path prunes): a sensor the data do not tie to another stays apart."""


def _pruned(fit) -> StateSpace:
    """The template's model with its static relations' insignificant coefficients zeroed."""
    import dataclasses

    C = np.array(fit.model.C, dtype=float)
    for row in fit.static_rows:
        small = np.abs(row.row) < PRUNE_T * np.asarray(row.std)
        C[row.column, : len(row.row)] = np.where(small, 0.0, row.row)
    return dataclasses.replace(fit.model, C=C)


def fit_template_checked(template, U, Y, roles, dt, spec, floor):
    """`fit_template` with the config's start values, fixed parameters and settings."""
    from canfdi.core.greybox import fit_template

    return fit_template(template, U, Y, roles, dt, start=dict(spec.parameters) or None,
                        fixed=spec.fixed, settings={k: str(v) for k, v in spec.settings.items()
                                                    if k not in ("fixed",)} or None)


def _text(row: dict) -> str:
    value = row.get("value")
    std = row.get("std")
    unit = row.get("unit", "")
    status = row.get("status", "")
    start = row.get("start")
    core = f"{row['name']:<8} {value:.6g} {unit}"
    if status == "estimated" and std is not None:
        core += f" +/- {std:.2g} (95 %: {row.get('low', float('nan')):.6g} .. " \
                f"{row.get('high', float('nan')):.6g})"
    return f"{core}  [{status}; start {start:.6g}]"

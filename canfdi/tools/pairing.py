"""Which shipped monitor config reads a scenario's bus, and which scenario plays a config's.

A scenario's bus is its bus profile's DBC for its plant and its number of drives
(canfdi.firmware_sim.profiles); a config's is its ``bus.dbc`` and the length of its ``drives:``. The
demo pairs a scenario with a config this way when the user names no config, and the benchmark
a config with a scenario when the user names none.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING

import yaml

if TYPE_CHECKING:
    from canfdi.core.settings import MonitorConfig
    from canfdi.firmware_sim.scenario import Scenario

__all__ = ["NoPairing", "config_bus", "config_for", "scenario_bus", "scenario_for",
           "without_faults"]


class NoPairing(LookupError):
    """No shipped config (or scenario) speaks that bus; the message says what to give."""


def _stem(dbc: str | Path | None) -> str | None:
    return None if dbc is None else Path(str(dbc)).name.removesuffix(".dbc")


def scenario_bus(scenario: Scenario) -> tuple[str | None, int]:
    """(DBC stem, drives) of the bus a scenario plays."""
    from canfdi.firmware_sim.profiles import get_profile

    return get_profile(scenario.profile).dbc(scenario.plant), len(scenario.drives)


def config_bus(config: MonitorConfig) -> tuple[str | None, int]:
    """(DBC stem, drives) of the bus a monitor config reads."""
    return _stem(config.bus.dbc), len(config.drive_list)


def _yaml_bus(path: Path) -> tuple[str | None, int]:
    """`config_bus` from the file alone (no validation: it only ranks candidates)."""
    try:
        data = yaml.safe_load(path.read_text()) or {}
    except (OSError, yaml.YAMLError):
        return None, 0
    bus = data.get("bus") if isinstance(data, dict) else None
    drives = data.get("drives") if isinstance(data, dict) else None
    dbc = bus.get("dbc") if isinstance(bus, dict) else None
    return _stem(dbc), len(drives) if isinstance(drives, list) and drives else 1


def config_for(scenario: Scenario, config_dir: Path) -> Path:
    """The config of ``config_dir`` that reads the scenario's bus: the plant's own config
    (its ``Plant.config``) when it does, else the first by name that does.

    Raises
    ------
    NoPairing : none does.
    """
    want = scenario_bus(scenario)
    own = config_dir / scenario.make_plant().config
    candidates = [own, *sorted(p for p in config_dir.glob("*.yaml") if p != own)]
    for path in candidates:
        if path.exists() and _yaml_bus(path) == want:
            return path
    dbc, drives = want
    raise NoPairing(f"no monitor config in {config_dir} reads {dbc}.dbc with {drives} "
                    f"drive{'s' if drives != 1 else ''} (the bus of scenario {scenario.name}): "
                    f"give one with --config")


def without_faults(scenario: Scenario) -> Scenario:
    """The scenario with no fault on any drive (named so: "<name> without faults")."""
    if not any(d.faults for d in scenario.drives):
        return scenario
    drives = tuple(dataclasses.replace(d, faults=()) for d in scenario.drives)
    return dataclasses.replace(scenario, name=f"{scenario.name} without faults", faults=(),
                               drives=drives)


def scenario_for(config: MonitorConfig, scenario_dir: Path, faults: bool = False) -> Scenario:
    """The shipped scenario that plays the config's bus, by name: a nominal one first and
    every drive of it without its faults; with ``faults``, one whose drives have faults
    (consecutive ones first), as it is.

    Raises
    ------
    NoPairing : none does.
    """
    from canfdi.firmware_sim.scenario import ScenarioError, load_scenario

    want = config_bus(config)
    prefer = "consecutive" if faults else "nominal"
    paths = sorted(scenario_dir.glob("*.yaml"), key=lambda p: (prefer not in p.stem, p.stem))
    for path in paths:
        try:
            scenario = load_scenario(path)
        except ScenarioError:
            continue
        if scenario_bus(scenario) != want:
            continue
        if not faults:
            return without_faults(scenario)
        if any(d.faults for d in scenario.drives):
            return scenario
    dbc, drives = want
    raise NoPairing(f"no scenario in {scenario_dir} plays {dbc}.dbc with {drives} "
                    f"drive{'s' if drives != 1 else ''}{' with faults' if faults else ''}: "
                    f"give one with --scenario")

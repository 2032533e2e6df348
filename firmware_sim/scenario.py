"""Scenarios: YAML files that say which plant runs, for how long, with which noise and faults.

    plant: dc_motor          # dc_motor | winding_machine | vtol
    duration: 60.0           # seconds
    seed: 1
    noise: {measurement: 0.01, process: 0.0}   # standard deviations; plant defaults if absent
    faults:
      - {target: actuator, index: 0, onset: 10.0, eta: 2.0, lambda: 10.0}
      - {target: sensor, index: 1, onset: 40.0, bias: 3.5}
      - {target: sensor, index: 2, onset: 70.0, kind: drift, rate: 0.05}

Optional: ``name``, ``description``. A fault's ``kind`` defaults to ``scale_bias`` for
actuators and ``bias`` for sensors; ``end`` (seconds) repairs it. Every error names its field,
e.g. ``faults[1].index``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from canfdi.config import read_yaml
from firmware_sim.faults import ACTUATOR_KINDS, SENSOR_KINDS, Fault
from firmware_sim.plants import PLANTS, Plant, make_plant

__all__ = ["SCENARIO_DIR", "Scenario", "ScenarioError", "load_scenario", "parse_scenario"]

SCENARIO_DIR = Path(__file__).resolve().parent / "scenarios"

# Parameters each kind takes, with the one that must be given (None: all optional).
_PARAMS = {
    ("actuator", "scale_bias"): ({"eta", "lambda"}, None),
    ("actuator", "stuck"): ({"value"}, None),
    ("sensor", "bias"): ({"bias"}, "bias"),
    ("sensor", "drift"): ({"rate"}, "rate"),
    ("sensor", "stuck"): ({"value"}, None),
    ("sensor", "scale"): ({"scale"}, "scale"),
    ("sensor", "noise"): ({"std"}, "std"),
}


class ScenarioError(ValueError):
    """A scenario problem; ``field`` is the dotted path of the offending key."""

    def __init__(self, field: str, message: str) -> None:
        super().__init__(f"{field}: {message}")
        self.field = field


@dataclass(frozen=True)
class Scenario:
    """A validated scenario.

    measurement_std : (q,); process_std : (n,); faults in the order given.
    """

    name: str
    description: str
    plant: str
    duration: float
    seed: int
    measurement_std: np.ndarray
    process_std: np.ndarray
    faults: tuple[Fault, ...]
    path: Path | None = None

    def make_plant(self) -> Plant:
        return make_plant(self.plant)


def _number(value: Any, field: str, minimum: float | None = None, strict: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not np.isfinite(value):
        raise ScenarioError(field, f"expected a number, got {value!r}")
    if minimum is not None and (value < minimum or (strict and value == minimum)):
        op = ">" if strict else ">="
        raise ScenarioError(field, f"must be {op} {minimum}, got {value}")
    return float(value)


def _stds(value: Any, field: str, size: int, default: np.ndarray) -> np.ndarray:
    if value is None:
        return np.array(default, dtype=float)
    if isinstance(value, list):
        if len(value) != size:
            raise ScenarioError(field, f"expected {size} values, got {len(value)}")
        return np.array([_number(v, f"{field}[{i}]", 0.0) for i, v in enumerate(value)])
    return np.full(size, _number(value, field, 0.0))


def _fault(data: Any, where: str, plant: Plant, duration: float) -> Fault:
    if not isinstance(data, dict):
        raise ScenarioError(where, "expected a mapping like {target: sensor, index: 0, ...}")
    target = data.get("target")
    if target not in ("actuator", "sensor"):
        raise ScenarioError(f"{where}.target", f"must be 'actuator' or 'sensor', got {target!r}")
    kinds = ACTUATOR_KINDS if target == "actuator" else SENSOR_KINDS
    kind = data.get("kind", kinds[0])
    if kind not in kinds:
        raise ScenarioError(f"{where}.kind", f"must be one of {', '.join(kinds)} for {target}s, "
                                             f"got {kind!r}")
    allowed, required = _PARAMS[(target, kind)]
    unknown = set(data) - {"target", "kind", "index", "onset", "end"} - allowed
    if unknown:
        key = sorted(unknown)[0]
        raise ScenarioError(f"{where}.{key}", f"not a parameter of a {target} {kind} fault "
                                              f"(allowed: {', '.join(sorted(allowed))})")
    if required and required not in data:
        raise ScenarioError(f"{where}.{required}", f"missing (a {kind} fault needs it)")
    count = plant.p if target == "actuator" else plant.q
    index = data.get("index")
    if isinstance(index, bool) or not isinstance(index, int) or not 0 <= index < count:
        names = plant.input_names if target == "actuator" else plant.output_names
        raise ScenarioError(f"{where}.index", f"must be an integer in [0, {count}) for "
                                              f"{plant.name} ({', '.join(names)}), got {index!r}")
    if "onset" not in data:
        raise ScenarioError(f"{where}.onset", "missing (seconds)")
    onset = _number(data["onset"], f"{where}.onset", 0.0)
    if onset >= duration:
        raise ScenarioError(f"{where}.onset", f"{onset} s is not before the end of the "
                                              f"scenario ({duration} s)")
    end = None
    if data.get("end") is not None:
        end = _number(data["end"], f"{where}.end", 0.0)
        if end <= onset:
            raise ScenarioError(f"{where}.end", f"must be after the onset ({onset} s), got {end}")
    params = {key: _number(data[key], f"{where}.{key}") for key in allowed if key in data}
    if "std" in params and params["std"] < 0:
        raise ScenarioError(f"{where}.std", "must be >= 0")
    if "lambda" in params:
        params["lam"] = params.pop("lambda")
    return Fault(target=target, index=index, kind=kind, onset=onset, end=end, **params)


def parse_scenario(data: Any, path: Path | None = None) -> Scenario:
    """Validate a loaded YAML document and build a Scenario."""
    if not isinstance(data, dict):
        raise ScenarioError("(top level)", "expected a mapping")
    allowed = {"name", "description", "plant", "duration", "seed", "noise", "faults"}
    for key in data:
        if key not in allowed:
            raise ScenarioError(str(key), f"unknown key (allowed: {', '.join(sorted(allowed))})")
    plant_name = data.get("plant")
    if plant_name not in PLANTS:
        raise ScenarioError("plant", f"unknown plant {plant_name!r} (known: {', '.join(PLANTS)})")
    plant = make_plant(plant_name)
    if "duration" not in data:
        raise ScenarioError("duration", "missing (seconds)")
    duration = _number(data["duration"], "duration", 0.0, strict=True)
    seed = data.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ScenarioError("seed", f"expected an integer >= 0, got {seed!r}")
    noise = data.get("noise") or {}
    if not isinstance(noise, dict):
        raise ScenarioError("noise", "expected a mapping {measurement: ..., process: ...}")
    for key in noise:
        if key not in ("measurement", "process"):
            raise ScenarioError(f"noise.{key}", "unknown key (allowed: measurement, process)")
    defaults = plant.noise_defaults()
    meas = _stds(noise.get("measurement"), "noise.measurement", plant.q, defaults.measurement)
    proc = _stds(noise.get("process"), "noise.process", plant.n, defaults.process)
    faults_data = data.get("faults") or []
    if not isinstance(faults_data, list):
        raise ScenarioError("faults", "expected a list of faults")
    faults = tuple(_fault(f, f"faults[{i}]", plant, duration) for i, f in enumerate(faults_data))
    name = data.get("name", path.stem if path else plant_name)
    description = data.get("description", "")
    if not isinstance(name, str) or not isinstance(description, str):
        raise ScenarioError("name" if not isinstance(name, str) else "description",
                            "expected a string")
    return Scenario(name=name, description=description, plant=plant_name, duration=duration,
                    seed=seed, measurement_std=meas, process_std=proc, faults=faults, path=path)


def load_scenario(path: str | Path) -> Scenario:
    """Read and validate a scenario file; a bare name is looked up in firmware_sim/scenarios."""
    path = Path(path)
    if not path.exists() and not path.suffix and (SCENARIO_DIR / f"{path}.yaml").exists():
        path = SCENARIO_DIR / f"{path}.yaml"
    data = read_yaml(path, ScenarioError, "scenario")
    return parse_scenario(data, path)

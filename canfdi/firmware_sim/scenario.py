"""Scenarios: YAML files that say which plant runs, for how long, with which noise and faults.

    plant: dc_motor          # dc_motor | winding_machine | vtol | servo_axis
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

The plant's own options (optional; only plants that take some, firmware_sim.plants), passed to
its constructor; an unknown option or a bad value is an error naming ``plant_options.<key>``:

    plant: servo_axis
    plant_options: {reference: commissioning, load_seed: 1}

The bus (optional): which bus profile the drive speaks (canfdi/firmware_sim/profiles: canfdi by
default, cia402, float_node) and its node ID (default: the profile's; canfdi has none):

    bus: {profile: cia402, node: 1}

Several drives of the same plant on one bus (optional): each with its name, node ID, faults
and seed offset (default: its index; its run uses seed + seed_offset). With ``drives:`` the
top-level ``faults`` and ``bus.node`` are not used (each drive says its own):

    bus: {profile: cia402}
    drives:
      - {name: left, node: 1, faults: [{target: actuator, index: 0, onset: 10.0, eta: 2.0}]}
      - {name: right, node: 2}

A scenario without ``drives:`` is one drive, named after the scenario, with the top-level
faults.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from canfdi.config import read_yaml
from canfdi.firmware_sim.faults import ACTUATOR_KINDS, SENSOR_KINDS, Fault
from canfdi.firmware_sim.plants import PLANTS, Plant, PlantOptionError, make_plant
from canfdi.firmware_sim.profiles import DEFAULT_PROFILE, PROFILES, BusProfile, get_profile

__all__ = ["MAX_DRIVES", "SCENARIO_DIR", "Drive", "Scenario", "ScenarioError", "load_scenario",
           "parse_scenario"]

MAX_DRIVES = 8
"""Drives on one bus at most (as many as one monitor diagnoses)."""

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
class Drive:
    """One drive on the scenario's bus.

    name : unique in the scenario; node : its node ID (None: the profile has none);
    faults : its fault schedule; seed_offset : its run uses the scenario's seed plus this.
    """

    name: str
    node: int | None
    faults: tuple[Fault, ...] = ()
    seed_offset: int = 0


@dataclass(frozen=True)
class Scenario:
    """A validated scenario.

    measurement_std : (q,); process_std : (n,); faults in the order given (the one drive's;
    empty with several drives: each has its own, in ``drives``). profile : the bus profile's
    name; drives : the drives on the bus (one, named after the scenario, when the YAML has no
    ``drives:``); plant_options : the plant's options (``plant_options:``), which
    `make_plant` passes to the plant: build the scenario's plant with it, never by name alone.
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
    profile: str = DEFAULT_PROFILE
    drives: tuple[Drive, ...] = ()
    plant_options: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not self.drives:
            node = get_profile(self.profile).default_node
            object.__setattr__(self, "drives", (Drive(self.name, node, self.faults),))

    def make_plant(self) -> Plant:
        """A fresh plant of the scenario, with its ``plant_options``."""
        return make_plant(self.plant, self.plant_options)

    def drive_scenario(self, index: int) -> Scenario:
        """Drive ``index`` alone: its faults, run with the seed plus its seed offset (the
        scenario itself, for a scenario of one drive with offset 0)."""
        drive = self.drives[index]
        return dataclasses.replace(self, seed=self.seed + drive.seed_offset,
                                   faults=drive.faults, drives=(drive,))


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
    allowed = {"name", "description", "plant", "plant_options", "duration", "seed", "noise",
               "faults", "bus", "drives"}
    for key in data:
        if key not in allowed:
            raise ScenarioError(str(key), f"unknown key (allowed: {', '.join(sorted(allowed))})")
    plant_name, plant_options, plant = _plant(data)
    if "duration" not in data:
        raise ScenarioError("duration", "missing (seconds)")
    duration = _number(data["duration"], "duration", 0.0, strict=True)
    seed = data.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ScenarioError("seed", f"expected an integer >= 0, got {seed!r}")
    meas, proc = _noise(data.get("noise") or {}, plant)
    faults_data = data.get("faults") or []
    if not isinstance(faults_data, list):
        raise ScenarioError("faults", "expected a list of faults")
    faults = tuple(_fault(f, f"faults[{i}]", plant, duration) for i, f in enumerate(faults_data))
    name = data.get("name", path.stem if path else plant_name)
    description = data.get("description", "")
    if not isinstance(name, str) or not isinstance(description, str):
        raise ScenarioError("name" if not isinstance(name, str) else "description",
                            "expected a string")
    profile, node = _bus(data.get("bus"), plant_name)
    if data.get("drives") is None:
        drives = (Drive(name=name, node=profile.default_node if node is None else node,
                        faults=faults),)
    else:
        _refuse_single_drive_keys(faults, node)
        drives = _drives(data["drives"], profile, plant, duration)
        faults = ()
    return Scenario(name=name, description=description, plant=plant_name, duration=duration,
                    seed=seed, measurement_std=meas, process_std=proc, faults=faults, path=path,
                    profile=profile.name, drives=drives, plant_options=dict(plant_options))


def _plant(data: dict) -> tuple[str, dict, Plant]:
    """The ``plant:`` and its ``plant_options:``: (name, options, a fresh plant)."""
    plant_name = data.get("plant")
    if plant_name not in PLANTS:
        raise ScenarioError("plant", f"unknown plant {plant_name!r} (known: {', '.join(PLANTS)})")
    plant_options = data.get("plant_options") or {}
    if not isinstance(plant_options, dict):
        raise ScenarioError("plant_options", f"expected a mapping like {{option: value}}, got "
                                             f"{plant_options!r}")
    try:
        plant = make_plant(plant_name, plant_options)
    except PlantOptionError as exc:
        message = str(exc).removeprefix(f"{exc.option}: ")
        raise ScenarioError(f"plant_options.{exc.option}", message) from None
    return plant_name, plant_options, plant


def _noise(noise: Any, plant: Plant) -> tuple[np.ndarray, np.ndarray]:
    """The ``noise:`` section: (measurement, process) standard deviations, the plant's defaults
    where it names none."""
    if not isinstance(noise, dict):
        raise ScenarioError("noise", "expected a mapping {measurement: ..., process: ...}")
    for key in noise:
        if key not in ("measurement", "process"):
            raise ScenarioError(f"noise.{key}", "unknown key (allowed: measurement, process)")
    defaults = plant.noise_defaults()
    meas = _stds(noise.get("measurement"), "noise.measurement", plant.q, defaults.measurement)
    proc = _stds(noise.get("process"), "noise.process", plant.n, defaults.process)
    return meas, proc


def _refuse_single_drive_keys(faults: tuple[Fault, ...], node: int | None) -> None:
    """With ``drives:``, the top level's ``faults:`` and ``bus.node`` are each drive's own."""
    if faults:
        raise ScenarioError("faults", "not used with drives: (each drive lists its own "
                                      "faults, drives[i].faults)")
    if node is not None:
        raise ScenarioError("bus.node", "not used with drives: (each drive names its "
                                        "node, drives[i].node)")


def _bus(data: Any, plant_name: str) -> tuple[BusProfile, int | None]:
    """The ``bus:`` section: (profile, node or None)."""
    if data is None:
        data = {}  # the default profile, which must cover the plant too
    if not isinstance(data, dict):
        raise ScenarioError("bus", "expected a mapping like {profile: cia402, node: 1}")
    for key in data:
        if key not in ("profile", "node"):
            raise ScenarioError(f"bus.{key}", "unknown key (allowed: node, profile)")
    try:
        profile = get_profile(data.get("profile", DEFAULT_PROFILE))
    except ValueError as exc:
        raise ScenarioError("bus.profile", str(exc)) from None
    if profile.dbc(plant_name) is None:
        covering = [p.name for p in PROFILES.values() if p.dbc(plant_name) is not None]
        raise ScenarioError("bus.profile", f"the {profile.name} profile has no DBC for plant "
                                           f"{plant_name} (profiles for {plant_name}: "
                                           f"{', '.join(covering)})")
    node = None if data.get("node") is None else _node(data["node"], "bus.node", profile)
    return profile, node


def _node(value: Any, field: str, profile: BusProfile) -> int:
    if profile.nodes is None:
        raise ScenarioError(field, f"the {profile.name} profile has no node IDs (one drive per "
                                   "bus, the DBC's IDs as written)")
    lo, hi = profile.nodes
    if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
        raise ScenarioError(field, f"a {profile.name} node ID is an integer in {lo}..{hi}, got "
                                   f"{value!r}")
    return value


def _drives(data: Any, profile: BusProfile, plant: Plant, duration: float
            ) -> tuple[Drive, ...]:
    """The ``drives:`` list."""
    if not isinstance(data, list) or not data:
        raise ScenarioError("drives", "expected a non-empty list like [{name: left, node: 1}]")
    if len(data) > 1 and profile.nodes is None:
        raise ScenarioError("drives", f"the {profile.name} profile carries one drive per bus "
                                      "(its frames have no node IDs); choose bus.profile "
                                      "cia402 or float_node for several")
    if len(data) > MAX_DRIVES:
        raise ScenarioError("drives", f"at most {MAX_DRIVES} drives on one bus, got {len(data)}")
    drives: list[Drive] = []
    for i, item in enumerate(data):
        where = f"drives[{i}]"
        if not isinstance(item, dict):
            raise ScenarioError(where, "expected a mapping like {name: left, node: 1}")
        for key in item:
            if key not in ("name", "node", "faults", "seed_offset"):
                raise ScenarioError(f"{where}.{key}", "unknown key (allowed: faults, name, "
                                                      "node, seed_offset)")
        name = item.get("name")
        if not isinstance(name, str) or not name:
            raise ScenarioError(f"{where}.name", f"expected a non-empty string, got {name!r}")
        if name in {d.name for d in drives}:
            raise ScenarioError(f"{where}.name", f"{name!r} names an earlier drive too")
        node = _drive_node(item.get("node"), f"{where}.node", profile, {d.node for d in drives})
        faults_data = item.get("faults") or []
        if not isinstance(faults_data, list):
            raise ScenarioError(f"{where}.faults", "expected a list of faults")
        faults = tuple(_fault(f, f"{where}.faults[{j}]", plant, duration)
                       for j, f in enumerate(faults_data))
        offset = item.get("seed_offset", i)
        if isinstance(offset, bool) or not isinstance(offset, int) or offset < 0:
            raise ScenarioError(f"{where}.seed_offset", f"expected an integer >= 0, got "
                                                        f"{offset!r}")
        drives.append(Drive(name=name, node=node, faults=faults, seed_offset=offset))
    return tuple(drives)


def _drive_node(value: Any, field: str, profile: BusProfile, taken: set[int | None]
                ) -> int | None:
    """A drive's ``node:``: required and unique where the profile has node IDs; None where it
    has none (a node given there is refused as `_node` refuses it)."""
    if profile.nodes is None:
        if value is not None:
            _node(value, field, profile)
        return None
    if value is None:
        raise ScenarioError(field, f"missing (the drive's node ID, "
                                   f"{profile.nodes[0]}..{profile.nodes[1]})")
    node = _node(value, field, profile)
    if node in taken:
        raise ScenarioError(field, f"node {node} is an earlier drive's too")
    return node


def load_scenario(path: str | Path) -> Scenario:
    """Read and validate a scenario file; a bare name is looked up in the shipped scenarios/."""
    path = Path(path)
    if not path.exists() and not path.suffix and (SCENARIO_DIR / f"{path}.yaml").exists():
        path = SCENARIO_DIR / f"{path}.yaml"
    data = read_yaml(path, ScenarioError, "scenario")
    return parse_scenario(data, path)

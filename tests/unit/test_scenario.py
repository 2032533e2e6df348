"""Scenario validation: every error names its field."""

import pytest

from firmware_sim.scenario import SCENARIO_DIR, ScenarioError, load_scenario, parse_scenario

BASE = {"plant": "dc_motor", "duration": 20.0, "seed": 1}


def _with(**changes):
    return {**BASE, **changes}


@pytest.mark.parametrize(
    ("data", "field"),
    [
        (_with(plant="steam_engine"), "plant"),
        ({"plant": "dc_motor"}, "duration"),
        (_with(duration=-1.0), "duration"),
        (_with(seed=-3), "seed"),
        (_with(noise={"measurement": [0.1, 0.1]}), "noise.measurement"),
        (_with(noise={"measurement": -0.1}), "noise.measurement"),
        (_with(noise={"jitter": 1}), "noise.jitter"),
        (_with(faults=[{"target": "sensor", "index": 7, "onset": 1.0, "bias": 1}]),
         "faults[0].index"),
        (_with(faults=[{"target": "actuator", "index": 1, "onset": 1.0, "eta": 2}]),
         "faults[0].index"),
        (_with(faults=[{"target": "sensor", "index": 0, "onset": -1.0, "bias": 1}]),
         "faults[0].onset"),
        (_with(faults=[{"target": "sensor", "index": 0, "onset": 30.0, "bias": 1}]),
         "faults[0].onset"),
        (_with(faults=[{"target": "sensor", "index": 0, "onset": 5.0, "end": 4.0, "bias": 1}]),
         "faults[0].end"),
        (_with(faults=[{"target": "valve", "index": 0, "onset": 1.0}]), "faults[0].target"),
        (_with(faults=[{"target": "sensor", "index": 0, "onset": 1.0, "kind": "melt"}]),
         "faults[0].kind"),
        (_with(faults=[{"target": "sensor", "index": 0, "onset": 1.0, "kind": "drift"}]),
         "faults[0].rate"),
        (_with(faults=[{"target": "sensor", "index": 0, "onset": 1.0, "bias": 1, "eta": 2}]),
         "faults[0].eta"),
        (_with(faults=[{"target": "sensor", "index": 0, "onset": 1.0, "bias": "big"}]),
         "faults[0].bias"),
        (_with(faults=[{}, {"target": "sensor", "index": 0, "bias": 1}]), "faults[0].target"),
        (_with(faults=[{"target": "sensor", "index": 0, "bias": 1}]), "faults[0].onset"),
        (_with(color="red"), "color"),
    ],
)
def test_errors_name_the_field(data, field):
    with pytest.raises(ScenarioError) as err:
        parse_scenario(data)
    assert err.value.field == field


def test_shipped_scenarios_load():
    names = sorted(p.stem for p in SCENARIO_DIR.glob("*.yaml"))
    for required in ("dc_motor_actuator", "dc_motor_sensors_a", "dc_motor_sensors_b",
                     "dc_motor_consecutive"):
        assert required in names
    plants = set()
    for name in names:
        sc = load_scenario(name)
        plants.add(sc.plant)
        if not sc.faults:
            plants.add(f"{sc.plant}:fault-free")
    for plant in ("dc_motor", "winding_machine", "vtol"):
        assert f"{plant}:fault-free" in plants, f"no fault-free scenario for {plant}"
    consecutive = load_scenario("dc_motor_consecutive")
    assert len({(f.target, f.index) for f in consecutive.faults}) >= 3
    assert all(f.end is None for f in consecutive.faults)


def test_issue_example_parses_with_defaults():
    sc = parse_scenario({"plant": "dc_motor", "duration": 60.0, "seed": 1,
                         "noise": {"measurement": 0.01, "process": 0.0},
                         "faults": [
                             {"target": "actuator", "index": 0, "onset": 10.0, "eta": 2.0,
                              "lambda": 10.0},
                             {"target": "sensor", "index": 1, "onset": 40.0, "bias": 3.5},
                             {"target": "sensor", "index": 2, "onset": 50.0, "kind": "drift",
                              "rate": 0.05}]})
    a, b, c = sc.faults
    assert (a.kind, a.eta, a.lam) == ("scale_bias", 2.0, 10.0)
    assert (b.kind, b.bias) == ("bias", 3.5) and (c.kind, c.rate) == ("drift", 0.05)
    assert sc.measurement_std.shape == (4,) and sc.process_std.shape == (3,)


def test_missing_file_names_it(tmp_path):
    with pytest.raises(ScenarioError, match="file not found"):
        load_scenario(tmp_path / "none.yaml")

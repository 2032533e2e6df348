"""Scenario validation: every error names its field."""

import pytest

from canfdi.firmware_sim.scenario import SCENARIO_DIR, ScenarioError, load_scenario, parse_scenario

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
    for plant in ("dc_motor", "winding_machine", "vtol", "servo_axis"):
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


# --- bus: and drives: -------------------------------------------------------------------------

CIA = {**BASE, "bus": {"profile": "cia402"}}
FAULT = {"target": "sensor", "index": 0, "onset": 1.0, "bias": 1}


@pytest.mark.parametrize(
    ("data", "field", "words"),
    [
        (_with(bus="cia402"), "bus", "mapping"),
        (_with(bus={"profile": "cia401"}), "bus.profile", "cia402"),
        (_with(bus={"profile": "canopen"}), "bus.profile", "known: canfdi, cia402, float_node"),
        ({**BASE, "plant": "vtol", "bus": {"profile": "cia402"}}, "bus.profile",
         "profiles for vtol: canfdi"),
        # The servo axis has no DBC of the default (canfdi) bus, with or without a bus section.
        ({**BASE, "plant": "servo_axis"}, "bus.profile", "profiles for servo_axis: float_node"),
        ({**BASE, "plant": "servo_axis", "bus": {"profile": "cia402"}}, "bus.profile",
         "profiles for servo_axis: float_node"),
        (_with(bus={"profile": "cia402", "node": 0}), "bus.node", "1..127"),
        (_with(bus={"profile": "cia402", "node": 128}), "bus.node", "1..127"),
        (_with(bus={"profile": "float_node", "node": 63}), "bus.node", "0..62"),
        (_with(bus={"profile": "cia402", "node": True}), "bus.node", "integer"),
        (_with(bus={"node": 1}), "bus.node", "no node IDs"),
        (_with(bus={"profile": "cia402", "bitrate": 500000}), "bus.bitrate", "unknown key"),
        ({**CIA, "drives": {"name": "left"}}, "drives", "list"),
        ({**CIA, "drives": []}, "drives", "list"),
        ({**CIA, "drives": ["left"]}, "drives[0]", "mapping"),
        ({**CIA, "drives": [{"node": 1}]}, "drives[0].name", "string"),
        ({**CIA, "drives": [{"name": "a"}]}, "drives[0].node", "missing"),
        ({**CIA, "drives": [{"name": "a", "node": 1}, {"name": "a", "node": 2}]},
         "drives[1].name", "earlier"),
        ({**CIA, "drives": [{"name": "a", "node": 1}, {"name": "b", "node": 1}]},
         "drives[1].node", "earlier"),
        ({**CIA, "drives": [{"name": "a", "node": 1}, {"name": "b", "node": 300}]},
         "drives[1].node", "1..127"),
        ({**CIA, "drives": [{"name": "a", "node": 1, "color": "red"}]}, "drives[0].color",
         "unknown key"),
        ({**CIA, "drives": [{"name": "a", "node": 1, "faults": [{**FAULT, "index": 9}]}]},
         "drives[0].faults[0].index", "integer"),
        ({**CIA, "drives": [{"name": "a", "node": 1, "faults": FAULT}]}, "drives[0].faults",
         "list"),
        ({**CIA, "drives": [{"name": "a", "node": 1, "seed_offset": -1}]},
         "drives[0].seed_offset", "integer"),
        ({**CIA, "faults": [FAULT], "drives": [{"name": "a", "node": 1}]}, "faults",
         "drives[i].faults"),
        ({**BASE, "bus": {"profile": "cia402", "node": 3}, "drives": [{"name": "a", "node": 1}]},
         "bus.node", "drives[i].node"),
        (_with(drives=[{"name": "a"}, {"name": "b"}]), "drives", "one drive per bus"),
        (_with(drives=[{"name": "a", "node": 1}]), "drives[0].node", "no node IDs"),
        ({**CIA, "drives": [{"name": f"d{i}", "node": i + 1} for i in range(9)]}, "drives",
         "at most 8"),
    ],
)
def test_bus_and_drives_errors_name_the_field(data, field, words):
    with pytest.raises(ScenarioError) as err:
        parse_scenario(data)
    assert err.value.field == field
    assert words in str(err.value)


def test_a_scenario_without_bus_is_one_canfdi_drive_named_after_it():
    sc = parse_scenario({**BASE, "name": "x", "faults": [FAULT]})
    assert sc.profile == "canfdi"
    assert [(d.name, d.node, d.seed_offset) for d in sc.drives] == [("x", None, 0)]
    assert sc.drives[0].faults == sc.faults and len(sc.faults) == 1
    assert sc.drive_scenario(0) == sc


@pytest.mark.parametrize(("profile", "node"), [("cia402", 1), ("float_node", 0)])
def test_a_profile_without_node_takes_its_default(profile, node):
    sc = parse_scenario({**BASE, "bus": {"profile": profile}})
    assert sc.profile == profile and sc.drives[0].node == node
    assert parse_scenario({**BASE, "bus": {"profile": profile, "node": 7}}).drives[0].node == 7


def test_issue_example_with_two_drives():
    sc = parse_scenario({"plant": "dc_motor", "duration": 60.0, "seed": 1,
                         "bus": {"profile": "cia402"},
                         "drives": [
                             {"name": "left", "node": 1, "faults": [
                                 {"target": "actuator", "index": 0, "onset": 10.0, "eta": 2.0,
                                  "lambda": 10.0}]},
                             {"name": "right", "node": 2}]})
    assert sc.faults == ()
    left, right = sc.drives
    assert (left.name, left.node, left.seed_offset, len(left.faults)) == ("left", 1, 0, 1)
    assert (right.name, right.node, right.seed_offset, right.faults) == ("right", 2, 1, ())
    assert sc.drive_scenario(1).seed == 2 and sc.drive_scenario(1).faults == ()
    assert sc.drive_scenario(0).faults == left.faults
    from canfdi.firmware_sim.simulate import Simulator

    with pytest.raises(ValueError, match=r"drive_scenario"):
        Simulator(sc)


def test_shipped_profile_scenarios():
    cia = load_scenario("dc_motor_consecutive_cia402")
    flt = load_scenario("dc_motor_consecutive_float")
    base = load_scenario("dc_motor_consecutive")
    assert (cia.profile, cia.drives[0].node) == ("cia402", 1)
    assert (flt.profile, flt.drives[0].node) == ("float_node", 0)
    for sc in (cia, flt):
        assert (sc.seed, sc.duration, sc.faults) == (base.seed, base.duration, base.faults)
    two = load_scenario("dc_motor_two_drives_cia402")
    assert two.profile == "cia402" and [d.node for d in two.drives] == [1, 2]
    assert two.drives[0].faults == base.faults and two.drives[1].faults == ()

import textwrap

import pytest
import yaml

from canfdi.config import ConfigError, load_config, parse_config
from tests.conftest import REPO

BASE = {
    "model": {"A": [[0.5]], "B": [[1.0]], "C": [[1.0], [2.0]]},
    "signals": {"inputs": ["u"], "outputs": ["y1", "y2"]},
}


def _with(path, value):
    import copy

    data = copy.deepcopy(BASE)
    node = data
    keys = path.split(".")
    for k in keys[:-1]:
        node = node.setdefault(k, {})
    node[keys[-1]] = value
    return data


def test_shipped_configs_load():
    for name in ("dc_motor", "inverted_pendulum"):
        cfg = load_config(REPO / "deploy" / "config" / f"{name}.yaml")
        assert cfg.name == name
    dc = load_config(REPO / "deploy" / "config" / "dc_motor.yaml")
    assert dc.model.B[1, 0] == 0.0823 and dc.design.sensor_window == 4


@pytest.mark.parametrize(
    ("path", "value", "field"),
    [
        ("model.B", [[1.0, 2.0, 3.0], [1, 1, 1]], "model.B"),
        ("model.time", "sometimes", "model.time"),
        ("signals.outputs", ["y1"], "signals.outputs"),
        ("signals.inputs", ["u", "u"], "signals.inputs"),
        ("noise.measurement", [0.1, 0.1, 0.1], "noise.measurement"),
        ("noise.measurement", -1.0, "noise.measurement"),
        ("design.sensor_window", -1, "design.sensor_window"),
        ("design.actuator_window", "big", "design.actuator_window"),
        ("design.max_window", 99, "design.max_window"),
        ("design.windw", 3, "design.windw"),
        ("extra", 1, "extra"),
    ],
)
def test_bad_fields_are_named(path, value, field):
    with pytest.raises(ConfigError) as err:
        parse_config(_with(path, value))
    assert err.value.field == field


def test_missing_file_and_bad_yaml(tmp_path):
    with pytest.raises(ConfigError, match="file not found"):
        load_config(tmp_path / "nope.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text(textwrap.dedent("model: [1, 2\n"))
    with pytest.raises(ConfigError, match="invalid YAML at line"):
        load_config(bad)


# -- the bus section for real drives (docs/bus.md) ----------------------------------------------


CONFIG = REPO / "deploy" / "config" / "dc_motor.yaml"


def _with_bus(tmp_path, bus: dict, drives=None):
    data = yaml.safe_load(CONFIG.read_text())
    data["bus"] = {**data["bus"], **bus}
    if drives is not None:
        data["drives"] = drives
    return parse_config(data, CONFIG)


def test_the_bus_section_parses_map_e2e_clock_node_monitor_and_drives(tmp_path):
    config = _with_bus(tmp_path, {
        "map": {"V": "DRIVE_CMD.V", "i_f": {"message": 0x105, "signal": "i_f"}},
        "e2e": {"default": "none", "messages": {"DRIVE_CMD": "canfdi"}},
        "clock": {"kind": "trigger", "message": "SYNC", "max_age": 0.02},
        "node": {"id": "(id & ~0x7F) | node", "shared": ["SYNC", 0x80]},
        "monitor": {"base": 0x6E0, "e2e": "none"},
        "transmit": False, "canopen": True,
    }, drives=[{"name": "left", "node": 1}, {"name": "right", "node": 2}])
    bus = config.bus
    assert str(bus.map["V"]) == "DRIVE_CMD.V" and str(bus.map["i_f"]) == "0x105.i_f"
    assert bus.e2e.default == "none" and bus.e2e.messages == {"DRIVE_CMD": "canfdi"}
    assert (bus.clock.kind, bus.clock.message, bus.clock.max_age) == ("trigger", "SYNC", 0.02)
    assert bus.node_id == "(id & ~0x7F) | node" and bus.monitor.base == 0x6E0
    assert bus.node_shared == ("SYNC", 0x80)
    assert (bus.transmit, bus.canopen) == (False, True)
    assert [(d.name, d.node) for d in config.drive_list] == [("left", 1), ("right", 2)]


def test_without_drives_the_config_is_one_drive_named_after_it(tmp_path):
    config = _with_bus(tmp_path, {})
    assert [(d.name, d.node) for d in config.drive_list] == [("dc_motor", None)]


@pytest.mark.parametrize(("bus", "drives", "field", "match"), [
    ({"map": {"Vv": "DRIVE_CMD.V"}}, None, "bus.map.Vv", "did you mean V"),
    ({"map": {"V": "V"}}, None, "bus.map.V", "MESSAGE.SIGNAL"),
    ({"e2e": {"default": "crc8"}}, None, "bus.e2e.default", "unknown E2E profile"),
    ({"e2e": {"messages": {"DRIVE_CMD": {"profil": "none"}}}}, None,
     "bus.e2e.messages.DRIVE_CMD.profile", "unknown E2E profile"),
    ({"clock": {"kind": "sync"}}, None, "bus.clock.kind", "unknown value 'sync'"),
    ({"clock": {"kind": "trigger"}}, None, "bus.clock.message", "needs the message"),
    ({"clock": {"kind": "grid", "message": "SYNC"}}, None, "bus.clock.message",
     "only a trigger clock"),
    ({"node": {"id": "__import__('os')"}}, None, "bus.node.id", "not a node-id template"),
    ({"node": {"id": "id + "}}, None, "bus.node.id", "not a node-id template"),
    ({"node": {"id": "id + node", "shared": "SYNC"}}, None, "bus.node.shared",
     "expected a list"),
    ({"node": {"shared": [True]}}, None, "bus.node.shared[0]", "message name or ID"),
    ({"node": {"sharde": []}}, None, "bus.node.sharde", "did you mean shared"),
    ({"monitor": {"base": 0x80, "ids": {"FDI_FAULT": 0x90}}}, None, "bus.monitor.ids",
     "not both"),
    ({"transmit": "no"}, None, "bus.transmit", "true or false"),
    ({"clok": {}}, None, "bus.clok", "did you mean clock"),
    ({}, [{"name": "a", "node": 1}, {"name": "b", "node": 2}], "bus.node.id",
     "node-id template"),
    ({"node": {"id": "id + node"}}, [{"name": "a", "node": 1}, {"name": "a", "node": 2}],
     "drives[1].name", "named twice"),
    ({"node": {"id": "id + node"}}, [{"name": "a"}, {"name": "b", "node": 2}],
     "drives[0].node", "need a node"),
    ({"node": {"id": "id + node"}}, [{"name": f"d{i}", "node": i} for i in range(9)], "drives",
     "at most 8"),
])
def test_a_bad_bus_entry_names_its_field(tmp_path, bus, drives, field, match):
    with pytest.raises(ConfigError, match=match) as info:
        _with_bus(tmp_path, bus, drives)
    assert info.value.field == field

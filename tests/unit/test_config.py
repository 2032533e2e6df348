import textwrap

import pytest

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

"""Which shipped config reads a scenario's bus and which scenario plays a config's."""

import pytest

from canfdi.config import load_config
from canfdi.firmware_sim.scenario import SCENARIO_DIR, load_scenario, parse_scenario
from canfdi.tools.pairing import NoPairing, config_for, scenario_for, without_faults
from tests.conftest import REPO

CONFIGS = REPO / "deploy" / "config"


@pytest.mark.parametrize(("scenario", "config"), [
    ("dc_motor_consecutive", "dc_motor.yaml"),
    ("dc_motor_consecutive_cia402", "dc_motor_cia402.yaml"),
    ("dc_motor_consecutive_float", "dc_motor_float.yaml"),
    ("dc_motor_two_drives_cia402", "dc_motor_two_drives_cia402.yaml"),
    ("winding_machine_consecutive", "winding_machine.yaml"),  # the plant's own, not _oe
])
def test_the_config_of_a_scenario_reads_its_bus(scenario, config):
    assert config_for(load_scenario(scenario), CONFIGS) == CONFIGS / config


@pytest.mark.parametrize(("config", "nominal", "faulty"), [
    ("dc_motor.yaml", "dc_motor_nominal", "dc_motor_consecutive"),
    ("dc_motor_cia402.yaml", "dc_motor_consecutive_cia402 without faults",
     "dc_motor_consecutive_cia402"),
    ("dc_motor_two_drives_cia402.yaml", "dc_motor_two_drives_cia402 without faults",
     "dc_motor_two_drives_cia402"),
])
def test_the_scenario_of_a_config_plays_its_bus(config, nominal, faulty):
    cfg = load_config(CONFIGS / config)
    clean = scenario_for(cfg, SCENARIO_DIR)
    assert clean.name == nominal
    assert not clean.faults and not any(d.faults for d in clean.drives)
    noisy = scenario_for(cfg, SCENARIO_DIR, faults=True)
    assert noisy.name == faulty and any(d.faults for d in noisy.drives)
    if nominal.endswith("without faults"):  # no nominal scenario: the faulty one, stripped
        stripped = without_faults(noisy)
        assert (stripped.name, stripped.drives, stripped.seed) == (clean.name, clean.drives,
                                                                   clean.seed)


def test_no_config_for_a_bus_none_reads_says_so():
    scenario = parse_scenario({"plant": "dc_motor", "duration": 1.0, "bus": {"profile": "cia402"},
                               "drives": [{"name": f"d{i}", "node": i} for i in (1, 2, 3)]})
    with pytest.raises(NoPairing, match=r"reads dc_motor_cia402\.dbc with 3 drives.*--config"):
        config_for(scenario, CONFIGS)

"""canfdi.tools.bench's choice of traffic: the scenarios a bench plays on a config's bus."""

import pytest

from canfdi.config import load_config
from canfdi.firmware_sim.scenario import ScenarioError
from canfdi.tools.bench import bench_scenarios, soak_frames_missing
from tests.conftest import REPO

CONFIGS = REPO / "deploy" / "config"


def test_by_default_the_shipped_scenarios_of_the_configs_bus():
    clean, faulty = bench_scenarios(load_config(CONFIGS / "dc_motor.yaml"))
    assert (clean.name, faulty.name) == ("dc_motor_nominal", "dc_motor_consecutive")


def test_a_named_scenario_plays_without_its_faults_and_with_them():
    clean, faulty = bench_scenarios(load_config(CONFIGS / "dc_motor.yaml"),
                                    "dc_motor_consecutive")
    assert faulty.name == "dc_motor_consecutive" and faulty.faults
    assert not clean.faults and not any(d.faults for d in clean.drives)


def test_a_scenario_that_does_not_load_says_so():
    with pytest.raises(ScenarioError):
        bench_scenarios(load_config(CONFIGS / "dc_motor.yaml"), "no_such_scenario")


def test_a_soak_frame_missing_from_the_segments_and_not_dropped_is_missing():
    r = {"daemon_frames": 1000, "daemon_messages_dropped": 3, "daemon_frames_in_segments": 997}
    assert soak_frames_missing(r) == 0
    assert soak_frames_missing({**r, "daemon_frames_in_segments": 990}) == 7

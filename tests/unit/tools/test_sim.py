"""canfdi.tools.sim: a scenario's drive written as a log."""

import dataclasses

import pytest

from canfdi.firmware_sim.emitter import Disturbance
from canfdi.firmware_sim.scenario import load_scenario
from canfdi.io.logs import frame_blocks
from canfdi.tools.sim import samples_to_play, write_scenario_log


def test_the_samples_played_follow_the_duration():
    scenario = load_scenario("dc_motor_consecutive")
    dt = scenario.make_plant().dt
    assert samples_to_play(scenario) == round(scenario.duration / dt)
    assert samples_to_play(scenario, 2.0) == round(2.0 / dt)


@pytest.mark.parametrize("suffix", [".log", ".mcap"])
def test_the_written_log_holds_every_frame_made(tmp_path, suffix):
    scenario = dataclasses.replace(load_scenario("dc_motor_consecutive"), duration=2.0)
    out = tmp_path / "deep" / f"drive{suffix}"
    outcome = write_scenario_log(scenario, Disturbance(), out)
    assert outcome["scenario"] == scenario.name and outcome["output"] == str(out)
    assert outcome["frames"] == outcome["frames_sent"] > 0 and outcome["skipped"] == 0
    assert outcome["samples"] == samples_to_play(scenario)
    assert sum(block.size for block in frame_blocks(out)) == outcome["frames"]

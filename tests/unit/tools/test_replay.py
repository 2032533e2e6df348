"""canfdi.tools.replay: a log through a monitor, recorded as a live run records it (kept only
when something was diagnosed), and the config a canfdi MCAP carries."""

import dataclasses

import pytest

from canfdi.config import load_config
from canfdi.firmware_sim.emitter import Disturbance
from canfdi.firmware_sim.scenario import load_scenario
from canfdi.io.reader import read_metadata
from canfdi.monitor import Monitor
from canfdi.tools.replay import NoRecordedConfig, recorded_config, replay_diagnosis
from canfdi.tools.sim import write_scenario_log
from tests.conftest import REPO

CONFIGS = REPO / "deploy" / "config"


@pytest.fixture(scope="module")
def drive_log(tmp_path_factory):
    """Four seconds of the DC motor's drive as a candump log."""
    scenario = dataclasses.replace(load_scenario("dc_motor_consecutive"), duration=4.0)
    path = tmp_path_factory.mktemp("replay") / "drive.log"
    write_scenario_log(scenario, Disturbance(), path)
    return path


def test_a_diagnosis_is_recorded_with_the_config_it_was_made_with(drive_log, tmp_path):
    config = load_config(CONFIGS / "dc_motor.yaml")
    out = tmp_path / "diagnosed.mcap"
    diagnosis = replay_diagnosis(Monitor(config, record_residuals=True), drive_log, out)
    assert diagnosis.diagnosed and diagnosis.result["samples"] > 0
    assert diagnosis.recorded == [out] and out.exists()
    assert diagnosis.replayed.frames > 0 and diagnosis.result["damage"] == []
    assert read_metadata(out)["config_name"] == config.name
    again = recorded_config(out, tmp_path)
    assert (again.name, again.inputs, again.outputs) == (config.name, config.inputs,
                                                         config.outputs)


def test_a_log_that_diagnosed_nothing_leaves_no_recording(drive_log, tmp_path):
    other = load_config(CONFIGS / "winding_machine.yaml")  # another bus: no frame matches
    out = tmp_path / "nothing.mcap"
    diagnosis = replay_diagnosis(Monitor(other, record_residuals=True), drive_log, out)
    assert not diagnosis.diagnosed and "no_samples" in diagnosis.result
    assert diagnosis.recorded == [] and not out.exists()


def test_a_log_that_cannot_be_read_leaves_no_recording(tmp_path):
    bad = tmp_path / "bad.log"
    bad.write_text("not a candump line\n")
    out = tmp_path / "out.mcap"
    with pytest.raises(ValueError):
        replay_diagnosis(Monitor(load_config(CONFIGS / "dc_motor.yaml"),
                                 record_residuals=True), bad, out)
    assert not out.exists()


def test_only_a_canfdi_mcap_carries_a_config(drive_log, tmp_path):
    with pytest.raises(NoRecordedConfig) as caught:
        recorded_config(drive_log, tmp_path)
    assert caught.value.error is None and caught.value.log == drive_log

"""canfdi.tools.soak's setup: which scenario a soak takes, its noise, its calibration."""

import dataclasses

import numpy as np

from canfdi.config import load_config
from canfdi.firmware_sim.scenario import load_scenario
from canfdi.tools.soak import calibrated, scenario_problem, with_noise_scale
from tests.conftest import REPO

CONFIG = REPO / "deploy" / "config" / "dc_motor.yaml"


def test_only_a_fault_free_scenario_of_the_emulated_plant_is_a_soak():
    assert scenario_problem(load_scenario("dc_motor_nominal")) is None
    assert "a soak is fault-free" in scenario_problem(load_scenario("dc_motor_consecutive"))
    other = dataclasses.replace(load_scenario("dc_motor_nominal"), plant="vtol")
    assert scenario_problem(other) == "plant: 'vtol'; canfdi soak emulates dc_motor"


def test_the_noise_scale_multiplies_the_measurement_noise_only():
    nominal = load_scenario("dc_motor_nominal")
    noisier = with_noise_scale(nominal, 3.0)
    np.testing.assert_allclose(noisier.measurement_std, 3.0 * nominal.measurement_std)
    assert dataclasses.replace(noisier, measurement_std=nominal.measurement_std) == nominal


def test_the_calibration_learns_the_drives_noise_on_another_seed():
    config = load_config(CONFIG)
    scenario = with_noise_scale(load_scenario("dc_motor_nominal"), 2.0)
    lines = []
    calibration = calibrated(config, CONFIG, scenario, 20.0, scenario.seed, lines.append)
    assert lines[0] == "calibrating on 20 s of the healthy drive"
    assert calibration.logs[0].endswith(f"seed{scenario.seed + 1}-20s")
    ratio = calibration.noise.std / np.asarray(config.design.measurement_std)
    assert np.all((ratio > 1.5) & (ratio < 2.5)), ratio

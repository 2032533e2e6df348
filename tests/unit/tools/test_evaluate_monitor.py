"""canfdi.tools.evaluate_monitor: which monitor `canfdi evaluate` evaluates on which drive."""

import pytest

from canfdi.config import load_config
from canfdi.tools.evaluate_monitor import SignalsDiffer, evaluated_monitor
from tests.conftest import REPO

CONFIGS = REPO / "deploy" / "config"


def test_faults_from_another_config_draw_there_and_monitor_the_given_one():
    monitored = load_config(CONFIGS / "dc_motor.yaml")
    truth = load_config(CONFIGS / "dc_motor.yaml")
    chosen = evaluated_monitor(monitored, "dc_motor", faults_from=truth)
    assert chosen.drawn is truth and chosen.monitor is monitored
    assert chosen.calibration is None


def test_faults_from_a_config_of_other_signals_are_refused():
    with pytest.raises(SignalsDiffer):
        evaluated_monitor(load_config(CONFIGS / "dc_motor.yaml"), "dc_motor",
                          faults_from=load_config(CONFIGS / "winding_machine.yaml"))


def test_a_calibrated_monitor_is_the_calibration_of_the_drawn_config():
    config = load_config(CONFIGS / "dc_motor.yaml")
    lines = []
    chosen = evaluated_monitor(config, "dc_motor", calibrate_seconds=20, noise_scale=2.0,
                               seed=3, progress=lines.append)
    assert chosen.drawn is config and chosen.monitor is chosen.calibration.config
    assert chosen.calibration.samples > 0
    assert lines[0] == "calibrating on 20 s of the healthy drive at 2x noise"
    # twice the config's noise, learned back from the healthy drive
    configured = config.design.measurement_std
    learned = chosen.calibration.noise.std
    assert all(1.5 < l / c < 2.5 for l, c in zip(learned, configured, strict=True))

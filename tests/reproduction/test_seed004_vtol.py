"""Hwang, Chang and Hsu's paper through the monitor: the uio method on the VTOL aircraft with
the airspeed variation dA present (frames from canfdi.firmware_sim's frame_log, as a bus would carry
them, into canfdi.monitor.Monitor)."""

from __future__ import annotations

import dataclasses
import subprocess
import sys

import numpy as np
import pytest

from canfdi.config import load_config
from canfdi.firmware_sim.emitter import frame_log
from canfdi.firmware_sim.scenario import load_scenario, parse_scenario
from canfdi.monitor import Monitor
from tests.conftest import REPO, feed_frame_log

CONFIG = REPO / "deploy" / "config" / "vtol_uio.yaml"
SENSORS = ["v_h", "v_v", "pitch_rate", "v_v_plus_rate_plus_angle"]


def _diagnose(scenario, config=CONFIG) -> Monitor:
    return feed_frame_log(Monitor(load_config(config)), frame_log(scenario))


def sensor_scenario(index: int):
    """Hwang, Chang and Hsu Figs. 3-6: a 1.0 bias on sensor ``index`` at 2 s."""
    return parse_scenario({"name": f"vtol_sensor_{index}", "plant": "vtol", "duration": 10.0,
                           "seed": 23 + index, "faults": [{"target": "sensor", "index": index,
                                                           "onset": 2.0, "bias": 1.0}]})


def test_actuator_biases_each_isolated_in_its_own_residual():
    """Fig. 2: +1.0 on the collective at 2 s, -1.0 on the cyclic at 3 s: two detections, two
    acceptances on the right actuators, each estimated within 5 % (here better than 1 %),
    the first accepted before the second fault, nothing else."""
    monitor = _diagnose(load_scenario("vtol_actuators"))
    kinds = [e.kind for e in monitor.events]
    assert kinds == ["detected", "accepted"] * 2, kinds
    first, second = (e for e in monitor.events if e.kind == "accepted")
    assert (first.target, first.index) == ("actuator", 0)
    assert (second.target, second.index) == ("actuator", 1)
    assert first.estimates["lambda"] == pytest.approx(1.0, rel=0.05)
    assert second.estimates["lambda"] == pytest.approx(-1.0, rel=0.05)
    assert first.accepted_sample < 300 <= second.detected_sample
    for event, onset in ((first, 200), (second, 300)):
        assert abs(event.onset_sample - onset) <= 3
        assert event.detected_sample - onset <= 10
        # The identification filter's own residual (the diagonal map) says the same.
        assert event.candidates == ()
        own = next(i.ranking[0] for i in monitor.diagnoser.isolations
                   if dataclasses.replace(i.event, drive=event.drive) == event)
        assert own["index"] == event.index
        assert own["fidf_lambda"] == pytest.approx(event.estimates["lambda"], rel=0.05)
    # The second fault moved its own FIDF residual, not the first's: the diagonal map.
    dg = monitor.diagnoser
    assert np.abs(dg.design.fault_dc[:2, :2] - np.eye(2)).max() < 1e-9


@pytest.mark.parametrize("index", range(4))
def test_sensor_bias_isolated_by_the_smallest_angle(index):
    """Figs. 3-6: a 1.0 bias on each sensor in turn, isolated by the smallest fault angle
    (eq. 23b against the columns of Hf(0)) and estimated within 5 %."""
    monitor = _diagnose(sensor_scenario(index))
    kinds = [e.kind for e in monitor.events]
    assert kinds == ["detected", "accepted"], kinds
    event = monitor.events[1]
    assert (event.target, event.index, event.name) == ("sensor", index, SENSORS[index])
    assert event.estimates["bias"] == pytest.approx(1.0, rel=0.05)
    assert abs(event.onset_sample - 200) <= 3
    # Smallest angle: over all fault columns and over the paper's GRGS angles alone.
    assert event.candidates == ()  # nothing explains the data as well
    ranking = monitor.diagnoser.isolations[0].ranking
    assert ranking[0]["index"] == index and ranking[0]["target"] == "sensor"
    grgs = {c["index"]: c["grgs_angle_deg"] for c in ranking if c["target"] == "sensor"}
    assert min(grgs, key=grgs.get) == index
    assert grgs[index] < 5.0


def test_no_alarm_from_the_parameter_variation_alone():
    """vtol_nominal: 60 s with dA present, no fault: nothing detected."""
    monitor = _diagnose(load_scenario("vtol_nominal"))
    assert monitor.events == []
    assert monitor.samples == 6000


@pytest.mark.parametrize("verb", ["replay", "demo"])
@pytest.mark.parametrize(("old", "new", "field"), [
    ("angle_threshold: 5.0", "angle_threshold: 120.0", "uio.angle_threshold"),
    ("actuator_pole: -2.0", "actuator_pole: 2.0", "uio.actuator_pole"),
    ("min_samples: 30", "min_samples: 30\n  observer: 3", "uio.observer"),
])
def test_bad_uio_section_exits_2_naming_the_field(tmp_path, verb, old, new, field):
    config = tmp_path / "bad.yaml"
    text = CONFIG.read_text()
    assert old in text
    config.write_text(text.replace(old, new, 1))
    args = [sys.executable, "-m", "canfdi", verb]
    if verb == "replay":
        log = tmp_path / "one.log"  # candump format: one frame is enough
        log.write_text("(0.000000) vcan0 120#0000000000000000\n")
        args.append(str(log))
    args += ["--config", str(config)]
    if verb == "demo":
        args += ["--scenario", "vtol_actuators"]
    res = subprocess.run(args, capture_output=True, text=True, timeout=120, cwd=REPO)
    assert res.returncode == 2, res.stderr
    assert field in res.stderr

"""The output-error paper (output-error residual, Page-Hinkley, step-model isolation, reset) on the
emulated
winding machine, through the monitor: frames -> assembler -> OutputErrorDiagnoser.

The paper's figures (Section 4) are for its machine; the emulator (canfdi/firmware_sim/plants/
winding_machine.py) uses chosen models of the same structure, so the issue's tolerances are
checked, with the paper's values in the comments.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from canfdi.config import load_config
from canfdi.monitor import Monitor
from tests.conftest import REPO, feed_frame_log

CONFIG = REPO / "deploy" / "config" / "winding_machine_oe.yaml"


class _Residuals:
    """A record sink keeping only the residual rows (the monitor's block path writes them)."""

    def __init__(self) -> None:
        self.k: list[np.ndarray] = []
        self.rn: list[np.ndarray] = []

    def write_residual_rows(self, k, t_ns, names, R, Rn, stat, drive=None) -> None:
        self.k.append(np.asarray(k))
        self.rn.append(np.asarray(Rn))

    def __getattr__(self, name):  # every other record: not needed here
        return lambda *args, **kwargs: None

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        return np.concatenate(self.k), np.vstack(self.rn)


def diagnose(scenario: str, config: Path = CONFIG, sink=None) -> Monitor:
    """A scenario's frames (firmware_sim.emitter.frame_log) through the monitor, in blocks."""
    from canfdi.firmware_sim.emitter import frame_log
    from canfdi.firmware_sim.scenario import load_scenario

    return feed_frame_log(Monitor(load_config(config), sink=sink),
                          frame_log(load_scenario(scenario)))


def _only_fault(monitor: Monitor):
    kinds = [e.kind for e in monitor.events]
    assert kinds == ["detected", "accepted"], monitor.events
    return monitor.events[0], monitor.events[1]


def _back_to_noise(sink: _Residuals, detected: int) -> None:
    """The residual is back near zero within 55 samples of detection (paper: k = 650 / 655
    for k_d = 601 / 605) and stays there."""
    k, rn = sink.arrays()
    after = rn[(k > detected + 55) & (k <= detected + 400)]
    assert len(after) > 300
    assert np.abs(after).max() < 5.0  # normalised: 5 noise standard deviations
    assert np.abs(after.mean(axis=0)).max() < 0.3


def test_sensor_fault_t1():
    """T1 bias 0.0095 at k_f = 600: paper k_d = 601, k_f^ = 600, amplitude 0.0097."""
    sink = _Residuals()
    detected, accepted = _only_fault(diagnose("winding_machine_sensor", sink=sink))
    assert detected.detected_sample <= 601
    assert (accepted.target, accepted.index) == ("sensor", 0)
    assert accepted.onset_sample == 600
    assert accepted.estimates["bias"] == pytest.approx(0.0095, rel=0.02)
    assert accepted.accepted_sample - accepted.detected_sample <= 55
    _back_to_noise(sink, accepted.detected_sample)


def test_actuator_fault_u1():
    """u1 bias 0.002 at k_f = 600: paper k_d = 605, k_f^ = 601, amplitude 2.12e-3."""
    sink = _Residuals()
    detected, accepted = _only_fault(diagnose("winding_machine_actuator", sink=sink))
    assert detected.detected_sample <= 605
    assert (accepted.target, accepted.index) == ("actuator", 0)
    assert abs(accepted.onset_sample - 600) <= 1
    assert accepted.estimates["lambda"] == pytest.approx(0.002, rel=0.06)
    assert accepted.variances["lambda"] > 0
    assert accepted.accepted_sample - accepted.detected_sample <= 55
    _back_to_noise(sink, accepted.detected_sample)


def test_consecutive_faults_each_diagnosed_on_top_of_the_previous():
    """Section 3.3: T1 bias at 600, not repaired; u1 bias 0.002 at 1200; T3 bias at 1800."""
    monitor = diagnose("winding_machine_consecutive")
    kinds = [e.kind for e in monitor.events]
    assert kinds == ["detected", "accepted"] * 3, monitor.events
    got = [e for e in monitor.events if e.kind == "accepted"]
    assert [(e.target, e.index) for e in got] == [("sensor", 0), ("actuator", 0), ("sensor", 2)]
    truth = [0.0095, 0.002, -0.004]
    for e, onset, size in zip(got, (600, 1200, 1800), truth, strict=True):
        assert abs(e.onset_sample - onset) <= 1
        assert e.detected_sample - onset <= 5
        value = e.estimates["bias" if e.target == "sensor" else "lambda"]
        assert value == pytest.approx(size, rel=0.03)
    assert len(monitor.diagnoser.compensation) == 3


def test_no_alarm_on_the_nominal_run():
    monitor = diagnose("winding_machine_nominal")
    assert monitor.events == []
    assert monitor.samples == 6000


def _cli(*args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "canfdi", *args], capture_output=True,
                          text=True, timeout=timeout, cwd=REPO)


def _bad_config(tmp_path: Path) -> Path:
    text = CONFIG.read_text().replace("kappa: 0.1", "kappa: -0.1")
    assert "kappa: -0.1" in text
    bad = tmp_path / "bad_oe.yaml"
    bad.write_text(text)
    return bad


@pytest.mark.parametrize("verb", ["replay", "demo"])
def test_a_bad_output_error_section_exits_2_naming_the_field(tmp_path, verb):
    bad = _bad_config(tmp_path)
    if verb == "replay":
        log = tmp_path / "x.log"
        log.write_text("")
        res = _cli("replay", str(log), "--config", str(bad))
    else:
        res = _cli("demo", "--scenario", "winding_machine_sensor", "--config", str(bad))
    assert res.returncode == 2, res.stderr
    assert "output_error.kappa" in res.stderr


def test_identify_round_trip(tmp_path):
    """Fit the models from a fault-free demo log, then the written config diagnoses the sensor
    scenario (and the fitted gains are the emulator's)."""
    log = tmp_path / "nominal.mcap"
    res = _cli("demo", "--scenario", "winding_machine_nominal", "-o", str(log), "--json")
    assert res.returncode == 0, res.stderr
    out = tmp_path / "oe.yaml"
    res = _cli("identify", str(log), "--config", str(CONFIG), "-o", str(out), "--json")
    assert res.returncode == 0, res.stderr
    report = json.loads(res.stdout)
    gains = {(o["output"], p["input"]): p["static_gain"]
             for o in report["outputs"] for p in o["pairs"]}
    true = {("T1", "u1"): 3.0, ("T1", "u2"): 2.0, ("Omega2", "u2"): 10.0, ("T3", "u2"): -1.5,
            ("T3", "u3"): 4.0}
    assert set(gains) == set(true)
    for key, value in true.items():
        assert gains[key] == pytest.approx(value, rel=0.01)
    config = load_config(out)
    assert config.method == "output_error"
    _, accepted = _only_fault(diagnose("winding_machine_sensor", config=out))
    assert (accepted.target, accepted.index, accepted.onset_sample) == ("sensor", 0, 600)
    assert accepted.estimates["bias"] == pytest.approx(0.0095, rel=0.02)


def test_identify_refuses_a_log_with_faults(tmp_path):
    log = tmp_path / "sensor.mcap"
    assert _cli("demo", "--scenario", "winding_machine_sensor", "-o", str(log),
                "--json").returncode == 0
    res = _cli("identify", str(log), "--config", str(CONFIG))
    assert res.returncode == 1 and "fault-free" in res.stderr
    res = _cli("identify", str(log), "--config", str(CONFIG), "--orders", "T1:u9=1,1,1")
    assert res.returncode == 2 and "--orders" in res.stderr

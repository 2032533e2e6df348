"""`canfdi design` end to end, as a user runs it."""

import json
import subprocess
import sys

from tests.conftest import REPO


def _canfdi(*args):
    return subprocess.run([sys.executable, "-m", "canfdi", *args], capture_output=True,
                          text=True, cwd=REPO, timeout=120)


def test_design_json_dc_motor():
    res = _canfdi("design", "deploy/config/dc_motor.yaml", "--json")
    assert res.returncode == 0, res.stderr
    out = json.loads(res.stdout)
    # The config fixes the actuator window at 8 (the smallest admissible is 1) and the sensors'
    # at the paper's 4.
    assert out["windows"] == {"actuator": 8, "sensor": 4}
    assert out["actuators"][0]["exists"] and out["actuators"][0]["min_window"] == 1
    assert len(out["actuators"][0]["vector"]) == 9 * 4
    speed = next(e for e in out["detectability"] if e["kind"] == "sensor" and e["index"] == 3)
    assert speed["detectable"] is False and speed["reason"]


def test_design_text_pendulum_and_window_override():
    res = _canfdi("design", "deploy/config/inverted_pendulum.yaml", "--sensor-window", "3")
    assert res.returncode == 0, res.stderr
    assert "sensor s=3" in res.stdout
    assert "sensor 0 position" in res.stdout and "Theorem 3" in res.stdout


def test_bad_config_exits_2_naming_the_field(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("model: {A: [[1]], B: [[1]], C: [[1, 2]]}\nsignals: {inputs: [u], "
                   "outputs: [y]}\n")
    res = _canfdi("design", str(bad))
    assert res.returncode == 2
    assert "model.C" in res.stderr and res.stderr.count("\n") == 1
    assert "Traceback" not in res.stderr


def test_help_explains():
    res = _canfdi("design", "--help")
    assert res.returncode == 0 and "fault-to-noise" in res.stdout

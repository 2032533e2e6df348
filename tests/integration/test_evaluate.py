"""`canfdi evaluate` (issue 10): a small real evaluation through the emulated DC motor and the
monitor's diagnoser; the figures are in range, large faults are found, -o writes a PNG, bad
arguments exit 2."""

import json

import pytest

from canfdi.cli import main
from tests.conftest import REPO

KEYS = ("runs", "detection_rate", "isolation_accuracy", "delay_mean_samples",
        "delay_p95_samples", "false_alarms_per_hour", "estimate_error_median")


def test_a_small_dc_motor_evaluation(capsys, tmp_path):
    rc = main(["evaluate", "--plant", "dc_motor", "--runs", "6", "--seed", "3", "--json",
               "--no-progress", "-o", str(tmp_path)])
    out = capsys.readouterr().out
    assert rc == 0
    r = json.loads(out)
    for key in KEYS:
        assert key in r, key
    assert r["runs"] == 6 and r["method"] == "parity"
    assert r["undetectable"] == ["s:omega_r"]
    assert r["faults"] == len(r["fault_list"]) > 0
    assert all(f["channel"] != "s:omega_r" for f in r["fault_list"])
    assert 0.0 <= r["detection_rate"] <= 1.0
    assert r["isolation_accuracy"] is None or 0.0 <= r["isolation_accuracy"] <= 1.0
    assert 0 <= r["delay_mean_samples"] <= r["delay_max_samples"]
    assert r["delay_p95_samples"] <= r["delay_max_samples"]
    assert r["false_alarms_per_hour"] >= 0 and r["fault_free_hours"] > 0
    assert r["estimate_error_median"] is None or r["estimate_error_median"] >= 0
    assert sum(sum(row.values()) for row in r["confusion"].values()) == r["faults"]
    assert r["detected"] + r["missed"] == r["faults"]
    png = tmp_path / "dc_motor_parity.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000
    assert json.loads((tmp_path / "dc_motor_parity.json").read_text())["runs"] == 6


def test_large_faults_are_all_detected_and_isolated(capsys):
    rc = main(["evaluate", "--plant", "dc_motor", "--runs", "4", "--seed", "2", "--fnr", "20",
               "50", "--json", "--no-progress"])
    r = json.loads(capsys.readouterr().out)
    assert rc == 0 and r["faults"] >= 3
    assert r["detection_rate"] == 1.0
    assert r["isolation_accuracy"] == 1.0  # i_a / i_f_plus_i_a count through the candidates
    assert r["delay_p95_samples"] <= 10
    assert r["estimate_error_median"] < 0.05


def test_the_text_report(capsys):
    rc = main(["evaluate", "--plant", "dc_motor", "--runs", "2", "--no-progress"])
    out = capsys.readouterr().out
    assert rc == 0
    for words in ("detection rate", "delay (samples)", "isolation", "false alarms",
                  "estimate error", "by fault-to-noise ratio", "confusion", "s:omega_r"):
        assert words in out, words


@pytest.mark.parametrize("args, words", [
    (["--plant", "nope"], "--plant"),
    (["--plant", "dc_motor", "--runs", "0"], "--runs"),
    (["--plant", "dc_motor", "--fnr", "5", "1"], "--fnr"),
    (["--plant", "dc_motor", "--kinds", "stuck"], "--kinds"),
    (["--plant", "dc_motor", "--method", "uio"], "no uio config for the dc_motor plant"),
    (["--plant", "dc_motor", "--method", "uio", "--config",
      str(REPO / "deploy" / "config" / "dc_motor.yaml")], "a parity config"),
    (["--plant", "vtol", "--config", str(REPO / "deploy" / "config" / "dc_motor.yaml")],
     "config error: signals"),
    (["--plant", "dc_motor", "--config", "/nonexistent.yaml"], "config error"),
])
def test_bad_arguments_exit_2(capsys, args, words):
    assert main(["evaluate", *args, "--no-progress"]) == 2
    assert words in capsys.readouterr().err


def test_a_method_is_evaluated_on_its_own_fault_model(capsys):
    """uio (seed 004) and output_error (seed 003) model additive faults: no scale faults are
    drawn for them unless asked; parity draws all three kinds."""
    rc = main(["evaluate", "--plant", "vtol", "--method", "uio", "--runs", "2", "--json",
               "--no-progress"])
    r = json.loads(capsys.readouterr().out)
    assert rc == 0 and r["settings"]["kinds"] == ["actuator_bias", "sensor_bias"]
    assert all(f["kind"] != "actuator_scale" for f in r["fault_list"])
    rc = main(["evaluate", "--plant", "vtol", "--runs", "1", "--json", "--no-progress"])
    r = json.loads(capsys.readouterr().out)
    assert rc == 0 and "actuator_scale" in r["settings"]["kinds"]

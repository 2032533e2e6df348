"""`canfdi calibrate` on generated logs of healthy drives whose noise is not the config's
(issue 16): the noise comes back, the calibrated monitor is silent where the config's alarms,
a log with a fault is refused with where, and every method takes the calibration."""

import dataclasses
import json
import subprocess
import sys

import numpy as np
import pytest
import yaml

from canfdi.config import load_config, parse_config
from canfdi.firmware_sim.emitter import frame_log
from canfdi.firmware_sim.scenario import load_scenario
from canfdi.io.logs import write_frames
from canfdi.tools.calibrate import calibrated_document
from tests.conftest import REPO
from tests.unit.tools.test_configdoc import assert_same, comments, hex_lines

CONFIGS = REPO / "deploy" / "config"


def cli(*args):
    return subprocess.run([sys.executable, "-m", "canfdi", *map(str, args)],
                          capture_output=True, text=True, timeout=600, cwd=REPO)


def healthy_log(path, scenario, scale, seed=None, duration=90.0, faults=False):
    """A log of the scenario's drive with its noise times ``scale`` (faults dropped unless
    asked for)."""
    sc = load_scenario(scenario)
    change = {"measurement_std": sc.measurement_std * scale, "duration": duration}
    if seed is not None:
        change["seed"] = seed
    if not faults:
        change.update(faults=(), drives=())
    write_frames(path, [frame_log(dataclasses.replace(sc, **change)).frames])
    return path


def assert_written_as_the_input(config, text):
    """The calibrated config is the input as its user wrote it: every comment, every hex
    literal (issue 26)."""
    original = config.read_text()
    for comment in comments(original):
        assert comment in text, comment
    for line in hex_lines(original):
        assert line in text, line


def replay_json(log, config):
    res = cli("replay", log, "--config", config, "--json", "--no-progress")
    assert res.returncode == 0, res.stderr
    return json.loads(res.stdout)


def replay_alarms(log, config):
    out = replay_json(log, config)
    return len(out["faults"]) + len(out["unexplained"])


def without_watchdog(config, tmp):
    """The config with the noise watchdog off (the monitor as it was before issue 16)."""
    doc = yaml.safe_load(config.read_text())
    doc["watchdog"] = {"enabled": False}
    out = tmp / f"{config.stem}-nowatchdog.yaml"
    out.write_text(yaml.safe_dump(doc))
    return out


@pytest.fixture(scope="module")
def twice_as_noisy(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("calibrate")
    return (healthy_log(tmp / "healthy.mcap", "dc_motor_nominal", 2.0),
            healthy_log(tmp / "later.asc", "dc_motor_nominal", 2.0, seed=77), tmp)


def test_a_twice_as_noisy_dc_motor_is_calibrated_and_then_silent(twice_as_noisy):
    healthy, later, tmp = twice_as_noisy
    out = tmp / "calibrated.yaml"
    res = cli("calibrate", healthy, "--config", CONFIGS / "dc_motor.yaml", "-o", out, "--json")
    assert res.returncode == 0, res.stderr
    report = json.loads(res.stdout)
    stds = [n["std"] for n in report["noise"]]
    np.testing.assert_allclose(stds, 0.02, rtol=0.05)
    assert [n["identified"].split()[0] for n in report["noise"]] == ["alone", "with", "with",
                                                                      "not"]
    for r in report["residuals"]:
        assert r["variance"] == pytest.approx(1.0, abs=0.15), r
    text = out.read_text()
    assert text.startswith("# Calibrated by `canfdi calibrate` on ")
    assert "healthy.mcap" in text and "9000 healthy" in text
    assert_written_as_the_input(CONFIGS / "dc_motor.yaml", text)
    config = load_config(out)
    np.testing.assert_allclose(config.design.measurement_std, stds, rtol=1e-3)
    # The config's own noise (half the drive's) alarms on healthy data without the noise
    # watchdog; with it (the default) the mismatch is said instead. The calibrated config, on
    # another healthy log of the same drive (another seed, python-can's ASC), is silent.
    assert replay_alarms(healthy, without_watchdog(CONFIGS / "dc_motor.yaml", tmp)) >= 1
    watched = replay_json(healthy, CONFIGS / "dc_motor.yaml")
    assert watched["mismatches"] and not watched["faults"]
    assert all(v == pytest.approx(2.0, rel=0.25)
               for m in watched["mismatches"] for v in m["estimates"].values())
    assert replay_alarms(later, out) == 0
    assert replay_json(later, out)["mismatches"] == []


def test_a_log_holding_a_fault_is_refused_saying_where(tmp_path):
    log = healthy_log(tmp_path / "faulty.mcap", "dc_motor_consecutive", 1.0, faults=True,
                      duration=15.0)
    res = cli("calibrate", log, "--config", CONFIGS / "dc_motor.yaml", "-o",
              tmp_path / "out.yaml")
    assert res.returncode == 1
    assert "faulty.mcap: not healthy" in res.stderr and "a:V" in res.stderr
    sample = int(res.stderr.split("at sample ")[1].split()[0])
    assert 1000 <= sample <= 1100  # the actuator fault's onset is sample 1000
    assert not (tmp_path / "out.yaml").exists()


@pytest.mark.parametrize(("scenario", "config", "section"), [
    ("winding_machine_nominal", "winding_machine_oe.yaml", "output_error"),
    ("vtol_nominal", "vtol_uio.yaml", None),
    ("dc_motor_consecutive_cia402", "dc_motor_cia402.yaml", None),
])
def test_every_method_and_bus_takes_the_calibration(tmp_path, scenario, config, section):
    log = healthy_log(tmp_path / "healthy.blf", scenario, 2.0, duration=60.0)
    out = tmp_path / "calibrated.yaml"
    res = cli("calibrate", log, "--config", CONFIGS / config, "-o", out, "--json")
    assert res.returncode == 0, res.stderr
    report = json.loads(res.stdout)
    prior = np.array([n["config_std"] for n in report["noise"]])
    np.testing.assert_allclose([n["std"] for n in report["noise"]], 2 * prior, rtol=0.05)
    calibrated = load_config(out)
    if section:  # the method's own noise level follows
        written = calibrated.method_options.sigma
        np.testing.assert_allclose(written, [n["std"] for n in report["noise"]], rtol=1e-3)
    # The file keeps the input's comments and hex IDs (cia402: base 0x680) and holds, value
    # for value, what calibrated_document (evaluate, soak, teach-in) makes of the same noise.
    text = out.read_text()
    assert_written_as_the_input(CONFIGS / config, text)
    doc = yaml.safe_load((CONFIGS / config).read_text())
    std = np.array([n["std"] for n in report["noise"]])
    expected = calibrated_document(doc, load_config(CONFIGS / config), std)
    assert_same(parse_config(yaml.safe_load(text), out), parse_config(expected, out))
    assert replay_alarms(log, out) == 0


def test_a_relative_dbc_still_points_at_its_file_from_the_output(tmp_path):
    (tmp_path / "a").mkdir()
    dbc = (REPO / "dbc" / "motor_drive.dbc").read_text()
    (tmp_path / "drive.dbc").write_text(dbc)
    text = (CONFIGS / "dc_motor.yaml").read_text().replace("dbc: motor_drive",
                                                             "dbc: ../drive.dbc")
    (tmp_path / "a" / "monitor.yaml").write_text(text)
    log = healthy_log(tmp_path / "h.mcap", "dc_motor_nominal", 1.0, duration=30.0)
    out = tmp_path / "b" / "c" / "calibrated.yaml"
    res = cli("calibrate", log, "--config", tmp_path / "a" / "monitor.yaml", "-o", out)
    assert res.returncode == 0, res.stderr
    assert "dbc: ../../drive.dbc" in out.read_text()
    assert load_config(out).bus.dbc is not None


def test_bad_input_exits_2_with_one_line(tmp_path):
    res = cli("calibrate", tmp_path / "none.mcap", "--config", CONFIGS / "dc_motor.yaml")
    assert res.returncode == 2 and "no such log" in res.stderr
    other = healthy_log(tmp_path / "cia402.mcap", "dc_motor_consecutive_cia402", 1.0,
                        duration=5.0)
    res = cli("calibrate", other, "--config", CONFIGS / "dc_motor.yaml")
    assert res.returncode == 2 and "no sample formed" in res.stderr
    short = healthy_log(tmp_path / "short.mcap", "dc_motor_nominal", 1.0, duration=2.0)
    res = cli("calibrate", short, "--config", CONFIGS / "dc_motor.yaml")
    assert res.returncode == 2 and "needs at least 1000" in res.stderr
    assert "Traceback" not in res.stderr


def test_calibrated_at_twice_the_noise_the_consecutive_faults_are_still_diagnosed(
        twice_as_noisy):
    healthy, _, tmp = twice_as_noisy
    out = tmp / "for_faults.yaml"
    assert cli("calibrate", healthy, "--config", CONFIGS / "dc_motor.yaml", "-o",
               out).returncode == 0
    faulty = healthy_log(tmp / "consecutive.mcap", "dc_motor_consecutive", 2.0, faults=True,
                         duration=40.0)
    res = cli("replay", faulty, "--config", out, "--json", "--no-progress")
    assert res.returncode == 0, res.stderr
    faults = json.loads(res.stdout)["faults"]
    assert [(f["kind"], f["index"], f["onset_sample"]) for f in faults] == [
        ("actuator", 0, 1000), ("sensor", 0, 2000), ("sensor", 1, 3000)]
    assert faults[0]["estimate"]["eta"] == pytest.approx(2.0, rel=0.02)
    assert faults[0]["estimate"]["lambda"] == pytest.approx(10.0, rel=0.05)
    assert faults[1]["estimate"]["bias"] == pytest.approx(0.5, rel=0.05)
    assert faults[2]["estimate"]["bias"] == pytest.approx(1.0, rel=0.05)

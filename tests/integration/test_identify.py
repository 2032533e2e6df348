"""Issue 26 end to end: a servo axis without a model (deploy/config/servo_axis_odrive.yaml,
model: {identify: {unknown_inputs: 1}}), a candump of its commissioning run, `canfdi identify`,
then the monitor on the same drive: the sensor biases diagnosed on the right channels, and 300
s of fault-free operation with the load changing without an alarm. The drive is not linear:
Coulomb friction, a load torque that steps and drifts, a velocity loop closed by the master on
the drive's own estimate (canfdi/firmware_sim/plants/servo_axis.py)."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from canfdi.config import load_config
from canfdi.firmware_sim.emitter import frame_log
from canfdi.firmware_sim.scenario import load_scenario
from canfdi.io.logs import write_frames

REPO = Path(__file__).resolve().parents[2]
CONFIG = REPO / "deploy" / "config" / "servo_axis_odrive.yaml"
ODRIVE_DBC = REPO / "tests" / "data" / "dbc" / "odrive" / "odrive-cansimple.dbc"

pytestmark = pytest.mark.slow


def _cli(*args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "canfdi", *args], capture_output=True,
                          text=True, timeout=timeout, cwd=REPO)


def _log(tmp: Path, scenario: str, name: str, **changes) -> Path:
    """The scenario's frames as a candump log (what `candump -L can0` records)."""
    sc = load_scenario(scenario)
    if changes:
        sc = dataclasses.replace(sc, **changes)
    path = tmp / name
    write_frames(path, [frame_log(sc).frames])
    return path


@pytest.fixture(scope="module")
def logs(tmp_path_factory) -> dict[str, Path]:
    tmp = tmp_path_factory.mktemp("servo")
    return {"commissioning": _log(tmp, "servo_axis_commissioning", "commissioning.log"),
            "faults": _log(tmp, "servo_axis_sensor_faults", "faults.log"),
            "operation": _log(tmp, "servo_axis_operation", "operation.log"),
            "tmp": tmp}


@pytest.fixture(scope="module")
def identified(logs) -> tuple[Path, dict]:
    out = logs["tmp"] / "servo_identified.yaml"
    res = _cli("identify", str(logs["commissioning"]), "--config", str(CONFIG), "-o", str(out),
               "--json")
    assert res.returncode == 0, res.stderr
    return out, json.loads(res.stdout)


def _replay(log: Path, config: Path) -> dict:
    res = _cli("replay", str(log), "--config", str(config), "--json", "--no-progress")
    assert res.returncode == 0, res.stderr
    return json.loads(res.stdout)


def test_the_commissioning_log_gives_a_model_with_its_load(identified):
    out, report = identified
    assert report["path"] == "measured state"
    assert report["unknown_inputs"]["count"] == 1
    assert report["details"]["rows_reached"] == ["Vel_Estimate", "Pos_Estimate"]
    fits = {o["output"]: o for o in report["validation"]["outputs"]}
    assert all(fits[name]["one_step_fit"] > 90 for name in fits)
    noise = {n["sensor"]: n["std"] for n in report["calibration"]["noise"]}
    # The scenario's noise (0.05 A, 0.01 turn/s, 1e-4 turn); the echo has none of its own:
    # its float32 rounding.
    assert noise["Iq_Measured"] == pytest.approx(0.05, rel=0.05)
    assert noise["Vel_Estimate"] == pytest.approx(0.01, rel=0.1)
    assert noise["Pos_Estimate"] == pytest.approx(1e-4, rel=0.1)
    assert 0 < noise["Iq_Setpoint"] < 1e-5
    config = load_config(out)
    assert config.model.r == 1 and config.unknown_inputs == ["load_torque"]


def test_the_written_config_keeps_the_users_file(identified):
    out, _ = identified
    text = out.read_text()
    original = CONFIG.read_text()
    for line in original.splitlines():
        if line.lstrip().startswith("#"):
            assert line.strip() in text, line
    assert "base: 0x7C0" in text
    assert text.startswith("# canfdi identify, ")
    assert "one-step fit" in text.split("name:")[0]
    doc = yaml.safe_load(text)
    assert doc["model"]["identify"] == {"unknown_inputs": 1}


def test_the_sensor_biases_are_diagnosed_on_their_channels(identified, logs):
    """Iq_Measured +0.5 A at 40 s and Vel_Estimate +0.1 turn/s at 80 s: each on its channel,
    within 10 % and 5 samples of its onset, accepted within 50 samples of it with no other
    candidate. (Issue 29's near twin: with the load decoupled, an Iq_Measured bias differed
    from a current-command offset only in a one-sample transient, and the diagnosis ended "no
    single fault fits", then accepted the channel 1,999 samples after its onset.)"""
    out, _ = identified
    result = _replay(logs["faults"], out)
    faults = result["faults"]
    assert [(f["kind"], f["name"]) for f in faults] == [("sensor", "Iq_Measured"),
                                                         ("sensor", "Vel_Estimate")]
    for f, bias, onset in zip(faults, (0.5, 0.1), (4000, 8000), strict=True):
        assert f["estimate"]["bias"] == pytest.approx(bias, rel=0.1)
        assert abs(f["onset_sample"] - onset) <= 5
        assert f["detected_sample"] - onset <= 5
        assert f["accepted_sample"] - onset <= 50 and f["candidates"] == []
    assert result["unexplained"] == []


@pytest.mark.parametrize("seconds", [60.0, 300.0])
def test_a_shorter_or_longer_commissioning_run_gives_the_same_diagnoses(seconds, logs, tmp_path):
    """Not tuned to one log: 1 and 5 minutes of commissioning give models that diagnose both
    biases on their channels (at 5 minutes the velocity's bias is seen only at the sensor
    window 2, which the design then takes)."""
    log = _log(tmp_path, "servo_axis_commissioning", "commissioning.log", duration=seconds)
    out = tmp_path / "identified.yaml"
    res = _cli("identify", str(log), "--config", str(CONFIG), "-o", str(out))
    assert res.returncode == 0, res.stderr
    result = _replay(logs["faults"], out)
    assert [f["name"] for f in result["faults"]] == ["Iq_Measured", "Vel_Estimate"]
    for f, bias, onset in zip(result["faults"], (0.5, 0.1), (4000, 8000), strict=True):
        assert f["estimate"]["bias"] == pytest.approx(bias, rel=0.1)
        assert f["detected_sample"] - onset <= 5
    assert result["unexplained"] == []


def test_300_s_of_operation_with_the_load_changing_raise_no_alarm(identified, logs):
    out, _ = identified
    result = _replay(logs["operation"], out)
    assert result["samples"] >= 29000
    assert result["faults"] == [] and result["unexplained"] == []


def test_odrives_published_dbc_reads_the_same_drive(logs, tmp_path):
    doc = yaml.safe_load(CONFIG.read_text())
    doc["bus"]["dbc"] = str(ODRIVE_DBC)
    config = tmp_path / "odrive.yaml"
    config.write_text(yaml.safe_dump(doc, sort_keys=False))
    out = tmp_path / "identified.yaml"
    res = _cli("identify", str(logs["commissioning"]), "--config", str(config), "-o", str(out),
               "--json")
    assert res.returncode == 0, res.stderr
    faults = _replay(logs["faults"], out)["faults"]
    assert [f["name"] for f in faults] == ["Iq_Measured", "Vel_Estimate"]


def test_without_the_unknown_input_the_model_is_refused_and_would_miss_the_velocity_bias(
        logs, tmp_path):
    """Identified without the load as an unknown input: `canfdi identify` refuses it (it
    cannot predict the velocity); taken anyway (the library, no validation), the load
    inflates the noise it learns and its monitor misses the Vel_Estimate bias."""
    doc = yaml.safe_load(CONFIG.read_text())
    doc["model"] = {"identify": {"unknown_inputs": 0, "order": 4}}
    del doc["signals"]["unknown_inputs"]
    config = tmp_path / "no_load.yaml"
    config.write_text(yaml.safe_dump(doc, sort_keys=False))
    res = _cli("identify", str(logs["commissioning"]), "--config", str(config))
    assert res.returncode == 1 and "record" in res.stderr
    assert len(res.stderr.strip().splitlines()[-1:]) == 1

    from canfdi.bus.dbc import BusMap
    from canfdi.core.sysid import identify_state_space
    from canfdi.tools.calibrate import read_records
    from canfdi.tools.identify import model_section

    cfg = load_config(config, allow_unidentified=True)
    records = read_records([logs["commissioning"]], cfg, lambda _: None, dt=0.01)
    _, floor = BusMap.from_config(cfg).resolution(records[0].U, records[0].Z)
    from canfdi.core.unknown_inputs import Record

    found = identify_state_space([Record(r.U, r.Z) for r in records], 0.01, order=4,
                                 floor_std=floor)
    doc["model"] = model_section(found.model, None)
    doc["noise"] = {"measurement": [float(v) for v in found.noise_std]}
    forced = tmp_path / "forced.yaml"
    forced.write_text(yaml.safe_dump(doc, sort_keys=False))
    names = [f["name"] for f in _replay(logs["faults"], forced)["faults"]]
    assert "Vel_Estimate" not in names


def test_refusals_say_what_to_record(logs, tmp_path):
    short = _log(tmp_path, "servo_axis_commissioning", "short.log", duration=20.0)
    res = _cli("identify", str(short), "--config", str(CONFIG))
    assert res.returncode == 1 and "too short" in res.stderr and "record at least" in res.stderr
    res = _cli("identify", str(logs["faults"]), "--config", str(CONFIG))
    assert res.returncode == 1 and "fault" in res.stderr and "near sample 3999" in res.stderr
    assert len(res.stderr.strip().splitlines()[-1:]) == 1


def test_bad_options_exit_2_in_one_line_naming_the_key(logs, tmp_path):
    res = _cli("identify", str(logs["commissioning"]), "--config", str(CONFIG), "--holdout",
               "0.95")
    assert res.returncode == 2 and "--holdout" in res.stderr
    doc = yaml.safe_load(CONFIG.read_text())
    doc["model"] = {"identify": {"unknown_inputs": 1, "ordr": 3}}
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(doc))
    res = _cli("identify", str(logs["commissioning"]), "--config", str(bad))
    assert res.returncode == 2 and "model.identify.ordr" in res.stderr
    assert "did you mean order" in res.stderr
    assert len(res.stderr.strip().splitlines()) == 1
    # A config still to identify cannot run: exit 2, saying how to learn the model.
    res = _cli("replay", str(logs["operation"]), "--config", str(CONFIG))
    assert res.returncode == 2 and "canfdi identify" in res.stderr


def test_a_constant_input_is_refused():
    from canfdi.tools.calibrate import Record
    from canfdi.tools.identify import Refusal, _check_data

    cfg = load_config(CONFIG, allow_unidentified=True)
    k = np.arange(6000)
    rec = Record(Path("flat"), k, np.ones((6000, 1)), np.random.default_rng(0).normal(
        size=(6000, 4)))
    with pytest.raises(Refusal, match="constant"):
        _check_data([rec], cfg, 0.01, np.zeros(1))
    rec = Record(Path("one step"), k, np.where(k < 3000, 0.0, 1.0)[:, None],
                 np.zeros((6000, 4)))
    with pytest.raises(Refusal, match="persistently exciting"):
        _check_data([rec], cfg, 0.01, np.zeros(1))

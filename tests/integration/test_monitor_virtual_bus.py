"""The monitor through the whole service on python-can's virtual bus (issue 4's acceptance).

Each test runs a scenario's emulator and `canfdi`'s monitor in one process (canfdi demo), with
an independent python-can receiver on the same channel and an MCAP log.
"""

import asyncio
import subprocess
import sys

import can
import numpy as np
import pytest

from canfdi import dbc as dbc_files
from canfdi.bus import e2e
from canfdi.config import load_config
from canfdi.firmware_sim.scenario import load_scenario, parse_scenario
from canfdi.io.reader import read_frames
from canfdi.io.writer import McapRecorder
from canfdi.tools.demo import run_demo
from tests.conftest import REPO

CONFIG = REPO / "deploy" / "config" / "dc_motor.yaml"


def _run(scenario, tmp_path=None, channel="canfdi-it"):
    config = load_config(CONFIG)
    listener = can.Bus(interface="virtual", channel=channel)
    recorders = []

    def recorder(metadata, drive_time):
        recorders.append(McapRecorder(tmp_path / "run.mcap", metadata=metadata))
        return recorders[-1]

    try:
        monitor, stats, truth = asyncio.run(run_demo(
            scenario, config, channel=channel, recorder=recorder if tmp_path else None))
        heard = []
        while (msg := listener.recv(timeout=0.0)) is not None:
            heard.append(msg)
    finally:
        listener.shutdown()
        for r in recorders:
            r.close()
    return monitor, stats, truth, heard


def _faults(monitor):
    return monitor.summary()["faults"]


def test_actuator_case_detected_fast_and_identified_within_2_percent():
    monitor, _, _, _ = _run(load_scenario("dc_motor_actuator"))
    (fault,) = _faults(monitor)
    s = monitor.diagnoser.design.actuator_window
    assert (fault["kind"], fault["index"]) == ("actuator", 0)
    assert 1000 <= fault["detected_sample"] <= 1000 + s + 3
    assert fault["estimate"]["eta"] == pytest.approx(2.0, rel=0.02)
    assert fault["estimate"]["lambda"] == pytest.approx(10.0, rel=0.02)


def test_sensor_case_a_f_10_10_01_0():
    """i_f is isolated with its bias. i_a and i_f_plus_i_a reach every w-decoupled residual only
    through f(i_a) - f(i_f_plus_i_a) (canfdi design), so that pair is reported as such."""
    monitor, _, _, _ = _run(load_scenario("dc_motor_sensors_a"))
    faults = {f["name"]: f for f in _faults(monitor)}
    assert faults["i_f"]["estimate"]["bias"] == pytest.approx(10.0, rel=0.02)
    pair = faults["i_a"]
    assert pair["estimate"]["bias"] == pytest.approx(10.0 - 0.1, rel=0.02)
    assert {c["name"] for c in pair["candidates"]} == {"i_a", "i_f_plus_i_a"}
    assert set(faults) == {"i_f", "i_a"}  # omega_r (healthy) never reported


def test_sensor_case_b_f_0_35_2_0():
    monitor, _, _, _ = _run(load_scenario("dc_motor_sensors_b"))
    (pair,) = _faults(monitor)
    assert pair["estimate"]["bias"] == pytest.approx(3.5 - 2.0, rel=0.02)
    cands = {c["name"]: c["estimates"]["bias"] for c in pair["candidates"]}
    assert cands["i_f_plus_i_a"] == pytest.approx(-1.5, rel=0.02)
    assert "i_f" not in cands and pair["name"] != "i_f"  # the healthy i_f is never blamed


def test_consecutive_faults_each_diagnosed_within_3_percent_none_spurious(tmp_path):
    scenario = load_scenario("dc_motor_consecutive")
    monitor, stats, truth, heard = _run(scenario, tmp_path)
    faults = _faults(monitor)
    assert [(f["kind"], f["index"]) for f in faults] == [(t["target"], t["index"]) for t in truth]
    for f, t in zip(faults, truth, strict=True):
        assert abs(f["onset_sample"] - t["onset_sample"]) <= 2
        for key in ("eta", "lambda", "bias"):
            if key in t:
                assert f["estimate"][key] == pytest.approx(t[key], rel=0.03), (f, t)
    assert monitor.summary()["unexplained"] == []

    # Every frame the emulator sent is in the MCAP, as a received frame.
    statuses = read_frames(tmp_path / "run.mcap").status
    received = statuses[statuses != "sent"]
    drive = received[received == "ok"]
    assert len(drive) == stats.frames_sent == len(received)

    # The fault frames an independent python-can + cantools listener decodes (with the
    # monitor's DBC) match.
    db = dbc_files.load("canfdi_monitor")
    fault_msgs = [db.decode_message(m.arbitration_id, m.data, decode_choices=False)
                  for m in heard if m.arbitration_id == 0x080]
    estimates = [db.decode_message(m.arbitration_id, m.data, decode_choices=False)
                 for m in heard if m.arbitration_id == 0x081]
    assert all(e2e.check(m.arbitration_id, m.data) for m in heard if m.arbitration_id < 0x100)
    accepted = [m for m in fault_msgs if m["State"] == 3]
    assert [(m["Kind"], m["Index"], m["Sample"]) for m in accepted] == [
        ({"actuator": 1, "sensor": 2}[f["kind"]], f["index"], f["accepted_sample"])
        for f in faults]
    # The last FDI_ESTIMATE of each channel is its latest total: the accepted estimate, or
    # the last refinement's.
    latest = {(f["kind"], f["index"]): f["estimate"] for f in faults}
    for r in monitor.summary()["refined"]:
        latest[(r["kind"], r["index"])] = r["estimate"]
    for f in faults:
        kind = {"actuator": 1, "sensor": 2}[f["kind"]]
        for key, param in (("eta", 0), ("lambda", 1), ("bias", 2)):
            if key in f["estimate"]:
                values = [m["Value"] for m in estimates
                          if (m["Kind"], m["Index"], m["Param"]) == (kind, f["index"], param)]
                want = latest[(f["kind"], f["index"])][key]
                assert values and values[-1] == pytest.approx(want, rel=1e-6)
    statuses = [m for m in heard if m.arbitration_id == 0x082]
    assert statuses, "FDI_STATUS heartbeat never sent"


def test_replay_of_the_live_log_gives_the_live_diagnoses(tmp_path):
    monitor, _, _, _ = _run(load_scenario("dc_motor_consecutive"), tmp_path)
    live = _faults(monitor)
    res = subprocess.run([sys.executable, "-m", "canfdi", "replay", str(tmp_path / "run.mcap"),
                          "--config", str(CONFIG), "--json"],
                         capture_output=True, text=True, timeout=300, cwd=REPO)
    assert res.returncode == 0, res.stderr
    import json

    replayed = json.loads(res.stdout)
    assert replayed["faults"] == live
    assert [t["index"] for t in replayed["truth"]] == [0, 0, 1]


def test_no_fault_in_1e5_fault_free_samples():
    scenario = parse_scenario({"plant": "dc_motor", "duration": 1000.0, "seed": 77,
                               "noise": {"measurement": 0.01}})
    monitor, stats, _, _ = _run(scenario, channel="canfdi-it-nominal")
    summary = monitor.summary()
    assert summary["samples"] == 100_000 == stats.samples
    assert summary["faults"] == [] and summary["detections"] == 0
    assert np.isfinite(monitor.diagnoser.thresholds).all()

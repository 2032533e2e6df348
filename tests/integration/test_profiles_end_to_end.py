"""The monitor on the ways real drives talk (issue 15's "shown end to end").

dc_motor_consecutive's drive speaks canfdi's own bus, CANopen CiA 402 (SYNC-triggered PDOs,
no E2E) and a node-id float32 protocol (currents polled by RTR, a time grid): `canfdi demo`
diagnoses the same faults on each; two CiA 402 drives on one bus are diagnosed apart; the
monitor's frames on a CANopen bus sit where the config puts them and decode with cantools;
replaying a profile's log (canfdi's MCAP, python-can's ASC and BLF) gives the live result.
"""

import asyncio
import json
import subprocess
import sys

import can
import numpy as np
import pytest

from canfdi import dbc as dbc_files
from canfdi.config import load_config
from canfdi.firmware_sim.emitter import frame_log
from canfdi.firmware_sim.scenario import load_scenario
from canfdi.tools.demo import run_demo
from canfdi.tools.samples import log_samples
from tests.conftest import REPO

CONFIGS = REPO / "deploy" / "config"
PROFILE_SCENARIOS = ["dc_motor_consecutive_cia402", "dc_motor_consecutive_float"]


def cli(*args, timeout=300):
    res = subprocess.run([sys.executable, "-m", "canfdi", *map(str, args)], capture_output=True,
                         text=True, timeout=timeout, cwd=REPO)
    return res


def demo_json(scenario, *extra):
    res = cli("demo", "--scenario", scenario, "--json", *extra)
    assert res.returncode == 0, res.stderr
    return json.loads(res.stdout)


def indices(faults):
    return [(f.get("drive"), f["kind"], f["index"], f["onset_sample"], f["detected_sample"],
             f["accepted_sample"]) for f in faults]


@pytest.fixture(scope="module")
def own_bus():
    return demo_json("dc_motor_consecutive")


@pytest.mark.parametrize("scenario", PROFILE_SCENARIOS)
def test_demo_diagnoses_each_profile_as_on_canfdis_own_bus(own_bus, scenario, tmp_path):
    log = tmp_path / "run.mcap"
    result = demo_json(scenario, "-o", log)
    got, want = result["faults"], own_bus["faults"]
    # The same faults, onsets and detections; the acceptance within a few samples (it comes as
    # soon as an estimate's spread crosses its bound, which the bus's quantisation moves).
    assert [f[1:-1] for f in indices(got)] == [f[1:-1] for f in indices(want)]
    assert all(abs(a[-1] - b[-1]) <= 5 for a, b in zip(indices(got), indices(want),
                                                          strict=True))
    assert len(want) == 3 and result["frames"]["invalid"] == 0
    for a, b in zip(got, want, strict=True):
        # The buses quantise differently (mV and 0.01 rpm against 0.01 V and 0.01 rad/s).
        for key, value in b["estimate"].items():
            assert a["estimate"][key] == pytest.approx(value, rel=5e-3, abs=5e-3)
    # The truth the demo prints is the scenario's: the faults of dc_motor_consecutive.
    assert [(t["target"], t["index"], t["onset_sample"]) for t in result["truth"]] == \
        [(f["kind"], f["index"], f["onset_sample"]) for f in want]
    # Replaying the run's own log gives the live result (the grid clock reads the frames'
    # recorded times, which the demo's virtual bus kept from the emulator).
    res = cli("replay", log, "--config", CONFIGS / f"{scenario.replace('consecutive_', '')}.yaml",
              "--json", "--no-progress")
    assert res.returncode == 0, res.stderr
    replayed = json.loads(res.stdout)
    assert indices(replayed["faults"]) == indices(got)
    assert replayed["samples"] == result["samples"]
    # The log tools assemble samples with the config's own clock too (identify, calibrate).
    k, U, Z = log_samples(log, load_config(CONFIGS / f"{scenario.replace('consecutive_', '')}"
                                                     ".yaml"))
    assert len(k) == result["samples"] and (k == range(len(k))).all()
    assert not np.isnan(Z[10:]).any() and not np.isnan(U[10:]).any()


@pytest.mark.parametrize(("scenario", "suffix"), [("dc_motor_consecutive_float", ".asc"),
                                                  ("dc_motor_consecutive_cia402", ".blf")])
def test_a_python_can_log_of_a_profile_bus_replays_to_the_same_diagnoses(scenario, suffix,
                                                                         tmp_path):
    # Frames written by python-can's own writer (RTR requests included), read back by its
    # reader inside canfdi replay.
    frames = frame_log(load_scenario(scenario)).frames
    path = tmp_path / f"bus{suffix}"
    with can.Logger(str(path)) as writer:
        for msg in frames.to_messages():
            writer.on_message_received(msg)
    config = CONFIGS / f"{scenario.replace('consecutive_', '')}.yaml"
    res = cli("replay", path, "--config", config, "--json", "--no-progress")
    assert res.returncode == 0, res.stderr
    result = json.loads(res.stdout)
    assert [(f["kind"], f["index"], f["onset_sample"]) for f in result["faults"]] == [
        ("actuator", 0, 1000), ("sensor", 0, 2000), ("sensor", 1, 3000)]
    assert result["frames"]["received"] == frames.size
    assert result["frames"]["invalid"] == 0


def test_a_log_of_another_bus_makes_no_sample_and_says_why(tmp_path):
    # The CiA 402 bus read with the float protocol's config: IDs 0x080.. are no float frames.
    frames = frame_log(load_scenario("dc_motor_consecutive_cia402"), duration=2.0).frames
    path = tmp_path / "cia402.log"
    with can.Logger(str(path)) as writer:
        for msg in frames.to_messages():
            writer.on_message_received(msg)
    res = cli("replay", path, "--config", CONFIGS / "dc_motor_float.yaml", "--no-progress")
    assert res.returncode == 1, res.stderr
    assert "0 samples: no frame matched the config's bus map" in res.stdout


def test_two_drives_on_one_canopen_bus_are_diagnosed_apart():
    result = demo_json("dc_motor_two_drives_cia402")
    assert {f["drive"] for f in result["faults"]} == {"left"}
    assert [(f["kind"], f["index"], f["onset_sample"]) for f in result["faults"]] == [
        ("actuator", 0, 1000), ("sensor", 0, 2000), ("sensor", 1, 3000)]
    assert {t["drive"] for t in result["truth"]} == {"left"}
    drives = result["drives"]
    assert drives["left"]["samples"] == drives["right"]["samples"] == 3999
    # One SYNC a period serves both drives and is counted once.
    scenario = load_scenario("dc_motor_two_drives_cia402")
    assert result["frames"]["received"] == frame_log(scenario).frames.size


def test_the_monitor_frames_on_a_canopen_bus_are_where_the_config_puts_them():
    # An independent receiver on the bus hears the monitor's fault frames at 0x680.. (not at
    # CANopen's SYNC and EMCY IDs 0x080..0x083) and decodes them with cantools from
    # canfdi_monitor.dbc, the Drive signal saying which drive.
    config = load_config(CONFIGS / "dc_motor_two_drives_cia402.yaml")
    listener = can.Bus(interface="virtual", channel="canfdi-cia402-it")
    try:
        asyncio.run(run_demo(load_scenario("dc_motor_two_drives_cia402"), config,
                             channel="canfdi-cia402-it"))
        heard = []
        while (msg := listener.recv(timeout=0.0)) is not None:
            heard.append(msg)
    finally:
        listener.shutdown()
    db = dbc_files.load("canfdi_monitor")
    by_id = {m.frame_id - 0x080 + 0x680: m for m in db.messages}
    ours = [m for m in heard if m.arbitration_id in by_id]
    assert not [m for m in heard if 0x081 <= m.arbitration_id <= 0x083]
    faults = [by_id[m.arbitration_id].decode(m.data, decode_choices=False) for m in ours
              if by_id[m.arbitration_id].name == "FDI_FAULT"]
    accepted = [f for f in faults if f["State"] == 3]
    assert [(f["Drive"], f["Kind"], f["Index"]) for f in accepted] == [(0, 1, 0), (0, 2, 0),
                                                                       (0, 2, 1)]
    status = [by_id[m.arbitration_id].decode(m.data, decode_choices=False) for m in ours
              if by_id[m.arbitration_id].name == "FDI_STATUS"]
    assert {s["Drive"] for s in status} == {0, 1}

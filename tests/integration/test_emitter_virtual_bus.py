"""The emulator on python-can's virtual bus, heard by an independent receiver."""

import asyncio
import json
import subprocess
import sys

import can
import numpy as np

from canfdi import dbc as dbc_files
from canfdi.bus import e2e
from firmware_sim.emitter import Disturbance, emit
from firmware_sim.scenario import load_scenario, parse_scenario
from firmware_sim.simulate import simulate
from tests.conftest import REPO


def _drain(bus: can.BusABC) -> list[can.Message]:
    out = []
    while (msg := bus.recv(timeout=0.0)) is not None:
        out.append(msg)
    return out


def test_every_frame_of_10k_samples_arrives_in_order_and_decodes():
    scenario = load_scenario("dc_motor_consecutive")
    channel = "canfdi-test-emitter"
    receiver = can.Bus(interface="virtual", channel=channel)
    sender = can.Bus(interface="virtual", channel=channel)
    try:
        stats = asyncio.run(emit(sender, scenario, speed=0, duration=100.0))
        frames = _drain(receiver)
    finally:
        sender.shutdown()
        receiver.shutdown()
    assert stats.samples == 10_000 and stats.clipped == {}
    db = dbc_files.load("motor_drive")
    drive = sorted(m.frame_id for m in db.messages if m.senders == ["DRIVE"])
    assert len(frames) == stats.frames_sent == 10_000 * len(drive)
    ids = np.array([f.arbitration_id for f in frames])
    # Each period sends its messages in ID order, and periods follow each other.
    np.testing.assert_array_equal(ids, np.tile(drive, 10_000))
    decoded = {fid: [] for fid in drive}
    for f in frames:
        assert e2e.check(f.arbitration_id, f.data)
        decoded[f.arbitration_id].append(
            db.decode_message(f.arbitration_id, f.data, decode_choices=False))
    for fid in drive:
        counters = np.array([d["Counter"] for d in decoded[fid]])
        np.testing.assert_array_equal(counters, np.arange(10_000) % 256)
    # The decoded values are the simulation's, to the DBC's resolution.
    truth = simulate(scenario, duration=100.0)
    currents = db.get_message_by_name("DRIVE_CURRENTS").frame_id
    i_f = np.array([d["i_f"] for d in decoded[currents]])
    np.testing.assert_allclose(i_f, truth.z[:, 0], atol=0.0005 + 1e-9)
    cmd = db.get_message_by_name("DRIVE_CMD").frame_id
    volts = np.array([d["V"] for d in decoded[cmd]])
    np.testing.assert_allclose(volts, truth.u_c[:, 0], atol=0.005 + 1e-9)


def test_disturbances_drop_and_corrupt_frames():
    scenario = parse_scenario({"plant": "dc_motor", "duration": 10.0, "seed": 9})
    channel = "canfdi-test-disturb"
    receiver = can.Bus(interface="virtual", channel=channel)
    sender = can.Bus(interface="virtual", channel=channel)
    try:
        stats = asyncio.run(emit(sender, scenario, speed=0, disturbance=Disturbance(
            drop=0.05, bad_crc=0.02, wrong_dlc=0.02, seed=3)))
        frames = _drain(receiver)
    finally:
        sender.shutdown()
        receiver.shutdown()
    db = dbc_files.load("motor_drive")
    total = 1000 * 3
    assert len(frames) == stats.frames_sent == total - stats.frames_dropped
    assert 0.03 * total < stats.frames_dropped < 0.07 * total
    lengths = {m.frame_id: m.length for m in db.messages}
    wrong = sum(f.dlc != lengths[f.arbitration_id] for f in frames)
    bad = sum(f.dlc == lengths[f.arbitration_id] and not e2e.check(f.arbitration_id, f.data)
              for f in frames)
    assert wrong == stats.frames_wrong_dlc > 0
    assert bad > 0 and bad <= stats.frames_bad_crc


def test_paced_run_takes_real_time_scaled_by_speed():
    """At --speed 10, 0.5 s of scenario time take at least 0.05 s of wall time."""
    scenario = parse_scenario({"plant": "dc_motor", "duration": 0.5, "seed": 1})
    bus = can.Bus(interface="virtual", channel="canfdi-test-paced")
    try:
        stats = asyncio.run(emit(bus, scenario, speed=10.0))
    finally:
        bus.shutdown()
    assert stats.samples == 50
    assert stats.elapsed >= 0.049 * 0.99


def test_cli_writes_truth_and_reports(tmp_path):
    truth = tmp_path / "truth.json"
    res = subprocess.run(
        [sys.executable, "-m", "canfdi", "sim", "--scenario", "dc_motor_actuator", "--speed", "0",
         "--duration", "2", "--truth", str(truth), "--quiet"],
        capture_output=True, text=True, cwd=REPO, timeout=120)
    assert res.returncode == 0, res.stderr
    report = json.loads(res.stdout)
    assert report["samples"] == 200 and report["frames_sent"] == 600
    faults = json.loads(truth.read_text())["faults"]
    assert faults == [{"target": "actuator", "index": 0, "kind": "scale_bias", "onset": 10.0,
                       "eta": 2.0, "lambda": 10.0, "name": "V", "onset_sample": 1000,
                       "end_sample": None}]


def test_cli_bad_scenario_exits_2_naming_the_field(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("plant: dc_motor\nduration: 5\nfaults:\n  - {target: sensor, index: 9, "
                   "onset: 1, bias: 1}\n")
    res = subprocess.run([sys.executable, "-m", "canfdi", "sim", "--scenario", str(bad)],
                         capture_output=True, text=True, cwd=REPO, timeout=60)
    assert res.returncode == 2 and "faults[0].index" in res.stderr

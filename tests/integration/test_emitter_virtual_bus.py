"""The emulator on python-can's virtual bus, heard by an independent receiver."""

import asyncio
import json
import subprocess
import sys
import time

import can
import numpy as np
import pytest

from canfdi import dbc as dbc_files
from canfdi.bus import e2e
from canfdi.firmware_sim.emitter import Disturbance, emit, frame_log
from canfdi.firmware_sim.profiles import PROFILES
from canfdi.firmware_sim.scenario import load_scenario, parse_scenario
from canfdi.firmware_sim.simulate import simulate
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
         "--duration", "2", "--truth", str(truth), "--quiet", "--json"],
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


# --- every bus profile, heard by python-can, cantools and python-canopen ----------------------

PROFILE_SCENARIOS = ["dc_motor_consecutive", "dc_motor_consecutive_cia402",
                     "dc_motor_consecutive_float", "dc_motor_two_drives_cia402"]
# DBC ID of a received frame ID, per profile (several drives: back to the DBC's node)
DBC_ID = {"canfdi": lambda fid: fid, "cia402": lambda fid: (fid & ~0x7F) | min(fid & 0x7F, 1),
          "float_node": lambda fid: fid & 0x1F}


def _emit_and_receive(scenario, channel, **kwargs):
    receiver = can.Bus(interface="virtual", channel=channel)
    sender = can.Bus(interface="virtual", channel=channel)
    try:
        stats = asyncio.run(emit(sender, scenario, **kwargs))
        frames = _drain(receiver)
    finally:
        sender.shutdown()
        receiver.shutdown()
    return stats, frames


@pytest.mark.parametrize("name", PROFILE_SCENARIOS)
def test_an_independent_receiver_logs_and_decodes_every_frame(tmp_path, name):
    """python-can receives an emit run, writes it with its own loggers (.asc, .blf), reads it
    back with its LogReader and cantools decodes every data frame: the frames are frame_log's,
    in order, and carry the drives' values."""
    scenario = load_scenario(name)
    stats, received = _emit_and_receive(scenario, f"canfdi-test-{name}", speed=0,
                                        duration=5.0, block=64)
    ref = frame_log(scenario, duration=5.0)
    assert stats.profile == scenario.profile and stats.clipped == {}
    assert len(received) == stats.frames_sent == ref.frames.size
    database = dbc_files.load(PROFILES[scenario.profile].dbc("dc_motor"))
    to_dbc = DBC_ID[scenario.profile]
    for suffix in (".asc", ".blf"):
        path = tmp_path / f"run{suffix}"
        with can.Logger(path) as writer:
            for msg in received:
                writer(msg)
        frames = list(can.LogReader(path))
        assert len(frames) == ref.frames.size, suffix
        np.testing.assert_array_equal([f.arbitration_id for f in frames], ref.frames.id)
        np.testing.assert_array_equal([f.is_remote_frame for f in frames],
                                      (ref.frames.flags & 2) != 0)
        np.testing.assert_array_equal([f.dlc for f in frames], ref.frames.dlc)
        data = [bytes(f.data) for f in frames if not f.is_remote_frame]
        want = [p for p, fl in zip(ref.frames.payloads(), ref.frames.flags.tolist(), strict=True)
                if not fl & 2]
        assert data == want, suffix
    # Every data frame decodes; the command and the speed are each drive's.
    values: dict[tuple[int, str], list[float]] = {}
    for f in frames:
        if f.is_remote_frame:
            continue
        for sig, v in database.decode_message(to_dbc(f.arbitration_id), f.data,
                                              decode_choices=False).items():
            values.setdefault((f.arbitration_id, sig), []).append(v)
    carriers = {"canfdi": lambda node: ((0x104, "V"), (0x106, "omega_r")),
                "cia402": lambda node: ((0x200 + node, "TargetVoltage"),
                                        (0x180 + node, "VelocityActualValue")),
                "float_node": lambda node: ((node << 5 | 0x0E, "Input_Voltage"),
                                            (node << 5 | 0x09, "Vel_Estimate"))}
    for drive in ref.drives:
        command, speed = carriers[scenario.profile](drive.node)
        np.testing.assert_allclose(values[command], drive.chunk.u_c[:, 0], atol=0.005)
        np.testing.assert_allclose(values[speed], drive.chunk.z[:, 3], atol=0.005)


@pytest.mark.parametrize("name", ["dc_motor_consecutive_cia402", "dc_motor_consecutive_float",
                                  "dc_motor_two_drives_cia402"])
def test_disturbed_emit_sends_what_frame_log_lists(name):
    scenario = load_scenario(name)
    disturbance = Disturbance(drop=0.05, wrong_dlc=0.05, seed=11)
    stats, received = _emit_and_receive(scenario, f"canfdi-test-disturbed-{name}", speed=0,
                                        duration=3.0, disturbance=disturbance, block=50)
    ref = frame_log(scenario, disturbance, duration=3.0)
    assert (stats.frames_dropped, stats.frames_wrong_dlc, stats.frames_sent) == (
        ref.stats.frames_dropped, ref.stats.frames_wrong_dlc, ref.stats.frames_sent)
    assert stats.frames_dropped > 0 and stats.frames_wrong_dlc > 0
    np.testing.assert_array_equal([m.arbitration_id for m in received], ref.frames.id)
    np.testing.assert_array_equal([m.dlc for m in received], ref.frames.dlc)


def test_bad_crc_is_refused_where_the_profile_has_no_crc():
    scenario = load_scenario("dc_motor_consecutive_float")
    bus = can.Bus(interface="virtual", channel="canfdi-test-nocrc")
    try:
        with pytest.raises(ValueError, match="no CRC"):
            asyncio.run(emit(bus, scenario, speed=0, disturbance=Disturbance(bad_crc=0.1)))
    finally:
        bus.shutdown()


def test_a_python_canopen_master_hears_the_cia402_drives():
    """python-canopen on the same virtual bus, with the EDS: both nodes' TPDOs arrive with the
    drives' values, and their heartbeats say OPERATIONAL."""
    import canopen

    scenario = load_scenario("dc_motor_two_drives_cia402")
    channel = "canfdi-test-canopen"
    eds = str(PROFILES["cia402"].eds("dc_motor"))
    network = canopen.Network()
    network.connect(interface="virtual", channel=channel)
    sender = can.Bus(interface="virtual", channel=channel)
    try:
        speeds: dict[int, list[float]] = {1: [], 2: []}
        nodes = {}
        for node_id in (1, 2):
            node = network.add_node(node_id, eds)
            node.tpdo.read(from_od=True)
            node.tpdo[1].add_callback(
                lambda m, n=node_id: speeds[n].append(m["Velocity actual value"].phys))
            nodes[node_id] = node
        stats = asyncio.run(emit(sender, scenario, speed=0, duration=2.0))
        deadline = time.monotonic() + 10.0
        while min(len(v) for v in speeds.values()) < 200 and time.monotonic() < deadline:
            time.sleep(0.01)
        states = {n: node.nmt.state for n, node in nodes.items()}
    finally:
        network.disconnect()
        sender.shutdown()
    assert stats.samples == 200
    ref = frame_log(scenario, duration=2.0)
    for i, node_id in enumerate((1, 2)):
        np.testing.assert_allclose(speeds[node_id], ref.drives[i].chunk.z[:, 3], atol=0.0006)
    assert states == {1: "OPERATIONAL", 2: "OPERATIONAL"}


def test_paced_cia402_run_keeps_sync_period_and_order():
    """At real time, SYNC comes every 10 ms and each period's PDOs arrive before the next SYNC;
    the heartbeat every 100 ms."""
    scenario = load_scenario("dc_motor_consecutive_cia402")
    stats, received = _emit_and_receive(scenario, "canfdi-test-paced-cia402", speed=1.0,
                                        duration=0.5)
    assert stats.samples == 50
    ids = [m.arbitration_id for m in received]
    # Periods in order: SYNC, TPDO1, TPDO2, RPDO1 (and every tenth period the heartbeat).
    period = [0x080, 0x181, 0x281, 0x201]
    expected = []
    for k in range(50):
        expected += period + ([0x701] if k % 10 == 0 else [])
    assert ids == expected
    sync_t = np.array([m.timestamp for m in received if m.arbitration_id == 0x080])
    assert abs(np.mean(np.diff(sync_t)) - 0.010) < 0.002
    hb_t = np.array([m.timestamp for m in received if m.arbitration_id == 0x701])
    assert abs(np.mean(np.diff(hb_t)) - 0.100) < 0.01


def test_cli_plays_a_profile_scenario_and_writes_per_drive_truth(tmp_path):
    truth = tmp_path / "truth.json"
    res = subprocess.run(
        [sys.executable, "-m", "canfdi", "sim", "--scenario", "dc_motor_two_drives_cia402",
         "--speed", "0", "--duration", "1", "--truth", str(truth), "--quiet", "--json"],
        capture_output=True, text=True, cwd=REPO, timeout=120)
    assert res.returncode == 0, res.stderr
    report = json.loads(res.stdout)
    assert report["profile"] == "cia402" and report["samples"] == 100
    assert report["frames_sent"] == 100 * (1 + 2 * 3) + 10 * 2
    doc = json.loads(truth.read_text())
    assert doc["profile"] == "cia402"
    assert [(d["name"], d["node"], len(d["faults"])) for d in doc["drives"]] == [
        ("left", 1, 3), ("right", 2, 0)]
    assert {f["drive"] for f in doc["faults"]} == {"left"}
    res = subprocess.run(
        [sys.executable, "-m", "canfdi", "sim", "--scenario", "dc_motor_consecutive_float",
         "--speed", "0", "--duration", "1", "--bad-crc", "0.1"],
        capture_output=True, text=True, cwd=REPO, timeout=60)
    assert res.returncode == 2 and "float_node" in res.stderr and "CRC" in res.stderr


def test_cli_records_a_healthy_run_to_a_candump_log(tmp_path):
    """`sim --healthy -o drive.log`: the scenario's drive without its faults, as a candump that
    python-can reads back frame for frame."""
    import can

    log, truth = tmp_path / "drive.log", tmp_path / "truth.json"
    res = subprocess.run(
        [sys.executable, "-m", "canfdi", "sim", "--scenario", "dc_motor_consecutive", "--healthy",
         "--duration", "2", "--truth", str(truth), "-o", str(log), "--quiet", "--json"],
        capture_output=True, text=True, cwd=REPO, timeout=120)
    assert res.returncode == 0, res.stderr
    report = json.loads(res.stdout)
    assert report["scenario"] == "dc_motor_consecutive without faults"
    assert report["samples"] == 200
    assert sum(1 for _ in can.CanutilsLogReader(str(log))) == report["frames"] > 0
    assert json.loads(truth.read_text())["faults"] == []

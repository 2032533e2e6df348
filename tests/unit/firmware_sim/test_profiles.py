"""The emulator's bus profiles: the registry, canfdi's frames unchanged, CiA 402 and the node-ID
float protocol decoded by cantools (the DBCs) and python-canopen (the EDS) back to the plant's
values, their timing, RTR polls, and several drives on one bus."""

from __future__ import annotations

import functools

import numpy as np
import pytest

from canfdi import dbc as dbc_files
from canfdi.bus.frames import FLAG_REMOTE, FrameBlock
from canfdi.firmware_sim.emitter import Disturbance, EmitStats, FrameEncoder, FrameLog, frame_log
from canfdi.firmware_sim.plants import PLANTS
from canfdi.firmware_sim.profiles import PROFILES, get_profile
from canfdi.firmware_sim.profiles.base import Field, Slot, pack
from canfdi.firmware_sim.profiles.cia402 import read_device
from canfdi.firmware_sim.scenario import SCENARIO_DIR, Scenario, load_scenario, parse_scenario
from canfdi.firmware_sim.simulate import Simulator

DT_NS = 10_000_000


@functools.cache
def _db(name: str):
    return dbc_files.load(name)


@functools.cache
def _log(scenario: str, duration: float = 3.0) -> FrameLog:
    return frame_log(load_scenario(scenario), duration=duration)


def _decode(log: FrameLog, database, node_of=lambda fid: fid) -> list[tuple[int, int, dict]]:
    """(t_ns, frame_id, decoded signals) of every data frame, with the DBC ID ``node_of(id)``."""
    out = []
    frames = log.frames
    for t, fid, flags, payload in zip(frames.t_ns.tolist(), frames.id.tolist(),
                                      frames.flags.tolist(), frames.payloads(), strict=True):
        if flags & FLAG_REMOTE:
            continue
        out.append((t, fid, database.decode_message(node_of(fid), payload,
                                                    decode_choices=False)))
    return out


def _series(decoded, frame_id: int, signal: str) -> np.ndarray:
    return np.array([d[signal] for _, fid, d in decoded if fid == frame_id])


# --- the registry ---------------------------------------------------------------------------


def test_registry_names_profiles_and_their_dbcs():
    assert sorted(PROFILES) == ["canfdi", "cia402", "float_node"]
    assert get_profile("cia402") is PROFILES["cia402"]
    with pytest.raises(ValueError, match=r"cia402"):
        get_profile("cia401")
    for profile in PROFILES.values():
        assert profile.dbc("dc_motor") in dbc_files.available(), profile.name
        assert "dc_motor" in profile.plants()
    # Every plant but the servo axis has a DBC of canfdi's own bus; the servo axis speaks the
    # node-id float protocol only (as an ODrive does).
    assert PROFILES["canfdi"].plants() == [name for name in PLANTS if name != "servo_axis"]
    assert PROFILES["float_node"].plants() == ["dc_motor", "servo_axis"]
    assert PROFILES["float_node"].dbc("servo_axis") in dbc_files.available()
    assert PROFILES["cia402"].dbc("vtol") is None and PROFILES["float_node"].dbc("vtol") is None


def test_pack_matches_cantools_and_counts_clipping():
    db = _db("dc_motor_cia402")
    message = db.get_message_by_name("TPDO2_node1")
    fields = [Field.of(sig) for sig in message.signals]
    values = np.array([[1.234, -20.0, 40.0], [0.0, 32.767, -32.768]])
    clipped: dict[str, int] = {}
    payloads = pack([(f, values[:, i]) for i, f in enumerate(fields)], 2, clipped)
    assert clipped == {"LineCurrent": 1}
    want = message.encode({"FieldCurrent": 1.234, "ArmatureCurrent": -20.0,
                           "LineCurrent": 32.767}).ljust(8, b"\0")
    assert payloads[0].tobytes() == want
    assert payloads[1].tobytes() == message.encode(dict(zip(
        ("FieldCurrent", "ArmatureCurrent", "LineCurrent"), values[1], strict=True))
    ).ljust(8, b"\0")


def test_slots_refuse_what_a_bus_cannot_carry():
    with pytest.raises(ValueError, match="11-bit"):
        Slot("X", 0x800, 8, 0.0)
    with pytest.raises(ValueError, match="DLC"):
        Slot("X", 0x100, 9, 0.0)
    with pytest.raises(ValueError, match="every"):
        Slot("X", 0x100, 8, 0.0, every=10, phase=10)


# --- canfdi: today's frames, frame for frame ---------------------------------------------------


def _reference_frame_log(scenario: Scenario, disturbance: Disturbance | None = None,
                         duration: float | None = None, frame_spacing: float = 130e-6):
    """frame_log as it was before bus profiles (git 'acf805d'), kept as the reference."""
    disturbance = disturbance or Disturbance()
    sim = Simulator(scenario)
    total = sim.total_samples if duration is None else round(duration / sim.plant.dt)
    chunk = sim.advance(total)
    encoder = FrameEncoder(sim.plant)
    payloads, clipped = encoder.encode(chunk)
    n, m = len(chunk), len(payloads)
    rng = np.random.default_rng(disturbance.seed)
    base = np.round(chunk.k * sim.plant.dt * 1e9).astype(np.int64)
    t = base[:, None] + np.round(np.arange(m) * frame_spacing * 1e9).astype(np.int64)
    if disturbance.jitter:
        t = t + np.round(rng.uniform(0.0, disturbance.jitter, (n, m)) * 1e9).astype(np.int64)
    ids = np.broadcast_to([lay.frame_id for lay in encoder.layouts], (n, m))
    dlc = np.broadcast_to([p.shape[1] for p in payloads], (n, m)).copy()
    data = np.zeros((n, m, 8), dtype=np.uint8)
    for i, p in enumerate(payloads):
        data[:, i, : p.shape[1]] = p
    stats = EmitStats(samples=n, clipped=clipped)
    u = rng.random((n, m, 3))
    keep = u[..., 0] >= disturbance.drop
    bad_crc = keep & (u[..., 1] < disturbance.bad_crc)
    data[..., 0] ^= np.where(bad_crc, 0xFF, 0).astype(np.uint8)
    wrong = keep & (u[..., 2] < disturbance.wrong_dlc)
    dlc = np.where(wrong, np.where(dlc > 2, dlc - 1, dlc + 1), dlc)
    stats.frames_dropped = int((~keep).sum())
    stats.frames_bad_crc = int(bad_crc.sum())
    stats.frames_wrong_dlc = int(wrong.sum())
    stats.frames_sent = int(keep.sum())
    order = np.argsort(t[keep], kind="stable")
    n_kept = int(keep.sum())
    frames = FrameBlock(t[keep][order], ids[keep][order], dlc[keep][order],
                        np.zeros(n_kept, dtype=np.uint8), data[keep][order])
    return frames, stats, sim.truth(), chunk


@pytest.mark.parametrize(("scenario", "disturbance"), [
    ("dc_motor_consecutive", None),
    ("dc_motor_consecutive", Disturbance(drop=0.05, jitter=0.002, bad_crc=0.03, wrong_dlc=0.02,
                                         seed=7)),
    ("winding_machine_consecutive", Disturbance(drop=0.1, seed=3)),
    ("vtol_actuators", None),
])
def test_canfdi_profile_is_frame_for_frame_todays(scenario, disturbance):
    sc = load_scenario(scenario)
    assert sc.profile == "canfdi" and len(sc.drives) == 1 and sc.drives[0].node is None
    frames, stats, truth, chunk = _reference_frame_log(sc, disturbance, duration=12.0)
    log = frame_log(sc, disturbance, duration=12.0)
    for name in ("t_ns", "id", "dlc", "flags", "data"):
        np.testing.assert_array_equal(getattr(log.frames, name), getattr(frames, name), name)
    assert log.stats.as_dict() == {**stats.as_dict(), "profile": "canfdi"}
    assert log.truth == truth and log.drives[0].truth == truth
    np.testing.assert_array_equal(log.chunk.z, chunk.z)
    np.testing.assert_array_equal(log.chunk.u_c, chunk.u_c)


# --- cia402 ----------------------------------------------------------------------------------


def test_cia402_frames_decode_to_the_plants_values():
    log = _log("dc_motor_consecutive_cia402", 12.0)
    assert log.profile == "cia402" and log.stats.clipped == {}
    db = _db("dc_motor_cia402")
    decoded = _decode(log, db)
    chunk = log.chunk
    n = len(chunk)
    assert set(log.frames.id.tolist()) == {0x080, 0x181, 0x201, 0x281, 0x701}
    assert not (log.frames.flags & FLAG_REMOTE).any()
    np.testing.assert_allclose(_series(decoded, 0x201, "TargetVoltage"), chunk.u_c[:, 0],
                               atol=0.0005 + 1e-9)
    for j, name in enumerate(("FieldCurrent", "ArmatureCurrent", "LineCurrent")):
        np.testing.assert_allclose(_series(decoded, 0x281, name), chunk.z[:, j],
                                   atol=0.0005 + 1e-9)
    factor = db.get_message_by_name("TPDO1_node1").get_signal_by_name(
        "VelocityActualValue").scale
    np.testing.assert_allclose(_series(decoded, 0x181, "VelocityActualValue"), chunk.z[:, 3],
                               atol=factor / 2 + 1e-9)
    assert set(_series(decoded, 0x181, "Statusword")) == {0x0237}
    assert set(_series(decoded, 0x201, "Controlword")) == {0x000F}
    assert set(_series(decoded, 0x701, "NMT_State")) == {5}
    assert len(_series(decoded, 0x181, "Statusword")) == n


def test_cia402_timing_sync_pdos_heartbeat():
    log = _log("dc_motor_consecutive_cia402")
    frames = log.frames
    n = len(log.chunk)
    t, ids = frames.t_ns, frames.id
    sync = t[ids == 0x080]
    np.testing.assert_array_equal(sync, np.arange(n) * DT_NS)
    assert (frames.dlc[ids == 0x080] == 0).all()
    period = t // DT_NS
    for fid in (0x181, 0x281, 0x201):
        # Exactly one per period, strictly after that period's SYNC and before the next.
        np.testing.assert_array_equal(period[ids == fid], np.arange(n))
        assert ((t[ids == fid] % DT_NS) > 0).all()
    # The master's RPDO follows the drive's TPDOs of the same period.
    assert (t[ids == 0x201] > t[ids == 0x281]).all() and (t[ids == 0x281] > t[ids == 0x181]).all()
    heartbeat = t[ids == 0x701]
    np.testing.assert_array_equal(np.diff(heartbeat), 100_000_000)
    assert heartbeat[0] // DT_NS == 0 and len(heartbeat) == n // 10


def test_cia402_a_trigger_on_sync_forms_period_k_at_sync_k_plus_1():
    """What a monitor's trigger clock sees (docs/bus.md), replayed here by hand: at SYNC k+1,
    the newest value of each signal received up to it is the command and the measurements of
    period k."""
    log = _log("dc_motor_consecutive_cia402")
    db = _db("dc_motor_cia402")
    newest: dict[str, float] = {}
    samples = []
    for fid, payload in zip(log.frames.id.tolist(), log.frames.payloads(), strict=True):
        if fid == 0x080:
            if newest:
                samples.append(dict(newest))
            continue
        newest.update(db.decode_message(fid, payload, decode_choices=False))
    chunk = log.chunk
    assert len(samples) == len(chunk) - 1
    v = np.array([s["TargetVoltage"] for s in samples])
    i_a = np.array([s["ArmatureCurrent"] for s in samples])
    np.testing.assert_allclose(v, chunk.u_c[:-1, 0], atol=0.0005 + 1e-9)
    np.testing.assert_allclose(i_a, chunk.z[:-1, 1], atol=0.0005 + 1e-9)


def test_cia402_dbc_describes_the_eds_pdos_of_node_1():
    """The DBC (for CAN tools and the monitor) and the EDS (the drive, read by python-canopen)
    say the same: COB-IDs, DLCs, each mapped object's bits, signedness and factor."""
    db = _db("dc_motor_cia402")
    device = read_device(PROFILES["cia402"].eds("dc_motor"), 1)
    assert device.sync_id == db.get_message_by_name("SYNC").frame_id == 0x080
    assert device.heartbeat_ms == db.get_message_by_name("HEARTBEAT_node1").cycle_time == 100
    assert device.cycle_us == 10_000
    pdos = (*device.tpdos, *device.rpdos)
    assert sorted(p.name(1) for p in pdos) == ["RPDO1_node1", "TPDO1_node1", "TPDO2_node1"]
    for pdo in pdos:
        message = db.get_message_by_name(pdo.name(1))
        assert (message.frame_id, message.length) == (pdo.cob_id, pdo.dlc)
        assert message.senders == (["DRIVE"] if pdo.kind == "TPDO" else ["MASTER"])
        signals = sorted(message.signals, key=lambda s: s.start)
        assert len(signals) == len(pdo.fields)
        for sig, (field, _index) in zip(signals, pdo.fields, strict=True):
            assert (sig.start, sig.length, sig.is_signed, sig.is_float) == (
                field.start, field.length, field.signed, field.is_float), sig.name
            assert sig.scale == pytest.approx(field.factor, rel=1e-15), sig.name


def test_cia402_tpdos_decode_with_python_canopen():
    """python-canopen, as a master reading the EDS, decodes the TPDOs to the same values."""
    import canopen

    log = _log("dc_motor_consecutive_cia402", 1.0)
    network = canopen.Network()
    node = canopen.RemoteNode(1, canopen.import_od(str(PROFILES["cia402"].eds("dc_motor")), 1))
    network.add_node(node)
    node.tpdo.read(from_od=True)
    speeds, currents = [], []
    node.tpdo[1].add_callback(lambda m: speeds.append(m["Velocity actual value"].phys))
    node.tpdo[2].add_callback(lambda m: currents.append(m["Field current actual value"].phys))
    for fid, payload, t in zip(log.frames.id.tolist(), log.frames.payloads(),
                               log.frames.t_ns.tolist(), strict=True):
        network.notify(fid, bytearray(payload), t / 1e9)
    np.testing.assert_allclose(speeds, log.chunk.z[:, 3], atol=0.0006)
    np.testing.assert_allclose(currents, log.chunk.z[:, 0], atol=0.0005 + 1e-9)


def test_cia402_has_no_crc_to_corrupt_and_keeps_other_disturbances():
    scenario = load_scenario("dc_motor_consecutive_cia402")
    with pytest.raises(ValueError, match=r"bad_crc.*no CRC"):
        frame_log(scenario, Disturbance(bad_crc=0.1), duration=1.0)
    log = frame_log(scenario, Disturbance(drop=0.1, wrong_dlc=0.1, jitter=0.001, seed=2),
                    duration=5.0)
    total = 500 * 4 + 50
    assert log.stats.frames_sent + log.stats.frames_dropped == total
    assert log.frames.size == log.stats.frames_sent
    assert 0.05 * total < log.stats.frames_dropped < 0.15 * total
    lengths = {0x080: 0, 0x181: 6, 0x201: 6, 0x281: 6, 0x701: 1}
    wrong = sum(int(d) != lengths[int(i)] for i, d in zip(log.frames.id, log.frames.dlc,
                                                         strict=True))
    assert wrong == log.stats.frames_wrong_dlc > 0
    assert (np.diff(log.frames.t_ns) >= 0).all()


# --- float_node -------------------------------------------------------------------------------


def test_float_node_frames_decode_to_the_plants_values():
    log = _log("dc_motor_consecutive_float", 12.0)
    assert log.profile == "float_node" and log.stats.clipped == {}
    db = _db("dc_motor_float")
    decoded = _decode(log, db)
    chunk = log.chunk
    f32 = functools.partial(np.testing.assert_allclose, rtol=2**-23, atol=1e-30)
    f32(_series(decoded, 0x00E, "Input_Voltage"), chunk.u_c[:, 0])
    f32(_series(decoded, 0x014, "Field_Current"), chunk.z[:, 0])
    f32(_series(decoded, 0x014, "Armature_Current"), chunk.z[:, 1])
    f32(_series(decoded, 0x017, "Bus_Current"), chunk.z[:, 2])
    f32(_series(decoded, 0x009, "Vel_Estimate"), chunk.z[:, 3])
    angle = np.cumsum(chunk.z[:, 3]) * 0.01
    np.testing.assert_allclose(_series(decoded, 0x009, "Pos_Estimate"), angle, rtol=1e-6)
    assert set(_series(decoded, 0x017, "Bus_Voltage")) == {320.0}
    assert set(_series(decoded, 0x001, "Axis_State")) == {8}


def test_float_node_ids_are_node_shift_5_or_cmd():
    log = frame_log(parse_scenario({"plant": "dc_motor", "duration": 0.5, "seed": 2,
                                    "bus": {"profile": "float_node", "node": 5}}))
    assert set(log.frames.id.tolist()) == {5 << 5 | cmd for cmd in (0x01, 0x09, 0x0E, 0x14, 0x17)}
    decoded = _decode(log, _db("dc_motor_float"), node_of=lambda fid: fid & 0x1F)
    np.testing.assert_allclose(_series(decoded, 5 << 5 | 0x0E, "Input_Voltage"),
                               log.chunk.u_c[:, 0], rtol=2**-23)


def test_float_node_currents_are_polled_by_rtr_and_answered():
    log = _log("dc_motor_consecutive_float")
    frames = log.frames
    n = len(log.chunk)
    remote = (frames.flags & FLAG_REMOTE) != 0
    assert set(frames.id[remote].tolist()) == {0x014, 0x017}
    assert (frames.dlc[remote] == 8).all() and not frames.data[remote].any()
    # Each request is answered by the next frame, a data frame of the same ID, in the same
    # period; every period polls both messages once.
    rows = np.flatnonzero(remote)
    assert len(rows) == 2 * n
    answers = rows + 1
    np.testing.assert_array_equal(frames.id[answers], frames.id[rows])
    assert not remote[answers].any()
    np.testing.assert_array_equal(frames.t_ns[answers] // DT_NS, frames.t_ns[rows] // DT_NS)
    for fid in (0x014, 0x017):
        data_rows = np.flatnonzero((frames.id == fid) & ~remote)
        np.testing.assert_array_equal(data_rows, answers[frames.id[rows] == fid])
    # The estimates open each period, the setpoint follows the polls; heartbeat every 100 ms.
    t, ids = frames.t_ns, frames.id
    np.testing.assert_array_equal(t[ids == 0x009], np.arange(n) * DT_NS)
    assert (t[ids == 0x00E] > t[(ids == 0x017) & ~remote]).all()
    assert ((t[ids == 0x00E] % DT_NS) < DT_NS // 2).all()
    np.testing.assert_array_equal(np.diff(t[ids == 0x001]), 100_000_000)


def test_float_node_wrong_dlc_spares_remote_frames():
    log = frame_log(load_scenario("dc_motor_consecutive_float"),
                    Disturbance(wrong_dlc=0.5, seed=1), duration=1.0)
    remote = (log.frames.flags & FLAG_REMOTE) != 0
    assert (log.frames.dlc[remote] == 8).all()
    assert log.stats.frames_wrong_dlc == int((log.frames.dlc[~remote] != np.array(
        [{0x001: 8, 0x009: 8, 0x00E: 4, 0x014: 8, 0x017: 8}[i]
         for i in log.frames.id[~remote].tolist()])).sum()) > 0


# --- several drives ---------------------------------------------------------------------------


def test_two_cia402_drives_share_sync_and_keep_their_node_ids():
    log = _log("dc_motor_two_drives_cia402", 12.0)
    assert [d.name for d in log.drives] == ["left", "right"]
    assert [d.node for d in log.drives] == [1, 2]
    ids = log.frames.id
    assert set(ids.tolist()) == {0x080, 0x181, 0x182, 0x281, 0x282, 0x201, 0x202, 0x701, 0x702}
    n = len(log.chunk)
    assert (ids == 0x080).sum() == n
    period = log.frames.t_ns // DT_NS
    for fid in (0x181, 0x182, 0x281, 0x282, 0x201, 0x202):
        np.testing.assert_array_equal(period[ids == fid], np.arange(n))
    db = _db("dc_motor_cia402")
    decoded = _decode(log, db, node_of=lambda fid: (fid & ~0x7F) | min(fid & 0x7F, 1))
    for i, drive in enumerate(log.drives):
        node = drive.node
        np.testing.assert_allclose(_series(decoded, 0x200 + node, "TargetVoltage"),
                                   drive.chunk.u_c[:, 0], atol=0.0005 + 1e-9)
        np.testing.assert_allclose(_series(decoded, 0x280 + node, "ArmatureCurrent"),
                                   drive.chunk.z[:, 1], atol=0.0005 + 1e-9, err_msg=str(i))
    # Faults on the left drive only; its run is dc_motor_consecutive's (same seed, offset 0).
    assert [f["name"] for f in log.drives[0].truth] == ["V", "i_f", "i_a"]
    assert log.drives[1].truth == [] and log.truth == log.drives[0].truth
    single = _log("dc_motor_consecutive_cia402", 12.0).chunk
    np.testing.assert_array_equal(log.drives[0].chunk.z, single.z)
    assert not np.array_equal(log.drives[1].chunk.z, single.z)


def test_two_float_drives_interleave_within_each_period():
    log = frame_log(parse_scenario({
        "plant": "dc_motor", "duration": 1.0, "seed": 3, "bus": {"profile": "float_node"},
        "drives": [{"name": "a", "node": 0}, {"name": "b", "node": 1,
                                               "faults": [{"target": "sensor", "index": 3,
                                                           "onset": 0.5, "bias": 2.0}]}]}))
    ids = set(log.frames.id.tolist())
    assert ids == {node << 5 | cmd for node in (0, 1) for cmd in (0x01, 0x09, 0x0E, 0x14, 0x17)}
    assert (np.diff(log.frames.t_ns) >= 0).all()
    decoded = _decode(log, _db("dc_motor_float"), node_of=lambda fid: fid & 0x1F)
    for drive in log.drives:
        np.testing.assert_allclose(_series(decoded, drive.node << 5 | 0x09, "Vel_Estimate"),
                                   drive.chunk.z[:, 3], rtol=2**-23)
    assert log.drives[1].truth[0]["onset_sample"] == 50


# --- every shipped scenario fits its profile's signals ----------------------------------------


@pytest.mark.parametrize("name", sorted(p.stem for p in SCENARIO_DIR.glob("*.yaml")))
def test_shipped_scenarios_encode_without_clipping(name):
    scenario = load_scenario(name)
    log = frame_log(scenario)
    assert log.stats.clipped == {}, name
    assert log.stats.frames_sent == log.frames.size > 0

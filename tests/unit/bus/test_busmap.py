"""BusMap: model names onto DBC messages, and frame decoding equal to cantools, scalar and batch."""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path

import cantools
import numpy as np
import pytest

from canfdi import dbc as dbc_files
from canfdi.bus.dbc import BusMap
from canfdi.bus.e2e import check, protect
from canfdi.bus.frames import FLAG_EXTENDED, STATUS_CODES, STATUS_NAMES, FrameBlock
from canfdi.config import BusConfig, ConfigError, load_config
from canfdi.core.settings import (
    ClockConfig,
    DriveConfig,
    E2EConfig,
    MonitorFramesConfig,
    SignalRef,
)
from canfdi.firmware_sim.chunk import SimChunk
from canfdi.firmware_sim.emitter import FrameEncoder
from canfdi.firmware_sim.scenario import load_scenario
from canfdi.firmware_sim.simulate import Simulator
from canfdi.monitor import Monitor

REPO = Path(__file__).resolve().parents[3]
DC_MOTOR_CONFIG = REPO / "deploy" / "config" / "dc_motor.yaml"
CONFIGS = REPO / "deploy" / "config"
DT_NS = 10_000_000  # motor_drive: dt = 0.01 s
# Frames of one period are spread over its first 300 us, in ID order, like a real drive.
FRAME_SPACING_NS = 100_000


def _block(ids, dlc, payloads) -> FrameBlock:
    """Frames of those IDs, lengths and payloads (times and flags 0)."""
    n = len(ids)
    return FrameBlock(np.zeros(n, dtype=np.int64), ids, dlc, np.zeros(n, dtype=np.uint8),
                      payloads)


@functools.cache
def dc_motor_config():
    return load_config(DC_MOTOR_CONFIG)


@functools.cache
def dc_motor_map() -> BusMap:
    """The DC motor's map as the monitor builds it (its own frames known as "monitor")."""
    return Monitor(dc_motor_config(), diagnose=False).bus_map


@functools.cache
def drive_traffic(n: int, k0: int = 0, scenario: str = "dc_motor_actuator"
                  ) -> tuple[SimChunk, tuple[tuple[int, int, bytes, int], ...]]:
    """Protected drive frames of samples k0 .. k0+n-1 of a canfdi.firmware_sim scenario.

    Returns
    -------
    chunk : the simulated samples.
    frames : (3 n,) (timestamp_ns, frame_id, payload, k), in ID order within each period.
    """
    sim = Simulator(load_scenario(scenario))
    if k0:
        sim.advance(k0)
    chunk = sim.advance(n)
    encoder = FrameEncoder(sim.plant)
    payloads, clipped = encoder.encode(chunk)
    assert clipped == {}
    frames = []
    for i, k in enumerate(chunk.k.tolist()):
        for j, (layout, block) in enumerate(zip(encoder.layouts, payloads, strict=True)):
            frames.append((k * DT_NS + j * FRAME_SPACING_NS, layout.frame_id,
                           block[i].tobytes(), k))
    return chunk, tuple(frames)


def as_log(frames) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(timestamps_ns, ids, dlc, payloads (N, 8)) arrays of (t, id, data, ...) tuples."""
    n = len(frames)
    payloads = np.zeros((n, 8), dtype=np.uint8)
    for i, frame in enumerate(frames):
        data = frame[2][:8]
        payloads[i, : len(data)] = np.frombuffer(data, dtype=np.uint8)
    t = np.array([f[0] for f in frames], dtype=np.int64)
    ids = np.array([f[1] for f in frames], dtype=np.int64)
    dlc = np.array([len(f[2]) for f in frames], dtype=np.int64)
    return t, ids, dlc, payloads


# -- mapping ------------------------------------------------------------------------------------


def test_dc_motor_config_maps_every_signal_to_its_message():
    bus_map = dc_motor_map()
    by_name = {}
    for layout, fields in zip(bus_map.layouts, bus_map.fields, strict=True):
        for name, vector, index in fields:
            by_name[name] = (layout.name, vector, index)
    assert by_name == {
        "V": ("DRIVE_CMD", "u", 0),
        "i_f": ("DRIVE_CURRENTS", "z", 0),
        "i_a": ("DRIVE_CURRENTS", "z", 1),
        "i_f_plus_i_a": ("DRIVE_CURRENTS", "z", 2),
        "omega_r": ("DRIVE_SPEED", "z", 3),
    }
    assert bus_map.slot_of == {(0x104, False): 0, (0x105, False): 1, (0x106, False): 2}
    assert {k[0] for k in bus_map.monitor_keys} == {0x080, 0x081, 0x082, 0x083}
    assert bus_map.unused_keys == frozenset()
    assert (bus_map.p, bus_map.q, bus_map.n_signals_max) == (1, 4, 3)
    assert bus_map.dbc_label == "motor_drive" and bus_map.counter_modulus == 256


def test_dbc_given_as_a_path_relative_to_the_config(tmp_path):
    target = tmp_path / "drive.dbc"
    target.write_text(dbc_files.path("motor_drive").read_text())
    config = dataclasses.replace(dc_motor_config(), path=tmp_path / "monitor.yaml",
                                 bus=BusConfig(dbc="drive.dbc"))
    bus_map = BusMap.from_config(config)
    assert bus_map.slot_of == dc_motor_map().slot_of
    assert bus_map.dbc_label == str(target)


def _config(**bus) -> object:
    """The DC motor config with some of its bus section replaced."""
    base = dc_motor_config()
    return dataclasses.replace(base, bus=dataclasses.replace(base.bus, **bus))


def test_an_unknown_model_signal_names_its_map_field_and_the_nearest_signals():
    config = dataclasses.replace(dc_motor_config(),
                                 outputs=["i_f", "i_a", "i_b", "omega_r"])
    with pytest.raises(ConfigError, match=r"no signal 'i_b' in motor_drive.*nearest signals: "
                                          r"i_f, i_a") as info:
        BusMap.from_config(config)
    assert info.value.field == "bus.map.i_b"


def test_the_map_takes_a_signal_by_message_name_or_id_whatever_its_name():
    config = _config(map={"i_f": SignalRef("DRIVE_CURRENTS", "i_a"),
                          "i_a": SignalRef(0x105, "i_f")})
    bus_map = BusMap.from_config(config)
    # (DBC signal, vector, model index), in payload order: signal i_f now carries model i_a.
    assert bus_map.fields[1] == (("i_f", "z", 1), ("i_a", "z", 0), ("i_f_plus_i_a", "z", 2))


@pytest.mark.parametrize(("ref", "field", "match"), [
    (SignalRef("DRIVE_CURENTS", "i_f"), "bus.map.i_f.message",
     r"no message 'DRIVE_CURENTS'.*did you mean DRIVE_CURRENTS"),
    (SignalRef(0x107, "i_f"), "bus.map.i_f.message", r"no message with ID 0x107"),
    (SignalRef("DRIVE_SPEED", "i_f"), "bus.map.i_f.signal",
     r"no signal 'i_f' in DRIVE_SPEED.*'i_f' is in DRIVE_CURRENTS"),
])
def test_a_bad_map_entry_names_its_key_and_the_nearest_names(ref, field, match):
    with pytest.raises(ConfigError, match=match) as info:
        BusMap.from_config(_config(map={"i_f": ref}))
    assert info.value.field == field


def test_missing_dbc_is_a_config_error():
    config = dataclasses.replace(dc_motor_config(), bus=BusConfig(dbc=None))
    with pytest.raises(ConfigError, match="a DBC file is needed to read the bus") as info:
        BusMap.from_config(config)
    assert info.value.field == "bus.dbc"


def test_dbc_that_does_not_exist_is_a_config_error(tmp_path):
    config = dataclasses.replace(dc_motor_config(), path=tmp_path / "monitor.yaml",
                                 bus=BusConfig(dbc="no_such_drive"))
    with pytest.raises(ConfigError, match="motor_drive") as info:
        BusMap.from_config(config)
    assert info.value.field == "bus.dbc"


_VENDOR_DBC = """VERSION ""
NS_ :
BS_:
BU_: MASTER DRIVE
BO_ 260 DRIVE_A: 4 DRIVE
 SG_ x : 0|16@1- (0.01,0) [-327.68|327.67] "" MASTER
 SG_ w : 16|16@1- (0.01,0) [-327.68|327.67] "" MASTER
BO_ 261 DRIVE_B: 4 DRIVE
 SG_ x : 0|16@1- (0.01,0) [-327.68|327.67] "" MASTER
BO_ 2348875520 EXT_FEEDBACK: 8 DRIVE
 SG_ y : 7|16@0- (0.5,1) [-1000|1000] "" MASTER
 SG_ Alive : 60|4@1+ (1,0) [0|15] "" MASTER
BO_ 40 SETPOINT: 2 MASTER
 SG_ u : 0|16@1+ (0.1,0) [0|6553.5] "" DRIVE
"""


def _vendor(tmp_path, inputs=("u",), outputs=("y", "w"), **bus):
    (tmp_path / "vendor.dbc").write_text(_VENDOR_DBC)
    base = dc_motor_config()
    bus = {"dbc": "vendor.dbc", "e2e": E2EConfig(default="none"), **bus}
    return dataclasses.replace(base, path=tmp_path / "monitor.yaml", inputs=list(inputs),
                               outputs=list(outputs), bus=BusConfig(**bus))


def test_a_signal_in_two_messages_must_be_mapped(tmp_path):
    with pytest.raises(ConfigError, match=r"'x' is in 2 messages of .*\(DRIVE_A, DRIVE_B\)"
                       ) as info:
        BusMap.from_config(_vendor(tmp_path, outputs=("y", "x")))
    assert info.value.field == "bus.map.x"
    config = _vendor(tmp_path, outputs=("y", "x"), map={"x": SignalRef("DRIVE_B", "x")})
    assert [lay.name for lay in BusMap.from_config(config).layouts] == [
        "SETPOINT", "DRIVE_B", "EXT_FEEDBACK"]


def test_any_sender_motorola_and_29_bit_messages_decode_as_cantools_does(tmp_path):
    bus_map = BusMap.from_config(_vendor(tmp_path))
    database = cantools.database.load_string(_VENDOR_DBC, database_format="dbc")
    message = database.get_message_by_name("EXT_FEEDBACK")
    payload = message.encode({"y": -123.5, "Alive": 9})
    key = (message.frame_id, True)
    assert key in bus_map.slot_of
    status, slot, values, _counter = bus_map.decode_frame(message.frame_id, payload,
                                                         FLAG_EXTENDED)
    assert (status, slot, values) == ("ok", bus_map.slot_of[key], (-123.5,))
    # Without its extended flag, the same ID is no message of the DBC.
    assert bus_map.decode_frame(message.frame_id, payload)[0] == "unknown_id"
    block = FrameBlock(np.zeros(2, dtype=np.int64), [message.frame_id] * 2, [8, 8],
                       [FLAG_EXTENDED, 0], np.frombuffer(payload * 2, np.uint8).reshape(2, 8))
    st, _sl, vals, _ = bus_map.decode_frames(block)
    assert [STATUS_NAMES[c] for c in st] == ["ok", "unknown_id"]
    assert vals[0, 0] == -123.5


def test_the_canfdi_profile_on_a_message_without_its_header_names_the_message(tmp_path):
    config = _vendor(tmp_path, e2e=E2EConfig(default="canfdi"))
    with pytest.raises(ConfigError, match="SETPOINT has no canfdi E2E header") as info:
        BusMap.from_config(config)
    assert info.value.field == "bus.e2e.default"


def test_a_counter_clock_needs_counters_and_says_so(tmp_path):
    with pytest.raises(ConfigError, match="counter clock needs an alive counter") as info:
        Monitor(_vendor(tmp_path), diagnose=False)
    assert info.value.field == "bus.clock.kind"


def test_node_ids_put_each_drive_on_its_own_ids(tmp_path):
    config = dataclasses.replace(
        _vendor(tmp_path, node_id="(id & ~0x0F) | node", clock=ClockConfig("grid")),
        drives=(DriveConfig("a", 1), DriveConfig("b", 2)))
    monitor = Monitor(config, diagnose=False)
    a, b = (d.bus_map for d in monitor.drives)
    assert [k[0] for k in a.keys] == [0x21, 0x101, 0x0C00FF01]
    assert [k[0] for k in b.keys] == [0x22, 0x102, 0x0C00FF02]
    # Each drive's messages are the other's "unused": known, not strangers.
    assert (0x22, False) in a.unused_keys and (0x21, False) in b.unused_keys
    bad = dataclasses.replace(config, bus=dataclasses.replace(config.bus,
                                                              node_id="id + node * 0x800"))
    with pytest.raises(ConfigError, match="not an 11-bit ID") as info:
        Monitor(bad, diagnose=False)
    assert info.value.field == "bus.node.id"


def test_monitor_ids_that_collide_are_refused_naming_them(tmp_path):
    config = _vendor(tmp_path, clock=ClockConfig("grid"),
                     monitor=MonitorFramesConfig(base=0x103))
    with pytest.raises(ConfigError, match=r"FDI_ESTIMATE 0x104, FDI_STATUS 0x105") as info:
        Monitor(config, diagnose=False)
    assert info.value.field == "bus.monitor"
    canopen = _vendor(tmp_path, clock=ClockConfig("grid"), canopen=True)
    with pytest.raises(ConfigError, match=r"FDI_FAULT 0x80 \(SYNC\), FDI_ESTIMATE 0x81 \(EMCY\)"):
        Monitor(canopen, diagnose=False)
    fine = _vendor(tmp_path, clock=ClockConfig("grid"), canopen=True,
                   monitor=MonitorFramesConfig(base=0x6E0))
    assert {k[0] for k in Monitor(fine, diagnose=False).frames.keys.values()} == {
        0x6E0, 0x6E1, 0x6E2, 0x6E3}


def test_monitor_ids_the_crc_confuses_with_the_drives_are_refused_when_both_carry_it():
    # 0x087 ^ 0x104 = 0x183, one of the ID differences canfdi's CRC-8 cannot see.
    base = dc_motor_config()
    moved = dataclasses.replace(base, bus=dataclasses.replace(
        base.bus, monitor=MonitorFramesConfig(ids={"FDI_FAULT": 0x087})))
    with pytest.raises(ConfigError, match="FDI_FAULT 0x87 with 0x104") as info:
        Monitor(moved, diagnose=False)
    assert info.value.field == "bus.monitor"
    # Without the CRC on the monitor's frames there is nothing to confuse.
    plain = dataclasses.replace(base, bus=dataclasses.replace(
        base.bus, monitor=MonitorFramesConfig(ids={"FDI_FAULT": 0x087}, e2e="none")))
    assert Monitor(plain, diagnose=False).frames.keys["FDI_FAULT"] == (0x087, False)


# -- decoding -----------------------------------------------------------------------------------


def test_decode_frame_equals_vectorised_decode_and_cantools_on_real_traffic():
    bus_map = dc_motor_map()
    database = dbc_files.load("motor_drive")
    _, frames = drive_traffic(600)
    _, ids, dlc, payloads = as_log(frames)
    status, slot, values, counters = bus_map.decode_frames(_block(ids, dlc, payloads))
    assert status.tolist() == [STATUS_CODES["ok"]] * len(frames)
    for i, (_, frame_id, data, k) in enumerate(frames):
        got_status, got_slot, got_values, got_counter = bus_map.decode_frame(frame_id, data)
        assert (got_status, got_slot) == ("ok", slot[i]) == ("ok",
                                                             bus_map.slot_of[(frame_id, False)])
        assert got_counter == counters[i]
        fields = bus_map.fields[got_slot]
        assert len(got_values) == len(fields)
        np.testing.assert_array_equal(values[i, : len(fields)], got_values)
        assert np.isnan(values[i, len(fields):]).all()
        assert counters[i] == k % 256
        reference = database.get_message_by_frame_id(frame_id).decode(
            data, decode_choices=False, scaling=True)
        assert reference["Counter"] == k % 256
        for (name, _, _), value in zip(fields, got_values, strict=True):
            assert value == pytest.approx(reference[name], rel=1e-12, abs=1e-12), (i, name)


def _mixed_frames() -> list[tuple[int, int, bytes]]:
    """Drive frames with every decode-level defect, plus monitor frames and strangers."""
    _, frames = drive_traffic(40)
    rng = np.random.default_rng(7)
    out = []
    for t, frame_id, data, _ in frames:
        out.append((t, frame_id, data))
        roll = rng.random()
        if roll < 0.15:
            position = int(rng.integers(len(data)))
            bad = bytearray(data)
            bad[position] ^= int(rng.integers(1, 256))
            out.append((t, frame_id, bytes(bad)))
        elif roll < 0.25:
            out.append((t, frame_id, data[:-1] if rng.random() < 0.5 else data + b"\0"))
        elif roll < 0.3:
            out.append((t, int(rng.choice([0x100, 0x200, 0x7FF, 0x107])), data))
        elif roll < 0.35:
            payload = bytes(8)
            out.append((t, 0x082, protect(0x082, payload, int(rng.integers(256)))))
        elif roll < 0.38:
            out.append((t, 0x081, bytes(8)))
    return out


def test_scalar_and_vectorised_decode_agree_on_defects():
    bus_map = dc_motor_map()
    frames = _mixed_frames()
    _, ids, dlc, payloads = as_log(frames)
    status, slot, values, counters = bus_map.decode_frames(_block(ids, dlc, payloads))
    seen = set()
    for i, (_, frame_id, data) in enumerate(frames):
        got_status, got_slot, got_values, got_counter = bus_map.decode_frame(frame_id, data)
        seen.add(got_status)
        assert STATUS_NAMES[status[i]] == got_status, i
        assert slot[i] == got_slot, i
        if got_status == "ok":
            np.testing.assert_array_equal(values[i, : len(got_values)], got_values)
        else:
            assert np.isnan(values[i]).all()
        # The E2E module is the reference for the CRC verdict of a right-length frame.
        if got_status in ("ok", "crc", "monitor"):
            assert check(frame_id, data) == (got_status != "crc"), i
        assert counters[i] == got_counter == (data[1] if got_status == "ok" else -1)
    assert seen == {"ok", "crc", "dlc", "unknown_id", "monitor"}


def test_decode_frames_handles_ids_and_lengths_outside_classic_can():
    bus_map = dc_motor_map()
    _, frames = drive_traffic(1)
    _, ids, dlc, payloads = as_log(frames)
    ids[0] = 0x1FFF_FFFF  # a 29-bit ID passed without its flag
    dlc[1] = 15  # an FD length code
    dlc[2] = 0
    status, slot, _, counters = bus_map.decode_frames(_block(ids, dlc, payloads))
    assert [STATUS_NAMES[c] for c in status] == ["unknown_id", "dlc", "dlc"]
    assert slot.tolist() == [-1, 1, 2]
    assert (counters == -1).all()


def test_a_value_outside_its_range_is_implausible_frame_by_frame_and_by_the_block():
    """bus.map.<name>.range: a mapped value outside it makes the frame "implausible" (no
    values, no counter), in decode_frame and decode_frames alike; a bad range is a config
    error naming it."""
    import yaml

    from canfdi.config import parse_config

    doc = yaml.safe_load((CONFIGS / "dc_motor_cia402.yaml").read_text())
    config = parse_config(doc, CONFIGS / "dc_motor_cia402.yaml")
    bus_map = BusMap.from_config(config)
    db = dbc_files.load("dc_motor_cia402")
    tpdo2 = db.get_message_by_name("TPDO2_node1")
    good = tpdo2.encode({"FieldCurrent": 1.0, "ArmatureCurrent": 10.0, "LineCurrent": 11.0})
    bad = tpdo2.encode({"FieldCurrent": 20.0, "ArmatureCurrent": 10.0, "LineCurrent": 11.0})
    assert bus_map.decode_frame(0x281, good)[0] == "ok"
    assert bus_map.decode_frame(0x281, bad)[:3] == ("implausible", bus_map.slot_of[(0x281,
                                                                                    False)], ())
    payloads = np.zeros((2, 8), dtype=np.uint8)
    payloads[0, :6], payloads[1, :6] = list(good), list(bad)
    status, _, values, _ = bus_map.decode_frames(_block([0x281, 0x281], [6, 6], payloads))
    assert [STATUS_NAMES[c] for c in status] == ["ok", "implausible"]
    assert not np.isnan(values[0, :3]).any() and np.isnan(values[1]).all()
    doc["bus"]["map"]["i_f"]["range"] = [5, -5]
    with pytest.raises(ConfigError, match=r"bus\.map\.i_f\.range"):
        parse_config(doc, CONFIGS / "dc_motor_cia402.yaml")


def test_a_value_the_sender_clipped_is_saturated_frame_by_frame_by_the_block_and_quantized():
    """A mapped value at a limit of what its signal carries (the VTOL's v_v at the raw range's
    end, 65.534 kt) is "saturated": no values, no counter, in decode_frame and decode_frames
    alike, and `quantize` gives NaN for every value of its message; one step inside it, or a
    limit at 0, is a value."""
    config = load_config(CONFIGS / "vtol.yaml")
    bus_map = BusMap.from_config(config)
    meas = dbc_files.load("vtol").get_message_by_name("DRIVE_MEAS")
    rows = [{"v_h": 1.0, "v_v": 65.534, "pitch_rate": 0.5},   # at the top: clipped
            {"v_h": 1.0, "v_v": 65.532, "pitch_rate": 0.5},   # a step inside
            {"v_h": -65.536, "v_v": 0.0, "pitch_rate": 0.5},  # at the bottom
            {"v_h": 0.0, "v_v": 0.0, "pitch_rate": 0.0}]      # zero is no limit of these
    frames = [protect(meas.frame_id, meas.encode({"CRC": 0, "Counter": 0, **r}), k)
              for k, r in enumerate(rows)]
    expected = ["saturated", "ok", "saturated", "ok"]
    slot = bus_map.slot_of[(meas.frame_id, False)]
    for frame, status in zip(frames, expected, strict=True):
        got = bus_map.decode_frame(meas.frame_id, frame)
        assert got[0] == status
        if status == "saturated":
            assert got[1:] == (slot, (), -1)
    payloads = np.array([list(f) for f in frames], dtype=np.uint8)
    status, _, values, counters = bus_map.decode_frames(
        _block([meas.frame_id] * 4, [meas.length] * 4, payloads))
    assert [STATUS_NAMES[c] for c in status] == expected
    clipped = np.array([s == "saturated" for s in expected])
    assert np.isnan(values[clipped]).all() and not np.isnan(values[~clipped, :3]).any()
    assert (counters[clipped] == -1).all() and (counters[~clipped] >= 0).all()
    # quantize: what evaluate and soak feed the monitor in place of frames.
    Z = np.array([[r["v_h"], r["v_v"], r["pitch_rate"], 2.0] for r in rows])
    U = np.ones((4, 2))
    U[1, 1] = 40.0  # the command's range ends at 32.767: its message is clipped
    U_q, Z_q = bus_map.quantize(U, Z)
    assert np.isnan(Z_q[clipped, :3]).all() and not np.isnan(Z_q[~clipped]).any()
    assert not np.isnan(Z_q[:, 3]).any()  # v_v_plus_rate_plus_angle: its own message
    assert np.isnan(U_q[1]).all() and not np.isnan(U_q[[0, 2, 3]]).any()


def test_a_limit_at_zero_is_none_and_a_float_signal_has_none():
    """`_clip_limits`: an unsigned [0|100] signal is saturated at 100 only; a float's range
    is its type's."""
    from canfdi.bus.codec import SignalLayout
    from canfdi.bus.dbc import _clip_limits

    assert _clip_limits(SignalLayout("n", 0, 8, False, False, 1.0, 0.0, 0.0, 100.0)) == (
        -np.inf, 99.5)
    assert _clip_limits(SignalLayout("x", 0, 32, True, True, 1.0, 0.0, None, None)) == (
        -np.inf, np.inf)
    lo, hi = _clip_limits(SignalLayout("s", 0, 8, True, False, 0.5, 0.0, None, None))
    assert (lo, hi) == (-63.75, 63.25)  # the raw range -128..127 times 0.5, half a step in

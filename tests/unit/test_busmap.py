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
from canfdi.bus.frames import STATUS_CODES, STATUS_NAMES, FrameBlock
from canfdi.config import BusConfig, ConfigError, load_config
from firmware_sim.emitter import FrameEncoder
from firmware_sim.scenario import load_scenario
from firmware_sim.simulate import SimChunk, Simulator

REPO = Path(__file__).resolve().parents[2]
DC_MOTOR_CONFIG = REPO / "deploy" / "config" / "dc_motor.yaml"
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
    return BusMap.from_config(dc_motor_config())


@functools.cache
def drive_traffic(n: int, k0: int = 0, scenario: str = "dc_motor_actuator"
                  ) -> tuple[SimChunk, tuple[tuple[int, int, bytes, int], ...]]:
    """Protected drive frames of samples k0 .. k0+n-1 of a firmware_sim scenario.

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
    assert bus_map.slot_of == {0x104: (0, 8), 0x105: (1, 8), 0x106: (2, 4)}
    assert bus_map.monitor_ids == {0x080, 0x081, 0x082, 0x083}
    assert bus_map.unused_ids == frozenset()
    assert (bus_map.p, bus_map.q, bus_map.n_signals_max) == (1, 4, 3)
    assert bus_map.dbc_label == "motor_drive"


def test_dbc_given_as_a_path_relative_to_the_config(tmp_path):
    target = tmp_path / "drive.dbc"
    target.write_text(dbc_files.path("motor_drive").read_text())
    config = dataclasses.replace(dc_motor_config(), path=tmp_path / "monitor.yaml",
                                 bus=BusConfig(dbc="drive.dbc"))
    bus_map = BusMap.from_config(config)
    assert bus_map.slot_of == dc_motor_map().slot_of
    assert bus_map.dbc_label == str(target)


def test_unknown_output_name_is_a_config_error_naming_its_field():
    config = dc_motor_config()
    outputs = [*config.outputs[:2], "i_b", *config.outputs[3:]]
    with pytest.raises(ConfigError, match="no signal 'i_b' in any DRIVE message of motor_drive"
                       ) as info:
        BusMap.from_config(dataclasses.replace(config, outputs=outputs))
    assert info.value.field == "signals.outputs[2]"


def test_unknown_input_name_is_a_config_error_naming_its_field():
    config = dataclasses.replace(dc_motor_config(), inputs=["U"])
    with pytest.raises(ConfigError) as info:
        BusMap.from_config(config)
    assert info.value.field == "signals.inputs[0]"


def test_reference_signal_is_found_but_monitor_signals_are_not_drive_signals():
    config = dc_motor_config()
    bus_map = BusMap.from_config(dataclasses.replace(config, inputs=["omega_ref"]))
    assert bus_map.fields[0] == (("omega_ref", "u", 0),)
    # FDI_STATUS.Samples is on the bus, but not sent by DRIVE.
    with pytest.raises(ConfigError) as info:
        BusMap.from_config(dataclasses.replace(config, inputs=["Samples"]))
    assert info.value.field == "signals.inputs[0]"


def test_e2e_header_is_not_a_model_signal():
    with pytest.raises(ConfigError, match="E2E header") as info:
        BusMap.from_config(dataclasses.replace(dc_motor_config(), inputs=["Counter"]))
    assert info.value.field == "signals.inputs[0]"


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


_TWO_MESSAGES_DBC = """VERSION ""
NS_ :
BS_:
BU_: DRIVE FDI
BO_ 260 DRIVE_A: 4 DRIVE
 SG_ CRC : 0|8@1+ (1,0) [0|255] "" FDI
 SG_ Counter : 8|8@1+ (1,0) [0|255] "" FDI
 SG_ x : 16|16@1- (0.01,0) [-327.68|327.67] "" FDI
BO_ 261 DRIVE_B: 4 DRIVE
 SG_ CRC : 0|8@1+ (1,0) [0|255] "" FDI
 SG_ Counter : 8|8@1+ (1,0) [0|255] "" FDI
 SG_ x : 16|16@1- (0.01,0) [-327.68|327.67] "" FDI
BO_ 262 DRIVE_C: 4 DRIVE
 SG_ y : 0|16@1- (0.01,0) [-327.68|327.67] "" FDI
 SG_ w : 16|16@1- (0.01,0) [-327.68|327.67] "" FDI
"""


def test_signal_in_two_drive_messages_is_a_config_error():
    database = cantools.database.load_string(_TWO_MESSAGES_DBC, database_format="dbc")
    with pytest.raises(ConfigError, match=r"'x' is in 2 DRIVE messages of test\.dbc "
                                          r"\(DRIVE_A, DRIVE_B\)") as info:
        BusMap.from_dbc(database, ["w"], ["x"], "test.dbc")
    assert info.value.field == "signals.outputs[0]"


def test_drive_message_without_e2e_header_is_rejected():
    database = cantools.database.load_string(_TWO_MESSAGES_DBC, database_format="dbc")
    with pytest.raises(ConfigError, match="DRIVE_C has no E2E header") as info:
        BusMap.from_dbc(database, ["y"], [], "test.dbc")
    assert info.value.field == "bus.dbc"


def test_drive_messages_without_model_signals_are_unused():
    database = dbc_files.load("motor_drive")
    bus_map = BusMap.from_dbc(database, ["V"], ["omega_r"], "motor_drive")
    assert [layout.name for layout in bus_map.layouts] == ["DRIVE_CMD", "DRIVE_SPEED"]
    assert bus_map.unused_ids == {0x105}
    _, frames = drive_traffic(4)
    statuses = [bus_map.decode_frame(f[1], f[2])[0] for f in frames]
    assert statuses == ["ok", "unused", "ok"] * 4


# -- decoding -----------------------------------------------------------------------------------


def test_decode_frame_equals_vectorised_decode_and_cantools_on_real_traffic():
    bus_map = dc_motor_map()
    database = dbc_files.load("motor_drive")
    _, frames = drive_traffic(600)
    _, ids, dlc, payloads = as_log(frames)
    status, slot, values, counters = bus_map.decode_frames(_block(ids, dlc, payloads))
    assert status.tolist() == [STATUS_CODES["ok"]] * len(frames)
    for i, (_, frame_id, data, k) in enumerate(frames):
        got_status, got_slot, got_values = bus_map.decode_frame(frame_id, data)
        assert (got_status, got_slot) == ("ok", slot[i]) == ("ok", bus_map.slot_of[frame_id][0])
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
        got_status, got_slot, got_values = bus_map.decode_frame(frame_id, data)
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
        assert counters[i] == (data[1] if len(data) >= 2 else -1)
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
    assert counters[2] == -1

"""The servo axis on its node-ID float bus, read with ODrive's own published DBC.

The emulator's frames of a servo axis run (canfdi.firmware_sim profile float_node) decode, through
canfdi's decoder (BusMap and the config's grid clock, as the monitor and the log tools
assemble samples) with the monitor config
deploy/config/servo_axis_odrive.yaml pointed at ODrive's odrive-cansimple.dbc as published
(tests/data/dbc/odrive/README.md), to the simulated values exactly at float32 precision; cantools
decodes the same payloads with ODrive's file to the same values; canfdi's servo_axis_float.dbc
has ODrive's layouts for the messages it shares with it.

The config carries no model yet (`canfdi identify` fills it in, and canfdi.config cannot parse
its ``identify:`` block yet), so the tests give it the plant's own linear model for decoding.
"""

from __future__ import annotations

import functools
from pathlib import Path

import cantools
import numpy as np
import pytest
import yaml

from canfdi import dbc as dbc_files
from canfdi.bus.clock import make_clock
from canfdi.bus.dbc import BusMap
from canfdi.bus.frames import FLAG_REMOTE, STATUS_NAMES
from canfdi.config import parse_config
from canfdi.core.settings import MonitorConfig
from canfdi.firmware_sim.emitter import FrameLog, frame_log
from canfdi.firmware_sim.plants import make_plant
from canfdi.firmware_sim.scenario import load_scenario, parse_scenario

REPO = Path(__file__).resolve().parents[3]
CONFIG = REPO / "deploy" / "config" / "servo_axis_odrive.yaml"
ODRIVE_DBC = REPO / "tests" / "data" / "dbc" / "odrive" / "odrive-cansimple.dbc"
USED = {"Heartbeat": 0x01, "Get_Encoder_Estimates": 0x09, "Set_Input_Torque": 0x0E,
        "Get_Iq": 0x14}


def _config(dbc: str) -> MonitorConfig:
    """The shipped config with the plant's linear model in place of its ``identify:`` block
    and ``bus.dbc`` set to ``dbc``."""
    doc = yaml.safe_load(CONFIG.read_text())
    assert doc["model"] == {"identify": {"unknown_inputs": 1}}
    model = make_plant("servo_axis").linear_model()
    doc["model"] = {"time": "discrete", "dt": 0.01,
                    **{name: model[name].tolist() for name in ("A", "B", "C", "F")}}
    doc["bus"]["dbc"] = dbc
    return parse_config(doc, CONFIG)


@functools.cache
def _log() -> FrameLog:
    """8 s of the commissioning run (the dither makes every command differ)."""
    return frame_log(load_scenario("servo_axis_commissioning"), duration=8.0)


def _samples(config: MonitorConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(k (N,), U (N, 1), Z (N, 4)) of the run's frames, decoded by the config's BusMap and
    assembled by its grid clock, as the monitor and the log tools do."""
    clock = make_clock(BusMap.from_config(config), 0.01, config.bus.clock)
    log = clock.push_batch(_log().frames)
    rest = clock.flush()
    k = np.concatenate([log.k, [s.k for s in rest]]).astype(np.int64)
    U = np.vstack([log.u, *[np.asarray(s.u)[None, :] for s in rest]])
    Z = np.vstack([log.z, *[np.asarray(s.z)[None, :] for s in rest]])
    return k, U, Z


@pytest.mark.parametrize("dbc", [str(ODRIVE_DBC), "servo_axis_float"],
                         ids=["odrive-cansimple", "servo_axis_float"])
def test_canfdi_decodes_the_bus_to_the_simulated_values(dbc):
    config = _config(dbc)
    chunk = _log().chunk
    k, U, Z = _samples(config)
    n = len(chunk)
    np.testing.assert_array_equal(k, np.arange(len(k)))
    assert len(k) >= n - 1
    f32 = functools.partial(np.asarray, dtype=np.float32)
    np.testing.assert_array_equal(U, f32(chunk.u_c[: len(k)]).astype(float))
    np.testing.assert_array_equal(Z, f32(chunk.z[: len(k)]).astype(float))
    # The values are not constant: the run moves every signal.
    assert np.ptp(Z, axis=0).min() > 0.5 and np.ptp(U) > 0.1
    # Every frame of the bus is known to the decoder: the mapped ones decode, the heartbeat is
    # an unused message of the DBC, the master's RTR polls are known requests.
    status, _, _, _ = BusMap.from_config(config).decode_frames(_log().frames)
    names = {STATUS_NAMES[code] for code in np.unique(status).tolist()}
    assert names == {"ok", "unused"}


def test_odrive_dbc_and_the_shipped_dbc_give_the_same_samples():
    k1, U1, Z1 = _samples(_config(str(ODRIVE_DBC)))
    k2, U2, Z2 = _samples(_config("servo_axis_float"))
    np.testing.assert_array_equal(k1, k2)
    np.testing.assert_array_equal(U1, U2)
    np.testing.assert_array_equal(Z1, Z2)


def test_cantools_decodes_the_payloads_with_odrives_dbc():
    log = _log()
    database = cantools.database.load_file(ODRIVE_DBC)  # strict: ODrive's file passes
    frames = log.frames
    remote = (frames.flags & FLAG_REMOTE) != 0
    decoded: dict[int, list[dict]] = {fid: [] for fid in USED.values()}
    for fid, payload in zip(frames.id[~remote].tolist(),
                            [p for p, r in zip(frames.payloads(), remote, strict=True) if not r],
                            strict=True):
        decoded[fid].append(database.decode_message(fid, payload, decode_choices=False))
    assert set(frames.id[remote].tolist()) == {USED["Get_Iq"]}
    chunk = log.chunk
    n = len(chunk)

    def series(message: str, signal: str) -> np.ndarray:
        return np.array([d[signal] for d in decoded[USED[message]]])

    want = {name: np.asarray(chunk.z[:, j], dtype=np.float32).astype(float)
            for j, name in enumerate(("Iq_Setpoint", "Iq_Measured", "Vel_Estimate",
                                      "Pos_Estimate"))}
    np.testing.assert_array_equal(series("Set_Input_Torque", "Input_Torque"),
                                  np.asarray(chunk.u_c[:, 0], dtype=np.float32).astype(float))
    for message, signals in (("Get_Iq", ("Iq_Setpoint", "Iq_Measured")),
                             ("Get_Encoder_Estimates", ("Pos_Estimate", "Vel_Estimate"))):
        for signal in signals:
            got = series(message, signal)
            assert len(got) == n, signal
            np.testing.assert_array_equal(got, want[signal], err_msg=signal)
    assert set(series("Heartbeat", "Axis_State")) == {8}
    assert set(series("Heartbeat", "Axis_Error")) == {0}
    assert len(series("Heartbeat", "Axis_State")) == n // 10


def test_the_shipped_dbc_has_odrives_layouts():
    ours = dbc_files.load("servo_axis_float")
    theirs = cantools.database.load_file(ODRIVE_DBC)
    assert sorted(m.name for m in ours.messages) == sorted(USED)
    for message in ours.messages:
        other = theirs.get_message_by_name(message.name)
        assert (message.frame_id, message.length) == (other.frame_id, other.length) == (
            USED[message.name], 8), message.name
        assert sorted(s.name for s in message.signals) == sorted(s.name for s in other.signals)
        for sig in message.signals:
            their = other.get_signal_by_name(sig.name)
            layout = (sig.start, sig.byte_order, sig.is_float, sig.scale, sig.offset)
            assert layout == (their.start, their.byte_order, their.is_float, their.scale,
                              their.offset), sig.name
            if (message.name, sig.name) == ("Heartbeat", "Axis_State"):
                # ODrive's file declares 32 bits; ours 8 (the state fits a byte, and the drive
                # sends the upper bytes as zeros, so both read the same value).
                assert (sig.length, their.length) == (8, 32)
            else:
                assert sig.length == their.length, sig.name


def test_the_config_maps_every_model_signal_onto_both_dbcs():
    doc = yaml.safe_load(CONFIG.read_text())
    plant = make_plant("servo_axis")
    assert doc["signals"]["inputs"] == list(plant.input_names)
    assert doc["signals"]["outputs"] == list(plant.output_names)
    assert doc["signals"]["unknown_inputs"] == ["load_torque"]
    assert doc["bus"]["dbc"] == "servo_axis_float" and plant.config == CONFIG.name
    theirs = cantools.database.load_file(ODRIVE_DBC)
    for name, where in doc["bus"]["map"].items():
        message, signal = where.split(".")
        assert signal == name  # ODrive's signal names are the model's
        theirs.get_message_by_name(message).get_signal_by_name(signal)
    bus_map = BusMap.from_config(_config(str(ODRIVE_DBC)))
    assert {lay.name: key[0] for lay, key in zip(bus_map.layouts, bus_map.keys, strict=True)} \
        == {"Get_Encoder_Estimates": 0x09, "Set_Input_Torque": 0x0E, "Get_Iq": 0x14}


def test_another_node_moves_every_id():
    log = frame_log(parse_scenario({"plant": "servo_axis", "duration": 0.5, "seed": 2,
                                    "bus": {"profile": "float_node", "node": 3}}))
    assert set(log.frames.id.tolist()) == {3 << 5 | cmd for cmd in USED.values()}
    theirs = cantools.database.load_file(ODRIVE_DBC)
    rows = np.flatnonzero(log.frames.id == (3 << 5 | 0x0E))
    payloads = log.frames.payloads()
    torque = [theirs.decode_message(0x0E, payloads[r])["Input_Torque"] for r in rows]
    np.testing.assert_array_equal(torque, np.asarray(log.chunk.u_c[:, 0], dtype=np.float32))

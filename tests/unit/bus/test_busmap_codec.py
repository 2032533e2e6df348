"""BusMap over a DBC the codec now reads whole: Motorola and scaled-float model signals, and
messages of no interest that cannot be compiled."""

from __future__ import annotations

import dataclasses

import cantools
import numpy as np

from canfdi.bus.dbc import BusMap
from canfdi.bus.e2e import protect
from canfdi.bus.frames import STATUS_CODES, FrameBlock
from canfdi.config import BusConfig, load_config
from tests.conftest import REPO

_DBC = """VERSION ""
NS_ :
BS_:
BU_: DRIVE FDI
BO_ 260 DRIVE_A: 8 DRIVE
 SG_ CRC : 0|8@1+ (1,0) [0|255] "" FDI
 SG_ Counter : 8|8@1+ (1,0) [0|255] "" FDI
 SG_ u : 23|12@0- (0.01,0) [-20.48|20.47] "" FDI
 SG_ z : 32|32@1- (0.5,-1) [-1E+030|1E+030] "" FDI
BO_ 261 DRIVE_B: 4 DRIVE
 SG_ CRC : 0|8@1+ (1,0) [0|255] "" FDI
 SG_ Counter : 8|8@1+ (1,0) [0|255] "" FDI
 SG_ y : 16|16@1- (0.001,0) [-32.768|32.767] "" FDI
BO_ 300 OTHER: 2 Vector__XXX
 SG_ outside : 20|8@1+ (1,0) [0|255] "" FDI
SIG_VALTYPE_ 260 z : 1;
"""


def test_motorola_and_scaled_float_model_signals_decode_as_cantools(tmp_path):
    (tmp_path / "test.dbc").write_text(_DBC)
    base = load_config(REPO / "deploy" / "config" / "dc_motor.yaml")
    config = dataclasses.replace(base, path=tmp_path / "monitor.yaml", inputs=["u"],
                                 outputs=["z", "y"], bus=BusConfig(dbc="test.dbc"))
    bus_map = BusMap.from_config(config)
    database = cantools.database.load_string(_DBC, database_format="dbc", strict=False)
    assert [lay.name for lay in bus_map.layouts] == ["DRIVE_A", "DRIVE_B"]
    # OTHER's signal lies outside its 2 bytes: the message is still known, by its ID.
    assert bus_map.unused_keys == {(300, False)}
    rng = np.random.default_rng(7)
    frames = []
    for k in range(40):
        a = database.get_message_by_name("DRIVE_A").encode(
            {"CRC": 0, "Counter": k, "u": round(rng.uniform(-20, 20), 2),
             "z": float(rng.normal(scale=1e3))}, strict=False)
        b = database.get_message_by_name("DRIVE_B").encode(
            {"CRC": 0, "Counter": k, "y": round(rng.uniform(-30, 30), 3)}, strict=False)
        frames += [(260, protect(260, a, k)), (261, protect(261, b, k))]
    n = len(frames)
    payloads = np.zeros((n, 8), dtype=np.uint8)
    for i, (_, data) in enumerate(frames):
        payloads[i, : len(data)] = np.frombuffer(data, np.uint8)
    block = FrameBlock(np.zeros(n, dtype=np.int64), np.array([f[0] for f in frames]),
                       np.array([len(f[1]) for f in frames]), np.zeros(n, dtype=np.uint8),
                       payloads)
    status, slot, values, _ = bus_map.decode_frames(block)
    assert status.tolist() == [STATUS_CODES["ok"]] * n
    for i, (frame_id, data) in enumerate(frames):
        got_status, got_slot, got, counter = bus_map.decode_frame(frame_id, data)
        assert counter == i // 2
        assert (got_status, got_slot) == ("ok", slot[i])
        want = database.get_message_by_frame_id(frame_id).decode(data, decode_choices=False)
        names = [name for name, _, _ in bus_map.fields[got_slot]]
        assert list(got) == [want[name] for name in names] == values[i, : len(names)].tolist()

"""The C core's frame decode (canfdi/_c/decode.c) against the numpy reference
(BusMap.decode_frames_reference, MessageLayout.decode): statuses, slots, counters and values
equal to the bit, on every shipped bus, on hostile blocks, on every message of the shipped and
public DBCs and on random signal layouts (both byte orders, every length 1-64, signed, floats,
multiplexing, CAN FD payloads)."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
from canfdi.configs import CONFIG_DIR
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from canfdi import dbc as dbc_files
from canfdi.bus import ctables
from canfdi.bus.codec import compile_layout
from canfdi.bus.ctables import EntrySpec, SlotSpec, build_tables
from canfdi.bus.e2e import make_profile
from canfdi.bus.frames import (
    FLAG_ERROR,
    FLAG_EXTENDED,
    FLAG_FD,
    FLAG_REMOTE,
    STATUS_CODES,
    FrameBlock,
)
from canfdi.config import NotIdentified, load_config
from canfdi.core import kernel
from canfdi.monitor import Monitor
from tests.conftest import REPO
from tests.unit.bus.cantools_reference import random_payloads
from tests.unit.bus.test_codec import _msg, _nested, _one_signal_messages, _sig

pytestmark = pytest.mark.c
C = "c" in kernel.available()
needs_c = pytest.mark.skipif(not C, reason="canfdi._ckernel is not built here")
CONFIGS = sorted(CONFIG_DIR.glob("*.yaml"))


def _same_values(got: np.ndarray, ref: np.ndarray) -> None:
    """Equal to the bit where numbers (the sign of a zero too), NaN where NaN."""
    assert got.shape == ref.shape
    np.testing.assert_array_equal(np.isnan(got), np.isnan(ref))
    both = ~np.isnan(ref)
    np.testing.assert_array_equal(got[both], ref[both])
    np.testing.assert_array_equal(np.signbit(got[both]), np.signbit(ref[both]))


def _same_decode(bus_map, block: FrameBlock) -> tuple:
    ref = bus_map.decode_frames_reference(block)
    got = kernel.get("c").decode_frames(bus_map, block)
    for name, a, b in zip(("status", "slot", "values", "counters"), got, ref, strict=True):
        assert a.dtype == b.dtype, name
        if name == "values":
            _same_values(a, b)
        else:
            np.testing.assert_array_equal(a, b, err_msg=name)
    return ref


def test_the_header_and_the_python_tables_agree():
    """decode.h's #defines are canfdi.bus.ctables.DECODE_H's numbers."""
    text = (REPO / "canfdi" / "_c" / "decode.h").read_text()
    found = {m[1]: int(m[2]) for m in re.finditer(r"#define (CFDI_\w+) (\d+)", text)}
    for name, value in ctables.DECODE_H.items():
        assert found.get(name) == value, name
    enum = dict(re.findall(r"CFDI_ST_(\w+) = (\d+)", text))
    assert {k.lower(): int(v) for k, v in enum.items()} == {
        k: STATUS_CODES[{"error": "error_frame"}.get(k, k)]
        for k in (k.lower() for k in enum)}


def _hostile(block: FrameBlock, rng: np.random.Generator, known_ids: list[int]) -> FrameBlock:
    """The block with a fifth of its frames damaged every way a bus or a log can: bits
    flipped, lengths wrong, IDs of other messages or none, remote, error, extended and FD
    flags, payloads of garbage, CAN FD payloads of up to 64 bytes."""
    n = block.size
    data = block.data.copy()
    ids = block.id.astype(np.int64).copy()
    dlc = block.dlc.copy()
    flags = block.flags.copy()
    long: dict[int, bytes] = {}
    kind = rng.integers(0, 10, n)
    rows = np.flatnonzero(kind == 0)
    data[rows, rng.integers(0, 8, rows.size)] ^= (1 << rng.integers(0, 8, rows.size)).astype(
        np.uint8)
    rows = np.flatnonzero(kind == 1)
    dlc[rows] = rng.integers(0, 9, rows.size)
    rows = np.flatnonzero(kind == 2)
    ids[rows] = rng.choice([*known_ids, 0, 0x7FF, 0x123], rows.size)
    rows = np.flatnonzero(kind == 3)
    flags[rows] |= rng.choice([FLAG_REMOTE, FLAG_ERROR, FLAG_EXTENDED, FLAG_FD],
                              rows.size).astype(np.uint8)
    rows = np.flatnonzero(kind == 4)
    data[rows] = rng.integers(0, 256, (rows.size, 8), dtype=np.uint8)
    rows = np.flatnonzero(kind == 5)
    ids[rows] = rng.integers(0, 1 << 29, rows.size)
    flags[rows] |= FLAG_EXTENDED
    for row in np.flatnonzero(kind == 6)[:50].tolist():
        size = int(rng.choice([12, 16, 20, 24, 32, 48, 64]))
        payload = rng.integers(0, 256, size, dtype=np.uint8).tobytes()
        dlc[row], flags[row] = size, flags[row] | FLAG_FD
        data[row] = np.frombuffer(payload[:8], np.uint8)
        long[row] = payload
    return FrameBlock(block.t_ns, ids, dlc, flags, data, long=long)


@needs_c
@pytest.mark.parametrize("path", CONFIGS, ids=[p.stem for p in CONFIGS])
def test_every_shipped_bus_decodes_alike_clean_and_hostile(path):
    from canfdi.tools.bench import bench_scenarios, make_traffic
    from canfdi.tools.pairing import NoPairing

    try:
        config = load_config(path)
        _, faulty = bench_scenarios(config)
    except NotIdentified:
        pytest.skip(f"{path.name} has no model yet: a Monitor needs one")
    except NoPairing:
        pytest.skip(f"no shipped scenario plays {path.name}'s bus")
    monitor = Monitor(config, kernel=kernel.get("python"))
    traffic = make_traffic(6000, faulty)
    rng = np.random.default_rng(len(path.stem))
    for d in monitor.drives:
        bus_map = d.bus_map
        status, _, _, _ = _same_decode(bus_map, traffic)
        assert (status == STATUS_CODES["ok"]).mean() > 0.2  # the drive's traffic decodes
        known = sorted({k[0] for k in bus_map.keys})
        hostile = _hostile(traffic, rng, known)
        status, _, _, _ = _same_decode(bus_map, hostile)
        seen = {name for name, code in STATUS_CODES.items() if (status == code).any()}
        assert {"ok", "dlc", "error_frame", "fd", "extended"} <= seen, seen


@needs_c
def test_the_e2e_profiles_decode_alike_on_a_bus(tmp_path):
    """canfdi's bus with AUTOSAR P01 (every Data ID mode), P02 and counter profiles on its
    messages: frames protected by each, then damaged, judged alike."""
    text = (CONFIG_DIR / "dc_motor.yaml").read_text()
    specs = {
        "DRIVE_CMD": "{profile: autosar_p01, data_id: 0x1234, data_id_mode: alt}",
        "DRIVE_CURRENTS": ("{profile: autosar_p02, data_id_list: [1, 2, 3, 4, 5, 6, 7, 8, 9, "
                           "10, 11, 12, 13, 14, 15, 16]}"),
        "DRIVE_SPEED": "{profile: autosar_p01, data_id: 0x345, data_id_mode: nibble}",
    }
    e2e = ("  clock: {kind: grid}\n  e2e:\n    messages:\n"  # moduli 15 and 16: no counter clock
           + "".join(f"      {k}: {v}\n" for k, v in specs.items()))
    text = text.replace("  dbc: motor_drive\n", "  dbc: motor_drive\n" + e2e, 1)
    path = tmp_path / "autosar.yaml"
    path.write_text(text)
    config = load_config(path)
    monitor = Monitor(config, kernel=kernel.get("python"))
    bus_map = monitor.bus_map
    rng = np.random.default_rng(7)
    n = 4000
    slot = rng.integers(0, len(bus_map.keys), n)
    data = rng.integers(0, 256, (n, 8), dtype=np.uint8)
    for s, profile in enumerate(bus_map.e2e):
        rows = np.flatnonzero(slot == s)
        length = bus_map.layouts[s].dlc
        data[rows, :length] = profile.protect_batch(data[rows, :length],
                                                    rng.integers(0, 1000, rows.size))
        data[rows, length:] = 0
    ids = np.array([bus_map.keys[s][0] for s in slot], dtype=np.int64)
    dlc = np.array([bus_map.layouts[s].dlc for s in slot], dtype=np.uint8)
    block = FrameBlock(np.arange(n) * 1000, ids, dlc, np.zeros(n, np.uint8), data)
    status, _, _, counters = _same_decode(bus_map, block)
    assert (status == STATUS_CODES["ok"]).mean() > 0.5 and (counters >= 0).any()
    status, _, _, _ = _same_decode(bus_map, _hostile(block, rng, sorted(set(ids.tolist()))))
    assert (status == STATUS_CODES["crc"]).any()


def _tables_of(message, layout):
    """One message as a bus of one slot whose model fields are all its signals, none of them
    ever saturated (NaN limits: no value is at or beyond one; an infinite float would be)."""
    names = tuple(s.name for s in layout.signals)
    inf, nan = (math.inf,) * len(names), (math.nan,) * len(names)
    slot = SlotSpec(layout, names, tuple(-x for x in inf), inf, nan, nan, False)
    none = make_profile("none", message.frame_id, bool(message.is_extended_frame),
                        message.length, {}, "bus.e2e")
    entry = EntrySpec(STATUS_CODES["ok"], message.length, bool(message.is_fd), none)
    return build_tables([entry], [slot], {(message.frame_id, bool(message.is_extended_frame)): 0},
                        len(names))


class _OneMessage:
    """What the C decoder needs of a bus map, for one message."""

    def __init__(self, message, layout):
        self._tables = _tables_of(message, layout)

    def c_tables(self):
        return self._tables


def _c_values(message, payloads: np.ndarray) -> dict[str, np.ndarray]:
    layout = compile_layout(message)
    n, length = payloads.shape[0], message.length
    body = np.zeros((n, max(length, 8)), dtype=np.uint8)
    body[:, :min(length, payloads.shape[1])] = payloads[:, :length]
    flags = np.full(n, (FLAG_EXTENDED if message.is_extended_frame else 0)
                    | (FLAG_FD if message.is_fd else 0), dtype=np.uint8)
    long = {i: body[i].tobytes() for i in range(n)} if length > 8 else {}
    block = FrameBlock(np.arange(n), np.full(n, message.frame_id), np.full(n, length, np.uint8),
                       flags, np.ascontiguousarray(body[:, :8]), long=long)
    status, _, values, counters = kernel.get("c").decode_frames(_OneMessage(message, layout),
                                                                block)
    assert (status == STATUS_CODES["ok"]).all() and (counters == -1).all()
    return {s.name: values[:, k] for k, s in enumerate(layout.signals)}


def _same_as_layout(message, payloads):
    ref = compile_layout(message).decode(payloads)
    got = _c_values(message, payloads)
    for name in ref:
        _same_values(got[name], ref[name])


def _messages():
    for name in dbc_files.available():
        for message in dbc_files.load(name).messages:
            if not getattr(message, "is_container", False):
                yield pytest.param(message, id=f"{name}:{message.name}")


@needs_c
@pytest.mark.parametrize("message", list(_messages()))
def test_every_shipped_dbc_message_decodes_as_the_layout(message):
    rng = np.random.default_rng(message.frame_id)
    _same_as_layout(message, random_payloads(message, rng))


@needs_c
def test_nested_multiplexing_and_wide_signals_decode_as_the_layout():
    rng = np.random.default_rng(3)
    _same_as_layout(_nested(), random_payloads(_nested(), rng))
    wide = _msg([_sig("W", 4, 64, signed=True, scale=0.5), _sig("U", 68, 64),
                 _sig("B", 135, 64, "big_endian", scale=3, offset=-7),
                 _sig("H", 208, 16, is_float=True, scale=2.0),
                 _sig("F", 224, 32, is_float=True), _sig("D", 256, 64, is_float=True)],
                length=48, is_fd=True)
    payloads = rng.integers(0, 256, (500, 48), dtype=np.uint8)
    payloads[:50, 26:28] = [0x00, 0x7C]  # float16 infinity, then NaNs and subnormals
    payloads[50:100, 26:28] = [0x01, 0x7E]
    payloads[100:150, 26] = rng.integers(0, 256, 50)
    payloads[100:150, 27] = 0x80
    _same_as_layout(wide, payloads)


@needs_c
@settings(max_examples=300, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow])
@given(message=_one_signal_messages(), seed=st.integers(0, 2**32 - 1))
def test_fuzz_any_signal_anywhere_decodes_as_the_layout(message, seed):
    rng = np.random.default_rng(seed)
    payloads = rng.integers(0, 256, (32, message.length), dtype=np.uint8)
    payloads[0], payloads[1] = 0, 0xFF
    _same_as_layout(message, payloads)


@needs_c
def test_malformed_tables_are_an_error_not_a_read_outside():
    from canfdi import _ckernel

    message = _msg([_sig("A", 0, 16), _sig("B", 16, 8)])
    tables = _tables_of(message, compile_layout(message))
    block = FrameBlock(np.arange(2), np.full(2, 0x123), np.full(2, 8, np.uint8),
                       np.zeros(2, np.uint8), np.zeros((2, 8), np.uint8))

    def run(changes=None):
        args = list(tables.c_args)
        for index, value in (changes or {}).items():
            args[index] = value
        out = (np.empty(2, np.int8), np.empty(2, np.int16), np.empty((2, tables.width)),
               np.empty(2, np.int64))
        _ckernel.decode_block(tuple(args), 2, block.id, block.dlc, block.flags, block.data,
                              np.full(2, -1, np.int32), np.zeros((0, 64), np.uint8), 0, *out)
        return out

    assert (run()[0] == STATUS_CODES["ok"]).all()
    bad_std = tables.std_entry.copy()
    bad_std[0] = 99  # an entry that is not there
    far = tables.sig_int.copy()
    far[1, ctables.DECODE_H["CFDI_SIG_START"]] = 60  # bits past the 8-byte payload
    parent = tables.sig_int.copy()
    parent[0, ctables.DECODE_H["CFDI_SIG_PARENT"]] = 1  # a multiplexer after what it selects
    entry = tables.entry.copy()
    entry[0, ctables.DECODE_H["CFDI_ENTRY_SIG_COUNT"]] = 9  # more signals than the table has
    profile = tables.entry.copy()
    profile[0, ctables.DECODE_H["CFDI_ENTRY_PROFILE"]] = 3
    bad_spec = tables.e2e_spec.copy()
    bad_spec[0, 0] = 7  # no such kind of profile
    for change in ({1: bad_std}, {12: far}, {12: parent}, {6: entry}, {6: profile},
                   {9: bad_spec}):
        with pytest.raises(ValueError, match="malformed"):
            run(change)
    with pytest.raises(ValueError, match="bytes"):  # a buffer shorter than its size says
        run({10: tables.sig_int[:1]})

"""Precompiled layouts encode and decode exactly like cantools, a block of frames at a time.

canfdi's own DBCs, then each case the codec covers (Motorola across byte boundaries, 64-bit
unsigned beyond 2**63, float64 with scale, nested multiplexing, 64-byte CAN FD payloads, 29-bit
IDs) against cantools, and a hypothesis property over single signals placed anywhere. Every
message of a set of public DBCs is in test_codec_dbc.py.
"""

import doctest
import math
from pathlib import Path

import cantools
import numpy as np
import pytest
from cantools.database.can import Message, Signal
from cantools.database.conversion import BaseConversion
from hypothesis import given, settings
from hypothesis import strategies as st

import canfdi.bus.codec as codec_module
from canfdi import dbc as dbc_files
from canfdi.bus.codec import compile_layout
from tests.unit.bus.cantools_reference import check_against_cantools, check_encode

DBC = Path(__file__).parents[2] / "data" / "dbc"


def _messages():
    for name in dbc_files.available():
        for message in dbc_files.load(name).messages:
            yield pytest.param(name, message.name, id=f"{name}:{message.name}")


def _random_values(layout, rng, n):
    values = {}
    for sig in layout.signals:
        if sig.is_float:
            values[sig.name] = rng.normal(scale=1e3, size=n).astype(np.float32).astype(float)
        else:
            lo, hi = sig.raw_limits()
            raw = rng.integers(lo, hi, size=n, endpoint=True)
            values[sig.name] = raw * sig.scale + sig.offset
            lo_p, hi_p = sig.physical_limits()
            values[sig.name] = np.clip(values[sig.name], lo_p, hi_p)
    return values


@pytest.mark.parametrize(("dbc", "message_name"), list(_messages()))
def test_layout_matches_cantools(dbc, message_name):
    message = dbc_files.load(dbc).get_message_by_name(message_name)
    layout = compile_layout(message)
    rng = np.random.default_rng(abs(hash(message_name)) % 2**32)
    n = 200
    values = _random_values(layout, rng, n)
    payloads, clipped = layout.encode(values, n)
    assert clipped == {}
    assert payloads.shape == (n, message.length)
    decoded = layout.decode(payloads)
    for i in range(0, n, 7):
        row = {k: float(v[i]) for k, v in values.items()}
        want = message.encode(row, scaling=True, strict=False)
        assert payloads[i].tobytes() == want, (message_name, i)
        ref = message.decode(want, decode_choices=False, scaling=True)
        for name, value in ref.items():
            assert decoded[name][i] == pytest.approx(value, rel=1e-12, abs=1e-9), name


def test_out_of_range_values_are_clipped_and_counted():
    message = dbc_files.load("motor_drive").get_message_by_name("DRIVE_CURRENTS")
    layout = compile_layout(message)
    payloads, clipped = layout.encode({"i_f": np.array([1.0, 50.0, -50.0, np.nan])}, 4)
    assert clipped == {"i_f": 3}
    np.testing.assert_allclose(layout.decode(payloads)["i_f"], [1.0, 32.767, -32.768, 0.0])


def test_a_signal_outside_the_payload_is_refused_by_name():
    import cantools

    sig = cantools.database.can.Signal("Speed", start=7, length=16, byte_order="big_endian")
    msg = cantools.database.can.Message(frame_id=1, name="M", length=1, signals=[sig],
                                        strict=False)
    with pytest.raises(ValueError, match=r"M\.Speed"):
        compile_layout(msg)


# -- each case against cantools ----------------------------------------------------------------

def _sig(name, start, length, order="little_endian", signed=False, scale=1, offset=0,
         is_float=False, **kwargs):
    conversion = BaseConversion.factory(scale=scale, offset=offset, is_float=is_float)
    return Signal(name, start, length, order, signed, conversion=conversion, **kwargs)


def _msg(signals, length=8, frame_id=0x123, **kwargs):
    return Message(frame_id=frame_id, name="M", length=length, signals=signals, strict=False,
                   **kwargs)


def _random(message, n=64, seed=0, extra=0):
    rng = np.random.default_rng(seed)
    payloads = rng.integers(0, 256, size=(n, message.length + extra), dtype=np.uint8)
    payloads[0, : message.length] = 0
    payloads[1, : message.length] = 0xFF
    return payloads


def _encodes_like_cantools(message, layout, values, n):
    """Our payloads are cantools' bytes for the same values, row by row."""
    payloads, clipped = layout.encode(values, n)
    assert clipped == {}
    assert payloads.shape == (n, message.length)
    for i in range(n):
        row = {k: float(v[i]) for k, v in values.items() if not math.isnan(v[i])}
        want = message.encode(row, scaling=True, strict=False)
        assert payloads[i].tobytes() == want, (i, row)
    return payloads


def test_motorola_signals_across_byte_boundaries():
    message = _msg([
        _sig("A", 3, 12, "big_endian"),                    # bytes 0-1
        _sig("B", 18, 16, "big_endian", signed=True),      # 3 bytes, not byte aligned
        _sig("C", 47, 16, "big_endian", scale=0.5, offset=-3),  # byte aligned: a typed view
        _sig("D", 63, 6, "big_endian", signed=True),       # within one byte
        _sig("E", 57, 2, "big_endian"),
    ])
    layout = compile_layout(message)
    payloads = _random(message, extra=5)
    check_against_cantools(message, layout, payloads, "motorola")
    check_encode(message, layout, payloads, "motorola")
    values = layout.decode(payloads)
    _encodes_like_cantools(message, layout, values, payloads.shape[0])
    # A hand-computed frame: A = 0xABC sits in byte 0's low nibble and byte 1.
    one, _ = layout.encode({"A": np.array([0xABC])}, 1)
    assert one[0, :2].tolist() == [0x0A, 0xBC]


def test_unsigned_64_bit_values_above_2_63_are_exact():
    message = _msg([
        _sig("LE", 0, 64),                       # typed view
        _sig("BE", 71, 64, "big_endian"),        # typed view, big-endian
        _sig("LE9", 132, 64),                    # over 9 bytes
        _sig("BE9", 195, 64, "big_endian"),      # over 9 bytes, big-endian
        _sig("S9", 268, 64, signed=True),        # signed, over 9 bytes
    ], length=48)
    layout = compile_layout(message)
    values = [2**64 - 1, 2**63, 2**63 + 1, 0x8000_0000_0000_0001, 0xDEAD_BEEF_CAFE_F00D, 1, 0]
    n = len(values)
    raw = {name: np.array(values, dtype=np.uint64) for name in ("LE", "BE", "LE9", "BE9")}
    raw["S9"] = np.array(values, dtype=np.uint64).view(np.int64)
    payloads, clipped = layout.encode_raw(raw, n)
    assert clipped == {}
    back = layout.decode_raw(payloads)
    for name, want in raw.items():
        assert back[name].dtype == want.dtype
        np.testing.assert_array_equal(back[name], want)
    for i in range(n):
        data = payloads[i].tobytes()
        ref = message.decode(data, decode_choices=False, scaling=False)
        assert ref == {name: int(v[i]) for name, v in raw.items()}
        assert message.encode(ref, scaling=False, strict=False) == data
    check_against_cantools(message, layout, _random(message), "u64")
    check_encode(message, layout, _random(message, seed=1), "u64")
    # Physical values: float64 of the exact integer, as cantools' int converts.
    assert layout.decode(payloads)["LE"][0] == float(2**64 - 1)
    # Physical values at and beyond the range end at the largest float64 inside it.
    big = np.array([2.0**64, 1e30, np.inf, -1.0])
    payloads, clipped = layout.encode({"LE": big, "BE9": big, "S9": -big}, 4)
    assert clipped == {"LE": 3, "BE9": 3, "S9": 3}
    back = layout.decode_raw(payloads)
    top = 2**64 - 2048  # the largest float64 below 2**64
    assert back["LE"].tolist() == back["BE9"].tolist() == [top, top, top, 0]
    assert back["S9"].tolist() == [-(2**63), -(2**63), -(2**63), 1]


def test_integer_scale_and_offset_are_exact_like_cantools_ints():
    # cantools computes raw * 7 - 3 in Python ints: one rounding to float, not two.
    message = _msg([_sig("N", 0, 53, scale=7, offset=-3), _sig("I", 53, 11, signed=True,
                                                                    scale=2**50, offset=1)])
    layout = compile_layout(message)
    payloads = _random(message, n=512, seed=6)
    check_against_cantools(message, layout, payloads, "integer scaling")


def test_float64_and_float32_signals_apply_scale_and_offset():
    message = _msg([
        _sig("F64", 0, 64, is_float=True, scale=0.5, offset=10),
        _sig("F64BE", 71, 64, "big_endian", is_float=True, scale=-2.5, offset=1e3),
        _sig("F32", 128, 32, is_float=True, scale=0.001, offset=-5),
        _sig("F32BE", 163, 32, "big_endian", is_float=True, scale=3, offset=0.25),  # unaligned
        _sig("F16", 204, 16, is_float=True, scale=2),     # unaligned
        _sig("F64W", 228, 64, is_float=True, scale=0.1),  # over 9 bytes
    ], length=40)
    layout = compile_layout(message)
    n = 64
    rng = np.random.default_rng(3)
    values = {name: rng.normal(scale=1e3, size=n) for name in ("F64", "F64BE", "F64W")}
    values["F32"] = rng.normal(scale=10, size=n)
    values["F32BE"] = rng.normal(scale=1e4, size=n)
    values["F16"] = rng.normal(scale=100, size=n)
    payloads = _encodes_like_cantools(message, layout, values, n)
    decoded = layout.decode(payloads)
    for name, v in values.items():
        np.testing.assert_array_equal(decoded[name], layout.signal(name).quantize(v))
    check_against_cantools(message, layout, payloads, "floats")
    check_against_cantools(message, layout, _random(message), "floats, random bits")
    check_encode(message, layout, _random(message, seed=2), "floats")
    # NaN and infinities are floats like any other: not clipped.
    special, clipped = layout.encode({"F32": np.array([np.nan, np.inf, -np.inf])}, 3)
    assert clipped == {}
    got = layout.decode(special)["F32"]
    assert math.isnan(got[0]) and got[1] == np.inf and got[2] == -np.inf


def _nested():
    return _msg([
        _sig("M1", 0, 4, is_multiplexer=True),
        _sig("M2", 4, 4, is_multiplexer=True, multiplexer_signal="M1", multiplexer_ids=[1]),
        _sig("S2", 8, 16, signed=True, scale=0.1, multiplexer_signal="M1",
             multiplexer_ids=[2, 3]),
        _sig("S", 8, 12, "big_endian", multiplexer_signal="M2", multiplexer_ids=[3, 4]),
        _sig("T", 24, 8, multiplexer_signal="M2", multiplexer_ids=[5]),
        _sig("Plain", 56, 8),
    ])


def test_nested_multiplexing_selects_as_cantools():
    message = _nested()
    layout = compile_layout(message)
    assert message.signal_tree == [{"M1": {1: [{"M2": {3: ["S"], 4: ["S"], 5: ["T"]}}],
                                           2: ["S2"], 3: ["S2"]}}, "Plain"]
    n = 256
    payloads = _random(message, n=n, seed=4)
    payloads[:, 0] = np.arange(n) % 256  # every (M1, M2) pair
    whole, refused = check_against_cantools(message, layout, payloads, "nested")
    assert whole and refused  # both valid and invalid multiplexer values were compared
    selected = layout.selected(payloads)
    m1, m2 = payloads[:, 0] & 0xF, payloads[:, 0] >> 4
    np.testing.assert_array_equal(selected["M2"], m1 == 1)
    np.testing.assert_array_equal(selected["S"], (m1 == 1) & ((m2 == 3) | (m2 == 4)))
    np.testing.assert_array_equal(selected["S2"], (m1 == 2) | (m1 == 3))
    assert "Plain" not in selected and "M1" not in selected
    check_encode(message, layout, payloads, "nested")
    # Encoding: the multiplexers' values choose what is written in each row.
    values = {"M1": np.array([1, 1, 2, 3, 1, 9]), "M2": np.array([3, 5, 3, 0, 4, 3]),
              "S": np.array([0x123, 7, 1, 1, 0xFFF, 1]),
              "S2": np.array([5.0, 5.0, -3.2, 3276.7, 5.0, 5.0]),
              "T": np.array([1, 200, 1, 1, 1, 1]), "Plain": np.arange(6)}
    payloads, clipped = layout.encode(values, 6)
    assert clipped == {}
    decoded = layout.decode(payloads)
    for i in range(5):  # row 5: M1 = 9 has no branch; cantools refuses to encode it
        tree = message.decode(payloads[i].tobytes(), decode_choices=False)
        assert set(tree) == {k for k, v in decoded.items() if not math.isnan(v[i])}
        want = message.encode({k: float(values[k][i]) for k in tree}, strict=False)
        assert payloads[i].tobytes() == want
    assert payloads[5].tolist() == [9, 0, 0, 0, 0, 0, 0, 5]


def test_cascaded_multiplexers_of_cantools_test_file():
    db = cantools.database.load_file(DBC / "cantools" / "issue_184_extended_mux_cascaded.dbc")
    message = db.get_message_by_name("ext_MUX_cascaded")
    layout = compile_layout(message)
    payloads = _random(message, n=512, seed=5)
    payloads[:, 0] = np.arange(512) % 4
    payloads[:, 1] = (np.arange(512) // 4) % 3
    check_against_cantools(message, layout, payloads, "cascaded")
    decoded = layout.decode(payloads)
    row = int(np.flatnonzero((payloads[:, 0] == 2) & (payloads[:, 1] == 1))[0])
    assert message.decode(payloads[row].tobytes(), decode_choices=False) == {
        k: v[row] for k, v in decoded.items() if not math.isnan(v[row])}
    assert math.isnan(decoded["muxed_B_0"][row]) and math.isnan(decoded["muxed_A_1"][row])


def test_multiplexer_values_given_clip_only_where_written():
    layout = compile_layout(_nested())
    values = {"M1": np.array([2, 1]), "S2": np.array([1e9, 1e9])}
    _, clipped = layout.encode(values, 2)
    assert clipped == {"S2": 1}  # row 1 does not carry S2: its value is not looked at


def test_64_byte_fd_payloads():
    message = _msg([
        _sig("Head", 0, 8),
        _sig("W", 440, 64),                            # bytes 55..62
        _sig("F", 480, 32, is_float=True),              # bytes 60..63 (overlaps W's end? no)
        _sig("Tail", 507, 5),                           # last bits of byte 63
        _sig("BE", 495, 12, "big_endian", signed=True),  # straddling bytes 61-62
        _sig("Mid", 250, 30, signed=True, scale=0.25),
    ], length=64, frame_id=0x1ABCDE, is_extended_frame=True, is_fd=True)
    message.signals.remove(message.get_signal_by_name("F"))  # W and F would overlap
    message.refresh()
    layout = compile_layout(message)
    assert (layout.dlc, layout.length, layout.is_fd, layout.is_extended) == (64, 64, True, True)
    payloads = _random(message, n=128, extra=6)  # bytes beyond 64 are ignored
    check_against_cantools(message, layout, payloads, "fd64")
    check_encode(message, layout, payloads, "fd64")
    encoded, _ = layout.encode(layout.decode(payloads), 128)
    assert encoded.shape == (128, 64)
    db = cantools.database.load_file(DBC / "opendbc" / "gwm_haval_h6_phev_2024.dbc",
                                     strict=False)
    longest = max(db.messages, key=lambda m: (m.length, len(m.signals)))
    assert longest.length == 64
    check_against_cantools(longest, compile_layout(longest), _random(longest), longest.name)


def test_29_bit_ids_are_recorded():
    db = cantools.database.load_file(DBC / "cantools" / "j1939.dbc")
    for message in db.messages:
        layout = compile_layout(message)
        assert layout.is_extended and layout.frame_id == message.frame_id > 0x7FF
    db = cantools.database.load_file(DBC / "cantools" / "fd_test.dbc")
    flags = {m.name: (compile_layout(m).is_extended, compile_layout(m).is_fd)
             for m in db.messages}
    assert flags == {"TestMsg_Ex": (True, False), "TestMsg_Std": (False, False),
                     "TestMsg_FDStd": (False, True), "TestMsg_FDEx": (True, True)}


def test_compile_only_the_named_signals_and_their_multiplexers():
    message = _nested()
    layout = compile_layout(message, signals=["S"])
    assert [s.name for s in layout.signals] == ["M1", "M2", "S"]
    m2 = layout.signal("M2")
    assert (m2.is_multiplexer, m2.multiplexer_signal, m2.multiplexer_ids) == (True, "M1", (1,))
    payloads = _random(message, n=64)
    payloads[:, 0] = 0x31
    full = compile_layout(message).decode(payloads)
    np.testing.assert_array_equal(layout.decode(payloads)["S"], full["S"])
    assert not np.isnan(full["S"]).any()
    assert compile_layout(message, signals=[]).signals == ()
    with pytest.raises(ValueError, match=r"M\.Nope"):
        compile_layout(message, signals=["Nope"])


def test_one_unrepresentable_signal_does_not_refuse_the_others():
    message = _msg([_sig("Good", 0, 8), _sig("Bad", 12, 16)], length=2)
    with pytest.raises(ValueError, match=r"M\.Bad"):
        compile_layout(message)
    layout = compile_layout(message, signals=["Good"])
    payloads = _random(message)
    check_against_cantools(message, layout, payloads, "good only")


def test_payload_widths_and_shapes():
    message = _msg([_sig("A", 4, 12), _sig("B", 23, 16, "big_endian")], length=5)
    layout = compile_layout(message)
    payloads = _random(message, n=16, extra=11)
    want = layout.decode(np.ascontiguousarray(payloads[:, :5]))
    for view in (payloads, payloads[:, :5], payloads[:, :9], np.asfortranarray(payloads)):
        got = layout.decode(view)
        for name in want:
            np.testing.assert_array_equal(got[name], want[name])
    raw = layout.decode_raw(payloads)
    raw["A"][:] = -1  # decode_raw never hands out a view of the caller's payloads
    assert layout.decode_raw(payloads)["A"].min() >= 0
    short = layout.decode(payloads[:, :3])  # read as if zero-padded
    np.testing.assert_array_equal(short["A"], want["A"])
    np.testing.assert_array_equal(short["B"], (payloads[:, 2].astype(float) * 256))
    with pytest.raises(ValueError, match="payloads"):
        layout.decode(payloads[0])
    assert layout.decode(np.zeros((0, 5), np.uint8))["A"].shape == (0,)


def test_the_docstring_examples_run():
    result = doctest.testmod(codec_module)
    assert result.attempted > 0 and result.failed == 0


# -- a property over single signals anywhere ----------------------------------------------------

_LENGTHS = [1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64]
_SCALINGS = [(1, 0), (2, 0), (3, 1), (7, -3), (1, 0.5), (0.5, 0), (0.1, -40), (-1.5, 7),
             (1e-3, 0.25), (3.0, 2**40)]


@st.composite
def _one_signal_messages(draw):
    length = draw(st.sampled_from(_LENGTHS))
    is_float = draw(st.integers(0, 4)) == 0
    bits = 8 * length
    if is_float:
        n = draw(st.sampled_from([b for b in (16, 32, 64) if b <= bits] or [16]))
        if n > bits:
            length, bits = 2, 16
    else:
        n = draw(st.integers(1, min(64, bits)))
    order = draw(st.sampled_from(["little_endian", "big_endian"]))
    first = draw(st.integers(0, bits - n))  # Intel: LSB; Motorola: MSB in network order
    start = first if order == "little_endian" else 8 * (first // 8) + 7 - first % 8
    scale, offset = draw(st.sampled_from(_SCALINGS))
    signed = not is_float and draw(st.booleans())
    sig = _sig("X", start, n, order, signed=signed, scale=scale, offset=offset,
               is_float=is_float)
    return _msg([sig], length=length, frame_id=draw(st.integers(0, 0x7FF)))


@settings(max_examples=400, deadline=None)
@given(message=_one_signal_messages(), seed=st.integers(0, 2**32 - 1))
def test_any_single_signal_matches_cantools(message, seed):
    layout = compile_layout(message)
    payloads = _random(message, n=24, seed=seed, extra=seed % 3)
    check_against_cantools(message, layout, payloads, str(message.signals[0]))
    check_encode(message, layout, payloads, str(message.signals[0]))

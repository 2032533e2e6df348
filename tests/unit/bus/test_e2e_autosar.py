"""AUTOSAR E2E Profiles 1 and 2 against an independent implementation and worked examples.

The reference is the ``autosar-e2e`` package (PyPI; Artur Drogunow, MIT; C code; import name
``e2e``), a test-only dependency. The worked examples are those of its own test suite
(github.com/zariiii9003/autosar-e2e, test/test_p01.py and test/test_p02.py); they are checked
here without the package, so they run wherever canfdi's tests do.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from canfdi.bus import e2e

WHERE = "bus.e2e.messages.M"
MODES = ("both", "alt", "low", "nibble")
ID_LIMIT = {"both": 0xFFFF, "alt": 0xFFFF, "low": 0xFF, "nibble": 0xFFF}


# --- worked examples -------------------------------------------------------------------------

# Data ID 0x123, 8 zero bytes (CRC byte 0, counter low nibble of byte 1): mode -> the frames
# with counter 0 and counter 1.
P01_EXAMPLES = {
    "both": ("cc00000000000000", "9101000000000000"),
    "alt": ("ce00000000000000", "0201000000000000"),
    "low": ("ce00000000000000", "9301000000000000"),
    "nibble": ("2a10000000000000", "7711000000000000"),
}


@pytest.mark.parametrize("mode", MODES)
def test_p01_worked_examples(mode: str) -> None:
    # LOW uses only the low byte of 0x123 (its high byte must be 0: SWS_E2E_00169).
    profile = e2e.AutosarP01(0x123 & ID_LIMIT[mode], 64, mode)
    for counter, expected in enumerate(P01_EXAMPLES[mode]):
        frame = profile.protect(bytes(8), counter)
        assert frame.hex() == expected
        assert profile.check(frame) and profile.counter(frame) == counter


def test_p01_worked_examples_that_fail() -> None:
    assert not e2e.AutosarP01(0x123, 64, "both").check(bytes.fromhex("cc10000000000000"))
    assert not e2e.AutosarP01(0x23, 64, "low").check(bytes.fromhex("9311000000000000"))
    assert not e2e.AutosarP01(0x123, 64, "nibble").check(bytes.fromhex("7721000000000000"))


def test_p01_counter_15_is_invalid_even_with_the_right_crc() -> None:
    profile = e2e.AutosarP01(0x123, 64)
    frame = bytearray(bytes(8))
    frame[1] = 0x0F
    frame[0] = e2e.crc8(b"\x23\x01" + bytes(frame[1:]), init=0) ^ 0xFF  # a right CRC
    assert not profile.check(bytes(frame))
    assert profile.counter(bytes(frame)) == 15


@pytest.mark.parametrize(
    ("data", "ids", "counter", "expected"),
    [
        (bytes(8), bytes(16), 1, "4501000000000000"),
        (bytes(range(8)), bytes(range(16)), 2, "bc02020304050607"),
        (bytes(range(8)), bytes(range(16)), 1, "6101020304050607"),
    ],
)
def test_p02_worked_examples(data: bytes, ids: bytes, counter: int, expected: str) -> None:
    profile = e2e.AutosarP02(ids, 64)
    frame = profile.protect(data, counter)
    assert frame.hex() == expected
    assert profile.check(frame)


def test_p02_worked_example_with_the_wrong_counter_fails() -> None:
    profile = e2e.AutosarP02(bytes(range(16)), 64)
    assert profile.check(bytes.fromhex("bc02020304050607"))
    assert not profile.check(bytes.fromhex("bc01020304050607"))


# --- against autosar-e2e, frame for frame ----------------------------------------------------

try:
    from e2e import crc as autosar_crc
    from e2e import p01, p02
except ImportError:  # the test extra is not installed: the worked examples above still run
    autosar_crc = p01 = p02 = None
needs_autosar_e2e = pytest.mark.skipif(p01 is None, reason="autosar-e2e (the test extra) is "
                                                           "not installed")


def _mode(name: str) -> int:
    return getattr(p01, f"E2E_P01_DATAID_{name.upper()}")


@st.composite
def _p01_cases(draw: st.DrawFn) -> tuple[str, int, int, int, bytes, int]:
    """mode, Data ID, data bytes, header byte offset, payload, counter."""
    mode = draw(st.sampled_from(MODES))
    n_bytes = draw(st.integers(2, 30))
    offset = draw(st.integers(0, n_bytes - 2))
    return (mode, draw(st.integers(0, ID_LIMIT[mode])), n_bytes, offset,
            draw(st.binary(min_size=n_bytes, max_size=n_bytes)), draw(st.integers(0, 10**6)))


def _ours_p01(mode: str, data_id: int, n_bytes: int, offset: int) -> e2e.AutosarP01:
    # autosar-e2e places the header at a byte offset: CRC, then the counter in the low nibble
    # of the next byte, the Data ID nibble in its high nibble (variants 1A/1C moved along).
    return e2e.AutosarP01(data_id, 8 * n_bytes, mode, crc_offset=8 * offset,
                          counter_offset=8 * offset + 8, data_id_nibble_offset=8 * offset + 12)


@needs_autosar_e2e
@given(_p01_cases())
def test_p01_protect_equals_autosar_e2e(case: tuple) -> None:
    mode, data_id, n_bytes, offset, payload, counter = case
    ours = _ours_p01(mode, data_id, n_bytes, offset)
    frame = ours.protect(payload, counter)
    theirs = bytearray(payload)
    theirs[offset + 1] = (theirs[offset + 1] & 0xF0) | counter % 15
    p01.e2e_p01_protect(theirs, data_id, data_id_mode=_mode(mode), offset=offset,
                        increment_counter=False)
    assert frame == bytes(theirs)
    assert p01.e2e_p01_check(bytearray(frame), data_id, data_id_mode=_mode(mode), offset=offset)


@needs_autosar_e2e
@given(_p01_cases(), st.integers(0, 29), st.integers(0, 255), st.booleans())
def test_p01_check_equals_autosar_e2e(case: tuple, byte: int, flip: int, garbage: bool) -> None:
    mode, data_id, n_bytes, offset, payload, counter = case
    ours = _ours_p01(mode, data_id, n_bytes, offset)
    frame = bytearray(payload if garbage else ours.protect(payload, counter))
    frame[byte % n_bytes] ^= flip
    frame = bytes(frame)
    expected = p01.e2e_p01_check(bytearray(frame), data_id, data_id_mode=_mode(mode), offset=offset)
    assert ours.check(frame) == expected
    row = np.frombuffer(frame, np.uint8)[None, :]
    assert ours.check_batch(row, np.array([n_bytes]))[0] == expected


@needs_autosar_e2e
@pytest.mark.parametrize("mode", MODES)
def test_p01_counts_like_an_autosar_e2e_sender(mode: str) -> None:
    # The sender increments before it writes: 1, 2, .., 14, 0, 1, .. (0xF skipped).
    data_id = 0x0ABC & ID_LIMIT[mode]
    ours = e2e.AutosarP01(data_id, 64, mode)
    buffer = bytearray(8)
    frames = []
    for k in range(40):
        buffer[2:] = bytes([k] * 6)
        p01.e2e_p01_protect(buffer, data_id, data_id_mode=_mode(mode))
        frames.append(bytes(buffer))
    block = np.frombuffer(b"".join(frames), np.uint8).reshape(40, 8)
    assert ours.counters(block).tolist() == [(k + 1) % 15 for k in range(40)]
    assert ours.check_batch(block, np.full(40, 8)).all()
    assert np.array_equal(ours.protect_batch(block, ours.counters(block)), block)


@needs_autosar_e2e
@given(st.binary(min_size=16, max_size=16), st.integers(2, 64), st.data(),
       st.integers(0, 10**6))
def test_p02_protect_equals_autosar_e2e(ids: bytes, n_bytes: int, data: st.DataObject,
                                        counter: int) -> None:
    payload = data.draw(st.binary(min_size=n_bytes, max_size=n_bytes), label="payload")
    ours = e2e.AutosarP02(ids, 8 * n_bytes)
    frame = ours.protect(payload, counter)
    theirs = bytearray(payload)
    theirs[1] = (theirs[1] & 0xF0) | counter % 16
    p02.e2e_p02_protect(theirs, ids, increment_counter=False)
    assert frame == bytes(theirs)
    assert p02.e2e_p02_check(frame, ids)


@needs_autosar_e2e
@given(st.binary(min_size=16, max_size=16), st.integers(2, 64), st.data(), st.booleans())
def test_p02_check_equals_autosar_e2e(ids: bytes, n_bytes: int, data: st.DataObject,
                                      garbage: bool) -> None:
    payload = data.draw(st.binary(min_size=n_bytes, max_size=n_bytes), label="payload")
    ours = e2e.AutosarP02(ids, 8 * n_bytes)
    frame = bytearray(payload if garbage else ours.protect(payload, data.draw(st.integers(0, 99))))
    frame[data.draw(st.integers(0, n_bytes - 1))] ^= data.draw(st.integers(0, 255))
    frame = bytes(frame)
    expected = p02.e2e_p02_check(frame, ids)
    assert ours.check(frame) == expected
    row = np.frombuffer(frame, np.uint8)[None, :]
    assert ours.check_batch(row, np.array([n_bytes]))[0] == expected


@needs_autosar_e2e
def test_p02_counts_like_an_autosar_e2e_sender() -> None:
    ids = bytes(range(0x40, 0x50))
    ours = e2e.make_profile({"profile": "autosar_p02", "data_id_list": list(ids)}, 0x200,
                            False, 8, {}, WHERE)
    buffer = bytearray(8)
    frames = []
    for k in range(40):
        buffer[2:] = bytes([255 - k] * 6)
        p02.e2e_p02_protect(buffer, ids)
        frames.append(bytes(buffer))
    block = np.frombuffer(b"".join(frames), np.uint8).reshape(40, 8)
    assert ours.counters(block).tolist() == [(k + 1) % 16 for k in range(40)]
    assert ours.check_batch(block, np.full(40, 8)).all()
    assert np.array_equal(ours.protect_batch(block, ours.counters(block)), block)


@needs_autosar_e2e
def test_crcs_equal_autosar_e2e() -> None:
    rng = np.random.default_rng(11)
    for n in range(40):
        data = rng.integers(0, 256, n, dtype=np.uint8).tobytes()
        assert e2e.crc8(data) == autosar_crc.calculate_crc8(data)
        assert e2e.crc8h2f(data) == autosar_crc.calculate_crc8_h2f(data)

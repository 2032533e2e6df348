"""E2E protection: CRC-8 SAE J1850, Data ID, alive counter, and the vectorised check."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from canfdi.bus import e2e

IDS = st.integers(min_value=0, max_value=0x7FF)
PAYLOADS = st.binary(min_size=2, max_size=8)


def _crc8_bitwise(data: bytes, init: int = 0xFF) -> int:
    # Independent of the table: the textbook MSB-first shift register.
    crc = init
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1D) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
    return crc ^ 0xFF


def test_crc8_check_value() -> None:
    assert e2e.crc8(b"123456789") == 0x4B


def test_crc8_empty_is_init_xor_final() -> None:
    assert e2e.crc8(b"") == 0x00
    assert e2e.crc8(b"", init=0x00) == 0xFF


@given(st.binary(max_size=32), st.integers(0, 255))
def test_crc8_matches_bitwise_reference(data: bytes, init: int) -> None:
    assert e2e.crc8(data, init) == _crc8_bitwise(data, init)


def test_data_id_is_low_byte_first() -> None:
    assert e2e.data_id(0x102) == b"\x02\x01"
    assert e2e.data_id(0x7FF) == b"\xff\x07"


def test_e2e_crc_covers_data_id_and_bytes_after_crc() -> None:
    payload = bytes([0xAA, 7, 1, 2, 3])
    assert e2e.e2e_crc(0x101, payload) == e2e.crc8(b"\x01\x01" + bytes([7, 1, 2, 3]))


@given(IDS, PAYLOADS, st.integers(min_value=0, max_value=10**6))
def test_protect_check_round_trip(arbitration_id: int, payload: bytes, counter: int) -> None:
    frame = e2e.protect(arbitration_id, payload, counter)
    assert isinstance(frame, bytes)
    assert len(frame) == len(payload)
    assert frame[2:] == payload[2:]
    assert e2e.counter_of(frame) == counter % 256
    assert e2e.check(arbitration_id, frame)


def test_protect_does_not_modify_its_argument() -> None:
    payload = bytearray(8)
    e2e.protect(0x100, payload, 5)
    assert payload == bytearray(8)


@pytest.mark.parametrize("length", [2, 4, 8])
def test_any_single_bit_flip_after_the_crc_fails(length: int) -> None:
    rng = np.random.default_rng(length)
    for _ in range(20):
        arbitration_id = int(rng.integers(0, 0x800))
        frame = e2e.protect(arbitration_id, rng.integers(0, 256, length, dtype=np.uint8).tobytes(),
                            int(rng.integers(0, 256)))
        for bit in range(8, 8 * length):
            corrupted = bytearray(frame)
            corrupted[bit // 8] ^= 1 << (bit % 8)
            assert not e2e.check(arbitration_id, corrupted), (arbitration_id, bit)


def test_crc_byte_bit_flip_fails() -> None:
    frame = e2e.protect(0x100, bytes(8), 1)
    for bit in range(8):
        corrupted = bytearray(frame)
        corrupted[0] ^= 1 << bit
        assert not e2e.check(0x100, corrupted)


@given(IDS, IDS, PAYLOADS, st.integers(0, 255))
def test_other_id_fails_unless_the_ids_are_confusable(
    id_sent: int, id_read: int, payload: bytes, counter: int
) -> None:
    frame = e2e.protect(id_sent, payload, counter)
    confusable = (id_sent ^ id_read) in e2e.UNDETECTED_ID_XORS
    assert e2e.check(id_read, frame) == (id_read == id_sent or confusable)


def test_other_id_fails_exhaustively_for_ids_differing_in_the_low_byte() -> None:
    rng = np.random.default_rng(0)
    for id_sent in (0x080, 0x100, 0x7FF):
        frame = e2e.protect(id_sent, rng.integers(0, 256, 8, dtype=np.uint8).tobytes(), 3)
        same_high = range(id_sent & 0x700, (id_sent & 0x700) + 0x100)
        assert [i for i in same_high if e2e.check(i, frame)] == [id_sent]


def test_undetected_id_xors_are_exactly_the_crc_blind_spots() -> None:
    # Brute force over every ID for one frame: the linear-algebra shortcut must agree.
    frame = e2e.protect(0, bytes(range(8)), 77)
    blind = tuple(i for i in range(1, 0x800) if e2e.check(i, frame))
    assert blind == e2e.UNDETECTED_ID_XORS
    assert blind == (0x183, 0x21B, 0x398, 0x436, 0x5B5, 0x62D, 0x7AE)


def test_confusable_ids() -> None:
    assert e2e.confusable_ids([0x080, 0x081, 0x082, 0x083]) == []
    assert e2e.confusable_ids([0x100, 0x083, 0x100]) == [(0x083, 0x100)]


def test_check_rejects_bad_lengths_without_raising() -> None:
    assert not e2e.check(0x100, b"")
    assert not e2e.check(0x100, b"\x00")
    assert not e2e.check(0x100, bytes(9))


def test_counter_delta() -> None:
    assert e2e.counter_delta(5, 6) == 1
    assert e2e.counter_delta(255, 0) == 1
    assert e2e.counter_delta(7, 7) == 0
    assert e2e.counter_delta(250, 3) == 9


@pytest.mark.parametrize(
    ("call", "name"),
    [
        (lambda: e2e.crc8(b"", init=256), "init"),
        (lambda: e2e.data_id(0x800), "arbitration_id"),
        (lambda: e2e.data_id(-1), "arbitration_id"),
        (lambda: e2e.check(0x800, bytes(8)), "arbitration_id"),
        (lambda: e2e.protect(0x100, b"\x00", 0), "payload"),
        (lambda: e2e.protect(0x100, bytes(9), 0), "payload"),
        (lambda: e2e.protect(0x100, bytes(8), -1), "counter"),
        (lambda: e2e.counter_of(b"\x00"), "payload"),
        (lambda: e2e.counter_delta(0, 256), "current"),
        (lambda: e2e.confusable_ids([0x800]), "arbitration_id"),
        (lambda: e2e.crc8_batch(np.zeros(3, np.uint8)), "data"),
        (lambda: e2e.crc8_batch(np.full((2, 2), 256)), "data"),
        (lambda: e2e.crc8_batch(np.zeros((2, 2), np.uint8), lengths=[0, 3]), "lengths"),
        (lambda: e2e.e2e_check_batch([1], np.zeros((1, 7), np.uint8), [8]), "payloads"),
        (lambda: e2e.e2e_check_batch([1, 2], np.zeros((1, 8), np.uint8), [8]), "ids"),
        (lambda: e2e.e2e_check_batch([0x800], np.zeros((1, 8), np.uint8), [8]), "ids"),
        (lambda: e2e.e2e_check_batch([1], np.zeros((1, 8), np.uint8), [9]), "dlc"),
        (lambda: e2e.e2e_check_batch([1], np.zeros((1, 8), np.uint8), [8, 8]), "dlc"),
    ],
)
def test_bad_input_names_the_argument(call, name: str) -> None:
    with pytest.raises(ValueError, match=name):
        call()


def test_crc8_batch_equals_scalar() -> None:
    rng = np.random.default_rng(1)
    data = rng.integers(0, 256, (500, 10), dtype=np.uint8)
    lengths = rng.integers(0, 11, 500)
    full = e2e.crc8_batch(data)
    masked = e2e.crc8_batch(data, lengths=lengths)
    assert full.dtype == np.uint8 and full.shape == (500,)
    for row, n, crc_full, crc_masked in zip(data, lengths, full, masked, strict=True):
        assert crc_full == e2e.crc8(row.tobytes())
        assert crc_masked == e2e.crc8(row[:n].tobytes())


def test_crc8_batch_accepts_int_arrays_and_empty() -> None:
    assert e2e.crc8_batch([[0x31, 0x32, 0x33, 0x34, 0x35, 0x36, 0x37, 0x38, 0x39]]).tolist() == [
        0x4B
    ]
    assert e2e.crc8_batch(np.zeros((0, 9), np.uint8)).shape == (0,)


def _random_frames(rng: np.random.Generator, n: int) -> tuple[np.ndarray, ...]:
    """n frames, half protected, half corrupted, with garbage beyond each DLC."""
    ids = rng.integers(0, 0x800, n)
    dlc = rng.integers(0, 9, n)
    payloads = rng.integers(0, 256, (n, 8), dtype=np.uint8)
    for i in range(n):
        if dlc[i] >= 2 and i % 2 == 0:
            payloads[i, : dlc[i]] = np.frombuffer(
                e2e.protect(int(ids[i]), payloads[i, : dlc[i]].tobytes(), i), np.uint8
            )
    return ids, payloads, dlc


def test_e2e_check_batch_equals_scalar() -> None:
    rng = np.random.default_rng(2)
    ids, payloads, dlc = _random_frames(rng, 2000)
    batch = e2e.e2e_check_batch(ids, payloads, dlc)
    scalar = [
        e2e.check(int(i), p[:d].tobytes()) for i, p, d in zip(ids, payloads, dlc, strict=True)
    ]
    assert batch.dtype == np.bool_ and batch.shape == (2000,)
    assert batch.tolist() == scalar
    # The protected half passes, so the comparison above is not all False.
    assert batch[(np.arange(2000) % 2 == 0) & (dlc >= 2)].all()


@given(st.lists(st.tuples(IDS, PAYLOADS, st.integers(0, 255), st.booleans()), max_size=40))
def test_e2e_check_batch_equals_scalar_hypothesis(frames: list) -> None:
    n = len(frames)
    ids = np.array([f[0] for f in frames], dtype=np.int64)
    dlc = np.array([len(f[1]) for f in frames], dtype=np.int64)
    payloads = np.zeros((n, 8), np.uint8)
    expected = []
    for i, (arbitration_id, payload, counter, protect) in enumerate(frames):
        frame = e2e.protect(arbitration_id, payload, counter) if protect else payload
        payloads[i, : len(frame)] = np.frombuffer(frame, np.uint8)
        expected.append(e2e.check(arbitration_id, frame))
    assert e2e.e2e_check_batch(ids, payloads, dlc).tolist() == expected


def test_e2e_check_batch_ignores_bytes_beyond_dlc() -> None:
    frame = np.frombuffer(e2e.protect(0x102, bytes([0, 0, 0x34, 0x12]), 9), np.uint8)
    payloads = np.zeros((2, 8), np.uint8)
    payloads[:, :4] = frame
    payloads[1, 4:] = [1, 2, 3, 4]
    assert e2e.e2e_check_batch([0x102, 0x102], payloads, [4, 4]).tolist() == [True, True]
    # The same bytes read with DLC 8 are a different message: the padding is covered.
    assert not e2e.e2e_check_batch([0x102], payloads[1:], [8])[0]


def test_e2e_check_batch_short_frames_are_invalid() -> None:
    payloads = np.zeros((3, 8), np.uint8)
    # A DLC-0/1 frame cannot carry CRC and counter, even if byte 0 happens to match.
    payloads[:, 0] = e2e.crc8(e2e.data_id(0x100))
    assert e2e.e2e_check_batch([0x100] * 3, payloads, [0, 1, 2]).tolist() == [
        False,
        False,
        e2e.check(0x100, payloads[2, :2].tobytes()),
    ]


def test_protect_batch_equals_scalar() -> None:
    rng = np.random.default_rng(3)
    for dlc in (2, 4, 8):
        payloads = rng.integers(0, 256, (300, dlc), dtype=np.uint8)
        counters = np.arange(1000, 1300)
        frames = e2e.protect_batch(0x101, payloads, counters)
        assert frames.shape == payloads.shape and frames.dtype == np.uint8
        assert not np.shares_memory(frames, payloads)
        for payload, counter, frame in zip(payloads, counters, frames, strict=True):
            assert frame.tobytes() == e2e.protect(0x101, payload.tobytes(), int(counter))
        padded = np.zeros((300, 8), np.uint8)
        padded[:, :dlc] = frames
        assert e2e.e2e_check_batch(np.full(300, 0x101), padded, np.full(300, dlc)).all()


def test_protect_batch_per_frame_ids_and_scalar_counter() -> None:
    ids = np.array([0x080, 0x100, 0x7FF])
    frames = e2e.protect_batch(ids, np.zeros((3, 8), np.uint8), 257)
    assert frames[:, 1].tolist() == [1, 1, 1]
    assert [e2e.check(int(i), f.tobytes()) for i, f in zip(ids, frames, strict=True)] == [True] * 3


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"payloads": np.zeros((2, 1), np.uint8)}, "payloads"),
        ({"payloads": np.zeros((2, 9), np.uint8)}, "payloads"),
        ({"arbitration_id": 0x800}, "arbitration_id"),
        ({"counters": [1, 2, 3]}, "counters"),
        ({"counters": -1}, "counters"),
    ],
)
def test_protect_batch_bad_input_names_the_argument(kwargs: dict, name: str) -> None:
    args = {"arbitration_id": 0x100, "payloads": np.zeros((2, 8), np.uint8), "counters": 0}
    args.update(kwargs)
    with pytest.raises(ValueError, match=name):
        e2e.protect_batch(**args)

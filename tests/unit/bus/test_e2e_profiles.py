"""E2E profiles: the registry, config errors, and per profile streaming == batch, round trips,
corrupted bytes and wrong Data IDs; the counter signal's bits against cantools."""

from __future__ import annotations

import doctest
import importlib
import pkgutil

import cantools
import numpy as np
import pytest
from cantools.database.can import Message, Signal
from hypothesis import assume, given
from hypothesis import strategies as st

from canfdi.bus import e2e
from canfdi.core.settings import ConfigError

WHERE = "bus.e2e.messages.M"
SIGNALS = {
    "Alive": (8, 4, "little_endian"),  # low nibble of byte 1
    "AliveBE": (19, 12, "big_endian"),  # bits 3..0 of byte 2, then byte 3
    "Speed": (16, 16, "little_endian"),
    "Wide": (0, 40, "little_endian"),
    "Tail": (56, 8, "little_endian"),
}

# name -> (spec, frame_id, is_extended, message length)
CASES: dict[str, tuple[object, int, bool, int]] = {
    "none": ("none", 0x123, False, 8),
    "counter": ({"profile": "counter", "signal": "Alive", "modulus": 15}, 0x123, False, 4),
    "counter_be": ({"profile": "counter", "signal": "AliveBE"}, 0x18FEF100, True, 8),
    "canfdi": ("canfdi", 0x105, False, 8),
    "canfdi_dlc4": ("canfdi", 0x106, False, 4),
    "p01_both": ({"profile": "autosar_p01", "data_id": 0x1234}, 0x123, False, 8),
    "p01_alt": ({"profile": "autosar_p01", "data_id": 0xBEEF, "data_id_mode": "alt"},
                0x123, False, 8),
    "p01_low": ({"profile": "autosar_p01", "data_id": 0x42, "data_id_mode": "low"},
                0x123, False, 6),
    "p01_nibble": ({"profile": "autosar_p01", "data_id": 0xABC, "data_id_mode": "nibble"},
                   0x123, False, 8),
    # CRC in the last covered byte (5 of 8), counter in the high nibble of the one before.
    "p01_offsets": ({"profile": "autosar_p01", "data_id": 0x0F0F, "crc_offset": 32,
                     "counter_offset": 28, "data_length": 40}, 0x18DA00F1, True, 8),
    "p02": ({"profile": "autosar_p02", "data_id_list": list(range(0x10, 0x20))},
            0x321, False, 8),
    "p02_fd": ({"profile": "autosar_p02", "data_id_list": [7] * 16, "data_length": 160},
               0x321, False, 24),
}
CRC_CASES = [name for name in CASES if not name.startswith(("none", "counter"))]


def _profile(name: str) -> e2e.E2EProfile:
    spec, frame_id, is_extended, length = CASES[name]
    return e2e.make_profile(spec, frame_id, is_extended, length, SIGNALS, WHERE)


def _covered_bytes(profile: e2e.E2EProfile, length: int) -> int:
    """How many leading bytes a profile's CRC covers (and so must see changed)."""
    return getattr(profile, "data_length", 8 * length) // 8


def _counter_bits(profile: e2e.E2EProfile) -> tuple[int, int]:
    """(byte, mask) of a counter that also selects the Data ID (P02, P01 alt), else (0, 0).

    Changing such a counter changes two parts of the CRC's input (the counter and the Data ID
    it selects), which can cancel for some IDs: that is the profile's property, not a bug, so
    the corrupted-byte test leaves those bits alone.
    """
    if isinstance(profile, e2e.AutosarP02):
        return 1, 0x0F
    if isinstance(profile, e2e.AutosarP01) and profile.data_id_mode == "alt":
        offset = profile.counter_offset
        return offset // 8, 0x0F << (offset % 8)
    return 0, 0


def test_module_doctests() -> None:
    modules = [e2e] + [importlib.import_module(f"{e2e.__name__}.{info.name}")
                       for info in pkgutil.iter_modules(e2e.__path__)]
    results = [doctest.testmod(module, optionflags=doctest.ELLIPSIS) for module in modules]
    # The registry's lookup and every profile class show their use.
    assert sum(result.attempted for result in results) >= 6
    assert [result.failed for result in results] == [0] * len(modules)


# --- CRCs -----------------------------------------------------------------------------------

# Check tables of AUTOSAR's Specification of CRC Routines (as reproduced in the tests of the
# autosar-e2e package): input -> CRC8 (SAE J1850), CRC8H2F.
CRC_TABLE = [
    (b"\x00\x00\x00\x00", 0x59, 0x12),
    (b"\xf2\x01\x83", 0x37, 0xC2),
    (b"\x0f\xaa\x00\x55", 0x79, 0xC6),
    (b"\x00\xff\x55\x11", 0xB8, 0x77),
    (b"\x33\x22\x55\xaa\xbb\xcc\xdd\xee\xff", 0xCB, 0x11),
    (b"\x92\x6b\x55", 0x8C, 0x33),
    (b"\xff\xff\xff\xff", 0x74, 0x6C),
    (b"123456789", 0x4B, 0xDF),
]


@pytest.mark.parametrize(("data", "j1850", "h2f"), CRC_TABLE)
def test_crcs_against_autosar_check_tables(data: bytes, j1850: int, h2f: int) -> None:
    assert e2e.crc8(data) == j1850
    assert e2e.crc8h2f(data) == h2f


def _crc8h2f_bitwise(data: bytes, init: int = 0xFF) -> int:
    crc = init
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = ((crc << 1) ^ 0x2F) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
    return crc ^ 0xFF


@given(st.binary(max_size=32), st.integers(0, 255))
def test_crc8h2f_matches_bitwise_reference(data: bytes, init: int) -> None:
    assert e2e.crc8h2f(data, init) == _crc8h2f_bitwise(data, init)


def test_crc8h2f_rejects_bad_init() -> None:
    with pytest.raises(ValueError, match="init"):
        e2e.crc8h2f(b"", init=256)


# --- registry and config errors --------------------------------------------------------------


def test_registry_names_match_the_profiles() -> None:
    assert sorted(e2e.PROFILES) == ["autosar_p01", "autosar_p02", "canfdi", "counter", "none"]
    for name in CASES:
        profile = _profile(name)
        assert isinstance(profile, e2e.E2EProfile)
        assert profile.name in e2e.PROFILES
        assert e2e.PROFILES[profile.name].__self__ is type(profile)  # type: ignore[attr-defined]
        assert repr(profile).startswith(type(profile).__name__)


def test_counter_moduli() -> None:
    moduli = {name: _profile(name).counter_modulus for name in CASES}
    assert moduli == {"none": None, "counter": 15, "counter_be": 4096, "canfdi": 256,
                      "canfdi_dlc4": 256, "p01_both": 15, "p01_alt": 15, "p01_low": 15,
                      "p01_nibble": 15, "p01_offsets": 15, "p02": 16, "p02_fd": 16}


def test_a_name_and_a_mapping_with_only_the_name_are_the_same() -> None:
    for name in ("none", "canfdi"):
        a = e2e.make_profile(name, 0x100, False, 8, {}, WHERE)
        b = e2e.make_profile({"profile": name}, 0x100, False, 8, {}, WHERE)
        assert repr(a) == repr(b)


def _error(spec: object, *, frame_id: int = 0x123, is_extended: bool = False, length: int = 8
           ) -> ConfigError:
    with pytest.raises(ConfigError) as info:
        e2e.make_profile(spec, frame_id, is_extended, length, SIGNALS, WHERE)
    return info.value


@pytest.mark.parametrize(
    ("spec", "kwargs", "field", "words"),
    [
        ("crc", {}, WHERE, ["unknown E2E profile 'crc'", "known: autosar_p01"]),
        ("canfid", {}, WHERE, ["did you mean canfdi"]),
        ({"profile": "autosar-p01"}, {}, f"{WHERE}.profile", ["did you mean autosar_p01"]),
        ({"profile": 1}, {}, f"{WHERE}.profile", ["unknown E2E profile 1"]),
        ({"signal": "Alive"}, {}, f"{WHERE}.profile", ["missing", "counter"]),
        (None, {}, WHERE, ["expected an E2E profile name or a mapping"]),
        (["counter"], {}, WHERE, ["got list"]),
        ({"profile": "none", "modulus": 3}, {}, f"{WHERE}.modulus", ["takes no options"]),
        ({"profile": "canfdi", "data_id": 3}, {}, f"{WHERE}.data_id", ["takes no options"]),
        # counter
        ({"profile": "counter"}, {}, f"{WHERE}.signal", ["missing", "Alive, AliveBE"]),
        ({"profile": "counter", "signal": "alive"}, {}, f"{WHERE}.signal",
         ["unknown signal 'alive'", "did you mean Alive"]),
        ({"profile": "counter", "signal": "Alive", "modulo": 15}, {}, f"{WHERE}.modulo",
         ["unknown key", "did you mean modulus"]),
        ({"profile": "counter", "signal": "Alive", "modulus": 17}, {}, f"{WHERE}.modulus",
         ["[2, 16]", "got 17"]),
        ({"profile": "counter", "signal": "Alive", "modulus": 1}, {}, f"{WHERE}.modulus",
         [">= 2"]),
        ({"profile": "counter", "signal": "Alive", "modulus": 2.5}, {}, f"{WHERE}.modulus",
         ["integer"]),
        ({"profile": "counter", "signal": "Wide"}, {}, f"{WHERE}.signal", ["40 bits", "1..32"]),
        ({"profile": "counter", "signal": "Tail"}, {"length": 4}, f"{WHERE}.signal",
         ["byte 8 of a 4-byte message"]),
        # canfdi
        ("canfdi", {"frame_id": 0x18FEF100, "is_extended": True}, WHERE,
         ["11-bit IDs only", "0x18fef100"]),
        ("canfdi", {"frame_id": 0x100, "is_extended": True}, WHERE, ["11-bit IDs only"]),
        ("canfdi", {"length": 1}, WHERE, ["2..8 bytes", "has 1"]),
        ("canfdi", {"length": 12}, WHERE, ["2..8 bytes", "has 12"]),
        # AUTOSAR Profile 1
        ({"profile": "autosar_p01"}, {}, f"{WHERE}.data_id", ["missing", "Data ID"]),
        ({"profile": "autosar_p01", "data_id": 0x10000}, {}, f"{WHERE}.data_id",
         ["[0, 65535]"]),
        ({"profile": "autosar_p01", "data_id": 0x100, "data_id_mode": "low"}, {},
         f"{WHERE}.data_id", ["0xff", "low"]),
        ({"profile": "autosar_p01", "data_id": 0x1000, "data_id_mode": "nibble"}, {},
         f"{WHERE}.data_id", ["0xfff", "nibble"]),
        ({"profile": "autosar_p01", "data_id": 1, "data_id_mode": "bothh"}, {},
         f"{WHERE}.data_id_mode", ["unknown value 'bothh'", "did you mean both"]),
        ({"profile": "autosar_p01", "data_id": 1, "data_idmode": "alt"}, {},
         f"{WHERE}.data_idmode", ["did you mean data_id_mode"]),
        ({"profile": "autosar_p01", "data_id": 1, "crc_offset": 4}, {}, f"{WHERE}.crc_offset",
         ["multiple of 8"]),
        ({"profile": "autosar_p01", "data_id": 1, "counter_offset": 10}, {},
         f"{WHERE}.counter_offset", ["multiple of 4"]),
        ({"profile": "autosar_p01", "data_id": 1, "counter_offset": 4}, {},
         f"{WHERE}.counter_offset", ["in the CRC byte"]),
        ({"profile": "autosar_p01", "data_id": 1, "crc_offset": 64}, {}, f"{WHERE}.crc_offset",
         ["0..56"]),
        ({"profile": "autosar_p01", "data_id": 1, "counter_offset": 64}, {},
         f"{WHERE}.counter_offset", ["0..60"]),
        ({"profile": "autosar_p01", "data_id": 1, "data_id_mode": "nibble",
          "data_id_nibble_offset": 8}, {}, f"{WHERE}.data_id_nibble_offset", ["is the counter"]),
        ({"profile": "autosar_p01", "data_id": 1, "data_id_mode": "nibble",
          "data_id_nibble_offset": 4}, {}, f"{WHERE}.data_id_nibble_offset", ["CRC byte"]),
        ({"profile": "autosar_p01", "data_id": 1, "data_id_mode": "nibble",
          "data_id_nibble_offset": 6}, {}, f"{WHERE}.data_id_nibble_offset", ["multiple of 4"]),
        ({"profile": "autosar_p01", "data_id": 1, "data_length": 36}, {},
         f"{WHERE}.data_length", ["multiple of 8"]),
        ({"profile": "autosar_p01", "data_id": 1, "data_length": 8}, {},
         f"{WHERE}.data_length", ["[16, 240]"]),
        ({"profile": "autosar_p01", "data_id": 1, "data_length": 72}, {},
         f"{WHERE}.data_length", ["do not fit the 8-byte message"]),
        ({"profile": "autosar_p01", "data_id": 1}, {"length": 32}, f"{WHERE}.data_length",
         ["missing", "longer than Profile 1's 240 bits"]),
        ({"profile": "autosar_p01", "data_id": 1}, {"length": 1}, WHERE, ["at least 2 bytes"]),
        # AUTOSAR Profile 2
        ({"profile": "autosar_p02"}, {}, f"{WHERE}.data_id_list", ["missing", "16 Data IDs"]),
        ({"profile": "autosar_p02", "data_id_list": [1] * 15}, {}, f"{WHERE}.data_id_list",
         ["16 integers in 0..255"]),
        ({"profile": "autosar_p02", "data_id_list": [256] + [1] * 15}, {},
         f"{WHERE}.data_id_list", ["16 integers"]),
        ({"profile": "autosar_p02", "data_id_list": [True] * 16}, {}, f"{WHERE}.data_id_list",
         ["16 integers"]),
        ({"profile": "autosar_p02", "data_id_list": "0123456789abcdef"}, {},
         f"{WHERE}.data_id_list", ["16 integers"]),
        ({"profile": "autosar_p02", "data_id_list": [1] * 16, "data_length": 72}, {},
         f"{WHERE}.data_length", ["do not fit"]),
        ({"profile": "autosar_p02", "data_id_list": [1] * 16, "data_length": 20}, {},
         f"{WHERE}.data_length", ["multiple of 8"]),
        ({"profile": "autosar_p02", "data_id_list": [1] * 16}, {"length": 1}, WHERE,
         ["at least 2 bytes"]),
    ],
)
def test_config_errors_name_the_field(spec: object, kwargs: dict, field: str,
                                      words: list[str]) -> None:
    error = _error(spec, **kwargs)
    assert error.field == field
    assert str(error).startswith(f"{field}: ")
    for word in words:
        assert word in str(error)


def test_options_take_yaml_values() -> None:
    # PyYAML reads 0x123 as an int; AUTOSAR's offsets come as ints; mode names are lower case.
    import yaml

    spec = yaml.safe_load("{profile: autosar_p01, data_id: 0x123, data_id_mode: nibble,"
                          " crc_offset: 8, counter_offset: 0, data_id_nibble_offset: 4}")
    profile = e2e.make_profile(spec, 0x123, False, 8, {}, WHERE)
    assert (profile.data_id, profile.crc_offset, profile.counter_offset,
            profile.data_id_nibble_offset) == (0x123, 8, 0, 4)


def test_make_profile_rejects_impossible_messages() -> None:
    with pytest.raises(ValueError, match="length"):
        e2e.make_profile("none", 0x100, False, 65, {}, WHERE)
    with pytest.raises(ValueError, match="11-bit"):
        e2e.make_profile("none", 0x800, False, 8, {}, WHERE)
    with pytest.raises(ValueError, match="29-bit"):
        e2e.make_profile("none", 0x20000000, True, 8, {}, WHERE)


# --- every profile: streaming == batch, round trips ------------------------------------------


@st.composite
def _blocks(draw: st.DrawFn) -> tuple[str, np.ndarray, np.ndarray, np.ndarray]:
    """A profile and a block of frames: protected, corrupted, garbage, short and long ones."""
    name = draw(st.sampled_from(sorted(CASES)))
    length = CASES[name][3]
    profile = _profile(name)
    n = draw(st.integers(0, 12))
    width = draw(st.sampled_from([length, length + 3]))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    payloads = rng.integers(0, 256, (n, width), dtype=np.uint8)
    counters = rng.integers(0, 10**6, n)
    protected = profile.protect_batch(payloads[:, :length], counters)
    kinds = rng.integers(0, 4, n)  # 0 protected, 1 one byte flipped, 2 garbage, 3 any length
    payloads[kinds <= 1, :length] = protected[kinds <= 1]
    flip = rng.integers(0, length, n)
    rows = np.flatnonzero(kinds == 1)
    payloads[rows, flip[rows]] ^= rng.integers(1, 256, rows.size, dtype=np.uint8)
    lengths = np.where(kinds == 3, rng.integers(0, width + 1, n), length)
    return name, payloads, lengths, counters


@given(_blocks())
def test_streaming_and_batch_forms_agree(block: tuple) -> None:
    name, payloads, lengths, _ = block
    profile = _profile(name)
    frames = [bytes(row[:n]) for row, n in zip(payloads, lengths, strict=True)]
    batch = profile.check_batch(payloads, lengths)
    assert batch.dtype == np.bool_ and batch.shape == (len(frames),)
    assert batch.tolist() == [profile.check(frame) for frame in frames]
    counters = profile.counters(payloads)
    if profile.counter_modulus is None:
        assert counters is None
        assert all(profile.counter(frame) is None for frame in frames)
    else:
        assert counters.dtype == np.int64 and counters.shape == (len(frames),)
        # The streaming form reads a frame as received; the batch form its padded row.
        valid = batch
        assert counters[valid].tolist() == [profile.counter(f)
                                            for f, ok in zip(frames, valid, strict=True) if ok]
        assert counters.tolist() == [profile.counter(bytes(row)) for row in payloads]


@pytest.mark.parametrize("name", sorted(CASES))
def test_batch_forms_take_empty_blocks_and_narrow_payloads(name: str) -> None:
    profile = _profile(name)
    assert profile.check_batch(np.zeros((0, 8), np.uint8), np.zeros(0, int)).shape == (0,)
    # A block of frames too short for the profile, in an array narrower than the message.
    narrow = np.zeros((3, 1), np.uint8)
    ok = profile.check_batch(narrow, np.array([0, 1, 1]))
    assert ok.tolist() == [profile.check(b""), profile.check(b"\x00"), profile.check(b"\x00")]
    if profile.counter_modulus is not None:
        assert profile.counters(narrow).tolist() == [profile.counter(b"\x00")] * 3


@given(st.sampled_from(sorted(CASES)), st.integers(0, 2**32 - 1), st.integers(1, 20))
def test_protect_then_check_round_trips(name: str, seed: int, n: int) -> None:
    profile = _profile(name)
    length = CASES[name][3]
    rng = np.random.default_rng(seed)
    payloads = rng.integers(0, 256, (n, length), dtype=np.uint8)
    before = payloads.copy()
    counters = rng.integers(0, 10**6, n)
    frames = profile.protect_batch(payloads, counters)
    assert frames.shape == payloads.shape and frames.dtype == np.uint8
    assert not np.shares_memory(frames, payloads) and np.array_equal(payloads, before)
    assert profile.check_batch(frames, np.full(n, length)).all()
    assert all(profile.check(frame.tobytes()) for frame in frames)
    if profile.counter_modulus is not None:
        expected = (counters % profile.counter_modulus).tolist()
        assert profile.counters(frames).tolist() == expected
        assert [profile.counter(frame.tobytes()) for frame in frames] == expected
    # The one-payload sender agrees with the block one.
    assert profile.protect(payloads[0].tobytes(), int(counters[0])) == frames[0].tobytes()


@given(st.sampled_from(sorted(CASES)), st.integers(0, 2**32 - 1))
def test_protect_changes_only_the_header(name: str, seed: int) -> None:
    profile = _profile(name)
    length = CASES[name][3]
    rng = np.random.default_rng(seed)
    payload = rng.integers(0, 256, length, dtype=np.uint8).tobytes()
    frame = profile.protect(payload, int(rng.integers(0, 1000)))
    changed = {i for i in range(length) if frame[i] != payload[i]}
    header = {
        "none": set(), "counter": {1}, "counter_be": {2, 3}, "canfdi": {0, 1},
        "canfdi_dlc4": {0, 1}, "p01_both": {0, 1}, "p01_alt": {0, 1}, "p01_low": {0, 1},
        "p01_nibble": {0, 1}, "p01_offsets": {3, 4}, "p02": {0, 1}, "p02_fd": {0, 1},
    }[name]
    assert changed <= header


@given(st.sampled_from(CRC_CASES), st.integers(0, 2**32 - 1), st.data())
def test_a_corrupted_byte_fails(name: str, seed: int, data: st.DataObject) -> None:
    profile = _profile(name)
    length = CASES[name][3]
    rng = np.random.default_rng(seed)
    frame = bytearray(profile.protect(rng.integers(0, 256, length, dtype=np.uint8).tobytes(),
                                      int(rng.integers(0, 1000))))
    byte = data.draw(st.integers(0, _covered_bytes(profile, length) - 1), label="byte")
    flip = data.draw(st.integers(1, 255), label="flip")
    counter_byte, counter_mask = _counter_bits(profile)
    if byte == counter_byte:
        flip &= 0xFF ^ counter_mask
    assume(flip)
    frame[byte] ^= flip
    assert not profile.check(bytes(frame))
    row = np.frombuffer(bytes(frame), np.uint8)[None, :]
    assert not profile.check_batch(row, np.array([length]))[0]


@pytest.mark.parametrize("name", CRC_CASES)
def test_every_single_bit_flip_fails(name: str) -> None:
    # Exhaustive over the bits of a few frames (the counter bits of P02 and P01-alt included:
    # one flipped bit never cancels against its Data ID for these configurations).
    profile = _profile(name)
    length = CASES[name][3]
    rng = np.random.default_rng(7)
    frames = profile.protect_batch(rng.integers(0, 256, (4, length), dtype=np.uint8),
                                   np.arange(4))
    covered = 8 * _covered_bytes(profile, length)
    flipped = np.repeat(frames, covered, axis=0)
    bits = np.tile(np.arange(covered), len(frames))
    flipped[np.arange(len(bits)), bits // 8] ^= (1 << (bits % 8)).astype(np.uint8)
    assert not profile.check_batch(flipped, np.full(len(flipped), length)).any()


def test_bytes_beyond_the_autosar_data_length_are_not_covered() -> None:
    profile = _profile("p01_offsets")  # 40 of the 64 bits
    frame = bytearray(profile.protect(bytes(8), 3))
    frame[5:] = b"\x01\x02\x03"
    assert profile.check(bytes(frame))
    assert not profile.check(bytes(frame[:4]))  # shorter than data_length


# --- wrong Data IDs ------------------------------------------------------------------------


@given(st.sampled_from(["both", "alt", "low", "nibble"]), st.integers(0, 0xFFFF),
       st.integers(1, 0xFF), st.integers(0, 100), st.binary(min_size=8, max_size=8))
def test_p01_wrong_data_id_fails(mode: str, data_id: int, delta: int, counter: int,
                                 payload: bytes) -> None:
    limit = {"low": 0xFF, "nibble": 0xFFF}.get(mode, 0xFFFF)
    data_id &= limit
    sender = e2e.AutosarP01(data_id, 64, mode)
    frame = sender.protect(payload, counter)
    # A Data ID that differs in one byte: the one that enters the CRC for this counter (ALT
    # takes the high byte for odd counters); NIBBLE also sends the high byte's low nibble.
    odd_alt = mode == "alt" and counter % 15 % 2 == 1
    other = data_id ^ (delta << 8 if odd_alt else delta)
    assume(other <= limit)
    receiver = e2e.AutosarP01(other, 64, mode)
    assert sender.check(frame)
    assert not receiver.check(frame)
    row = np.frombuffer(frame, np.uint8)[None, :]
    assert not receiver.check_batch(row, np.array([8]))[0]


def test_p01_alt_and_low_ignore_the_bytes_they_do_not_use() -> None:
    # ALT folds in the low byte for even counters, the high byte for odd ones; LOW the low only.
    alt_a, alt_b = e2e.AutosarP01(0x1234, 64, "alt"), e2e.AutosarP01(0x9934, 64, "alt")
    assert alt_b.check(alt_a.protect(bytes(8), 2)) and not alt_b.check(alt_a.protect(bytes(8), 3))
    nibble_a, nibble_b = e2e.AutosarP01(0x134, 64, "nibble"), e2e.AutosarP01(0x234, 64, "nibble")
    # NIBBLE: the high byte is not in the CRC (a 0x00 is), but its sent nibble is compared.
    assert not nibble_b.check(nibble_a.protect(bytes(8), 1))


@given(st.lists(st.integers(0, 255), min_size=16, max_size=16), st.integers(0, 15),
       st.integers(0, 15), st.integers(1, 255), st.binary(min_size=8, max_size=8))
def test_p02_only_the_data_id_of_the_frames_counter_counts(ids: list[int], counter: int,
                                                           index: int, delta: int,
                                                           payload: bytes) -> None:
    frame = e2e.AutosarP02(ids, 64).protect(payload, counter)
    other = list(ids)
    other[index] ^= delta
    assert e2e.AutosarP02(other, 64).check(frame) == (index != counter)


def test_canfdi_profile_other_id_fails() -> None:
    frame = e2e.CanfdiProfile(0x105).protect(bytes(8), 9)
    assert not e2e.CanfdiProfile(0x104).check(frame)
    assert e2e.CanfdiProfile(0x105 ^ e2e.UNDETECTED_ID_XORS[0]).check(frame)  # the blind spot


# --- canfdi's profile is the module's functions bound to one ID ------------------------------


@given(st.integers(0, 0x7FF), st.integers(0, 2**32 - 1), st.integers(0, 30))
def test_canfdi_profile_equals_the_module_functions(frame_id: int, seed: int, n: int) -> None:
    profile = e2e.make_profile("canfdi", frame_id, False, 8, {}, WHERE)
    rng = np.random.default_rng(seed)
    payloads = rng.integers(0, 256, (n, 8), dtype=np.uint8)
    counters = rng.integers(0, 1000, n)
    protected = profile.protect_batch(payloads, counters)
    assert np.array_equal(protected, e2e.protect_batch(frame_id, payloads, counters))
    payloads[::2] = protected[::2]
    dlc = rng.integers(0, 9, n)
    dlc[::3] = 8
    assert np.array_equal(profile.check_batch(payloads, dlc),
                          e2e.e2e_check_batch(np.full(n, frame_id), payloads, dlc))
    assert profile.counters(payloads).tolist() == payloads[:, 1].tolist()


def test_canfdi_profile_rejects_can_fd_lengths_in_a_wide_block() -> None:
    profile = e2e.CanfdiProfile(0x105)
    frame = np.frombuffer(profile.protect(bytes(8), 1), np.uint8)
    block = np.zeros((2, 64), np.uint8)
    block[:, :8] = frame
    assert profile.check_batch(block, np.array([8, 12])).tolist() == [True, False]
    assert not profile.check(block[1, :12].tobytes())


# --- the counter signal against cantools ---------------------------------------------------


@st.composite
def _signals(draw: st.DrawFn) -> tuple[int, int, str]:
    """A signal of 1..32 bits anywhere in an 8-byte message, in DBC start-bit numbering."""
    bits = draw(st.integers(1, 32))
    if draw(st.booleans()):
        return draw(st.integers(0, 64 - bits)), bits, "little_endian"
    msb = draw(st.integers(0, 64 - bits))  # MSB-first position of the MSB
    return 8 * (msb // 8) + 7 - msb % 8, bits, "big_endian"


@given(_signals(), st.binary(min_size=8, max_size=8), st.integers(0, 2**40))
def test_counter_signal_bits_match_cantools(place: tuple[int, int, str], payload: bytes,
                                            value: int) -> None:
    start, bits, byte_order = place
    message = Message(frame_id=0x100, name="M", length=8,
                      signals=[Signal("Alive", start=start, length=bits, byte_order=byte_order)])
    profile = e2e.make_profile({"profile": "counter", "signal": "Alive"}, 0x100, False, 8,
                               {"Alive": place}, WHERE)
    raw = message.decode(payload, decode_choices=False, scaling=False)["Alive"]
    assert profile.counter(payload) == raw
    assert profile.counters(np.frombuffer(payload, np.uint8)[None, :]).tolist() == [raw]
    value %= 1 << bits
    assert profile.protect(bytes(8), value) == message.encode({"Alive": value}, scaling=False)
    # Writing the counter leaves every other bit of the payload as it was.
    written = profile.protect(payload, value)
    assert message.decode(written, decode_choices=False, scaling=False)["Alive"] == value
    mask = int.from_bytes(message.encode({"Alive": (1 << bits) - 1}, scaling=False), "big")
    keep = int.from_bytes(payload, "big") & ~mask
    assert int.from_bytes(written, "big") & ~mask == keep


def test_counter_profile_from_a_dbc_signal() -> None:
    db = cantools.database.load_string(
        'VERSION ""\nBS_:\nBU_: ECU\n'
        "BO_ 2566844926 Status: 8 ECU\n"
        ' SG_ Alive : 55|4@0+ (1,0) [0|14] "" ECU\n'
        ' SG_ Speed : 0|16@1+ (0.1,0) [0|6553.5] "" ECU\n', "dbc")
    message = db.get_message_by_name("Status")
    signals = {s.name: (s.start, s.length, s.byte_order) for s in message.signals}
    profile = e2e.make_profile({"profile": "counter", "signal": "Alive", "modulus": 15},
                               message.frame_id, message.is_extended_frame, message.length,
                               signals, WHERE)
    frames = profile.protect_batch(np.zeros((20, 8), np.uint8), np.arange(20))
    decoded = [message.decode(f.tobytes())["Alive"] for f in frames]
    assert decoded == [k % 15 for k in range(20)]
    assert profile.counters(frames).tolist() == decoded


# --- bad arrays name the argument ----------------------------------------------------------


@pytest.mark.parametrize("name", sorted(CASES))
def test_bad_arrays_name_the_argument(name: str) -> None:
    profile = _profile(name)
    length = CASES[name][3]
    good = np.zeros((2, length), np.uint8)
    with pytest.raises(ValueError, match="payloads"):
        profile.check_batch(np.zeros(8, np.uint8), np.array([8]))
    with pytest.raises(ValueError, match="payloads"):
        profile.check_batch(np.full((2, length), 300), np.array([length, length]))
    with pytest.raises(ValueError, match="lengths"):
        profile.check_batch(good, np.array([length]))
    with pytest.raises(ValueError, match="lengths"):
        profile.check_batch(good, np.array([length, length + 1]))
    with pytest.raises(ValueError, match="counters"):
        profile.protect_batch(good, np.array([1, 2, 3]))
    with pytest.raises(ValueError, match="counters"):
        profile.protect_batch(good, np.array([-1, 2]))
    with pytest.raises(ValueError, match="counters"):
        profile.protect_batch(good, np.array([0.5, 2]))
    if name != "none":
        with pytest.raises(ValueError, match="payloads"):
            profile.protect_batch(np.zeros((2, 1), np.uint8), np.array([1, 2]))

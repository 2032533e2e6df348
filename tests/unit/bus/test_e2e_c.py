"""The C core's E2E profiles (canfdi/_c/e2e.c) against the Python profiles: built alone with
-std=c99 -pedantic -Werror under AddressSanitizer and UndefinedBehaviorSanitizer, every
profile's tables (``c_spec()``) run on thousands of random payloads (valid frames, frames with
a bit flipped or a wrong length, noise), the check and counter row for row equal to the
profile's ``check`` and ``counter``; malformed tables a negative status, never a sanitizer
report. And e2e.h's #defines against canfdi.bus.e2e.cspec."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from canfdi.bus import e2e
from canfdi.bus.e2e.bitfield import BitField
from canfdi.bus.e2e.cspec import E2E_H, KIND_COUNTER, KIND_CRC, KIND_NONE
from tests.conftest import REPO

CORE = REPO / "canfdi" / "_c"
DRIVER = Path(__file__).parent / "c" / "e2e_main.c"
CC = shutil.which("gcc") or shutil.which("cc")
FLAGS = ["-std=c99", "-pedantic", "-Wall", "-Wextra", "-Werror", "-ffp-contract=off", "-g",
         "-O1", "-fsanitize=address,undefined", "-fno-sanitize-recover=all",
         "-fno-omit-frame-pointer"]
ROW = 64
EBADARG = -1
WHERE = "bus.e2e.messages.M"
N_ROWS = 3000
N_SWEEPS = 8

SIGNALS = {
    "Alive": (8, 4, "little_endian"),      # low nibble of byte 1
    "Bit": (13, 1, "little_endian"),        # one bit of byte 1
    "Seven": (60, 7, "little_endian"),      # bits 4..7 of byte 7, 0..2 of byte 8
    "Wide": (3, 32, "little_endian"),       # 5 pieces: bytes 0..4
    "Last": (504, 8, "little_endian"),      # byte 63
    "AliveBE": (19, 12, "big_endian"),      # bits 3..0 of byte 2, then byte 3
    "WideBE": (4, 32, "big_endian"),        # 5 pieces: bytes 0..4, MSB at bit 4 of byte 0
    "ByteBE": (87, 8, "big_endian"),        # byte 10
    "OddBE": (34, 10, "big_endian"),        # bits 2..0 of byte 4, bits 7..1 of byte 5
}

# name -> (spec, frame_id, is_extended, message length)
CASES: dict[str, tuple[object, int, bool, int]] = {
    "none": ("none", 0x123, False, 8),
    "counter_le4_mod15": ({"profile": "counter", "signal": "Alive", "modulus": 15},
                          0x123, False, 4),
    "counter_le1": ({"profile": "counter", "signal": "Bit"}, 0x123, False, 2),
    "counter_le7_mod100": ({"profile": "counter", "signal": "Seven", "modulus": 100},
                           0x123, False, 12),
    "counter_le32": ({"profile": "counter", "signal": "Wide"}, 0x123, False, 8),
    "counter_le32_mod": ({"profile": "counter", "signal": "Wide", "modulus": 3_000_000_007},
                         0x123, False, 8),
    "counter_last_byte": ({"profile": "counter", "signal": "Last", "modulus": 200},
                          0x123, False, 64),
    "counter_be12": ({"profile": "counter", "signal": "AliveBE"}, 0x18FEF100, True, 8),
    "counter_be32_mod": ({"profile": "counter", "signal": "WideBE", "modulus": 2**31 + 5},
                         0x123, False, 8),
    "counter_be8_mod200": ({"profile": "counter", "signal": "ByteBE", "modulus": 200},
                           0x123, False, 16),
    "counter_be10_mod1000": ({"profile": "counter", "signal": "OddBE", "modulus": 1000},
                             0x123, False, 8),
    "canfdi_0x000": ("canfdi", 0x000, False, 8),
    "canfdi_0x105": ("canfdi", 0x105, False, 8),
    "canfdi_0x2a5": ("canfdi", 0x2A5, False, 4),
    "canfdi_0x7ff": ("canfdi", 0x7FF, False, 2),
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
    "p01_alt_offsets": ({"profile": "autosar_p01", "data_id": 0x5A3C, "data_id_mode": "alt",
                         "crc_offset": 8, "counter_offset": 4, "data_length": 16},
                        0x123, False, 2),
    # 30 bytes (P01's longest), CRC last, the nibble in the high half of byte 2.
    "p01_nibble_long": ({"profile": "autosar_p01", "data_id": 0x7FE, "data_id_mode": "nibble",
                         "crc_offset": 232, "counter_offset": 12,
                         "data_id_nibble_offset": 20, "data_length": 240},
                        0x123, False, 32),
    "p01_low_fd": ({"profile": "autosar_p01", "data_id": 0xC3, "data_id_mode": "low",
                    "crc_offset": 64, "counter_offset": 0, "data_length": 120},
                   0x123, False, 16),
    "p02": ({"profile": "autosar_p02", "data_id_list": list(range(0x10, 0x20))},
            0x321, False, 8),
    "p02_short": ({"profile": "autosar_p02", "data_id_list": [0xFF - i for i in range(16)]},
                  0x321, False, 2),
    "p02_fd": ({"profile": "autosar_p02", "data_id_list": [7] * 16, "data_length": 160},
               0x321, False, 24),
    "p02_64": ({"profile": "autosar_p02",
                "data_id_list": [(37 * i + 11) & 0xFF for i in range(16)]}, 0x321, False, 64),
}

pytestmark = pytest.mark.skipif(CC is None, reason="no C compiler (gcc or cc) on the PATH")


def _profile(name: str) -> e2e.E2EProfile:
    spec, frame_id, is_extended, length = CASES[name]
    return e2e.make_profile(spec, frame_id, is_extended, length, SIGNALS, WHERE)


def _profiles() -> dict[str, e2e.E2EProfile]:
    profiles = {name: _profile(name) for name in CASES}
    # Beyond what a config can make: a Profile 2 longer than any CAN payload (never passes).
    profiles["p02_2048_bits"] = e2e.AutosarP02(bytes(range(16)), 2048)
    return profiles


PROFILES = _profiles()


@pytest.fixture(scope="module")
def driver(tmp_path_factory) -> Path:
    exe = tmp_path_factory.mktemp("e2esan") / "e2e"
    res = subprocess.run([CC, *FLAGS, f"-I{CORE}", str(DRIVER), str(CORE / "e2e.c"),
                          "-o", str(exe)], capture_output=True, text=True, timeout=300)
    if res.returncode != 0 and "asan" in res.stderr.lower():
        pytest.skip(f"the compiler has no sanitizer runtime: {res.stderr.strip()[:200]}")
    assert res.returncode == 0, res.stderr
    return exe


def _run(exe: Path, mode: str, payload: bytes) -> np.ndarray:
    res = subprocess.run([str(exe), mode], input=payload, capture_output=True, timeout=120)
    assert res.returncode == 0, res.stderr.decode(errors="replace")[-3000:]
    return np.frombuffer(res.stdout, np.int64)


def _case(spec: np.ndarray, table: np.ndarray, rows: np.ndarray, lengths: np.ndarray) -> bytes:
    assert spec.dtype == np.int32 and spec.shape == (E2E_H["CFDI_E2E_INTS"],)
    assert table.dtype == np.uint8 and table.shape == (E2E_H["CFDI_E2E_BYTES"],)
    record = np.dtype([("payload", np.uint8, ROW), ("length", "<i8")])
    data = np.zeros(len(rows), record)
    data["payload"] = rows
    data["length"] = lengths
    return spec.tobytes() + table.tobytes() + np.int64(len(rows)).tobytes() + data.tobytes()


def _run_cases(exe: Path, cases: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]
               ) -> list[tuple[int, np.ndarray, np.ndarray]]:
    """(spec_check status, (N,) checks, (N,) counters) of each case, from one run."""
    out = _run(exe, "r", b"".join(_case(*case) for case in cases))
    results, at = [], 0
    for _, _, rows, _ in cases:
        n = len(rows)
        pairs = out[at + 1: at + 1 + 2 * n].reshape(n, 2)
        results.append((int(out[at]), pairs[:, 0], pairs[:, 1]))
        at += 1 + 2 * n
    assert at == len(out)
    return results


def _field(spec: np.ndarray, count_at: str, at: str) -> BitField | None:
    """The field a table describes (to forge frames the profile would not send)."""
    count, first = spec[E2E_H[count_at]], E2E_H[at]
    size = E2E_H["CFDI_E2E_PIECE_INTS"]
    pieces = tuple(tuple(int(v) for v in spec[first + k * size: first + (k + 1) * size])
                   for k in range(count))
    return BitField(sum(p[2] for p in pieces), pieces) if pieces else None


def _payloads(name: str, profile: e2e.E2EProfile, rng: np.random.Generator,
              n: int) -> tuple[np.ndarray, np.ndarray]:
    """(n + sweeps, 64) rows and their lengths.

    n rows: about 40 % valid frames (half of them of the message's length), 25 % valid frames
    with one bit flipped (mostly in the bytes every frame has), 15 % valid frames cut or grown
    by a few bytes, 20 % noise of any length; the bytes beyond each length noise too. Then,
    for a CRC profile, sweeps: a valid frame with its counter (and extra field) set to any
    value, often one that fails (P01's 15, a wrong Data ID nibble), then once with each of the
    256 values of its CRC byte, so that one row of each sweep has the CRC the C core computes.
    """
    spec = profile.c_spec()[0]
    message_length = CASES[name][3] if name in CASES else ROW
    min_length = int(spec[E2E_H["CFDI_E2E_MIN_LEN"]])
    low = min(min_length, ROW)
    high = min(int(spec[E2E_H["CFDI_E2E_MAX_LEN"]]), ROW)
    rows = rng.integers(0, 256, (n, ROW), dtype=np.uint8)
    lengths = rng.integers(0, ROW + 1, n)
    kind = rng.choice(4, n, p=[0.4, 0.25, 0.15, 0.2])
    can_pass = min_length <= ROW
    if can_pass:
        for i in np.flatnonzero(kind < 3):
            length = (message_length if rng.random() < 0.5
                      else int(rng.integers(low, high + 1)))
            counter = int(rng.integers(0, 2**33))
            rows[i, :length] = np.frombuffer(profile.protect(bytes(rows[i, :length]), counter),
                                             np.uint8)
            lengths[i] = length
            if kind[i] == 1 and length:
                reach = max(low, 1) if rng.random() < 0.7 else length
                bit = int(rng.integers(0, 8 * min(reach, length)))
                rows[i, bit // 8] ^= np.uint8(1 << bit % 8)
            elif kind[i] == 2:
                lengths[i] = int(np.clip(length + rng.choice([-3, -2, -1, 1, 2, 3]), 0, ROW))
    # The lengths at the edges of what passes, a few times each.
    edges = [x for x in (low - 1, low, low + 1, high, high + 1) if 0 <= x <= ROW]
    lengths[:len(edges) * 3] = np.repeat(edges, 3)
    if spec[E2E_H["CFDI_E2E_KIND"]] != KIND_CRC or not can_pass:
        return rows, lengths
    counter = _field(spec, "CFDI_E2E_COUNTER_PIECES", "CFDI_E2E_COUNTER_AT")
    extra = _field(spec, "CFDI_E2E_EXTRA_PIECES", "CFDI_E2E_EXTRA_AT")
    limit = (int(spec[E2E_H["CFDI_E2E_COUNTER_MAX_HI"]]) << 16
             | int(spec[E2E_H["CFDI_E2E_COUNTER_MAX_LO"]]))
    crc_byte = int(spec[E2E_H["CFDI_E2E_CRC_BYTE"]])
    sweeps = []
    for sweep in range(N_SWEEPS):
        length = message_length
        frame = np.frombuffer(profile.protect(rng.bytes(length), int(rng.integers(0, 2**20))),
                              np.uint8).copy()[None, :]
        if counter is not None:
            top = (1 << counter.length) - 1
            value = limit + 1 if sweep % 2 and limit < top else int(rng.integers(0, top + 1))
            counter.write_batch(frame, np.array([value]))
        if extra is not None and sweep % 4 >= 2:
            extra.write_batch(frame, rng.integers(0, 1 << extra.length, 1))
        block = np.tile(np.pad(frame, ((0, 0), (0, ROW - length))), (256, 1))
        block[:, crc_byte] = np.arange(256)
        sweeps.append(block)
    rows = np.concatenate([rows, *sweeps])
    lengths = np.concatenate([lengths, np.full(256 * N_SWEEPS, message_length)])
    return rows, lengths


def _python(profile: e2e.E2EProfile, rows: np.ndarray,
            lengths: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    checks, counters = [], []
    for row, length in zip(rows, lengths, strict=True):
        payload = bytes(row[:length])
        checks.append(int(profile.check(payload)))
        counter = profile.counter(payload)
        counters.append(-1 if counter is None else counter)
    return np.array(checks, np.int64), np.array(counters, np.int64)


def test_the_header_and_cspec_agree():
    defines = dict(re.findall(r"^#define (CFDI_E2E_\w+) (\d+)",
                              (CORE / "e2e.h").read_text(), re.MULTILINE))
    assert {k: int(v) for k, v in defines.items()} == E2E_H


def test_every_profile_of_the_registry_compiles_itself():
    for name in e2e.PROFILES:
        assert any(p.name == name for p in PROFILES.values()), name
    for name, profile in PROFILES.items():
        assert isinstance(profile, e2e.E2EProfile)
        spec, table = profile.c_spec()
        assert spec.dtype == np.int32 and spec.shape == (E2E_H["CFDI_E2E_INTS"],), name
        assert table.dtype == np.uint8 and table.shape == (E2E_H["CFDI_E2E_BYTES"],), name
        kind = {"none": KIND_NONE, "counter": KIND_COUNTER}.get(profile.name, KIND_CRC)
        assert spec[E2E_H["CFDI_E2E_KIND"]] == kind, name


def test_c_checks_and_counters_are_pythons_row_for_row(driver):
    rng = np.random.default_rng(20240611)
    cases, expected = [], []
    for name, profile in PROFILES.items():
        rows, lengths = _payloads(name, profile, rng, N_ROWS)
        spec, table = profile.c_spec()
        cases.append((spec, table, rows, lengths))
        expected.append(_python(profile, rows, lengths))
    results = _run_cases(driver, cases)
    for (name, profile), (status, checks, counters), (want_checks, want_counters), case in zip(
            PROFILES.items(), results, expected, cases, strict=True):
        assert status == 0, name
        bad = np.flatnonzero((checks != want_checks) | (counters != want_counters))
        if bad.size:
            i = bad[0]
            row = bytes(case[2][i, :case[3][i]]).hex()
            pytest.fail(f"{name} ({profile!r}) row {i}: payload {row}: C check "
                        f"{checks[i]} counter {counters[i]}, Python {want_checks[i]} "
                        f"{want_counters[i]} ({bad.size} rows differ)")
        # The random data exercise both answers where a profile has both.
        if name == "none":
            assert checks.all()
        elif name == "p02_2048_bits":
            assert not checks.any()
        else:
            assert checks.any() and not checks.all(), name


def _malformed() -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Tables that are no profile, one fault each, from valid ones."""
    h = E2E_H
    piece = h["CFDI_E2E_PIECE_INTS"]
    c0 = h["CFDI_E2E_COUNTER_AT"]
    x0 = h["CFDI_E2E_EXTRA_AT"]
    p01 = PROFILES["p01_nibble"].c_spec()
    p02 = PROFILES["p02"].c_spec()
    counter = PROFILES["counter_le32"].c_spec()
    none = PROFILES["none"].c_spec()
    faults: dict[str, tuple[tuple[np.ndarray, np.ndarray], dict[int, int]]] = {
        "counter byte at min_len": (p01, {c0 + h["CFDI_E2E_PIECE_BYTE"]: 8}),
        "counter byte far out": (p01, {c0 + h["CFDI_E2E_PIECE_BYTE"]: 2**31 - 1}),
        "extra byte out": (p01, {x0 + h["CFDI_E2E_PIECE_BYTE"]: 64}),
        "counter bit 8": (p01, {c0 + h["CFDI_E2E_PIECE_BIT"]: 8}),
        "counter width 0": (p01, {c0 + h["CFDI_E2E_PIECE_WIDTH"]: 0}),
        "counter width 9": (p01, {c0 + h["CFDI_E2E_PIECE_WIDTH"]: 9}),
        "bit + width over 8": (p01, {c0 + h["CFDI_E2E_PIECE_BIT"]: 4,
                                     c0 + h["CFDI_E2E_PIECE_WIDTH"]: 5}),
        "shift + width over 32": (p01, {c0 + h["CFDI_E2E_PIECE_SHIFT"]: 29}),
        "piece count 6": (counter, {h["CFDI_E2E_COUNTER_PIECES"]: 6}),
        "piece count huge": (counter, {h["CFDI_E2E_COUNTER_PIECES"]: 2**31 - 1}),
        "extra piece count 6": (p01, {h["CFDI_E2E_EXTRA_PIECES"]: 6}),
        "an unused piece slot set": (p01, {c0 + piece + h["CFDI_E2E_PIECE_WIDTH"]: 4}),
        "seed mask 16": (p01, {h["CFDI_E2E_SEED_MASK"]: 16}),
        "seed mask huge": (p01, {h["CFDI_E2E_SEED_MASK"]: 2**31 - 1}),
        "trail mask 16": (p02, {h["CFDI_E2E_TRAIL_MASK"]: 16}),
        "trail 2": (p02, {h["CFDI_E2E_TRAIL"]: 2}),
        "trail mask without a trail": (p01, {h["CFDI_E2E_TRAIL_MASK"]: 1}),
        "crc byte at min_len": (p01, {h["CFDI_E2E_CRC_BYTE"]: 8}),
        "crc end past min_len": (p01, {h["CFDI_E2E_CRC_END"]: 9}),
        "crc first past end": (p02, {h["CFDI_E2E_CRC_FIRST"]: 8, h["CFDI_E2E_CRC_END"]: 7}),
        "crc first past min_len, to length": (PROFILES["canfdi_0x105"].c_spec(),
                                              {h["CFDI_E2E_CRC_FIRST"]: 3}),
        "crc end with to length": (PROFILES["canfdi_0x105"].c_spec(),
                                   {h["CFDI_E2E_CRC_END"]: 2}),
        "to length 2": (p01, {h["CFDI_E2E_CRC_TO_LENGTH"]: 2}),
        "xor out 256": (p02, {h["CFDI_E2E_XOR_OUT"]: 256}),
        "counter max half 0x10000": (counter, {h["CFDI_E2E_COUNTER_MAX_LO"]: 0x10000}),
        "extra value half 0x10000": (p01, {h["CFDI_E2E_EXTRA_VALUE_HI"]: 0x10000}),
        "extra value without a field": (p02, {h["CFDI_E2E_EXTRA_VALUE_LO"]: 3}),
        "kind 3": (p01, {h["CFDI_E2E_KIND"]: 3}),
        "max below min": (p01, {h["CFDI_E2E_MAX_LEN"]: 7}),
        "none with a counter": (none, {h["CFDI_E2E_COUNTER_PIECES"]: 1}),
        "counter kind with a crc": (counter, {h["CFDI_E2E_XOR_OUT"]: 1}),
    }
    tables = {}
    for name, ((spec, table), changes) in faults.items():
        spec = spec.copy()
        for index, value in changes.items():
            spec[index] = value
        tables[name] = (spec, table)
    for index in range(h["CFDI_E2E_INTS"]):
        for value in (-1, -(2**31)):
            spec = p02[0].copy()
            spec[index] = value
            tables[f"spec[{index}] = {value}"] = (spec, p02[1])
    return tables


def test_malformed_tables_are_a_status_not_a_crash(driver):
    rng = np.random.default_rng(7)
    tables = _malformed()
    rows = rng.integers(0, 256, (40, ROW), dtype=np.uint8)
    lengths = np.concatenate([np.arange(0, 65, 8), rng.integers(0, ROW + 1, 31)])
    results = _run_cases(driver, [(spec, table, rows, lengths)
                                  for spec, table in tables.values()])
    for name, (status, checks, counters) in zip(tables, results, strict=True):
        assert status == EBADARG, name
        assert (checks == EBADARG).all(), name
        assert (counters == EBADARG).all(), name


def test_the_untouched_tables_pass_the_spec_check(driver):
    """The faults above start from tables that are well formed (a fault, not the base, is
    what the check rejects)."""
    rows, lengths = np.zeros((1, ROW), np.uint8), np.array([8])
    results = _run_cases(driver, [(*p.c_spec(), rows, lengths) for p in PROFILES.values()])
    assert [status for status, _, _ in results] == [0] * len(PROFILES)


def test_null_pointers_are_a_status(driver):
    spec, table = PROFILES["p01_both"].c_spec()
    out = _run(driver, "n", spec.tobytes() + table.tobytes())
    assert out.tolist() == [EBADARG] * 7 + [0] + [EBADARG] * 3


@pytest.mark.parametrize("name", sorted(PROFILES))
def test_the_c_protection_is_the_profiles(driver, name):
    """cfdi_e2e_protect (the MCU monitor's frames) writes what the profile's ``protect``
    writes, for random payloads of every length the profile takes and any counter (reduced by
    its modulus); a length it does not take is refused, the payload untouched."""
    profile = PROFILES[name]
    spec, table = profile.c_spec()
    rng = np.random.default_rng(sum(map(ord, name)))
    low = int(spec[E2E_H["CFDI_E2E_MIN_LEN"]])
    high = min(int(spec[E2E_H["CFDI_E2E_MAX_LEN"]]), ROW)
    n = 400
    rows = rng.integers(0, 256, (n, ROW), dtype=np.uint8)
    fits = rng.random(n) < 0.85
    lengths = np.where(fits & (low <= high), rng.integers(min(low, ROW), high + 1, n),
                       rng.integers(0, ROW + 1, n))
    counters = rng.integers(0, 2**63, n, dtype=np.uint64) >> rng.integers(0, 64, n).astype(
        np.uint64)
    record = np.dtype([("payload", np.uint8, ROW), ("length", "<i8"), ("counter", "<u8")])
    data = np.zeros(n, record)
    data["payload"], data["length"], data["counter"] = rows, lengths, counters
    res = subprocess.run([str(driver), "p"], input=spec.tobytes() + table.tobytes()
                         + np.int64(n).tobytes() + data.tobytes(), capture_output=True,
                         timeout=120)
    assert res.returncode == 0, res.stderr.decode(errors="replace")[-3000:]
    out = np.frombuffer(res.stdout, np.dtype([("status", "<i8"), ("payload", np.uint8, ROW)]))
    assert len(out) == n
    protected = 0
    for i in range(n):
        length = int(lengths[i])
        if low <= length <= high:
            want = profile.protect(bytes(rows[i, :length]), int(counters[i]))
            assert out["status"][i] == 0, (name, length)
            assert out["payload"][i, :length].tobytes() == want, (name, length, int(counters[i]))
            assert profile.check(want)
            protected += 1
            np.testing.assert_array_equal(out["payload"][i, length:], rows[i, length:])
        else:
            assert out["status"][i] == EBADARG, (name, length)
            np.testing.assert_array_equal(out["payload"][i], rows[i])
    assert protected >= (n // 2 if low <= ROW else 0)

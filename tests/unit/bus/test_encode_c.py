"""The C core's message encoder (canfdi/_c/encode.c: the monitor's frames on a drive's MCU)
against canfdi.bus.codec's MessageLayout.encode: built alone with -std=c99 -pedantic -Werror
under AddressSanitizer and UndefinedBehaviorSanitizer (float casts included), any signal
anywhere (both byte orders, every length, signed, scaled, 32- and 64-bit floats) with values in
range, beyond it, NaN and infinite, byte for byte; malformed tables refused. And encode.h's
#defines against canfdi.bus.ctables.ENCODE_H."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from canfdi.bus import ctables, e2e
from canfdi.bus.codec import compile_layout
from tests.conftest import REPO
from tests.unit.bus.test_codec import _msg, _one_signal_messages, _sig

CORE = REPO / "canfdi" / "_c"
DRIVER = Path(__file__).parent / "c" / "encode_main.c"
CC = shutil.which("gcc") or shutil.which("cc")
FLAGS = ["-std=c99", "-pedantic", "-Wall", "-Wextra", "-Werror", "-ffp-contract=off", "-g",
         "-O1", "-fsanitize=address,undefined,float-cast-overflow",
         "-fno-sanitize-recover=all", "-fno-omit-frame-pointer"]
H = ctables.ENCODE_H
ROLES = ("KIND", "STATE", "DRIVE", "INDEX", "SAMPLE")
NONE_PROFILE = e2e.make_profile("none", 0x123, False, 8, {}, "bus.monitor.e2e")

pytestmark = pytest.mark.skipif(CC is None, reason="no C compiler (gcc or cc) on the PATH")


@pytest.fixture(scope="module")
def driver(tmp_path_factory) -> Path:
    exe = tmp_path_factory.mktemp("encodesan") / "encode"
    res = subprocess.run([CC, *FLAGS, f"-I{CORE}", str(DRIVER), str(CORE / "encode.c"),
                          str(CORE / "e2e.c"), "-lm", "-o", str(exe)], capture_output=True,
                         text=True, timeout=300)
    if res.returncode != 0 and "asan" in res.stderr.lower():
        pytest.skip(f"the compiler has no sanitizer runtime: {res.stderr.strip()[:200]}")
    assert res.returncode == 0, res.stderr
    return exe


def _encode(exe: Path, length: int, sig_int: np.ndarray, sig_real: np.ndarray,
            by_role: np.ndarray, profile: e2e.E2EProfile = NONE_PROFILE
            ) -> tuple[int, np.ndarray, np.ndarray]:
    """(cfdi_message_check, (rows,) cfdi_encode statuses, (rows, 64) payloads) of one case."""
    spec, table = profile.c_spec()
    n = len(sig_int)
    data = (np.int64(length).tobytes() + np.int64(n).tobytes()
            + np.ascontiguousarray(sig_int, dtype="<i8").tobytes()
            + np.ascontiguousarray(sig_real, dtype="<f8").tobytes()
            + spec.tobytes() + table.tobytes() + np.int64(len(by_role)).tobytes()
            + np.ascontiguousarray(by_role, dtype="<f8").tobytes())
    res = subprocess.run([str(exe)], input=data, capture_output=True, timeout=120)
    assert res.returncode == 0, res.stderr.decode(errors="replace")[-3000:]
    check = int(np.frombuffer(res.stdout[:8], "<i8")[0])
    rows = np.frombuffer(res.stdout[8:], np.dtype([("status", "<i8"), ("payload", "u1", 64)]))
    return check, rows["status"], rows["payload"]


def _values(layout, rng: np.random.Generator, n: int) -> dict[str, np.ndarray]:
    """n values of each signal: decoded from random payloads (in range), and beyond the range,
    NaN, infinities, huge, zero and half-way values."""
    payloads = rng.integers(0, 256, (n, layout.dlc), dtype=np.uint8)
    decoded = layout.decode(payloads)
    out = {}
    for sig in layout.signals:
        v = np.asarray(decoded[sig.name], dtype=np.float64).copy()
        lo, hi = sig.physical_limits()
        specials = np.array([np.nan, np.inf, -np.inf, 1e308, -1e308, 0.0, -0.0, lo, hi,
                             lo - abs(lo) - 1, hi + abs(hi) + 1, 0.5, 2.5, -1.5, 3.4e38,
                             3.5e38, -3.41e38])
        k = min(len(specials), n // 2)
        v[-k:] = specials[:k]
        out[sig.name] = v
    return out


def _check_message(driver: Path, message, seed: int) -> None:
    layout = compile_layout(message)
    names = [s.name for s in layout.signals]
    roles = dict(zip(names, ROLES, strict=False))
    if any(s.is_float and s.length == 16 for s in layout.signals):
        with pytest.raises(ValueError, match="32- and 64-bit floats"):
            ctables.message_tables(layout, (0x123, False), NONE_PROFILE, roles)
        return
    t = ctables.message_tables(layout, (0x123, False), NONE_PROFILE, roles)
    n = 40
    values = _values(layout, np.random.default_rng(seed), n)
    by_role = np.zeros((n, H["CFDI_N_ROLES"]))
    for name, role in roles.items():
        by_role[:, H[f"CFDI_ROLE_{role}"]] = values[name]
    check, status, payloads = _encode(driver, t.length, t.sig_int, t.sig_real, by_role)
    assert check == 0 and (status == 0).all()
    given_values = {name: values[name] for name in roles}
    want, _ = layout.encode(given_values, n)
    np.testing.assert_array_equal(payloads[:, :t.length], want)
    assert (payloads[:, t.length:] == 0xEE).all()  # nothing written past the payload


@settings(max_examples=300, deadline=None)
@given(message=_one_signal_messages(), seed=st.integers(0, 2**32 - 1))
def test_any_signal_anywhere_encodes_as_the_layout(driver, message, seed):
    _check_message(driver, message, seed)


def test_several_signals_of_both_byte_orders(driver):
    message = _msg([
        _sig("A", 3, 12, "big_endian"),
        _sig("B", 18, 16, "big_endian", signed=True),
        _sig("C", 47, 16, "big_endian", scale=0.5, offset=-3),
        _sig("D", 63, 6, "big_endian", signed=True),
        _sig("E", 57, 2, "big_endian"),
    ])
    _check_message(driver, message, 1)
    message = _msg([
        _sig("F", 0, 32, is_float=True, scale=2.0, offset=1.0),
        _sig("G", 32, 20, signed=True, scale=0.01),
        _sig("H", 52, 12, scale=3, offset=-100),
    ])
    _check_message(driver, message, 2)
    message = _msg([_sig("U", 0, 64), _sig("S", 64, 64, signed=True)], length=16)
    _check_message(driver, message, 3)


def test_the_monitor_dbc_messages_encode_as_the_layout(driver):
    import cantools

    db = cantools.database.load_file(str(REPO / "dbc" / "canfdi_monitor.dbc"))
    for message in db.messages:
        _check_message(driver, message, message.frame_id)


def test_malformed_tables_are_refused(driver):
    layout = compile_layout(_msg([_sig("A", 0, 8), _sig("B", 8, 16, signed=True)]))
    t = ctables.message_tables(layout, (0x123, False), NONE_PROFILE, {"A": "KIND", "B": "STATE"})
    by_role = np.ones((1, H["CFDI_N_ROLES"]))
    check, status, payloads = _encode(driver, t.length, t.sig_int, t.sig_real, by_role)
    assert check == 0 and status[0] == 0
    bad = []
    for col, value in ((H["CFDI_ENC_START"], 60), (H["CFDI_ENC_START"], -1),
                       (H["CFDI_ENC_START"], 512), (H["CFDI_ENC_LENGTH"], 0),
                       (H["CFDI_ENC_LENGTH"], 65), (H["CFDI_ENC_FLAGS"], 8),
                       (H["CFDI_ENC_ROLE"], H["CFDI_N_ROLES"]), (H["CFDI_ENC_ROLE"], -1)):
        forged = t.sig_int.copy()
        forged[1, col] = value
        bad.append((t.length, forged))
    floats = t.sig_int.copy()
    floats[0, H["CFDI_ENC_FLAGS"]], floats[0, H["CFDI_ENC_LENGTH"]] = 4, 16  # a float16
    bad += [(t.length, floats), (0, t.sig_int), (65, t.sig_int), (1, t.sig_int)]
    for length, forged in bad:
        check, status, payloads = _encode(driver, length, forged, t.sig_real, by_role)
        assert check < 0 and status[0] < 0, (length, forged.tolist())
        assert (payloads[0] == 0xEE).all()  # untouched
    # A length the E2E profile does not take.
    p01 = e2e.make_profile({"profile": "autosar_p01", "data_id": 1}, 0x123, False, 8, {},
                           "bus.monitor.e2e")
    check, status, _ = _encode(driver, 4, t.sig_int[:1], t.sig_real[:1], by_role, p01)
    assert check < 0 and status[0] < 0


def test_the_header_and_the_python_tables_agree():
    text = (CORE / "encode.h").read_text()
    defines = dict(re.findall(r"#define (CFDI_(?:ENC|ROLE|N_ROLES)\w*) (\d+)", text))
    assert {k: int(v) for k, v in defines.items()} == H

"""The C core built alone with -std=c99 -pedantic -Werror under AddressSanitizer and
UndefinedBehaviorSanitizer (any out-of-bounds access or undefined operation aborts), run on
the cases of test_kernel.py and hostile sizes, its results against the numpy reference."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from canfdi.core.detect import change_point_block
from canfdi.core.residuals import fir_rows
from tests.conftest import REPO
from tests.unit.core.test_kernel import _bank_case, _detector_case

CORE = REPO / "canfdi" / "_c"
DRIVER = Path(__file__).parent / "c" / "sanitized_main.c"
CC = shutil.which("gcc") or shutil.which("cc")
FLAGS = ["-std=c99", "-pedantic", "-Wall", "-Wextra", "-Werror", "-ffp-contract=off", "-g",
         "-O1", "-fsanitize=address,undefined", "-fno-sanitize-recover=all",
         "-fno-omit-frame-pointer"]

pytestmark = pytest.mark.skipif(CC is None, reason="no C compiler (gcc or cc) on the PATH")


@pytest.fixture(scope="module")
def driver(tmp_path_factory) -> Path:
    exe = tmp_path_factory.mktemp("csan") / "sanitized"
    res = subprocess.run([CC, *FLAGS, f"-I{CORE}", str(DRIVER), str(CORE / "bank.c"),
                          str(CORE / "decode.c"), str(CORE / "detect.c"), str(CORE / "e2e.c"),
                          "-lm", "-o", str(exe)],
                         capture_output=True, text=True, timeout=300)
    if res.returncode != 0 and "asan" in res.stderr.lower():
        pytest.skip(f"the compiler has no sanitizer runtime: {res.stderr.strip()[:200]}")
    assert res.returncode == 0, res.stderr
    return exe


def _run(exe: Path, mode: str, payload: bytes) -> bytes:
    res = subprocess.run([str(exe), mode], input=payload, capture_output=True, timeout=120)
    assert res.returncode == 0, res.stderr.decode(errors="replace")[-2000:]
    return res.stdout


def _i64(*values: int) -> bytes:
    return np.array(values, dtype=np.int64).tobytes()


@pytest.mark.parametrize(("S", "width", "m", "rows", "lost"),
                         [(0, 1, 1, 1, 0.0), (4, 6, 5, 300, 0.0), (8, 9, 12, 400, 0.02),
                          (10, 4, 2, 11, 1.0)])
def test_residuals_under_the_sanitizers_are_numpys(driver, S, width, m, rows, lost):
    x, blocks, uses = _bank_case(np.random.default_rng(S * 100 + width), S, width, m, rows, lost)
    out = _run(driver, "f", _i64(rows, width, S, m) + x.tobytes() + blocks.tobytes()
               + (uses != 0).astype(np.uint8).tobytes())
    assert np.frombuffer(out[:8], np.int64)[0] == 0
    got = np.frombuffer(out[8:], np.float64).reshape(rows - S, m)
    ref = fir_rows(x, blocks, uses)
    np.testing.assert_array_equal(np.isnan(got), np.isnan(ref))
    np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-12 * np.nanmax(np.abs(ref),
                                                                             initial=1.0))


def test_sizes_that_do_not_fit_are_a_status_not_a_crash(driver):
    """rows <= S and zero widths come back as a negative status, nothing read past the
    buffers the sizes describe."""
    for rows, width, S, m in [(3, 2, 3, 1), (0, 2, 0, 1), (5, 0, 1, 1), (5, 1, 1, 0)]:
        x = np.zeros(rows * width)
        coef = np.zeros((S + 1) * width * m)
        out = _run(driver, "f", _i64(rows, width, S, m) + x.tobytes() + coef.tobytes()
                   + np.zeros(coef.size, np.uint8).tobytes())
        assert np.frombuffer(out[:8], np.int64)[0] < 0, (rows, width, S, m)


@pytest.mark.parametrize(("n", "c", "lost", "jump_at"),
                         [(0, 1, 0.0, None), (1, 3, 0.0, None), (500, 4, 0.05, 300),
                          (9000, 2, 0.0, 8500), (200, 6, 1.0, None)])
def test_page_hinkley_under_the_sanitizers_is_numpys_bit_for_bit(driver, n, c, lost, jump_at):
    k, x, delta, h, state, last_zero = _detector_case(np.random.default_rng(n + c), n, c, lost,
                                                      jump_at)
    out = _run(driver, "p", _i64(n, c) + k.astype(np.int64).tobytes() + x.tobytes()
               + delta.tobytes() + h.tobytes() + state.tobytes()
               + last_zero.astype(np.int64).tobytes())
    ref = change_point_block(k, x, delta, h, state, last_zero)
    status, done = np.frombuffer(out[:16], np.int64)
    assert status == 0 and done == ref.done
    rows = len(ref.g_up)
    at = 16
    for name, dtype, count in (("g_up", np.float64, rows * c), ("g_down", np.float64, rows * c),
                               ("alarm", np.int8, c), ("state", np.float64, 2 * c),
                               ("last_zero", np.int64, 2 * c)):
        size = np.dtype(dtype).itemsize * count
        got = np.frombuffer(out[at: at + size], dtype)
        np.testing.assert_array_equal(got, np.asarray(getattr(ref, name)).ravel(), err_msg=name)
        at += size
    assert at == len(out)


def _decode(driver: Path, tables, block) -> tuple:
    """cfdi_decode_block under the sanitizers on a drive's tables and a block of frames."""
    n = block.size
    rows = sorted(block.long)
    long_row = np.full(n, -1, np.int32)
    longdata = np.zeros((len(rows), 64), np.uint8)
    for i, row in enumerate(rows):
        longdata[i, :len(block.long[row][:64])] = np.frombuffer(block.long[row][:64], np.uint8)
        long_row[row] = i
    t = tables
    head = _i64(len(t.std_id), len(t.ext_id), len(t.entry), t.n_slots, len(t.e2e_spec),
                len(t.sig_int), len(t.ids_int), t.width, n, len(rows))
    arrays = (t.std_id, t.std_entry, t.ext_id, t.ext_entry, t.entry, t.e2e_spec, t.e2e_bytes,
              t.sig_int,
              t.sig_real, t.ids_int, t.ids_real, block.id.astype(np.uint32), block.dlc,
              block.flags, block.data, long_row, longdata)
    out = _run(driver, "d", head + b"".join(np.ascontiguousarray(a).tobytes() for a in arrays))
    rc = np.frombuffer(out[:8], np.int64)[0]
    if rc != 0:
        return (rc,)
    at = 8
    parts = []
    for dtype, count in ((np.int8, n), (np.int16, n), (np.float64, n * t.width),
                         (np.int64, n)):
        size = np.dtype(dtype).itemsize * count
        parts.append(np.frombuffer(out[at:at + size], dtype))
        at += size
    parts[2] = parts[2].reshape(n, t.width)
    return tuple(parts)


@pytest.mark.parametrize("name", ["dc_motor", "dc_motor_cia402", "dc_motor_float",
                                  "dc_motor_two_drives_cia402", "vtol"])
def test_decode_of_hostile_frames_under_the_sanitizers_is_numpys(driver, name):
    """Every shipped bus profile's traffic with a fifth of its frames damaged (bit flips,
    wrong lengths, foreign and extended IDs, remote, error and FD flags, garbage, CAN FD
    payloads to 64 bytes): the C decode reads nothing outside a buffer and gives the numpy
    reference's statuses, slots, values and counters."""
    from canfdi.configs import CONFIG_DIR

    from canfdi.config import load_config
    from canfdi.core import kernel
    from canfdi.monitor import Monitor
    from canfdi.tools.bench import bench_scenarios, make_traffic
    from tests.unit.core.test_kernel_decode import _hostile, _same_values

    config = load_config(CONFIG_DIR / f"{name}.yaml")
    _, faulty = bench_scenarios(config)
    traffic = make_traffic(3000, faulty)
    monitor = Monitor(config, kernel=kernel.get("python"))
    rng = np.random.default_rng(11)
    for d in monitor.drives:
        block = _hostile(traffic, rng, sorted({k[0] for k in d.bus_map.keys}))
        got = _decode(driver, d.bus_map.c_tables(), block)
        ref = d.bus_map.decode_frames_reference(block)
        for a, b in zip(got, ref, strict=True):
            if a.dtype == np.float64:
                _same_values(a, b)
            else:
                np.testing.assert_array_equal(a, b)


def test_malformed_decode_tables_are_a_status_under_the_sanitizers(driver):
    """Tables whose indices point outside themselves come back as a negative status, nothing
    read outside the arrays their sizes describe."""
    from canfdi.configs import CONFIG_DIR

    from canfdi.bus import ctables
    from canfdi.bus.frames import FrameBlock
    from canfdi.config import load_config
    from canfdi.monitor import Monitor

    tables = Monitor(load_config(CONFIG_DIR / "dc_motor.yaml")).bus_map.c_tables()
    block = FrameBlock(np.arange(3), np.array([0x104, 0x105, 0x106]), np.full(3, 8, np.uint8),
                       np.zeros(3, np.uint8), np.zeros((3, 8), np.uint8))
    h = ctables.DECODE_H
    for table, row, col, value in [("sig_int", 0, h["CFDI_SIG_START"], 500),
                                   ("sig_int", 1, h["CFDI_SIG_IDS_COUNT"], 99),
                                   ("sig_int", 0, h["CFDI_SIG_COLUMN"], 7),
                                   ("entry", 0, h["CFDI_ENTRY_SIG_AT"], 40),
                                   ("entry", 2, h["CFDI_ENTRY_LENGTH"], 65),
                                   ("ext_entry", None, None, 9),
                                   ("std_entry", 0, None, 1000)]:
        arrays = dict(vars(tables))
        a = arrays[table].copy()
        if table == "ext_entry":
            a = np.array([9], np.int32)
            arrays["ext_id"] = np.array([5], np.int64)
        elif col is None:
            a[row] = value
        else:
            a[row, col] = value
        arrays[table] = a
        got = _decode(driver, type(tables)(**arrays), block)
        assert len(got) == 1 and got[0] < 0, (table, row, col)


def test_the_core_compiles_as_float32_for_the_mcu():
    """Every file of the core (not the CPython face) compiles with -DCFDI_FLOAT32, the real
    type the Cortex-M4F's FPU takes, under the same warnings as errors."""
    for source in sorted(CORE.glob("*.c")):
        # (cfdi_run.c, the generated project's runner, needs the project's tables: the
        # float32 build of tests/integration/test_codegen.py compiles it.)
        if source.name in ("_kernel.c", "cfdi_run.c"):
            continue
        res = subprocess.run([CC, "-std=c99", "-pedantic", "-Wall", "-Wextra", "-Werror",
                              "-DCFDI_FLOAT32", "-fsyntax-only", f"-I{CORE}", str(source)],
                             capture_output=True, text=True, timeout=120)
        assert res.returncode == 0, f"{source.name}: {res.stderr}"

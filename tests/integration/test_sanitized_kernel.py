"""The hostile-input, garbage-frame and damaged-log suites through the C kernel built with
AddressSanitizer and UndefinedBehaviorSanitizer (issue 42): the extension as setup.py builds
it, with -fsanitize=address,undefined -fno-sanitize-recover=all, loaded in place of the
installed one into a pytest run of those suites with CANFDI_KERNEL=c (and the suites that
alternate kernels on both). A read or write outside a buffer or an undefined operation in the
C aborts the run with the sanitizer's report."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

from tests.conftest import REPO

CORE = REPO / "canfdi" / "_c"
CC = shutil.which("gcc")
SUITES = ["tests/integration/test_hostile_logs.py", "tests/integration/test_damaged_logs.py",
          "tests/unit/io/test_damaged_logs.py", "tests/unit/core/test_kernel_decode.py",
          "tests/unit/core/test_kernel.py", "tests/unit/core/test_kernel_gate.py",
          "tests/unit/core/test_kernel_clock.py", "tests/methods/test_information_kernel.py",
          "tests/methods/test_decide_kernel.py"]

pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(CC is None, reason="no gcc: the sanitizers' runtime is gcc's")]


def _runtime(name: str) -> str | None:
    found = subprocess.run([CC, f"-print-file-name={name}"], capture_output=True,
                           text=True).stdout.strip()
    return found if os.path.isabs(found) and os.path.exists(found) else None


def test_the_hostile_suites_pass_through_the_sanitized_c_kernel(tmp_path):
    asan, stdcxx = _runtime("libasan.so"), _runtime("libstdc++.so.6")
    if asan is None or stdcxx is None:
        pytest.skip("gcc has no AddressSanitizer runtime (libasan) here")
    kernel = tmp_path / "_ckernel.abi3.so"
    build = subprocess.run(
        [CC, "-shared", "-fPIC", "-O1", "-g", "-fno-omit-frame-pointer",
         "-fsanitize=address,undefined", "-fno-sanitize-recover=all", "-std=c99", "-Wall",
         "-Wextra", "-Werror", "-ffp-contract=off", "-fno-strict-aliasing",
         "-DPy_LIMITED_API=0x030B0000", f"-I{sysconfig.get_paths()['include']}", f"-I{CORE}",
         *(str(CORE / f) for f in ("_kernel.c", "bank.c", "counter.c", "decide.c", "decode.c",
                                    "detect.c", "e2e.c", "gate.c", "info.c", "latest.c")),
         "-lm", "-o", str(kernel)], capture_output=True, text=True, timeout=300)
    assert build.returncode == 0, build.stderr
    # libstdc++ preloaded too: matplotlib's C++ throws, and the sanitizer must find the real
    # __cxa_throw to let it.
    env = {**os.environ, "LD_PRELOAD": f"{asan} {stdcxx}", "CANFDI_KERNEL": "c",
           "ASAN_OPTIONS": "detect_leaks=0:abort_on_error=0",
           "UBSAN_OPTIONS": "halt_on_error=1:print_stacktrace=1",
           "CANFDI_DAMAGED_LOGS": "45", "OPENBLAS_NUM_THREADS": "1"}
    run = subprocess.run(
        [sys.executable, str(Path(__file__).with_name("sanitized_kernel_runner.py")),
         str(kernel), "-q", "-p", "no:cacheprovider", "-p", "no:randomly",
         f"--basetemp={tmp_path / 'inner'}", *SUITES],
        cwd=REPO, env=env, capture_output=True, text=True, timeout=1500)
    tail = (run.stdout[-3000:] + run.stderr[-3000:])
    assert run.returncode == 0, tail
    assert " passed" in run.stdout and "AddressSanitizer" not in run.stderr, tail

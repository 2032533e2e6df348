"""The import-linter contracts of pyproject.toml hold: the layers (cli -> tools -> service ->
monitor -> config -> methods/io -> bus -> core), verbs independent of each other, the core and
the methods pure, the monitor free of the emulator."""

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import REPO

CONTRACTS = (
    "Arrows point one way",
    "A verb never imports another verb",
    "The library behind one verb never imports another's",
    "The numerical core and the methods are pure",
    "The monitor never imports the emulator",
)


def test_import_contracts_hold():
    exe = shutil.which("lint-imports") or str(Path(sys.executable).parent / "lint-imports")
    if not Path(exe).exists():
        pytest.fail("lint-imports (import-linter) is not installed: pip install -e '.[test]'")
    res = subprocess.run([exe], capture_output=True, text=True, cwd=REPO, timeout=120)
    assert res.returncode == 0, res.stdout + res.stderr
    assert "BROKEN" not in res.stdout
    # Each contract is checked (none dropped from pyproject.toml unnoticed).
    flat = " ".join(res.stdout.split())
    for name in CONTRACTS:
        assert name in flat, f"contract {name!r} is not checked"
    assert f"Contracts: {len(CONTRACTS)} kept, 0 broken" in flat

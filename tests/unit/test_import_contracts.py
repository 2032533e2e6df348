"""The import-linter contracts of pyproject.toml hold: the layers (cli -> tools -> service ->
monitor -> config -> methods/io -> bus -> core), verbs independent of each other, the core and
the methods pure, the monitor free of the emulator."""

import re
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


def _layers() -> list[set[str]]:
    """The layers contract of pyproject.toml, top first: each a set of module names."""
    import tomllib

    contracts = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["importlinter"][
        "contracts"]
    layers = next(c for c in contracts if c["type"] == "layers")["layers"]
    return [{m.strip() for m in re.split(r"[:|]", layer)} for layer in layers]


def _layer_of(module: str, layers: list[set[str]]) -> int | None:
    for depth, layer in enumerate(layers):
        if any(module == m or module.startswith(m + ".") for m in layer):
            return depth
    return None


def test_the_examples_in_docstrings_keep_the_layers_too():
    """import-linter reads import statements, not the doctests' ``>>> from canfdi...``: a
    layer's examples import nothing from a layer above it either (issue 44 found the bus's
    examples loading configs through canfdi.config)."""
    layers = _layers()
    wrong = []
    for path in sorted((REPO / "canfdi").rglob("*.py")):
        module = ".".join(path.relative_to(REPO).with_suffix("").parts).removesuffix(
            ".__init__")
        own = _layer_of(module, layers)
        if own is None:
            continue
        for line in path.read_text().splitlines():
            found = re.match(r"\s*(?:>>>|\.\.\.)\s+(?:from|import)\s+(canfdi[\w.]*)", line)
            if found:
                theirs = _layer_of(found[1], layers)
                if theirs is not None and theirs < own:
                    wrong.append(f"{module}: {line.strip()}")
    assert wrong == []

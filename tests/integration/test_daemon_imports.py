"""The daemon imports what it uses: `canfdi run` loads no asammdf, pandas, pyarrow or
matplotlib, even where they are installed (this venv has them: the mf4 and fleet extras),
and `canfdi --version` imports nothing of canfdi's but its version."""

import json
import subprocess
import sys

import pytest
from canfdi.configs import CONFIG_DIR

HEAVY = ("asammdf", "pandas", "pyarrow", "matplotlib", "scipy.stats", "scipy.signal")

PROBE = """
import atexit, json, sys
sys.argv = ["canfdi", *json.loads(sys.argv[1])]
atexit.register(lambda: print(json.dumps(sorted(
    m for m in {heavy} if sys.modules.get(m) is not None)), file=sys.stderr))
from canfdi.__main__ import console
console()
"""


def loaded(*args: str) -> tuple[int, list[str]]:
    res = subprocess.run([sys.executable, "-c", PROBE.format(heavy=HEAVY), json.dumps(args)],
                         capture_output=True, text=True, timeout=120)
    return res.returncode, json.loads(res.stderr.strip().splitlines()[-1])


@pytest.mark.parametrize("verb", ["run", "capture"])
def test_the_daemon_verbs_load_none_of_the_heavy_packages(verb, tmp_path):
    pytest.importorskip("asammdf")  # else there is nothing to keep out
    out = ["--no-record"] if verb == "run" else ["-o", str(tmp_path / "c.mcap")]
    code, heavy = loaded(verb, "--config", str(CONFIG_DIR / "dc_motor.yaml"), *out,
                         "--duration", "0.3", "--channel", "canfdi-imports", "--retry-for", "5")
    assert code in (0, 1)  # 1: the capture heard nothing (said, and no file)
    assert heavy == []


def test_codegen_loads_no_mf4_support(tmp_path):
    """`canfdi codegen` reads a config and writes C: python-can's MF4 support (asammdf, with
    pandas and pyarrow: a second and more of its few) stays out."""
    pytest.importorskip("asammdf")
    code, heavy = loaded("codegen", str(CONFIG_DIR / "dc_motor.yaml"), "-o",
                         str(tmp_path / "project"))
    assert code == 0 and (tmp_path / "project" / "cfdi_tables.c").exists()
    assert not {"asammdf", "pandas", "pyarrow"} & set(heavy), heavy


def test_version_imports_nothing_heavy():
    code, heavy = loaded("--version")
    assert code == 0 and heavy == []
    res = subprocess.run([sys.executable, "-X", "importtime", "-m", "canfdi", "--version"],
                         capture_output=True, text=True, timeout=60)
    assert "numpy" not in res.stderr and res.stdout.strip().startswith("canfdi ")


def test_other_verbs_keep_python_cans_mf4_support(tmp_path):
    """Only run, capture and codegen keep asammdf out: export writes .mf4 through it."""
    pytest.importorskip("asammdf")
    from tests.cli import canfdi_main as main

    log = tmp_path / "d.log"
    assert main(["sim", "--scenario", "dc_motor_actuator", "--duration", "1", "-o", str(log),
                 "--quiet"]) == 0
    res = subprocess.run([sys.executable, "-m", "canfdi", "export", str(log), "-o",
                          str(tmp_path / "d.mf4")], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert (tmp_path / "d.mf4").stat().st_size > 0

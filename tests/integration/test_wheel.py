"""What a user installs is the wheel (issue 28): built from this tree, installed into a fresh
venv, its verbs run from outside the source tree on what ships inside it (the configs, the
scenarios, the DBCs, the emulator under canfdi's namespace).

The fresh venv gets the wheel alone (``--no-deps``); the dependencies come from the test's own
environment through a path file, which adds that site-packages directory but not its own path
files, so the editable install of this checkout stays out of it. What the test shows is that
the wheel holds what the verbs need, and that nothing reaches back into the checkout.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

from tests.conftest import REPO

pytestmark = pytest.mark.slow


def _run(argv: list[str], cwd: Path, env: dict[str, str], timeout: float = 600) -> str:
    done = subprocess.run(argv, cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=timeout)
    assert done.returncode == 0, f"{argv[1:]}: exit {done.returncode}\n{done.stderr[-2000:]}"
    return done.stdout


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> tuple[Path, Path, dict[str, str]]:
    """(the venv's bin directory, a working directory outside the tree, the environment)."""
    tmp = tmp_path_factory.mktemp("wheel")
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps",
                    "-q", "-w", str(tmp / "dist"), str(REPO)], check=True, cwd=tmp,
                   capture_output=True)
    (wheel,) = (tmp / "dist").glob("canfdi-*.whl")
    venv = tmp / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
    bin_dir = venv / "bin"
    subprocess.run([bin_dir / "python", "-m", "pip", "install", "-q", "--no-deps", "--no-index",
                    str(wheel)], check=True, capture_output=True)
    site = subprocess.run([bin_dir / "python", "-c", "import sysconfig; "
                           "print(sysconfig.get_paths()['purelib'])"], check=True,
                          capture_output=True, text=True).stdout.strip()
    (Path(site) / "test-dependencies.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    work = tmp / "work"
    work.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "CAN_CONFIG")}
    env["PATH"] = f"{bin_dir}{os.pathsep}{env.get('PATH', '')}"
    return bin_dir, work, env


def test_the_wheel_holds_the_package_data_and_no_generic_top_level_name(tmp_path):
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps",
                    "-q", "-w", str(tmp_path), str(REPO)], check=True, capture_output=True)
    (wheel,) = tmp_path.glob("canfdi-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    tops = {n.split("/")[0] for n in names}
    assert {t for t in tops if not t.endswith(".dist-info")} == {"canfdi"}
    for shipped in ("canfdi/configs/dc_motor.yaml", "canfdi/configs/dc_motor_cia402.yaml",
                    "canfdi/dbc/motor_drive.dbc", "canfdi/dbc/canfdi_monitor.dbc",
                    "canfdi/firmware_sim/scenarios/dc_motor_consecutive.yaml",
                    "canfdi/firmware_sim/profiles/dc_motor_cia402.eds", "canfdi/py.typed"):
        assert shipped in names, shipped
    configs = sorted(p.name for p in (REPO / "deploy" / "config").glob("*.yaml"))
    assert sorted(n.split("/")[-1] for n in names if n.startswith("canfdi/configs/")
                  and n.endswith(".yaml")) == configs


def test_the_installed_verbs_run_outside_the_tree_on_what_ships(installed):
    bin_dir, work, env = installed
    where = _run([str(bin_dir / "python"), "-c",
                  "import canfdi, canfdi.configs, importlib.util; print(canfdi.__file__); "
                  "print(canfdi.configs.CONFIG_DIR); "
                  "print(importlib.util.find_spec('firmware_sim'))"], work, env)
    package, configs, squatter = where.split()
    assert Path(package).is_relative_to(bin_dir.parent)
    assert Path(configs).is_relative_to(bin_dir.parent) and squatter == "None"
    demo = json.loads(_run([str(bin_dir / "canfdi"), "demo", "--no-live", "--json", "-o",
                            "demo.mcap"], work, env))
    assert len(demo["faults"]) == 3 and (work / "demo.mcap").is_file()
    evaluation = json.loads(_run([str(bin_dir / "canfdi"), "evaluate", "--plant", "dc_motor",
                                  "--runs", "2", "--json", "--no-progress"], work, env))
    assert evaluation["runs"] == 2
    soak = json.loads(_run([str(bin_dir / "canfdi"), "soak", "--samples", "20000", "--runs",
                            "2", "--json", "--no-progress"], work, env))
    assert soak["samples"] == 20000
    bench = json.loads(_run([str(bin_dir / "canfdi"), "bench", "--quick", "--json"], work, env))
    assert bench
    assert sorted(p.name for p in work.iterdir()) == ["demo.mcap"]

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
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

from canfdi.core.kernel import available as available_kernels
from tests.conftest import REPO

pytestmark = pytest.mark.slow


def _clean_copy(tmp: Path) -> Path:
    """The tree copied without what a build or a developer left in it (an in-place extension
    must not slip into a wheel that failed to build its own)."""
    src = tmp / "src"
    shutil.copytree(REPO, src, ignore=shutil.ignore_patterns(
        "*.so", ".venv", "build", "dist", "*.egg-info", "__pycache__", ".git", "node_modules",
        ".pytest_cache", ".ruff_cache", ".hypothesis"))
    return src


def _run(argv: list[str], cwd: Path, env: dict[str, str], timeout: float = 600) -> str:
    done = subprocess.run(argv, cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=timeout)
    assert done.returncode == 0, f"{argv[1:]}: exit {done.returncode}\n{done.stderr[-2000:]}"
    return done.stdout


def _install(wheel: Path, tmp: Path, env: dict[str, str]) -> tuple[Path, Path, dict[str, str]]:
    """``wheel`` installed in a fresh venv under ``tmp`` (the test dependencies reachable
    through a .pth): (its bin directory, a working directory outside the tree, ``env`` with
    that bin directory first on PATH)."""
    venv = tmp / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, env=env)
    bin_dir = venv / "bin"
    # In ``env`` too: a PYTHONPATH to a tree holding canfdi.egg-info (a test run from a
    # checkout) would have pip take canfdi for installed and skip the wheel.
    subprocess.run([bin_dir / "python", "-m", "pip", "install", "-q", "--no-deps", "--no-index",
                    str(wheel)], check=True, capture_output=True, env=env)
    site = subprocess.run([bin_dir / "python", "-c", "import sysconfig; "
                           "print(sysconfig.get_paths()['purelib'])"], check=True,
                          capture_output=True, text=True, env=env).stdout.strip()
    (Path(site) / "test-dependencies.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    work = tmp / "work"
    work.mkdir()
    env = dict(env, PATH=f"{bin_dir}{os.pathsep}{env.get('PATH', '')}")
    return bin_dir, work, env


def _plain_env() -> dict[str, str]:
    """This process's environment without what would let the tree's own code be imported."""
    return {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "CAN_CONFIG")}


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> tuple[Path, Path, dict[str, str]]:
    """(the venv's bin directory, a working directory outside the tree, the environment)."""
    tmp = tmp_path_factory.mktemp("wheel")
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps",
                    "-q", "-w", str(tmp / "dist"), str(REPO)], check=True, cwd=tmp,
                   capture_output=True)
    (wheel,) = (tmp / "dist").glob("canfdi-*.whl")
    return _install(wheel, tmp, _plain_env())


def test_the_wheel_holds_the_package_data_and_no_generic_top_level_name(tmp_path):
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps",
                    "-q", "-w", str(tmp_path), str(_clean_copy(tmp_path))], check=True,
                   capture_output=True)
    (wheel,) = tmp_path.glob("canfdi-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    tops = {n.split("/")[0] for n in names}
    assert {t for t in tops if not t.endswith(".dist-info")} == {"canfdi"}
    for shipped in ("canfdi/configs/dc_motor.yaml", "canfdi/configs/dc_motor_cia402.yaml",
                    "canfdi/dbc/motor_drive.dbc", "canfdi/dbc/canfdi_monitor.dbc",
                    "canfdi/firmware_sim/scenarios/dc_motor_consecutive.yaml",
                    "canfdi/firmware_sim/profiles/dc_motor_cia402.eds", "canfdi/py.typed"):
        assert shipped in names, shipped
    # The C core's sources ship (codegen copies them); the extension where a compiler built it.
    from canfdi.tools.codegen import CORE_FILES

    for shipped in ("canfdi/_c/_kernel.c", "canfdi/_c/README.md",
                    *(f"canfdi/_c/{name}" for name in CORE_FILES)):
        assert shipped in names, shipped
    if "c" in available_kernels():  # this install could build it: so must the wheel's build
        assert any(n.startswith("canfdi/_ckernel") and n.endswith(".so") for n in names)
    configs = sorted(p.name for p in (REPO / "deploy" / "config").glob("*.yaml"))
    assert sorted(n.split("/")[-1] for n in names if n.startswith("canfdi/configs/")
                  and n.endswith(".yaml")) == configs
    # their first line points editors at the schema beside them
    assert "canfdi/configs/canfdi-config.schema.json" in names


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
    # codegen's project from the wheel's own files (the C core and the shipped config) builds
    _run([str(bin_dir / "canfdi"), "codegen", str(Path(configs) / "dc_motor.yaml"), "-o",
          "mcu"], work, env)
    if shutil.which("make") and (shutil.which("cc") or shutil.which("gcc")):
        subprocess.run(["make", "-s", "-C", str(work / "mcu"), "host"], check=True,
                       capture_output=True, text=True, timeout=300)
    shutil.rmtree(work / "mcu")
    assert sorted(p.name for p in work.iterdir()) == ["demo.mcap"]


def test_without_a_compiler_the_wheel_installs_and_runs_on_numpy(tmp_path):
    """CC that cannot compile: the optional extension is left out, the install succeeds, the
    kernel is python, and asking for c is one line and exit 2."""
    src = _clean_copy(tmp_path)
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w",
                    str(tmp_path / "dist"), str(src)], check=True, capture_output=True,
                   env=dict(_plain_env(), CC="false"), cwd=tmp_path)
    (wheel,) = (tmp_path / "dist").glob("canfdi-*.whl")
    assert not any(n.endswith(".so") for n in zipfile.ZipFile(wheel).namelist())
    bin_dir, work, env = _install(wheel, tmp_path, _plain_env())
    version = _run([str(bin_dir / "canfdi"), "--version"], work, env).splitlines()
    assert version[1] == "kernel: python (built: python)"
    done = subprocess.run([str(bin_dir / "canfdi"), "evaluate", "--plant", "dc_motor", "--runs",
                           "1", "--kernel", "c", "--no-progress"], cwd=work, env=env,
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [
        "canfdi evaluate: kernel c: not built in this install (no C compiler when canfdi was "
        "installed); use --kernel python"]
    evaluation = json.loads(_run([str(bin_dir / "canfdi"), "evaluate", "--plant", "dc_motor",
                                  "--runs", "1", "--json", "--no-progress"], work, env))
    assert evaluation["kernel"] == "python"

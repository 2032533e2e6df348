"""--kernel and CANFDI_KERNEL on the verbs: the kernel named, the same diagnosis on both, one
line and exit 2 for a kernel that is none or not built here."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from canfdi.core import kernelchoice
from tests.cli import canfdi_main, canfdi_parser
from tests.conftest import REPO

CONFIG = str(REPO / "deploy" / "config" / "dc_motor.yaml")
VERBS = ("run", "replay", "capture", "demo", "bench", "fleet", "evaluate")


def test_every_verb_that_runs_a_monitor_takes_kernel():
    parser = canfdi_parser()
    sub = next(a for a in parser._actions if a.dest == "verb")
    for verb in VERBS:
        options = {o for a in sub.choices[verb]._actions for o in a.option_strings}
        assert "--kernel" in options, verb


def test_version_names_the_kernel_in_use():
    out = subprocess.run([sys.executable, "-m", "canfdi", "--version"], capture_output=True,
                         text=True, timeout=60, cwd=REPO)
    lines = out.stdout.splitlines()
    assert lines[0].startswith("canfdi ") and lines[1].startswith("kernel: ")
    assert lines[1].split()[1] == kernelchoice.choose()
    env = {"CANFDI_KERNEL": "python", "PATH": "/usr/bin:/bin"}
    out = subprocess.run([sys.executable, "-m", "canfdi", "--version"], capture_output=True,
                         text=True, timeout=60, cwd=REPO, env=env)
    assert out.stdout.splitlines()[1].startswith("kernel: python (built: ")


def test_an_unknown_kernel_is_one_line_and_exit_2(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("CANFDI_KERNEL", "fortran")
    assert canfdi_main(["replay", str(tmp_path / "none.log"), "--config", CONFIG]) == 2
    monkeypatch.delenv("CANFDI_KERNEL")
    log = tmp_path / "x.log"
    log.write_text("(0.000000) vcan0 123#00\n")
    capsys.readouterr()
    monkeypatch.setenv("CANFDI_KERNEL", "fortran")
    assert canfdi_main(["replay", str(log), "--config", CONFIG]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["canfdi replay: kernel: expected one of c, python, got 'fortran'"]


def test_asking_for_c_where_it_was_not_built_is_one_line_and_exit_2(tmp_path, capsys,
                                                                    monkeypatch):
    monkeypatch.setattr(kernelchoice, "built", lambda: ["python"])
    log = tmp_path / "x.log"
    log.write_text("(0.000000) vcan0 123#00\n")
    assert canfdi_main(["replay", str(log), "--config", CONFIG, "--kernel", "c"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("canfdi replay: kernel c: not built")
    assert canfdi_main(["evaluate", "--plant", "dc_motor", "--runs", "1", "--kernel", "c",
                        "--no-progress"]) == 2


@pytest.mark.c
def test_replay_and_evaluate_give_the_same_diagnosis_on_both_kernels(tmp_path, capsys):
    log = tmp_path / "demo.mcap"
    assert canfdi_main(["demo", "--no-live", "--json", "-o", str(log), "--kernel", "c"]) == 0
    capsys.readouterr()
    outs = {}
    for name in ("python", "c"):
        assert canfdi_main(["replay", str(log), "--json", "--no-progress",
                            "--kernel", name]) == 0
        outs[name] = json.loads(capsys.readouterr().out)
    assert len(outs["c"]["faults"]) == 3
    for got, want in zip(outs["c"]["faults"], outs["python"]["faults"], strict=True):
        # the decisions exactly; the numbers to rounding (the C residuals sum in their order)
        assert {k: v for k, v in got.items() if k not in ("estimate", "variance")} == {
            k: v for k, v in want.items() if k not in ("estimate", "variance")}
        for key in ("estimate", "variance"):
            assert got[key] == pytest.approx(want[key], rel=1e-12)
    runs = {}
    for name in ("python", "c"):
        assert canfdi_main(["evaluate", "--plant", "dc_motor", "--runs", "3", "--json",
                            "--no-progress", "--kernel", name]) == 0
        runs[name] = json.loads(capsys.readouterr().out)
    assert runs["c"]["kernel"] == "c" and runs["python"]["kernel"] == "python"
    for key in ("faults", "detected", "isolation", "false_alarms"):
        assert runs["c"][key] == runs["python"][key], key
    assert runs["c"]["estimate_error_median"] == pytest.approx(
        runs["python"]["estimate_error_median"], rel=1e-9)

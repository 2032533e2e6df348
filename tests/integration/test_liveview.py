"""The live view: rendered in a pseudo-terminal by `canfdi demo`; off when not a terminal."""

import io
import os
import pty
import re
import subprocess
import sys

from rich.console import Console

from canfdi.config import load_config
from canfdi.liveview import render, snapshot
from tests.conftest import REPO

CONFIG = REPO / "deploy" / "config" / "dc_motor.yaml"
ANSI = re.compile(r"\x1b\[[0-9;?]*[A-Za-z]")


def _in_pty(*args: str) -> tuple[int, str]:
    """Run ``canfdi ARGS`` with a pseudo-terminal as stdin, stdout and stderr."""
    master, slave = pty.openpty()
    proc = subprocess.Popen([sys.executable, "-m", "canfdi", *args], stdin=slave,
                            stdout=slave, stderr=slave, cwd=REPO, close_fds=True)
    os.close(slave)
    chunks = []
    while True:
        try:
            data = os.read(master, 65536)
        except OSError:  # EIO: the child closed the terminal
            break
        if not data:
            break
        chunks.append(data)
    os.close(master)
    return proc.wait(timeout=300), ANSI.sub("", b"".join(chunks).decode(errors="replace"))


def test_demo_renders_the_live_view_in_a_pseudo_terminal():
    code, text = _in_pty("demo", "--scenario", "dc_motor_actuator", "--speed", "0")
    assert code == 0
    assert "Page-Hinkley / threshold" in text and "a:V" in text
    assert "active faults (compensated):" in text and "eta 2.00" in text
    assert "accepted" in text and "diagnosed:" in text  # diagnoses scroll above the view


def test_no_live_view_when_stdout_is_not_a_terminal():
    res = subprocess.run([sys.executable, "-m", "canfdi", "demo", "--scenario",
                          "dc_motor_actuator"], capture_output=True, text=True, timeout=300,
                         cwd=REPO)
    assert res.returncode == 0
    assert "Page-Hinkley / threshold" not in res.stdout and "\x1b[" not in res.stdout


def test_render_shows_each_residual_against_its_threshold_and_the_counters():
    from canfdi.monitor import Monitor

    monitor = Monitor(load_config(CONFIG))
    console = Console(file=io.StringIO(), width=100, force_terminal=False)
    console.print(render(snapshot(monitor), "test"))
    out = console.file.getvalue()
    # A fresh monitor checks the configured noise on its first samples before it announces.
    assert "test  checking" in out and "frames 0 received" in out
    for name, h in zip(monitor.diagnoser.residual_names, monitor.diagnoser.thresholds,
                       strict=True):
        assert re.search(rf"{re.escape(name)}\s+-\s+\.+\s+0\.0/{h:.1f}", out), name
    snap = snapshot(monitor)
    assert snap["state"] == "checking" and snap["faults"] == [] and snap["samples"] == 0


def test_run_renders_the_live_view_with_its_log_lines_above_it():
    code, text = _in_pty("run", "--config", str(CONFIG), "--no-record", "--duration", "2",
                         "--channel", "canfdi-live-test")
    assert code == 0
    assert "canfdi run: dc_motor on virtual canfdi-live-test" in text
    assert "Page-Hinkley / threshold" in text and "s:omega_r" in text
    assert "monitoring virtual canfdi-live-test" in text and "stopped:" in text

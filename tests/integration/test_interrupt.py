"""Ctrl-C anywhere (issue 28): one line, exit status 130, never a traceback; a daemon-like
verb stops in order first (its log complete), then exits 130 as well."""

from __future__ import annotations

import signal
import subprocess
import sys
import time

from canfdi.io.reader import read_metadata
from tests.conftest import REPO

CONFIG = REPO / "deploy" / "config" / "dc_motor.yaml"


def test_ctrl_c_while_a_replay_starts_is_one_line_and_130(tmp_path):
    log = tmp_path / "drive.log"
    subprocess.run([sys.executable, "-m", "canfdi", "sim", "--scenario", "dc_motor_consecutive",
                    "-o", str(log), "--quiet"], check=True, capture_output=True, cwd=REPO)
    # -X importtime says on stderr each module imported: Ctrl-C comes once canfdi's own code
    # runs (the verbs being imported, or the design), not while Python itself still starts:
    # a signal then is the interpreter's to report, before any code of ours has run.
    proc = subprocess.Popen([sys.executable, "-X", "importtime", "-m", "canfdi", "replay",
                             str(log), "--config", str(CONFIG), "--json", "--no-progress"],
                            cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    started = ""
    while "canfdi.cli" not in started and proc.poll() is None:
        started = proc.stderr.readline()
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, (proc.returncode, err[-2000:])
    said = [line for line in err.strip().splitlines() if not line.startswith("import time:")]
    assert said == ["canfdi: interrupted"] and out == ""


def test_ctrl_c_stops_run_in_order_then_130(tmp_path):
    log = tmp_path / "run.mcap"
    proc = subprocess.Popen([sys.executable, "-m", "canfdi", "run", "--config", str(CONFIG),
                             "-o", str(log), "--channel", "canfdi-interrupt-test", "--quiet"],
                            cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        seen = ""
        deadline = time.monotonic() + 60
        while "monitoring" not in seen and time.monotonic() < deadline:
            seen += proc.stderr.readline()
        assert "monitoring" in seen, seen
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, err
    assert "stopped:" in err and "Traceback" not in err
    assert read_metadata(log)["config_name"] == "dc_motor"

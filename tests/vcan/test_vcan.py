"""Real SocketCAN (vcan0): separate processes, can-utils, a vanishing interface, SIGTERM.

Skipped with a reason where there is no vcan0; `deploy/vcan-harness` provides one (a User-Mode
Linux kernel on hosts without CAN). Syscalls are slow there, so scenarios run at real time.
"""

from __future__ import annotations

import json
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from canfdi.io.reader import read_frames, read_log
from tests.conftest import REPO

pytestmark = pytest.mark.vcan

CONFIG = REPO / "deploy" / "config" / "dc_motor.yaml"
CANFDI = [sys.executable, "-m", "canfdi"]


class Monitor:
    """`canfdi run` on vcan0 in its own process, its output collected by threads."""

    def __init__(self, log: Path, *extra: str) -> None:
        self.log = log
        self.proc = subprocess.Popen(
            [*CANFDI, "run", "--config", str(CONFIG), "--interface", "socketcan",
             "--channel", "vcan0", "-o", str(log), *extra],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO)
        self.stdout: list[str] = []
        self.stderr: list[str] = []
        self._ready = threading.Event()
        threading.Thread(target=self._pump, args=(self.proc.stdout, self.stdout),
                         daemon=True).start()
        threading.Thread(target=self._pump, args=(self.proc.stderr, self.stderr),
                         daemon=True).start()
        if not self._ready.wait(timeout=180):
            self.proc.kill()
            pytest.fail("canfdi run never reported it was monitoring:\n" + "".join(self.stderr))

    def _pump(self, stream, sink: list[str]) -> None:
        for line in stream:
            sink.append(line)
            if "monitoring" in line:
                self._ready.set()

    def stop(self) -> float:
        """SIGTERM; returns the seconds it took to exit (asserting exit status 0)."""
        start = time.monotonic()
        self.proc.send_signal(signal.SIGTERM)
        code = self.proc.wait(timeout=30)
        took = time.monotonic() - start
        assert code == 0, "".join(self.stderr)
        return took

    def events(self) -> list[dict]:
        return [m for topic, _, m in read_log(self.log) if topic == "/canfdi/events"]


def sim(scenario: str, *extra: str, truth: Path | None = None) -> subprocess.CompletedProcess:
    cmd = [*CANFDI, "sim", "--scenario", scenario, "--interface", "socketcan",
           "--channel", "vcan0", "--quiet", *extra]
    if truth is not None:
        cmd += ["--truth", str(truth)]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=REPO)


def accepted(events: list[dict]) -> list[dict]:
    return [e for e in events if e["kind"] == "accepted"]


def test_consecutive_faults_across_processes_seen_by_candump(tmp_path):
    """Emulator and monitor as separate processes; candump hears the fault frames and
    `cantools decode` decodes them; SIGTERM stops the daemon within a second with a complete,
    readable MCAP."""
    dump = tmp_path / "candump.log"
    with dump.open("w") as out:
        candump = subprocess.Popen(["candump", "-L", "vcan0"], stdout=out,
                                   stderr=subprocess.DEVNULL)
    monitor = Monitor(tmp_path / "run.mcap")
    try:
        res = sim("dc_motor_consecutive", truth=tmp_path / "truth.json")
        assert res.returncode == 0, res.stderr
        time.sleep(2.0)  # the monitor drains its socket
        took = monitor.stop()
    finally:
        candump.terminate()
        candump.wait(timeout=10)
        if monitor.proc.poll() is None:
            monitor.proc.kill()
    assert took < 1.0, f"SIGTERM took {took:.2f} s"
    truth = json.loads((tmp_path / "truth.json").read_text())["faults"]
    faults = accepted(monitor.events())
    assert [(f["target"], f["index"]) for f in faults] == [(t["target"], t["index"])
                                                           for t in truth]
    for f, t in zip(faults, truth, strict=True):
        for key in ("eta", "lambda", "bias"):
            if key in t:
                assert f["estimates"][key] == pytest.approx(t[key], rel=0.03)
    # The log is complete (summary written) and holds every frame the emulator sent.
    reader = read_log(monitor.log)
    list(reader)
    assert reader.complete
    sent = json.loads(res.stdout)["frames_sent"]
    assert (read_frames(monitor.log).status == "ok").sum() == sent
    # candump saw our FDI frames, and cantools decodes them from candump's output.
    lines = [ln for ln in dump.read_text().splitlines() if " 080#" in ln or " 081#" in ln]
    assert lines, "candump saw no fault frame"
    decoded = subprocess.run(
        [sys.executable, "-m", "cantools", "decode", str(REPO / "dbc" / "canfdi_monitor.dbc")],
        input="\n".join(lines) + "\n", capture_output=True, text=True, timeout=60)
    assert decoded.returncode == 0, decoded.stderr
    assert decoded.stdout.count("FDI_FAULT(") == len(
        [ln for ln in lines if " 080#" in ln])
    assert "State: accepted" in decoded.stdout or "State: 3" in decoded.stdout


def test_frames_injected_with_cansend_are_counted_and_logged(tmp_path):
    monitor = Monitor(tmp_path / "bad.mcap")
    try:
        injected = [
            "104#0011",                 # DRIVE_CMD with DLC 2 instead of 8
            "105#0000000000000000",     # DRIVE_CURRENTS with a wrong CRC
            "7FF#DEADBEEF",             # an ID not in the DBC
            "12345678#01",              # an extended ID
        ]
        for frame in injected:
            subprocess.run(["cansend", "vcan0", frame], check=True, timeout=30)
        time.sleep(1.5)
        monitor.stop()
    finally:
        if monitor.proc.poll() is None:
            monitor.proc.kill()
    statuses = [s for s in read_frames(monitor.log).status.tolist() if s != "sent"]
    assert sorted(statuses) == sorted(["dlc", "crc", "unknown_id", "extended"])


def _ip(*args: str) -> None:
    subprocess.run(["ip", "link", *args], check=True, timeout=30)


def test_interface_down_up_and_delete_readd_mid_run(tmp_path):
    """The monitor logs the loss, reopens the bus and goes on diagnosing."""
    scenario = tmp_path / "outages.yaml"
    # Onsets 2 s after the reference steps (every 4 s), where no signal nears its DBC range.
    scenario.write_text(
        "plant: dc_motor\nduration: 38.0\nseed: 8\nnoise: {measurement: 0.01}\nfaults:\n"
        "  - {target: actuator, index: 0, onset: 6.0, eta: 2.0, lambda: 10.0}\n"
        "  - {target: sensor, index: 0, onset: 18.0, bias: 0.5}\n"
        "  - {target: sensor, index: 1, onset: 30.0, bias: 1.0}\n")
    monitor = Monitor(tmp_path / "outage.mcap")

    def wait_for(text: str, timeout: float = 120.0) -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if any(text in line for line in monitor.stdout):
                return
            time.sleep(0.1)
        pytest.fail(f"the monitor never printed {text!r}:\n" + "".join(monitor.stdout))

    try:
        emulator = subprocess.Popen(
            [*CANFDI, "sim", "--scenario", str(scenario), "--interface", "socketcan",
             "--channel", "vcan0", "--quiet"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
            text=True, cwd=REPO)
        wait_for("FAULT      actuator 0")
        _ip("set", "vcan0", "down")
        time.sleep(1.0)
        _ip("set", "vcan0", "up")
        wait_for("FAULT      sensor 0")
        _ip("delete", "vcan0")
        time.sleep(1.0)
        _ip("add", "dev", "vcan0", "type", "vcan")
        _ip("set", "vcan0", "up")
        _, err = emulator.communicate(timeout=300)
        assert emulator.returncode == 0, err
        time.sleep(2.0)
        monitor.stop()
    finally:
        if monitor.proc.poll() is None:
            monitor.proc.kill()
    log_text = "".join(monitor.stderr)
    assert log_text.count("bus error") >= 2, log_text
    assert log_text.count("bus open") >= 3, log_text
    faults = accepted(monitor.events())
    summary = [(e["kind"], e["sample"], e.get("target"), e.get("index"), e.get("estimates"))
               for e in monitor.events()]
    assert [(f["target"], f["index"]) for f in faults] == [("actuator", 0), ("sensor", 0),
                                                           ("sensor", 1)], summary
    assert faults[2]["estimates"]["bias"] == pytest.approx(1.0, rel=0.03)


def test_systemd_units_verify():
    """`systemd-analyze verify` accepts the units (paths pointed at this checkout's venv)."""
    analyze = shutil.which("systemd-analyze")
    if analyze is None:
        pytest.fail("systemd-analyze missing: the vcan harness installs systemd")
    venv = Path(sys.executable).parent.parent
    with_units = Path(REPO / "deploy" / "systemd")
    tmp = Path(subprocess.run(["mktemp", "-d"], capture_output=True, text=True).stdout.strip())
    try:
        for unit in with_units.glob("*.service"):
            (tmp / unit.name).write_text(unit.read_text().replace("/opt/canfdi/.venv",
                                                                  str(venv)))
        res = subprocess.run([analyze, "verify", *map(str, tmp.glob("*.service"))],
                             capture_output=True, text=True, timeout=120)
        problems = [ln for ln in (res.stdout + res.stderr).splitlines()
                    if "canfdi" in ln and "Documentation" not in ln]
        assert res.returncode == 0 and not problems, res.stdout + res.stderr
    finally:
        shutil.rmtree(tmp)


def test_the_monitor_socket_gets_a_large_receive_buffer():
    """A busy moment of the monitor must not lose frames in the kernel's socket queue."""
    import socket

    from canfdi.service import RECEIVE_BUFFER_BYTES, open_bus

    bus = open_bus("socketcan", "vcan0")
    try:
        size = bus.socket.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
    finally:
        bus.shutdown()
    assert size >= RECEIVE_BUFFER_BYTES  # the kernel doubles the value it is given

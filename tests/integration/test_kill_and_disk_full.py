"""Issue 7 on the host (no vcan): a killed `canfdi demo`'s truncated MCAP replays, and a full
disk under the live service drops and counts records, says "degraded" in FDI_STATUS, keeps
diagnosing and sending fault frames, and resumes recording in a new segment.

The same on real SocketCAN with separate processes (kill -9 of `canfdi capture` and `canfdi
run`, a full tmpfs) is in tests/vcan/test_vcan_reliability.py.
"""

from __future__ import annotations

import asyncio
import errno
import json
import logging
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import can
import pytest

from canfdi.config import load_config
from canfdi.firmware_sim.emitter import emit
from canfdi.firmware_sim.scenario import load_scenario
from canfdi.io.reader import read_frames, read_log, read_metadata, read_samples
from canfdi.io.segments import log_segments
from canfdi.io.writer import McapRecorder
from canfdi.monitor import Monitor
from canfdi.service import MonitorService
from canfdi.tools.session import recording_counts
from tests.conftest import REPO

CONFIG = REPO / "deploy" / "config" / "dc_motor.yaml"
CANFDI = [sys.executable, "-m", "canfdi"]
FDI_FAULT, FDI_STATUS = 0x080, 0x082
DEGRADED = 3  # FDI_STATUS State (dbc/README.md)


@pytest.mark.skipif(not hasattr(signal, "SIGKILL"), reason="needs SIGKILL")
def test_replay_reads_the_mcap_of_a_sigkilled_demo(tmp_path):
    """`canfdi demo -o X.mcap` killed with SIGKILL after its first diagnosis: the file has no
    summary, `canfdi replay` reads it (streaming, up to the last complete record), exits 0 and
    reports the fault the live run had diagnosed."""
    log = tmp_path / "killed.mcap"
    proc = subprocess.Popen(
        [*CANFDI, "demo", "--speed", "4", "-o", str(log), "--channel", "canfdi-kill-test"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO)
    lines: list[str] = []
    fault = threading.Event()

    def pump() -> None:
        for line in proc.stdout:
            lines.append(line)
            if "FAULT" in line:
                fault.set()

    threading.Thread(target=pump, daemon=True).start()
    try:
        assert fault.wait(timeout=300), "the demo never printed a FAULT:\n" + "".join(lines)
        time.sleep(2.0)  # twice the recorder's flush interval: the diagnosis is on disk
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == -signal.SIGKILL
    live = [ln for ln in lines if "FAULT" in ln]
    assert "actuator 0 (V)" in live[0]

    reader = read_log(log)
    list(reader)
    assert reader.truncated and not reader.complete  # killed: no summary, no footer
    assert read_metadata(log)["config_name"] == "dc_motor"
    frames = read_frames(log)
    assert frames.size > 1000 * 3  # beyond the first fault's 1000 samples of 3 frames

    res = subprocess.run([*CANFDI, "replay", str(log), "--config", str(CONFIG), "--json",
                          "--no-progress"], capture_output=True, text=True, timeout=300,
                         cwd=REPO)
    assert res.returncode == 0, res.stderr
    result = json.loads(res.stdout)
    assert len(result["truth"]) == 3  # the demo's metadata survived the kill
    assert len(result["faults"]) >= 1
    first = result["faults"][0]
    assert (first["kind"], first["index"], first["name"]) == ("actuator", 0, "V")
    assert first["estimate"]["eta"] == pytest.approx(2.0, rel=0.03)
    assert first["estimate"]["lambda"] == pytest.approx(10.0, rel=0.03)
    assert result["frames"]["received"] == (frames.status != "sent").sum()


class Disk:
    """Opens real files whose writes fail with ENOSPC while ``full()`` says so."""

    def __init__(self, full) -> None:
        self.full = full

    def open(self, path: Path):
        return _FlakyFile(open(path, "wb"), self)


class _FlakyFile:
    def __init__(self, file, disk: Disk) -> None:
        self.file = file
        self.disk = disk

    def _check(self) -> None:
        if self.disk.full():
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    def write(self, data: bytes) -> int:
        self._check()
        return self.file.write(data)

    def flush(self) -> None:
        self._check()
        self.file.flush()

    def close(self) -> None:
        self.file.close()


def test_full_disk_under_the_service_degrades_then_resumes(tmp_path, caplog):
    """The disk is full while the monitor handles samples 500 to 2500 (the first two faults
    of dc_motor_consecutive are accepted then): every fault still gets its FDI_FAULT frame,
    FDI_STATUS says "degraded" during the episode only, the recorder warns once when it fails
    and once when it resumes (in run-0001.mcap), and its counters say what was lost."""
    caplog.set_level(logging.INFO, logger="canfdi.io.writer")
    config = load_config(CONFIG)
    scenario = load_scenario("dc_motor_consecutive")
    monitor = Monitor(config)
    full_from, full_to = 500, 2500
    disk = Disk(lambda: full_from <= monitor.samples < full_to)
    path = tmp_path / "run.mcap"
    # The recorder's clock is the monitor's sample time: its 1 s flushes and retries fall on
    # the same samples on a fast or a slow machine.
    recorder = McapRecorder(path, metadata=monitor.metadata(), opener=disk.open,
                            clock=lambda: monitor.samples * monitor.dt)
    monitor.sink = recorder
    channel = "canfdi-disk-full-test"
    observer = can.Bus(interface="virtual", channel=channel)

    async def main():
        stop = asyncio.Event()
        service = MonitorService(monitor, lambda: can.Bus(interface="virtual", channel=channel),
                                 status_period=0.02)
        task = asyncio.create_task(service.run(stop))
        while service.bus is None:
            await asyncio.sleep(0.01)
        bus = can.Bus(interface="virtual", channel=channel)
        try:
            stats = await emit(bus, scenario, speed=10)
            while service.stats.frames < stats.frames_sent and not task.done():
                await asyncio.sleep(0.01)
            await asyncio.sleep(0.1)  # a few more status frames after the end
        finally:
            bus.shutdown()
            stop.set()
            await task
        return stats

    try:
        stats = asyncio.run(main())
    finally:
        recorder.close()
    heard = []
    while (msg := observer.recv(timeout=0)) is not None:
        heard.append(msg)
    observer.shutdown()

    # Diagnosis went on: three faults, the first two accepted while the disk was full.
    accepted = [e for e in monitor.events if e.kind == "accepted"]
    assert [(e.target, e.index) for e in accepted] == [("actuator", 0), ("sensor", 0),
                                                       ("sensor", 1)]
    assert all(full_from <= e.sample < full_to for e in accepted[:2])
    fault_frames = {(m.data[2] & 0x03, (m.data[2] >> 2) & 0x03, m.data[3])
                    for m in heard if m.arbitration_id == FDI_FAULT}
    for kind, index in ((1, 0), (2, 0), (2, 1)):  # Kind 1 actuator, 2 sensor; State 3 accepted
        assert (kind, 3, index) in fault_frames

    # FDI_STATUS: monitoring, then degraded while failing, then not degraded again.
    states = [m.data[2] & 0x0F for m in heard if m.arbitration_id == FDI_STATUS]
    runs = [s == DEGRADED for i, s in enumerate(states) if i == 0 or
            (s == DEGRADED) != (states[i - 1] == DEGRADED)]
    assert runs == [False, True, False], states

    # The recorder: one warning per episode, counters, a second segment.
    messages = [r.getMessage() for r in caplog.records if r.name == "canfdi.io.writer"]
    assert len([m for m in messages if "failed" in m]) == 1, messages
    assert len([m for m in messages if "resumed" in m]) == 1, messages
    assert recorder.last_error is not None and recorder.last_error.errno == errno.ENOSPC
    assert recorder.messages_dropped > 0
    counts = recording_counts(recorder)
    assert counts == {"segments": [str(path), str(tmp_path / "run-0001.mcap")],
                      "written": recorder.messages_written,
                      "dropped": recorder.messages_dropped,
                      "write_errors": recorder.write_errors,
                      "last_error": os.strerror(errno.ENOSPC)}
    assert log_segments(path) == [path, tmp_path / "run-0001.mcap"]
    first, second = read_log(path), read_log(tmp_path / "run-0001.mcap")
    list(first), list(second)
    assert first.truncated and second.complete

    # One gap in the samples of the log: it starts at most a flush interval (100 samples,
    # and the block the clock jumped with: 150 in all) before the failure and ends by a retry
    # interval (the same margin) after space returned. (The rows still buffered in the
    # recorder when it resumed are kept, so the gap may end before the disk was freed.)
    k = set(read_samples(path).k.tolist())
    missing = sorted(set(range(stats.samples)) - k)
    assert missing == list(range(missing[0], missing[-1] + 1))
    assert full_from - 150 <= missing[0] and missing[-1] < full_to + 150
    received = read_frames(path)
    received = received.select(received.status != "sent")
    dropped_frames = stats.frames_sent - received.size
    assert 0 < dropped_frames <= recorder.messages_dropped
    events = [m for t, _, m in read_log(tmp_path / "run-0001.mcap") if t == "/canfdi/events"]
    assert [(e["target"], e["index"]) for e in events if e["kind"] == "accepted"] == [
        ("sensor", 1)]


def test_capture_says_when_it_is_recording(tmp_path):
    """The readiness line a supervisor (or a test) waits for before starting the traffic."""
    out = tmp_path / "cap.mcap"
    res = subprocess.run([*CANFDI, "capture", "--config", str(CONFIG), "-o", str(out),
                          "--interface", "virtual", "--channel", "canfdi-ready-test",
                          "--duration", "0.5"], capture_output=True, text=True, timeout=120,
                         cwd=REPO)
    # Nothing is sent on that channel: the capture says so and ends 1 (issue 28).
    assert res.returncode == 1, res.stderr
    assert f"canfdi capture: recording virtual canfdi-ready-test to {out}" in res.stderr
    assert "no frame was received" in res.stderr and "write errors" not in res.stderr

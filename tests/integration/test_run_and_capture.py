"""`canfdi run` stops cleanly on SIGTERM; `canfdi capture`'s pipeline records every frame."""

import asyncio
import os
import signal
import subprocess
import sys
import time

import can

from canfdi.config import load_config
from canfdi.firmware_sim.emitter import emit
from canfdi.firmware_sim.scenario import load_scenario
from canfdi.io.reader import read_frames, read_log, read_metadata, read_samples
from canfdi.io.writer import McapRecorder
from canfdi.monitor import Monitor
from canfdi.service import MonitorService
from tests.conftest import REPO

CONFIG = REPO / "deploy" / "config" / "dc_motor.yaml"


def test_run_stops_on_sigterm_with_a_readable_log(tmp_path):
    log = tmp_path / "run.mcap"
    proc = subprocess.Popen(
        [sys.executable, "-m", "canfdi", "run", "--config", str(CONFIG), "-o", str(log),
         "--channel", "canfdi-run-test"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO)
    try:
        deadline = time.monotonic() + 60
        seen = ""
        while time.monotonic() < deadline:
            line = proc.stderr.readline()
            seen += line
            if "monitoring" in line:
                break
        assert "monitoring" in seen, seen
        time.sleep(1.5)  # at least one FDI_STATUS period
        sent = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        code = proc.wait(timeout=10)
        assert time.monotonic() - sent < 2.0
    finally:
        if proc.poll() is None:
            proc.kill()
    assert code == 0, proc.stderr.read()
    meta = read_metadata(log)
    assert meta["config_name"] == "dc_motor" and "design_json" in meta
    frames = read_frames(log)
    sent_ids = frames.id[frames.status == "sent"]
    assert len(sent_ids) and (sent_ids == 0x082).all()


def test_run_bad_config_exits_2():
    bad = REPO / "deploy" / "config" / "inverted_pendulum.yaml"  # no bus.dbc
    res = subprocess.run([sys.executable, "-m", "canfdi", "run", "--config", str(bad),
                          "--no-record"], capture_output=True, text=True, timeout=120, cwd=REPO)
    assert res.returncode == 2 and "bus.dbc" in res.stderr


def test_capture_pipeline_records_every_frame_and_sample(tmp_path):
    config = load_config(CONFIG)
    scenario = load_scenario("dc_motor_actuator")
    monitor = Monitor(config, diagnose=False)
    out = tmp_path / "cap.mcap"
    recorder = McapRecorder(out, metadata=monitor.metadata())
    monitor.sink = recorder
    channel = "canfdi-capture-test"

    async def main():
        stop = asyncio.Event()
        service = MonitorService(monitor, lambda: can.Bus(interface="virtual", channel=channel),
                                 status_period=0)
        task = asyncio.create_task(service.run(stop))
        while service.bus is None:
            await asyncio.sleep(0.01)
        bus = can.Bus(interface="virtual", channel=channel)
        try:
            stats = await emit(bus, scenario, speed=0, duration=5.0)
            while service.stats.frames < stats.frames_sent and not task.done():
                await asyncio.sleep(0.01)
        finally:
            bus.shutdown()
            stop.set()
            await task
        return stats

    stats = asyncio.run(main())
    recorder.close()
    topics = [t for t, _, _ in read_log(out)]
    assert read_frames(out).size == stats.frames_sent == 1500
    assert len(read_samples(out).k) == 500
    assert "/canfdi/events" not in topics
    assert os.path.getsize(out) > 0


def test_run_removes_its_own_old_logs_and_nothing_else(tmp_path, capfd):
    """recording.keep_days (issue 27): at start the daemon removes the logs it named itself
    that are older than the bound, and leaves everything else in the directory."""
    from tests.cli import canfdi_main as main

    text = CONFIG.read_text()
    assert "  rotate_minutes: 60\n" in text
    config = tmp_path / "dc_motor.yaml"
    config.write_text(text.replace("  rotate_minutes: 60\n",
                                   "  rotate_minutes: 60\n  keep_days: 30\n"))
    logs = tmp_path / "logs"
    logs.mkdir()
    old = time.time() - 40 * 86400
    names = {"dc_motor-20251001-120000.mcap": old, "dc_motor-20251001-120000-0001.mcap": old,
             "dc_motor-20261120-120000.mcap": time.time() - 5 * 86400,
             "notes.mcap": old, "other-20251001-120000.mcap": old, "dc_motor-old.mcap": old}
    for name, mtime in names.items():
        (logs / name).write_bytes(b"x" * 100)
        os.utime(logs / name, (mtime, mtime))
    assert main(["run", "--config", str(config), "--log-dir", str(logs), "--duration", "0.5",
                 "--channel", "canfdi-keep-test", "--quiet"]) == 0
    left = sorted(p.name for p in logs.iterdir())
    new = [n for n in left if n not in names]
    assert len(new) == 1 and new[0].startswith("dc_motor-2")
    assert sorted(set(left) - set(new)) == ["dc_motor-20261120-120000.mcap", "dc_motor-old.mcap",
                                            "notes.mcap", "other-20251001-120000.mcap"]
    assert "removed 2 old log file(s)" in capfd.readouterr().err

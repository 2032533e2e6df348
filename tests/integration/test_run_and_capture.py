"""`canfdi run` stops cleanly on SIGTERM; `canfdi capture`'s pipeline records every frame."""

import asyncio
import os
import signal
import subprocess
import sys
import time

import can

from canfdi.config import load_config
from canfdi.io.reader import read_frames, read_log, read_metadata, read_samples
from canfdi.io.writer import McapRecorder
from canfdi.monitor import Monitor
from canfdi.service import MonitorService
from firmware_sim.emitter import emit
from firmware_sim.scenario import load_scenario
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

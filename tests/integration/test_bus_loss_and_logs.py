"""A lost bus is reopened with backoff; python-can logs replay like the MCAP they came from."""

import asyncio
import json
import os
import subprocess
import sys

import can
import pytest

from canfdi.config import load_config
from canfdi.io.reader import read_frames
from canfdi.monitor import Monitor
from canfdi.service import MonitorService
from tests.conftest import REPO

CONFIG = REPO / "deploy" / "config" / "dc_motor.yaml"


class FlakyBus(can.BusABC):
    """Delivers the frames it is given, then fails as an unplugged interface would."""

    def __init__(self, frames, fail_after, **kwargs):
        super().__init__(channel="flaky", **kwargs)
        self.frames = list(frames)
        self.fail_after = fail_after
        self.channel_info = "flaky"

    def _recv_internal(self, timeout):
        if self.fail_after is not None and self.fail_after <= 0:
            raise can.CanOperationError("interface went down")
        if not self.frames:
            return None, False
        if self.fail_after is not None:
            self.fail_after -= 1
        return self.frames.pop(0), False

    def send(self, msg, timeout=None):
        return None


def test_lost_bus_is_reopened_and_diagnosis_goes_on(tmp_path):
    # Frames of a demo log: the first half comes on a bus that then dies, the rest on the next.
    from canfdi.cli.demo import run_demo
    from canfdi.io.writer import McapRecorder
    from firmware_sim.scenario import load_scenario

    log = tmp_path / "src.mcap"
    recs = []
    asyncio.run(run_demo(load_scenario("dc_motor_actuator"), load_config(CONFIG),
                         channel="canfdi-flaky-src",
                         recorder=lambda md: recs.append(McapRecorder(log, metadata=md))
                         or recs[-1]))
    recs[0].close()
    logged = read_frames(log)
    ok = logged.select(logged.status == "ok")
    frames = [can.Message(timestamp=t / 1e9, arbitration_id=i, data=data, is_extended_id=False)
              for t, i, data in zip(ok.t_ns.tolist(), ok.id.tolist(), ok.payloads(), strict=True)]
    half = len(frames) // 2
    buses = [FlakyBus(frames[:half], fail_after=half), FlakyBus(frames[half:], fail_after=None)]
    opened = []

    def factory():
        if len(opened) == 1 and not opened[0]._failed_once:
            opened[0]._failed_once = True
            raise can.CanOperationError("still down")  # one failed reopen: backoff, retry
        bus = buses[len(opened)]
        bus._failed_once = False
        opened.append(bus)
        return bus

    monitor = Monitor(load_config(CONFIG))

    async def main():
        stop = asyncio.Event()
        service = MonitorService(monitor, factory, status_period=0, max_backoff=0.2)
        task = asyncio.create_task(service.run(stop))
        for _ in range(600):
            await asyncio.sleep(0.05)
            if service.stats.frames >= len(frames):
                break
        stop.set()
        return await task

    stats = asyncio.run(main())
    assert len(opened) == 2 and stats.bus_errors == 1 and stats.reopen_attempts >= 3
    assert stats.frames == len(frames)
    (fault,) = monitor.summary()["faults"]
    assert fault["kind"] == "actuator"
    assert fault["estimate"]["lambda"] == pytest.approx(10.0, rel=0.02)


@pytest.mark.parametrize("suffix", [".blf", ".asc", ".log"])
def test_python_can_logs_replay_to_the_same_diagnoses(tmp_path, suffix):
    src = tmp_path / "demo.mcap"
    res = subprocess.run([sys.executable, "-m", "canfdi", "demo", "--scenario",
                          "dc_motor_sensors_b", "--json", "-o", str(src)],
                         capture_output=True, text=True, timeout=300, cwd=REPO)
    assert res.returncode == 0, res.stderr
    live = json.loads(res.stdout)["faults"]
    out = tmp_path / f"frames{suffix}"
    with can.Logger(str(out)) as writer:
        logged = read_frames(src)
        received = logged.select(logged.status != "sent")
        for t, i, data, extended in zip(received.t_ns.tolist(), received.id.tolist(),
                                        received.payloads(), received.extended.tolist(),
                                        strict=True):
            writer.on_message_received(can.Message(
                timestamp=t / 1e9, arbitration_id=i, data=data, is_extended_id=extended,
                channel=0))
    res = subprocess.run([sys.executable, "-m", "canfdi", "replay", str(out), "--config",
                          str(CONFIG), "--json"], capture_output=True, text=True, timeout=300,
                         cwd=REPO)
    assert res.returncode == 0, res.stderr
    replayed = json.loads(res.stdout)["faults"]
    assert [(f["kind"], f["index"], f["accepted_sample"]) for f in replayed] == \
        [(f["kind"], f["index"], f["accepted_sample"]) for f in live]
    for a, b in zip(replayed, live, strict=True):
        for key, value in b["estimate"].items():
            # Text formats keep microsecond timestamps and full payloads: same numbers.
            assert a["estimate"][key] == pytest.approx(value, rel=1e-9)


def test_a_socket_bus_gets_a_large_receive_buffer():
    """open_bus enlarges the socket's receive queue (here a UDP socket stands in for a
    SocketCAN one; the vcan test checks the real thing)."""
    import socket

    from canfdi.service import RECEIVE_BUFFER_BYTES, _enlarge_receive_buffer

    class SocketBus:
        pass

    bus = SocketBus()
    bus.socket = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    before = bus.socket.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
    _enlarge_receive_buffer(bus)
    after = bus.socket.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
    bus.socket.close()
    if os.geteuid() == 0:  # privileged: past net.core.rmem_max
        assert after >= RECEIVE_BUFFER_BYTES
    assert after >= before

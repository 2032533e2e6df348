"""A lost bus is reopened with backoff; python-can logs of every format, gzip-compressed or not,
replay like the MCAP they came from; unknown and damaged logs are one error line."""

import asyncio
import gzip
import json
import os
import shutil
import subprocess
import sys
import time

import can
import pytest

from canfdi.config import load_config
from canfdi.io.formats import format_of
from canfdi.io.reader import read_frames
from canfdi.monitor import Monitor
from canfdi.service import MonitorService
from tests.cli import canfdi_main as main
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
    from canfdi.firmware_sim.scenario import load_scenario
    from canfdi.io.writer import McapRecorder
    from canfdi.tools.demo import run_demo

    log = tmp_path / "src.mcap"
    recs = []
    asyncio.run(run_demo(load_scenario("dc_motor_actuator"), load_config(CONFIG),
                         channel="canfdi-flaky-src",
                         recorder=lambda md, drive_time: recs.append(McapRecorder(log, metadata=md))
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
    assert stats.bus_down_s > 0  # one failed reopen and its backoff
    assert stats.frames == len(frames)
    (fault,) = monitor.summary()["faults"]
    assert fault["kind"] == "actuator"
    assert fault["estimate"]["lambda"] == pytest.approx(10.0, rel=0.02)


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    """A demo run's MCAP and its live diagnoses (dc_motor_sensors_b: two sensor faults)."""
    src = tmp_path_factory.mktemp("demo") / "demo.mcap"
    res = subprocess.run([sys.executable, "-m", "canfdi", "demo", "--scenario",
                          "dc_motor_sensors_b", "--json", "-o", str(src)],
                         capture_output=True, text=True, timeout=300, cwd=REPO)
    assert res.returncode == 0, res.stderr
    return src, json.loads(res.stdout)["faults"]


def python_can_log(src, out):
    """The frames the monitor received in ``src``, written by python-can itself (can.Logger;
    a .blf.gz is a .blf gzipped, which python-can reads but does not write)."""
    logged = read_frames(src)
    received = logged.select(logged.status != "sent")
    target = out.with_suffix("") if out.name.endswith(".blf.gz") else out
    with can.Logger(str(target)) as writer:
        for t, i, data, extended in zip(received.t_ns.tolist(), received.id.tolist(),
                                        received.payloads(), received.extended.tolist(),
                                        strict=True):
            writer.on_message_received(can.Message(
                timestamp=t / 1e9, arbitration_id=i, data=data, is_extended_id=extended,
                channel=0))
        # python-can's SQLite writer drops what is still queued when it is stopped.
        while isinstance(writer, can.SqliteWriter) and not writer.buffer.empty():
            time.sleep(0.01)
    if target != out:
        with open(target, "rb") as f, gzip.open(out, "wb") as g:
            shutil.copyfileobj(f, g)
    return out


def replay(log, capsys):
    """`canfdi replay LOG --config dc_motor.yaml --json`, in this process: its faults."""
    assert main(["replay", str(log), "--config", str(CONFIG), "--json", "--no-progress"]) == 0
    return json.loads(capsys.readouterr().out)["faults"]


def same_diagnoses(replayed, live):
    assert [(f["kind"], f["index"], f["accepted_sample"]) for f in replayed] == \
        [(f["kind"], f["index"], f["accepted_sample"]) for f in live]
    for a, b in zip(replayed, live, strict=True):
        for key, value in b["estimate"].items():
            # Every format keeps microsecond timestamps and full payloads: same numbers.
            assert a["estimate"][key] == pytest.approx(value, rel=1e-9)


SUFFIXES = [".blf", ".asc", ".log", ".trc", ".csv", ".db", ".mf4", ".asc.gz", ".log.gz",
            ".trc.gz", ".csv.gz", ".blf.gz"]


@pytest.mark.parametrize("suffix", SUFFIXES)
def test_python_can_logs_replay_to_the_same_diagnoses(demo, tmp_path, capsys, suffix):
    src, live = demo
    missing = format_of(f"x{suffix}").missing()
    if missing:
        pytest.skip(missing)
    out = python_can_log(src, tmp_path / f"frames{suffix}")
    same_diagnoses(replay(out, capsys), live)


def test_a_gzipped_log_replays_as_the_uncompressed_one(demo, tmp_path, capsys):
    # The command line as a user types it: `canfdi replay x.asc.gz --config dc_motor.yaml`.
    src, live = demo
    plain = python_can_log(src, tmp_path / "frames.asc")
    packed = tmp_path / "frames.asc.gz"
    with open(plain, "rb") as f, gzip.open(packed, "wb") as g:
        shutil.copyfileobj(f, g)
    results = []
    for log in (plain, packed):
        res = subprocess.run([sys.executable, "-m", "canfdi", "replay", str(log), "--config",
                              str(CONFIG), "--json"], capture_output=True, text=True,
                             timeout=300, cwd=REPO)
        assert res.returncode == 0, res.stderr
        results.append(json.loads(res.stdout))
    assert results[0] == results[1]
    same_diagnoses(results[1]["faults"], live)


def test_an_exported_log_replays_to_the_same_diagnoses(demo, tmp_path, capsys):
    # canfdi export writes the monitor's own frames too (as Tx); replay keeps them, as a
    # monitor elsewhere on the bus hears them, and they change nothing.
    src, live = demo
    for fmt in ("trc.gz", "csv", "mcap"):
        out = tmp_path / f"exported.{fmt}"
        assert main(["export", str(src), "--format", fmt, "-o", str(out), "--no-progress"]) == 0
        same_diagnoses(replay(out, capsys), live)


def run_cli(*args):
    return subprocess.run([sys.executable, "-m", "canfdi", *map(str, args)],
                          capture_output=True, text=True, timeout=120, cwd=REPO)


@pytest.mark.parametrize("verb", ["replay", "export"])
def test_an_unknown_suffix_is_one_line_and_exit_2(tmp_path, verb):
    log = tmp_path / "frames.pcapng"
    log.write_bytes(b"\x0a\x0d\x0d\x0a" * 100)
    extra = ["--config", CONFIG] if verb == "replay" else ["--format", "asc"]
    res = run_cli(verb, log, *extra)
    assert res.returncode == 2
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in res.stderr, res.stderr
    assert "frames.pcapng" in lines[0] and ".asc.gz" in lines[0] and ".mcap" in lines[0]


@pytest.mark.parametrize("suffix", [".mcap", ".asc", ".blf", ".log", ".trc", ".db",
                                    ".asc.gz", ".mf4"])
def test_a_damaged_log_is_one_line_and_no_traceback(tmp_path, suffix):
    missing = format_of(f"x{suffix}").missing()
    if missing:
        pytest.skip(missing)
    log = tmp_path / f"damaged{suffix}"
    log.write_bytes(os.urandom(4000))
    res = run_cli("replay", log, "--config", CONFIG, "--json", "--no-progress")
    assert res.returncode == 2 and res.stdout == ""  # issue 17: not a log of its suffix
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in res.stderr, res.stderr
    assert f"damaged{suffix}" in lines[0] and "not a readable" in lines[0]
    res = run_cli("export", log, "--format", "asc", "-o", tmp_path / "out.asc")
    assert res.returncode == 2 and "Traceback" not in res.stderr, res.stderr
    assert len(res.stderr.strip().splitlines()) == 1


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


def test_a_log_no_frame_of_which_matches_the_map_says_so_and_exits_1(tmp_path):
    # Another bus's traffic (IDs the DBC does not define, a 29-bit frame): nothing to diagnose.
    log = tmp_path / "other_bus.log"
    with can.Logger(str(log)) as writer:
        for i in range(50):
            writer.on_message_received(can.Message(timestamp=1.0 + i / 100, arbitration_id=0x7E5,
                                                   data=bytes(8), is_extended_id=False))
        writer.on_message_received(can.Message(timestamp=2.0, arbitration_id=0x18FF0102,
                                               data=bytes(8), is_extended_id=True))
    res = run_cli("replay", log, "--config", CONFIG, "--no-progress")
    assert res.returncode == 1, res.stderr
    assert "0 samples: no frame matched the config's bus map (51 frames: 50 unknown_id, " \
        "1 extended)" in res.stdout, res.stdout
    res = run_cli("replay", log, "--config", CONFIG, "--json", "--no-progress")
    assert res.returncode == 1 and "no frame matched" in res.stderr
    assert json.loads(res.stdout)["no_samples"].startswith("0 samples: no frame matched")

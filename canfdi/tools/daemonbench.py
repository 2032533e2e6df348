"""The daemon as a supervisor sees it: `canfdi run` started as its own process on a bus shared
with this one, fed the drive's frames at their real rate among foreign ones.

What `canfdi bench` reports from it: how long `canfdi --version` takes, how long from the
process's start to the first frame of the drive handled (its log line "receiving the drives'
frames"), at a first start (nothing in its cache directory: the design computed) and at a
restart (the design remembered, canfdi.core.memo), its RSS once monitoring (and recording),
and its CPU on a bus where 90 % of the frames are not the drive's, with the receive filters
(the default, at the first start) and with ``--no-filters`` (at the restart).

The bus must be one that separate processes share: python-can's ``udp_multicast`` (the
default: IP multicast on this host, no hardware) or SocketCAN (``socketcan`` on vcan0, where
the filters are the kernel's; `deploy/vcan-harness` provides one).
"""

from __future__ import annotations

import json
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from canfdi.bus.frames import FrameBlock

__all__ = ["DAEMON_BUS", "FOREIGN_SHARE", "daemon_figures", "version_time"]

DAEMON_BUS = ("udp_multicast", "239.74.163.2")  # python-can's UdpMulticastBus.DEFAULT_GROUP_IPv4
"""The bus the daemon benchmark shares with its daemon by default: python-can's IPv4
multicast group on this host."""
FOREIGN_SHARE = 0.9
"""Share of the frames on the benchmark's bus that are not the drive's."""
FIRST_FRAME_LINE = "receiving the drives' frames"
"""The daemon's log line at its first frame of the drive (canfdi.service)."""


def _command() -> list[str]:
    return [sys.executable, "-m", "canfdi"]


def version_time(runs: int = 5) -> float:
    """Median seconds of `canfdi --version` in a new process (the interpreter's start
    included)."""
    times = []
    for _ in range(runs):
        start = time.perf_counter()
        subprocess.run([*_command(), "--version"], check=True, capture_output=True)
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def foreign_traffic(traffic: FrameBlock, share: float = FOREIGN_SHARE,
                    avoid: set[int] | None = None) -> list[tuple[float, int, bytes]]:
    """(time s from the start, ID, payload) of the drive's frames at their own times with
    foreign frames between them, so that ``share`` of all frames are foreign (IDs 0x500 up,
    none of ``avoid``), spread evenly over each gap."""
    avoid = avoid or set()
    foreign_ids = [i for i in range(0x500, 0x600) if i not in avoid][:16]
    per_frame = round(share / (1.0 - share))
    t = (traffic.t_ns - traffic.t_ns[0]) / 1e9
    gaps = np.diff(np.append(t, t[-1] + (t[-1] - t[0]) / max(len(t) - 1, 1)))
    out = []
    payloads = traffic.payloads()
    for i in range(traffic.size):
        out.append((float(t[i]), int(traffic.id[i]), payloads[i]))
        for j in range(per_frame):
            out.append((float(t[i] + gaps[i] * (j + 1) / (per_frame + 1)),
                        foreign_ids[(i * per_frame + j) % len(foreign_ids)], bytes(8)))
    return out


class _Feeder(threading.Thread):
    """Sends the schedule on the shared bus at its times, over and over, until stopped."""

    def __init__(self, interface: str, channel: str,
                 schedule: list[tuple[float, int, bytes]]) -> None:
        super().__init__(daemon=True)
        import can

        self.bus = can.Bus(interface=interface, channel=channel)
        self.messages = [(t, can.Message(arbitration_id=i, data=d, is_extended_id=False))
                         for t, i, d in schedule]
        self.span = schedule[-1][0] + 0.01 if schedule else 1.0
        self.sent = 0
        self.halt = threading.Event()

    def run(self) -> None:
        start = time.monotonic()
        repeat = 0
        while not self.halt.is_set():
            base = start + repeat * self.span
            for t, msg in self.messages:
                delay = base + t - time.monotonic()
                if delay > 0.0005 and self.halt.wait(delay):
                    return
                try:
                    self.bus.send(msg)
                    self.sent += 1
                except Exception:  # a full socket buffer: the frame is lost
                    pass
            repeat += 1

    def close(self) -> None:
        self.halt.set()
        self.join(timeout=5)
        self.bus.shutdown()


def _cpu_s(pid: int) -> float:
    """User + system CPU seconds of a process so far (/proc/PID/stat)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _rss_mib(pid: int) -> tuple[float, float]:
    """(VmRSS, VmHWM) of a process, MiB."""
    values = {}
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        key, _, rest = line.partition(":")
        if key in ("VmRSS", "VmHWM"):
            values[key] = int(rest.split()[0]) / 1024.0
    return values.get("VmRSS", float("nan")), values.get("VmHWM", float("nan"))


def _one_daemon(config_path: Path, interface: str, channel: str, schedule, seconds: float,
                filters: bool, workdir: Path, cache: Path) -> dict:
    """Start `canfdi run` while the feeder sends; its start-up, RSS, CPU and counters."""
    feeder = _Feeder(interface, channel, schedule)
    lines: list[str] = []
    first = threading.Event()
    cmd = [*_command(), "run", "--config", str(config_path), "-i", interface, "-c", channel,
           "--log-dir", str(workdir), "--quiet", "--log-format", "json", "--retry-for", "20"]
    if not filters:
        cmd.append("--no-filters")
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "CANFDI_CACHE_DIR": str(cache)}
    feeder.start()
    start = time.monotonic()
    daemon = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                              env=env)
    seen: dict[str, float] = {}

    def pump() -> None:
        for line in daemon.stderr:
            lines.append(line)
            if FIRST_FRAME_LINE in line and "first" not in seen:
                seen["first"] = time.monotonic() - start
                first.set()

    reader = threading.Thread(target=pump, daemon=True)
    reader.start()
    try:
        if not first.wait(60):
            raise RuntimeError("the daemon handled no frame within 60 s: "
                               + " | ".join(ln.strip() for ln in lines[-5:]))
        time.sleep(1.0)  # past the first blocks, the recorder's first chunk
        cpu0, wall0 = _cpu_s(daemon.pid), time.monotonic()
        sent0 = feeder.sent
        time.sleep(seconds)
        cpu1, wall1 = _cpu_s(daemon.pid), time.monotonic()
        sent1 = feeder.sent
        rss, hwm = _rss_mib(daemon.pid)
        daemon.send_signal(signal.SIGTERM)
        daemon.wait(timeout=60)
        reader.join(timeout=5)
    finally:
        if daemon.poll() is None:
            daemon.kill()
            daemon.wait()
        feeder.close()
    stopped = {}
    for line in lines:
        if '"stopped: ' in line:
            stopped = json.loads(json.loads(line)["message"].split("stopped: ", 1)[1])
    return {"first_frame_s": seen["first"], "rss_mib": rss, "rss_peak_mib": hwm,
            "cpu_share": (cpu1 - cpu0) / (wall1 - wall0),
            "bus_fps": (sent1 - sent0) / (wall1 - wall0),
            "frames_received": stopped.get("frames")}


def daemon_figures(config, traffic: FrameBlock, interface: str = DAEMON_BUS[0],
                   channel: str = DAEMON_BUS[1], quick: bool = False,
                   progress: Callable[[str], None] | None = None) -> dict:
    """`canfdi run` as its own process: --version time, first frame, RSS, CPU with and
    without receive filters on a bus of ``FOREIGN_SHARE`` foreign frames (``config``: the
    monitor config, run from its file; ``traffic``: the drive's frames, of which the first
    20 s plus the measured stretch are played: 5 s, 2 with ``quick``). A bus that cannot be
    shared gives {"daemon_error": why}."""
    from canfdi.monitor import Monitor

    say = progress or (lambda msg: None)
    seconds = 2.0 if quick else 5.0
    # The drive's frames for the daemon's start, its warm-up and the measured stretch.
    end = np.searchsorted(traffic.t_ns, traffic.t_ns[0] + int((seconds + 20.0) * 1e9))
    traffic = traffic.slice(0, int(end))
    say("the daemon: canfdi --version")
    out: dict = {"daemon_version_s": version_time()}
    # Only the bus map is needed: no diagnoser, so no threshold calibration here.
    avoid = {f["can_id"] for f in Monitor(config, diagnose=False).receive_filters()}
    schedule = foreign_traffic(traffic, avoid=avoid)
    out["daemon_bus"] = f"{interface} {channel}"
    out["daemon_foreign_share"] = FOREIGN_SHARE
    with tempfile.TemporaryDirectory(prefix="canfdi-daemon-bench-") as tmp:
        for filters in (True, False):
            key = "filtered" if filters else "unfiltered"
            say(f"the daemon on {interface} {channel}, 90% foreign frames, "
                f"{'with' if filters else 'without'} receive filters ({seconds:g} s)")
            try:
                r = _one_daemon(Path(config.path), interface, channel, schedule, seconds,
                                filters, Path(tmp) / key, Path(tmp) / "cache")
            except (OSError, RuntimeError, ValueError) as exc:
                return {**out, "daemon_error": str(exc)}
            out[f"daemon_{key}"] = r
    f, u = out["daemon_filtered"], out["daemon_unfiltered"]
    out["daemon_first_frame_first_start_s"] = f["first_frame_s"]
    out["daemon_first_frame_s"] = u["first_frame_s"]  # a restart: the design remembered
    out["daemon_rss_mib"] = max(f["rss_mib"], u["rss_mib"])
    out["daemon_cpu_filtered"] = f["cpu_share"]
    out["daemon_cpu_unfiltered"] = u["cpu_share"]
    out["daemon_bus_fps"] = f["bus_fps"]
    return out

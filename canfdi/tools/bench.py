"""Measurements behind `canfdi bench`: every figure is measured in one run on this machine.

Frames come from the plant emulator (the DC motor's drive, three frames per 10 ms period),
generated once and reused, so every stage is timed on the same traffic.
"""

from __future__ import annotations

import asyncio
import math
import os
import statistics
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from canfdi.bus.frames import FLAG_EXTENDED, FLAG_REMOTE, FrameBlock

if TYPE_CHECKING:
    from canfdi.core.kernel import Kernel
    from canfdi.firmware_sim.scenario import Scenario

__all__ = ["bench_scenarios", "bus_limit", "data_lengths", "make_traffic", "run_bench",
           "run_daemon_bench", "soak_frames_missing"]


def frame_bits(dlc: int, stuffed: bool) -> int:
    """Bits of a classic CAN data frame with an 11-bit ID, interframe space included.

    SOF 1, ID 11, RTR 1, IDE 1, r0 1, DLC 4, data 8 dlc, CRC 15, delimiters and ACK 3, EOF 7,
    IFS 3: 47 + 8 dlc. Worst-case bit stuffing adds one bit per 4 over the 34 + 8 dlc bits from
    SOF to the end of the CRC.
    """
    bits = 47 + 8 * dlc
    if stuffed:
        bits += (34 + 8 * dlc - 1) // 4
    return bits


def bus_limit(dlcs, bitrate: float = 1e6) -> tuple[float, float]:
    """Frames/s of a saturated bus carrying frames of these data lengths (a remote request
    counts 0) in these proportions: (without stuffing, with worst-case stuffing)."""
    sizes = np.asarray(dlcs, dtype=np.int64)
    plain = float(np.mean(frame_bits(sizes, False)))
    stuffed = float(np.mean(frame_bits(sizes, True)))
    return bitrate / plain, bitrate / stuffed


def data_lengths(traffic: FrameBlock) -> np.ndarray:
    """(N,) bytes of data on the wire per frame (0 for a remote request, whatever its DLC)."""
    return np.where((traffic.flags & FLAG_REMOTE) != 0, 0, traffic.dlc).astype(np.int64)


def bench_scenarios(config, scenario: str | None = None) -> tuple[Scenario, Scenario]:
    """(the bench's fault-free scenario, the same bus with faults for the latency):
    ``scenario`` (a YAML file or a shipped name) without and with its faults, else the shipped
    scenarios that play the config's bus (canfdi.tools.pairing.scenario_for).

    Raises
    ------
    NoPairing
        No shipped scenario plays the config's bus.
    ScenarioError
        ``scenario`` does not load.
    """
    from canfdi.firmware_sim.scenario import SCENARIO_DIR, load_scenario
    from canfdi.tools.pairing import scenario_for, without_faults

    if scenario is not None:
        faulty = load_scenario(scenario)
        return without_faults(faulty), faulty
    return (scenario_for(config, SCENARIO_DIR),
            scenario_for(config, SCENARIO_DIR, faults=True))


def make_traffic(frames: int, scenario: str | Scenario = "dc_motor_nominal") -> FrameBlock:
    """The first ``frames`` frames of a scenario's bus (run past its duration as needed)."""
    from canfdi.firmware_sim.emitter import frame_log
    from canfdi.firmware_sim.scenario import load_scenario

    sc = load_scenario(scenario) if isinstance(scenario, str) else scenario
    second = frame_log(sc, duration=1.0).frames.size  # frames per second of this bus
    log = frame_log(sc, duration=math.ceil(frames / max(second, 1)) + 1.0)
    return log.frames.slice(0, min(frames, log.frames.size))


def _rss_mib() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def _timed(fn: Callable[[], object]) -> tuple[float, float]:
    """(wall seconds, CPU seconds) of fn()."""
    w0, c0 = time.perf_counter(), time.process_time()
    fn()
    return time.perf_counter() - w0, time.process_time() - c0


def _feed(monitor, traffic: FrameBlock, block: int = 4096,
          on_block: Callable[[int], None] | None = None) -> None:
    n = traffic.size
    for i in range(0, n, block):
        j = min(n, i + block)
        monitor.on_frames(traffic.slice(i, j))
        if on_block is not None:
            on_block(j)


def run_bench(config, frames: int = 1_000_000, quick: bool = False,
              progress: Callable[[str], None] | None = None, workdir: Path | None = None,
              scenario: Scenario | str = "dc_motor_nominal",
              faulty: Scenario | str = "dc_motor_consecutive",
              identify: Callable | None = None, identify_config: Path | None = None,
              daemon_bus: tuple[str, str] | None = None, kernel: Kernel | None = None) -> dict:
    """Measure everything; returns the JSON-ready result.

    ``scenario`` plays the config's bus fault-free (throughput, decode, capture, replay);
    ``faulty`` plays it with faults (latency, diagnoses included). ``identify``:
    canfdi.tools.identify.identify, handed in by the verb (one verb's library does not import
    another's), timed with ``identify_config`` (the servo axis's) on a commissioning log of
    the servo axis (`identify_time`). ``daemon_bus`` (interface, channel): measure `canfdi
    run` as its own process on that bus too (canfdi.tools.daemonbench). ``kernel``: what the
    monitors measured run on (canfdi.core.kernel; by default a command's); every kernel built is
    also timed side by side (`kernel_comparison`)."""
    from canfdi.core.kernel import resolve as resolve_kernel
    from canfdi.io.writer import McapRecorder
    from canfdi.monitor import Monitor

    say = progress or (lambda msg: None)
    tmp = Path(workdir or tempfile.mkdtemp(prefix="canfdi-bench-"))
    kernel = kernel or resolve_kernel()
    out: dict = {"frames": frames, "quick": quick, "kernel": kernel.name}

    say(f"generating {frames:,} drive frames")
    traffic = make_traffic(frames, scenario)
    n = traffic.size
    sizes = data_lengths(traffic)
    plain, stuffed = bus_limit(sizes)
    out["scenario"] = getattr(scenario, "name", scenario)
    out["bus_limit_fps"] = plain
    out["bus_limit_stuffed_fps"] = stuffed
    out["frame_dlcs"] = sorted(set(sizes.tolist()))

    # -- throughput from memory: decode -> assemble -> diagnose -> record ------------------
    say("throughput from memory (decode, assemble, diagnose, record)")
    monitor = Monitor(config, kernel=kernel)  # calibration happens here, outside the timing
    log_path = tmp / "bench.mcap"
    recorder = McapRecorder(log_path, metadata=monitor.metadata())
    monitor.sink = recorder
    warm = min(n // 10, 100_000)
    rss = {}

    def mark(done: int) -> None:
        if "start" not in rss and done >= warm:
            rss["start"] = (_rss_mib(), done)

    wall, cpu = _timed(lambda: (_feed(monitor, traffic, on_block=mark), recorder.close()))
    rss_end = _rss_mib()
    out["throughput_fps"] = n / wall
    out["throughput_ratio"] = out["throughput_fps"] / plain
    out["throughput_ratio_stuffed"] = out["throughput_fps"] / stuffed
    out["cpu_s_per_1e6_frames"] = cpu / n * 1e6
    out["throughput_samples"] = monitor.samples
    out["throughput_false_alarms"] = len(monitor.events)
    r0, f0 = rss.get("start", (rss_end, n))
    measured = max(n - f0, 1)
    out["rss_growth_mib"] = (rss_end - r0) / measured * 1e6
    out["rss_measured_frames"] = measured
    out["log_bytes_per_frame"] = log_path.stat().st_size / n

    # -- replay: a long capture log (frames + samples), and the monitor log just written -----
    say("replay (block path) over a capture log and over the monitor log")
    capture_path = tmp / "long-capture.mcap"
    capturer = Monitor(config, diagnose=False)
    cap_recorder = McapRecorder(capture_path, metadata=capturer.metadata())
    capturer.sink = cap_recorder
    _feed(capturer, traffic)
    cap_recorder.close()
    out.update(_replay_rates(config, capture_path, "replay", kernel, runs=3 if quick else 5,
                             one_core=True))
    out.update(_replay_rates(config, log_path, "replay_monitor_log", kernel, runs=1,
                             one_core=False))

    # -- decode: ours (vectorised, precompiled) against cantools --------------------------
    say("decode: canfdi against cantools")
    from canfdi.bus.dbc import load_dbc

    bus_map = monitor.bus_map
    db, _ = load_dbc(config.bus.dbc, config.path)
    wall_ours, _ = _timed(lambda: bus_map.decode_frames(traffic))
    # cantools decodes every data frame of a DBC message (at the DBC's own IDs) among the first
    # frames: the whole message, as its decode does.
    msgs = {(m.frame_id, m.is_extended_frame): m for m in db.messages}
    head = traffic.slice(0, min(n, 30_000 if quick else 100_000))
    payloads = head.payloads()
    work = [(msgs[key], payloads[i]) for i, key in enumerate(zip(
        head.id.tolist(), ((head.flags & FLAG_EXTENDED) != 0).tolist(), strict=True))
        if key in msgs and not head.flags[i] & FLAG_REMOTE]
    wall_ct, _ = _timed(lambda: [m.decode(d, decode_choices=False) for m, d in work])
    sub = min(n, 30_000 if quick else 100_000)
    out["decode_fps"] = n / wall_ours
    out["cantools_decode_fps"] = len(work) / wall_ct
    out["decode_ratio_vs_cantools"] = out["decode_fps"] / out["cantools_decode_fps"]

    # -- capture: canfdi capture's path against python-can's BLF logger ---------------------
    say("capture: MCAP against python-can BLF")
    import can

    messages = traffic.to_messages(sub)
    from canfdi.service import MonitorService

    def ours(rep: int) -> Callable[[], None]:
        cap = Monitor(config, diagnose=False)  # built outside the timing
        cap_rec = McapRecorder(tmp / f"capture-{rep}.mcap", metadata=cap.metadata())
        cap.sink = cap_rec
        service = MonitorService(cap, lambda: None, status_period=0)

        def write() -> None:
            for i in range(0, sub, 4096):
                service._process(messages[i:i + 4096])
            cap_rec.close()
        return write

    def blf() -> None:
        with can.Logger(str(tmp / "capture.blf")) as logger:
            for msg in messages:
                logger.on_message_received(msg)

    # Best of three, interleaved: one timing of each swung the ratio by 30 % on this shared
    # machine, as whatever else ran slowed one side or the other.
    wall_ours = wall_blf = math.inf
    for rep in range(3):
        wall_ours = min(wall_ours, _timed(ours(rep))[0])
        wall_blf = min(wall_blf, _timed(blf)[0])
    out["capture_fps"] = sub / wall_ours
    out["python_can_blf_fps"] = sub / wall_blf
    out["capture_ratio_vs_python_can"] = out["capture_fps"] / out["python_can_blf_fps"]

    # -- over the virtual bus, and latency at 50 % load --------------------------------------
    say("over python-can's virtual bus")
    out.update(_virtual_bus(config, traffic, sub, kernel))
    say("latency at 50% bus load")
    out.update(_latency(config, plain, faulty, seconds=2.0 if quick else 6.0, kernel=kernel))
    say("the kernels side by side")
    out["kernels"] = kernel_comparison(config, traffic, make_traffic(min(n, 200_000), faulty),
                                       repeats=3)
    if identify is not None and identify_config is not None:
        minutes = 2.0 if quick else 10.0
        say(f"identify: {minutes:g} minutes of a 100 Hz drive, on one core")
        out.update(identify_time(identify, identify_config, tmp, minutes))
    if daemon_bus is not None:
        from canfdi.tools.daemonbench import daemon_figures

        out.update(daemon_figures(config, traffic, *daemon_bus, quick=quick, progress=say))
    return out


def run_daemon_bench(config, scenario: Scenario | str, interface: str, channel: str, *,
                     quick: bool = False, progress: Callable[[str], None] | None = None
                     ) -> dict:
    """The daemon measurement alone (`canfdi bench --daemon-only`): canfdi.tools.daemonbench
    on 10^5 frames of the scenario's drive, on the bus ``interface`` ``channel``."""
    from canfdi.tools.daemonbench import daemon_figures

    say = progress or (lambda msg: None)
    say("generating the drive's frames")
    return daemon_figures(config, make_traffic(100_000, scenario), interface, channel,
                          quick=quick, progress=say)


IDENTIFY_SCENARIO = "servo_axis_commissioning"


def identify_time(identify: Callable, config_path: Path, workdir: Path, minutes: float
                  ) -> dict:
    """`canfdi identify`'s whole path (read a candump log, assemble, fit with its unknown
    input, validate, learn the noise as calibrate does, design) with the config at
    ``config_path`` over ``minutes`` of the servo axis's commissioning run at 100 Hz,
    confined to one core: wall and CPU seconds."""
    import dataclasses

    from canfdi.config import load_config, read_yaml
    from canfdi.firmware_sim.emitter import frame_log
    from canfdi.firmware_sim.scenario import load_scenario
    from canfdi.io.logs import write_frames

    config = load_config(config_path, allow_unidentified=True)
    doc = read_yaml(config_path, ValueError, "config")
    scenario = dataclasses.replace(load_scenario(IDENTIFY_SCENARIO), duration=minutes * 60.0)
    log = workdir / "commissioning.log"
    write_frames(log, [frame_log(scenario).frames])
    cores = os.sched_getaffinity(0) if hasattr(os, "sched_setaffinity") else None
    if cores is not None:
        os.sched_setaffinity(0, {max(cores)})
    try:
        result: dict = {}
        wall, cpu = _timed(lambda: result.update(model=identify([log], config, doc)))
    finally:
        if cores is not None:
            os.sched_setaffinity(0, cores)
    found = result["model"].report
    return {"identify_minutes": minutes, "identify_samples": sum(found["samples"].values()),
            "identify_wall_s": wall, "identify_cpu_s": cpu, "identify_one_core": cores is not None,
            "identify_path": found["path"]}


def _replay_rates(config, path: Path, key: str, kernel: Kernel | None, runs: int,
                  one_core: bool) -> dict:
    """`canfdi replay`'s block path over a log (read, decode, assemble, residuals, detection,
    diagnosis; no recording), the median of ``runs`` runs: samples/s on every core this
    process may use (the log is read ahead on a second one), samples per CPU second of
    those runs, and, with ``one_core``, samples/s confined to one core (the reading thread
    and the monitor sharing it): the rate per core."""
    from canfdi.io.logs import frame_blocks
    from canfdi.monitor import Monitor

    def once() -> tuple[float, float, int]:
        replayer = Monitor(config, record_residuals=False, kernel=kernel)  # outside the timing

        def replay() -> None:
            for block in frame_blocks(path):
                replayer.on_frames(block)

        wall, cpu = _timed(replay)
        return wall, cpu, replayer.samples

    timed = [once() for _ in range(runs)]
    samples = timed[0][2]
    out = {
        f"{key}_samples_per_s": samples / statistics.median(w for w, _, _ in timed),
        f"{key}_samples_per_cpu_s": samples / statistics.median(c for _, c, _ in timed),
        f"{key}_samples": samples,
    }
    if one_core and hasattr(os, "sched_setaffinity"):
        cores = os.sched_getaffinity(0)
        # Threads inherit the affinity of the thread that starts them: the read-ahead thread
        # frame_blocks starts shares the one core.
        os.sched_setaffinity(0, {max(cores)})
        try:
            one = [once() for _ in range(runs)]
        finally:
            os.sched_setaffinity(0, cores)
        out[f"{key}_one_core_samples_per_s"] = samples / statistics.median(w for w, _, _ in one)
    return out


def damaged_copy(traffic: FrameBlock, seed: int = 1, share: float = 0.2) -> FrameBlock:
    """The frames with ``share`` of them damaged as a bad bus or log damages them, in equal
    parts: a bit flipped, a wrong length, another message's ID, a remote or error flag, a
    payload of garbage (deterministic for ``seed``): what the sample clocks' slow path (their
    state machine, frame by frame) meets."""
    rng = np.random.default_rng(seed)
    n = traffic.size
    data, ids = traffic.data.copy(), traffic.id.copy()
    dlc, flags = traffic.dlc.copy(), traffic.flags.copy()
    kind = np.where(rng.random(n) < share, rng.integers(0, 5, n), -1)
    rows = np.flatnonzero(kind == 0)
    data[rows, rng.integers(0, 8, rows.size)] ^= (1 << rng.integers(0, 8, rows.size)).astype(
        np.uint8)
    rows = np.flatnonzero(kind == 1)
    dlc[rows] = rng.integers(0, 9, rows.size)
    rows = np.flatnonzero(kind == 2)
    ids[rows] = rng.choice(np.unique(traffic.id), rows.size)
    rows = np.flatnonzero(kind == 3)
    flags[rows] |= rng.choice([FLAG_REMOTE, 4], rows.size).astype(np.uint8)
    rows = np.flatnonzero(kind == 4)
    data[rows] = rng.integers(0, 256, (rows.size, 8), dtype=np.uint8)
    return FrameBlock(traffic.t_ns, ids, dlc, flags, data, long=dict(traffic.long))


def kernel_comparison(config, nominal: FrameBlock, faulty: FrameBlock, repeats: int = 3
                      ) -> dict[str, dict[str, float]]:
    """Every kernel built, timed side by side on the same frames (best of ``repeats``,
    interleaved, as one shared machine's load swings one timing): decode, assemble and
    diagnose from memory, no recording, on ``nominal`` (monitoring) and ``faulty`` (with
    diagnoses); and decode and assemble alone (the sample clock's samples, no diagnosis) on
    ``nominal`` and on a fifth of it damaged (`damaged_copy`). {kernel: {"monitor_fps",
    "monitor_cpu_s_per_1e6_frames", "faulty_fps", "faults", "assemble_fps",
    "assemble_damaged_fps"}}."""
    from canfdi.core import kernel as kernels
    from canfdi.monitor import Monitor

    damaged = damaged_copy(nominal)
    best: dict[str, dict[str, float]] = {}
    for _ in range(repeats):
        for name in kernels.available():
            row = best.setdefault(name, {"monitor_fps": 0.0, "faulty_fps": 0.0,
                                         "monitor_cpu_s_per_1e6_frames": math.inf,
                                         "assemble_fps": 0.0, "assemble_damaged_fps": 0.0})
            for key, traffic in (("monitor", nominal), ("faulty", faulty)):
                monitor = Monitor(config, record_residuals=False, kernel=kernels.get(name))
                wall, cpu = _timed(lambda m=monitor, t=traffic: (_feed(m, t), m.finish()))
                row[f"{key}_fps"] = max(row[f"{key}_fps"], traffic.size / wall)
                if key == "monitor":
                    row["monitor_cpu_s_per_1e6_frames"] = min(
                        row["monitor_cpu_s_per_1e6_frames"], cpu / traffic.size * 1e6)
                else:
                    row["faults"] = float(sum(e.kind == "accepted" for e in monitor.events))
            for key, traffic in (("assemble", nominal), ("assemble_damaged", damaged)):
                clocks = [d.clock for d in Monitor(config, diagnose=False,
                                                   kernel=kernels.get(name)).drives]
                wall, _ = _timed(lambda c=clocks, t=traffic: [clock.push_batch(t) for clock in c])
                row[f"{key}_fps"] = max(row[f"{key}_fps"], traffic.size / wall)
    return best


def _virtual_bus(config, traffic: FrameBlock, count: int, kernel: Kernel | None = None) -> dict:
    """Frames/s the service consumes from a virtual bus fed as fast as python-can sends."""
    import can

    from canfdi.monitor import Monitor
    from canfdi.service import MonitorService

    channel = f"canfdi-bench-{os.getpid()}"
    messages = traffic.to_messages(count)
    monitor = Monitor(config, kernel=kernel)

    async def main() -> float:
        stop = asyncio.Event()
        service = MonitorService(monitor, lambda: can.Bus(interface="virtual", channel=channel),
                                 status_period=0)
        task = asyncio.create_task(service.run(stop))
        while service.bus is None:
            await asyncio.sleep(0.01)
        sender = can.Bus(interface="virtual", channel=channel)
        start = time.perf_counter()

        def send_all() -> None:
            for msg in messages:
                sender.send(msg)

        thread = threading.Thread(target=send_all)
        thread.start()
        while service.stats.frames < len(messages) and not task.done():
            await asyncio.sleep(0.005)
        wall = time.perf_counter() - start
        thread.join()
        sender.shutdown()
        stop.set()
        await task
        return wall

    wall = asyncio.run(main())
    return {"virtual_bus_fps": len(messages) / wall}


def _latency(config, bus_fps: float, faulty: Scenario | str, seconds: float,
             kernel: Kernel | None = None) -> dict:
    """The live service's reaction time at 50 % of the bus limit.

    The faulty scenario's frames are delivered to the service at their scheduled
    times (50 % load), each stamped on arrival; a latency is measured for every handled block
    that completed a sample: from its last frame's arrival to the end of its handling, fault
    frames sent on a virtual bus included. Frames are delivered from the monitor's own event
    loop so that a second busy Python thread (an in-process emulator) does not add its GIL
    turns to the monitor's time: on a real bus the drive is another node.
    """
    import can

    from canfdi.monitor import Monitor
    from canfdi.service import MonitorService

    frames_per_s = 0.5 * bus_fps
    count = int(frames_per_s * seconds)
    traffic = make_traffic(count, faulty)
    messages = traffic.to_messages()
    channel = f"canfdi-latency-{os.getpid()}"
    latencies: list[int] = []
    monitor = Monitor(config, kernel=kernel)
    sent_before = {}

    async def main() -> None:
        stop = asyncio.Event()
        service = MonitorService(monitor, lambda: can.Bus(interface="virtual", channel=channel),
                                 status_period=0, latencies=latencies)
        task = asyncio.create_task(service.run(stop))
        while service.bus is None:
            await asyncio.sleep(0.01)
        loop = asyncio.get_running_loop()
        start = loop.time() + 0.05
        period = 1.0 / frames_per_s
        for i, msg in enumerate(messages):
            delay = start + i * period - loop.time()
            if delay > 0:
                await asyncio.sleep(delay)
            msg.timestamp = time.time()
            service.deliver(msg)
        while service.stats.frames < len(messages) and not task.done():
            await asyncio.sleep(0.005)
        sent_before["sent"] = service.stats.sent
        stop.set()
        await task

    asyncio.run(main())
    ms = np.array(latencies) / 1e6
    return {
        "latency_p50_ms": float(np.percentile(ms, 50)) if len(ms) else float("nan"),
        "latency_p99_ms": float(np.percentile(ms, 99)) if len(ms) else float("nan"),
        "latency_mean_ms": float(statistics.fmean(ms)) if len(ms) else float("nan"),
        "latency_blocks": len(ms),
        "latency_load_fps": frames_per_s,
        "latency_faults_diagnosed": sum(e.kind == "accepted" for e in monitor.events),
        "latency_fault_frames_sent": sent_before.get("sent", 0),
    }


# ------------------------------------------------------------------------------------------
# the daemon soak: `canfdi run`'s path fed for a long time, its memory watched
# ------------------------------------------------------------------------------------------

LOOP_SAMPLES = 102_400
"""Control periods of the traffic a soak plays over and over: a multiple of 256 (the alive
counter, k mod 256, and with it the E2E CRC repeat) and of 800 (the DC motor's speed reference,
a square wave of 8 s at 100 Hz), so that every frame of a repeat is the one the drive sends at
that time; 1024 s of the drive."""

SOAK_WARMUP_FRAMES = 2_000_000
"""Frames a soak runs before its reference RSS is taken (caches, arenas, the first segments)."""


def loop_traffic(scenario: Scenario | str, samples: int = LOOP_SAMPLES,
                 search: int = 6400) -> tuple[FrameBlock, int]:
    """``samples`` control periods of a scenario's bus that play seamlessly over and over.

    Repeat r of the stretch is sent ``r * samples * dt`` later: its counters and CRCs are those
    of the drive at that time when ``samples`` is a multiple of their period. The plant's state
    does not come back exactly (noise, the controller's dither), so the stretch starts where it
    comes back closest: among the first ``search`` periods, the start a whose state x(a) is
    nearest x(a + samples) (each state scaled by its spread), so that at the seam the frames
    jump by as little as possible from what the drive would send next.

    Returns
    -------
    (FrameBlock, int)
        The frames of periods a .. a + samples - 1, stamped as generated, and the time in ns
        to add to them per repeat (``samples * dt``).
    """
    from canfdi.firmware_sim.emitter import frame_log
    from canfdi.firmware_sim.scenario import load_scenario

    sc = load_scenario(scenario) if isinstance(scenario, str) else scenario
    probe = frame_log(sc, duration=1.0)
    dt = float(probe.chunk.t[1] - probe.chunk.t[0])
    log = frame_log(sc, duration=(samples + search) * dt)
    # (periods, states of every drive) and how far each state is from its value one stretch on
    x = np.hstack([d.chunk.x for d in log.drives])
    scale = np.maximum(x.std(axis=0), 1e-12)
    miss = np.linalg.norm((x[samples:samples + search] - x[:search]) / scale, axis=1)
    start = int(np.argmin(miss))
    period_ns = round(samples * dt * 1e9)
    t0 = log.chunk.k[0] * dt  # 0: a stretch's periods are k = start ..
    lo, hi = np.searchsorted(log.frames.t_ns, [round((t0 + start * dt) * 1e9),
                                               round((t0 + start * dt) * 1e9) + period_ns])
    return log.frames.slice(int(lo), int(hi)), period_ns


def _verify_segment(path: str, delete: bool) -> tuple[str, int, str | None]:
    """(file name, frames in it, None or what is wrong with it) for one closed segment of a
    soak's log, read alone with canfdi's reader (every chunk's CRC checked); the file is
    deleted afterwards when ``delete``. Runs in a worker process, whose memory is not the
    monitor's."""
    from canfdi.io.damage import Damage
    from canfdi.io.reader import iter_frame_blocks
    from canfdi.io.scan import MAGIC

    damage = Damage()
    problem = None
    frames = 0
    try:
        for block in iter_frame_blocks(path, segments=False, damage=damage):
            frames += block.size
        with open(path, "rb") as f:
            f.seek(-len(MAGIC), os.SEEK_END)
            if f.read() != MAGIC:
                problem = "no footer (not closed cleanly)"
    except (OSError, ValueError) as exc:
        problem = str(exc)
    if damage:
        problem = "; ".join(damage.lines())
    if delete:
        Path(path).unlink(missing_ok=True)
    return Path(path).name, frames, problem


def soak_frames_missing(r: dict) -> int:
    """Frames of a `run_daemon_soak` (its result ``r``) that reached neither its rotated
    segments nor the count of messages it dropped: more than 0, or an unreadable segment, and
    its log does not check out."""
    return r["daemon_frames"] - r["daemon_messages_dropped"] - r["daemon_frames_in_segments"]


def run_daemon_soak(config, frames: int, rotate_bytes: int,
                    scenario: Scenario | str = "dc_motor_nominal",
                    progress: Callable[[str], None] | None = None,
                    workdir: Path | None = None, warmup: int = SOAK_WARMUP_FRAMES,
                    keep_segments: bool = False, loop_samples: int = LOOP_SAMPLES) -> dict:
    """`canfdi run`'s path fed ``frames`` frames as fast as it takes them; its RSS and its log.

    The service's own handling: python-can Messages, made fresh for every block of
    ``MonitorService.block`` frames as a bus would deliver them, through
    ``MonitorService._process`` (FrameBlock.from_messages, the monitor, the recorder), with
    the recorder `canfdi run` opens (the config's rotation by time, by size ``rotate_bytes``).
    The traffic is `loop_traffic` (``loop_samples`` periods) played over and over. RSS is
    read after every block from ``warmup`` frames on (the reference), and each segment, once
    closed, is read back whole by a worker process (frames counted, every chunk's CRC
    checked, the footer present) and deleted unless ``keep_segments``: the disk holds about
    two segments at a time.

    Returns the JSON-ready result (keys ``daemon_*``).
    """
    import collections
    import concurrent.futures
    import multiprocessing

    from canfdi.io.segments import segment_path
    from canfdi.io.writer import McapRecorder
    from canfdi.monitor import Monitor
    from canfdi.service import MonitorService

    say = progress or (lambda msg: None)
    tmp = Path(workdir or tempfile.mkdtemp(prefix="canfdi-soak-"))
    warmup = min(warmup, frames // 5)
    say(f"generating {loop_samples:,} control periods to play over and over")
    loop, period_ns = loop_traffic(scenario, loop_samples)
    monitor = Monitor(config)
    log = tmp / f"{config.name}-soak.mcap"
    recorder = McapRecorder(log, metadata=monitor.metadata(),
                            rotate_bytes=rotate_bytes,
                            rotate_seconds=config.recording.rotate_minutes * 60.0)
    monitor.sink = recorder
    service = MonitorService(monitor, lambda: None, status_period=0)
    block = service.block
    # One worker reads the closed segments back while the monitor runs.
    pool = concurrent.futures.ProcessPoolExecutor(
        max_workers=1, mp_context=multiprocessing.get_context("spawn"))
    # The harness's own memory stays constant too: results are folded in as they arrive, and
    # the RSS series (frames fed, MiB: at warm-up, every 1 % of the run, at the end) is
    # allocated up front.
    pending: collections.deque[concurrent.futures.Future] = collections.deque()
    submitted = verified = in_segments = 0
    unreadable: dict[str, str] = {}

    def check(upto: int) -> None:
        nonlocal submitted
        while submitted < upto:
            pending.append(pool.submit(_verify_segment, str(segment_path(log, submitted)),
                                       not keep_segments))
            submitted += 1

    def fold(wait: bool) -> None:
        nonlocal verified, in_segments
        while pending and (wait or pending[0].done()):
            name, count, problem = pending.popleft().result()
            verified += 1
            in_segments += count
            if problem:
                unreadable[name] = problem

    series = np.zeros((102, 2))
    points = 0
    every = max(frames // 100, 1)
    rss_start = rss_max = rss_now = math.nan
    fed = in_service = 0
    say(f"feeding {frames:,} frames through the service, segments of "
        f"{rotate_bytes / 2**20:g} MiB")
    start = time.perf_counter()
    repeat = 0
    while fed < frames:
        shift = repeat * period_ns
        for i in range(0, loop.size, block):
            j = min(loop.size, i + block, i + frames - fed)
            part = loop.slice(i, j)
            messages = FrameBlock(part.t_ns + shift, part.id, part.dlc, part.flags,
                                  part.data).to_messages()
            t0 = time.perf_counter()
            service._process(messages)
            in_service += time.perf_counter() - t0
            del messages
            before = fed
            fed += j - i
            if fed >= warmup:
                rss_now = _rss_mib()
                if math.isnan(rss_start):
                    rss_start = rss_max = rss_now
                    series[points] = fed, rss_now
                    points += 1
                rss_max = max(rss_max, rss_now)
                if (fed // every != before // every or fed >= frames) and points < len(series):
                    series[points] = fed, rss_now
                    points += 1
                if fed // (10 * every) != before // (10 * every):
                    say(f"{fed:,} frames, RSS {rss_now:.2f} MiB "
                        f"({rss_now - rss_start:+.2f} since warm-up)")
            check(recorder.segments - 1)  # every segment but the open one
            fold(wait=False)
            if fed >= frames:
                break
        repeat += 1
    wall = time.perf_counter() - start
    monitor.finish()
    recorder.close()
    check(recorder.segments)
    say(f"verifying the last of {recorder.segments} segments")
    fold(wait=True)
    pool.shutdown()
    if workdir is None and not keep_segments:
        tmp.rmdir()  # every segment was deleted once read back
    stats = monitor.frame_stats
    return {
        "daemon_frames": fed,
        "daemon_scenario": getattr(scenario, "name", scenario),
        "daemon_loop_samples": loop_samples,
        "daemon_loop_frames": loop.size,
        "daemon_fps": fed / wall,
        "daemon_service_fps": fed / in_service,
        "daemon_seconds": wall,
        "daemon_samples": monitor.samples,
        "daemon_false_alarms": len(monitor.events),
        "daemon_frame_stats": stats,
        "daemon_rss_warmup_frames": warmup,
        "daemon_rss_start_mib": rss_start,
        "daemon_rss_max_mib": rss_max,
        "daemon_rss_end_mib": rss_now,
        "daemon_rss_max_growth_mib": rss_max - rss_start,
        "daemon_rss_end_growth_mib": rss_now - rss_start,
        "daemon_rss_series": [[int(f), round(float(m), 3)] for f, m in series[:points]],
        "daemon_rotate_mib": rotate_bytes / 2**20,
        "daemon_segments": recorder.segments,
        "daemon_log_bytes": recorder.bytes_written,
        "daemon_segments_verified": verified,
        "daemon_frames_in_segments": in_segments,
        "daemon_messages_dropped": recorder.messages_dropped,
        "daemon_unreadable_segments": unreadable,
        "daemon_segments_kept": keep_segments,
        "daemon_log_dir": str(tmp) if keep_segments or workdir is not None else None,
    }

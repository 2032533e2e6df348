"""The drive firmware on a bus: a scenario's frames, published through python-can.

Every control period k the drive sends each of its DBC messages once (sender DRIVE), carrying
the command u_c(k), the measurements z(k) and the references, with the alive counter k mod 256
and the E2E CRC (dbc/README.md). Frames are encoded a block of samples at a time with the
precompiled layouts of canfdi.bus.codec; sending is paced in real time (``speed`` 1), faster
(``speed`` N) or as fast as the bus takes them (``speed`` 0).

For tests, frames can be dropped, delayed (jitter), sent with a wrong CRC or a wrong DLC.
`frame_log` gives the same frames without a bus, as arrays stamped with their ideal arrival
times (offline tests and evaluations: no pacing, no event loop).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import can
import numpy as np

from canfdi import dbc as dbc_files
from canfdi.bus.codec import MessageLayout, compile_layout
from canfdi.bus.e2e import protect_batch
from canfdi.bus.frames import FrameBlock
from firmware_sim.plants import Plant
from firmware_sim.scenario import Scenario
from firmware_sim.simulate import SimChunk, Simulator

__all__ = ["Disturbance", "EmitStats", "FrameEncoder", "FrameLog", "emit", "frame_log"]

log = logging.getLogger("firmware_sim.emitter")

_E2E_SIGNALS = {"CRC", "Counter"}


@dataclass(frozen=True)
class Disturbance:
    """Bus misbehaviour to inject, per frame (probabilities) and per sample (jitter, seconds)."""

    drop: float = 0.0
    jitter: float = 0.0
    bad_crc: float = 0.0
    wrong_dlc: float = 0.0
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("drop", "bad_crc", "wrong_dlc"):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"{name}: a probability in [0, 1], got {value}")
        if self.jitter < 0:
            raise ValueError(f"jitter: must be >= 0 seconds, got {self.jitter}")

    @property
    def active(self) -> bool:
        return bool(self.drop or self.jitter or self.bad_crc or self.wrong_dlc)


@dataclass
class EmitStats:
    """What the emitter did."""

    samples: int = 0
    frames_sent: int = 0
    frames_dropped: int = 0
    frames_bad_crc: int = 0
    frames_wrong_dlc: int = 0
    send_retries: int = 0
    reopens: int = 0
    clipped: dict[str, int] = field(default_factory=dict)
    elapsed: float = 0.0

    def as_dict(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


class FrameEncoder:
    """Turns simulated samples into the drive's protected frames, a block at a time.

    The DBC is the contract: every signal of a DRIVE message other than CRC and Counter must be
    one of the plant's input, output or reference names.
    """

    def __init__(self, plant: Plant, database=None) -> None:
        database = database or dbc_files.load(plant.dbc)
        sources = {}
        for j, name in enumerate(plant.input_names):
            sources[name] = ("u_c", j)
        for j, name in enumerate(plant.output_names):
            sources[name] = ("z", j)
        for j, name in enumerate(plant.reference_names):
            sources[name] = ("ref", j)
        self.layouts: list[MessageLayout] = []
        self._sources: list[list[tuple[str, str, int]]] = []
        for message in sorted(database.messages, key=lambda m: m.frame_id):
            if "DRIVE" not in (message.senders or []):
                continue
            layout = compile_layout(message)
            mapping = []
            for sig in layout.signals:
                if sig.name in _E2E_SIGNALS:
                    continue
                if sig.name not in sources:
                    raise ValueError(f"{plant.dbc}: {message.name}.{sig.name} is not an input, "
                                     f"output or reference of {plant.name}")
                mapping.append((sig.name, *sources[sig.name]))
            self.layouts.append(layout)
            self._sources.append(mapping)
        if not self.layouts:
            raise ValueError(f"{plant.dbc}: no message is sent by DRIVE")

    def encode(self, chunk: SimChunk) -> tuple[list[np.ndarray], dict[str, int]]:
        """Protected payloads of every drive message for every sample of the chunk.

        Returns
        -------
        payloads : one (N, dlc) uint8 array per message, in ``self.layouts`` order.
        clipped : signal name -> number of values clipped to the DBC range.
        """
        n = len(chunk)
        counters = chunk.k.astype(np.int64) & 0xFF
        out, clipped = [], {}
        for layout, mapping in zip(self.layouts, self._sources, strict=True):
            values = {name: getattr(chunk, src)[:, j] for name, src, j in mapping}
            payload, clip = layout.encode(values, n)
            for name, count in clip.items():
                clipped[name] = clipped.get(name, 0) + count
            out.append(protect_batch(layout.frame_id, payload, counters))
        return out, clipped


class _Link:
    """The emitter's bus, reopened through ``reopen`` when its interface goes away."""

    def __init__(self, bus: can.BusABC, reopen: Callable[[], can.BusABC] | None) -> None:
        self.bus = bus
        self.reopen = reopen
        self.opened: list[can.BusABC] = []

    async def send(self, msg: can.Message, stats: EmitStats) -> None:
        # SocketCAN answers ENOBUFS when its transmit queue is full and ENETDOWN while the link
        # is down: wait and retry rather than lose the frame. A deleted and re-added interface
        # needs a new socket (the old one is bound to the old interface index): reopen.
        for attempt in range(400):
            try:
                self.bus.send(msg)
                return
            except (can.CanOperationError, OSError):
                stats.send_retries += 1
                await asyncio.sleep(0.001 * min(attempt + 1, 25))
                if self.reopen is not None and attempt % 40 == 39:
                    with contextlib.suppress(can.CanError, OSError):
                        fresh = self.reopen()
                        self.opened.append(fresh)
                        self.bus = fresh
                        stats.reopens += 1
                        log.warning("bus reopened after send failures")
        raise can.CanOperationError(f"could not send 0x{msg.arbitration_id:X} after 400 tries")

    def close_reopened(self) -> None:
        for bus in self.opened:
            with contextlib.suppress(Exception):
                bus.shutdown()


async def emit(
    bus: can.BusABC,
    scenario: Scenario,
    *,
    speed: float = 1.0,
    duration: float | None = None,
    disturbance: Disturbance | None = None,
    block: int = 256,
    on_block: Callable[[SimChunk, EmitStats], None] | None = None,
    stop: asyncio.Event | None = None,
    reopen: Callable[[], can.BusABC] | None = None,
) -> EmitStats:
    """Publish a scenario's frames on ``bus``.

    Parameters
    ----------
    speed : 1 real time, N times real time, 0 as fast as the bus accepts frames.
    duration : seconds to run (default: the scenario's duration).
    disturbance : drops, jitter and corruption to inject (none by default).
    block : samples simulated and encoded per step.
    on_block : called after each block is sent (progress reporting).
    stop : set it to end the run early (orderly: the current sample is completed).
    reopen : opens the bus again when sending keeps failing (an interface deleted and re-added);
        buses it opens are shut down at the end, ``bus`` stays the caller's.
    """
    if speed < 0:
        raise ValueError(f"speed: must be >= 0, got {speed}")
    disturbance = disturbance or Disturbance()
    rng = np.random.default_rng(disturbance.seed)
    sim = Simulator(scenario)
    encoder = FrameEncoder(sim.plant)
    dt = sim.plant.dt
    total = sim.total_samples if duration is None else round(duration / dt)
    stats = EmitStats()
    loop = asyncio.get_running_loop()
    t0 = loop.time()
    wall0 = time.perf_counter()
    link = _Link(bus, reopen)
    try:
        while sim.k < total and not (stop is not None and stop.is_set()):
            chunk = sim.advance(min(block, total - sim.k))
            payloads, clipped = encoder.encode(chunk)
            for name, count in clipped.items():
                if name not in stats.clipped:
                    log.warning("signal %s clipped to its DBC range", name)
                stats.clipped[name] = stats.clipped.get(name, 0) + count
            for i, k in enumerate(chunk.k):
                if speed > 0:
                    delay = t0 + k * dt / speed - loop.time()
                    if disturbance.jitter:
                        delay += rng.uniform(0.0, disturbance.jitter)
                    if delay > 0:
                        await asyncio.sleep(delay)
                elif i % 32 == 0:
                    await asyncio.sleep(0)  # let the rest of the loop (a monitor, say) run
                for layout, payload in zip(encoder.layouts, payloads, strict=True):
                    data = payload[i].tobytes()
                    if disturbance.active:
                        u = rng.random(3)
                        if u[0] < disturbance.drop:
                            stats.frames_dropped += 1
                            continue
                        if u[1] < disturbance.bad_crc:
                            data = bytes([data[0] ^ 0xFF]) + data[1:]
                            stats.frames_bad_crc += 1
                        if u[2] < disturbance.wrong_dlc:
                            data = data[:-1] if len(data) > 2 else data + b"\x00"
                            stats.frames_wrong_dlc += 1
                    msg = can.Message(arbitration_id=layout.frame_id, data=data,
                                      is_extended_id=False, timestamp=time.time())
                    await link.send(msg, stats)
                    stats.frames_sent += 1
                stats.samples += 1
            if on_block is not None:
                on_block(chunk, stats)
    finally:
        link.close_reopened()
    stats.elapsed = time.perf_counter() - wall0
    return stats


@dataclass(frozen=True)
class FrameLog:
    """A scenario's drive frames as arrays, in arrival order.

    frames : the frames (canfdi.bus.frames.FrameBlock), sample k's from k dt on;
    stats : what was injected; truth : the scenario's injected faults; chunk : the simulated
    run.
    """

    frames: FrameBlock
    stats: EmitStats
    truth: list[dict]
    chunk: SimChunk


def frame_log(scenario: Scenario, disturbance: Disturbance | None = None,
              duration: float | None = None, frame_spacing: float = 130e-6) -> FrameLog:
    """The frames ``emit`` would send for a scenario, with its disturbance, without a bus.

    Sample k's messages leave at k dt + i ``frame_spacing`` (i: the message's place, ID order;
    130 us is one 8-byte frame at 1 Mbit/s); jitter delays each frame independently by
    U(0, jitter) seconds, so frames of a period can arrive reordered. Drops, bad CRCs and wrong
    DLCs are drawn per frame as in ``emit``.
    """
    disturbance = disturbance or Disturbance()
    sim = Simulator(scenario)
    total = sim.total_samples if duration is None else round(duration / sim.plant.dt)
    chunk = sim.advance(total)
    encoder = FrameEncoder(sim.plant)
    payloads, clipped = encoder.encode(chunk)
    n, m = len(chunk), len(payloads)
    rng = np.random.default_rng(disturbance.seed)
    base = np.round(chunk.k * sim.plant.dt * 1e9).astype(np.int64)
    t = base[:, None] + np.round(np.arange(m) * frame_spacing * 1e9).astype(np.int64)
    if disturbance.jitter:
        t = t + np.round(rng.uniform(0.0, disturbance.jitter, (n, m)) * 1e9).astype(np.int64)
    ids = np.broadcast_to([lay.frame_id for lay in encoder.layouts], (n, m))
    dlc = np.broadcast_to([p.shape[1] for p in payloads], (n, m)).copy()
    data = np.zeros((n, m, 8), dtype=np.uint8)
    for i, p in enumerate(payloads):
        data[:, i, : p.shape[1]] = p
    stats = EmitStats(samples=n, clipped=clipped)
    u = rng.random((n, m, 3))
    keep = u[..., 0] >= disturbance.drop
    bad_crc = keep & (u[..., 1] < disturbance.bad_crc)
    data[..., 0] ^= np.where(bad_crc, 0xFF, 0).astype(np.uint8)
    wrong = keep & (u[..., 2] < disturbance.wrong_dlc)
    dlc = np.where(wrong, np.where(dlc > 2, dlc - 1, dlc + 1), dlc)
    stats.frames_dropped = int((~keep).sum())
    stats.frames_bad_crc = int(bad_crc.sum())
    stats.frames_wrong_dlc = int(wrong.sum())
    stats.frames_sent = int(keep.sum())
    order = np.argsort(t[keep], kind="stable")
    n_kept = int(keep.sum())
    frames = FrameBlock(t[keep][order], ids[keep][order], dlc[keep][order],
                        np.zeros(n_kept, dtype=np.uint8), data[keep][order])
    return FrameLog(frames=frames, stats=stats, truth=sim.truth(), chunk=chunk)

"""The drives on a bus: a scenario's frames, published through python-can.

The scenario's bus profile (profiles/: canfdi by default, cia402, float_node) says
which frames each control period carries, when within the period, and what each holds: on
canfdi's own bus, every DBC message of the drive once per period with the alive counter
k mod 256 and the E2E CRC (dbc/README.md); on a CANopen bus, SYNC, the master's RPDOs, the
drives' TPDOs and heartbeats; on a node-ID float bus, estimates, RTR polls and answers,
setpoints. Several drives of one scenario (``drives:``) share the bus, their frames
interleaved in time. Frames are encoded a block of samples at a time (numpy); sending is paced
in real time (``speed`` 1), faster (``speed`` N) or as fast as the bus takes them
(``speed`` 0).

For tests, frames can be dropped, delayed (jitter), sent with a wrong CRC (profiles with a
CRC) or a wrong DLC (data frames). `frame_log` gives the same frames without a bus, as a
FrameBlock stamped with their ideal arrival times (offline tests and evaluations: no pacing, no
event loop).
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

from canfdi.bus.frames import FLAG_REMOTE, FrameBlock
from canfdi.firmware_sim.chunk import SimChunk
from canfdi.firmware_sim.profiles import BusProfile, Slot, get_profile
from canfdi.firmware_sim.profiles.canfdi import FrameEncoder
from canfdi.firmware_sim.scenario import Scenario
from canfdi.firmware_sim.simulate import Simulator

__all__ = ["Disturbance", "DriveLog", "EmitStats", "FrameEncoder", "FrameLog", "emit",
           "frame_log"]

log = logging.getLogger("canfdi.firmware_sim.emitter")

FRAME_SPACING = 130e-6
"""Seconds between frames sent back to back (one 8-byte frame at 1 Mbit/s)."""
_BURST = 0.5e-3
"""A paced `emit` sends a frame due within this many seconds at once (asyncio sleeps are
millisecond-coarse); the first frame of a period is always waited for."""


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
    profile: str = "canfdi"

    def as_dict(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


class _Bus:
    """A scenario's drives, simulated side by side, and its profile's encoder."""

    def __init__(self, scenario: Scenario, frame_spacing: float,
                 disturbance: Disturbance) -> None:
        self.profile: BusProfile = get_profile(scenario.profile)
        self.sims = [Simulator(scenario.drive_scenario(i)) for i in range(len(scenario.drives))]
        self.plant = self.sims[0].plant
        self.encoder = self.profile.encoder(self.plant, [d.node for d in scenario.drives],
                                            frame_spacing)
        self.slots: tuple[Slot, ...] = self.encoder.slots
        if disturbance.bad_crc and not any(slot.crc for slot in self.slots):
            raise ValueError(f"bad_crc: the {self.profile.name} profile's frames carry no CRC")
        self.every = np.array([slot.every for slot in self.slots])
        self.phase = np.array([slot.phase for slot in self.slots])

    @property
    def k(self) -> int:
        return self.sims[0].k

    @property
    def total_samples(self) -> int:
        return self.sims[0].total_samples

    def advance(self, count: int) -> tuple[list[SimChunk], np.ndarray, dict[str, int]]:
        """Every drive's next ``count`` samples and the (count, slots, 8) payloads."""
        chunks = [sim.advance(count) for sim in self.sims]
        data, clipped = self.encoder.encode(chunks)
        return chunks, data, clipped

    def scheduled(self, k: np.ndarray) -> np.ndarray:
        """(N, slots) bool: which slot is sent in which period."""
        return (np.asarray(k)[:, None] % self.every) == self.phase


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


def _count_clipped(stats: EmitStats, clipped: dict[str, int]) -> None:
    """Add a block's clipped signals to the run's; a signal's first clipping is logged."""
    for name, count in clipped.items():
        if name not in stats.clipped:
            log.warning("signal %s clipped to its DBC range", name)
        stats.clipped[name] = stats.clipped.get(name, 0) + count


def _disturbed(payload: bytes, slot: Slot, u: np.ndarray, disturbance: Disturbance,
               stats: EmitStats) -> bytes | None:
    """One frame's payload after the disturbance, or None when it is dropped.

    ``u`` holds the frame's three uniform draws (drop, bad CRC, wrong DLC); what was injected is
    counted in ``stats``.
    """
    if u[0] < disturbance.drop:
        stats.frames_dropped += 1
        return None
    if slot.crc and u[1] < disturbance.bad_crc:
        payload = bytes([payload[0] ^ 0xFF]) + payload[1:]
        stats.frames_bad_crc += 1
    if not slot.remote and u[2] < disturbance.wrong_dlc:
        payload = payload[:-1] if len(payload) > 2 else payload + b"\x00"
        stats.frames_wrong_dlc += 1
    return payload


def _message(slot: Slot, payload: bytes, stamp: float) -> can.Message:
    """The python-can message of one slot's frame (a remote frame carries the slot's DLC)."""
    if slot.remote:
        return can.Message(arbitration_id=slot.frame_id, is_remote_frame=True, dlc=slot.dlc,
                           is_extended_id=False, timestamp=stamp)
    return can.Message(arbitration_id=slot.frame_id, data=payload, is_extended_id=False,
                       timestamp=stamp)


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
    frame_spacing: float = FRAME_SPACING,
) -> EmitStats:
    """Publish a scenario's frames (its bus profile's, every drive's) on ``bus``.

    Parameters
    ----------
    speed : 1 real time, N times real time, 0 as fast as the bus accepts frames. Frames carry
        the time they are sent, except at speed 0, where they carry the time they would leave
        at in real time (the run's start plus k dt plus the slot's offset): a bus that keeps
        the sender's timestamps (python-can's virtual bus with ``preserve_timestamps=True``)
        then shows a receiver the drive's timing, which a time-grid sample clock needs.
    duration : seconds to run (default: the scenario's duration).
    disturbance : drops, jitter and corruption to inject (none by default).
    block : samples simulated and encoded per step.
    on_block : called after each block is sent (progress reporting), with the first drive's
        chunk.
    stop : set it to end the run early (orderly: the current sample is completed).
    reopen : opens the bus again when sending keeps failing (an interface deleted and re-added);
        buses it opens are shut down at the end, ``bus`` stays the caller's.
    frame_spacing : the profile lays out a period's frames this many seconds apart; a paced
        run sends each frame at its offset (frames due within 0.5 ms of each other leave back
        to back).

    Raises
    ------
    ValueError : a ``bad_crc`` disturbance on a profile without CRC.
    """
    if speed < 0:
        raise ValueError(f"speed: must be >= 0, got {speed}")
    disturbance = disturbance or Disturbance()
    rng = np.random.default_rng(disturbance.seed)
    run = _Bus(scenario, frame_spacing, disturbance)
    slots = run.slots
    dt = run.plant.dt
    total = run.total_samples if duration is None else round(duration / dt)
    stats = EmitStats(profile=run.profile.name)
    loop = asyncio.get_running_loop()
    t0 = loop.time()
    epoch0 = time.time()
    wall0 = time.perf_counter()
    link = _Link(bus, reopen)
    try:
        while run.k < total and not (stop is not None and stop.is_set()):
            chunks, data, clipped = run.advance(min(block, total - run.k))
            chunk = chunks[0]
            _count_clipped(stats, clipped)
            scheduled = run.scheduled(chunk.k)
            for i, k in enumerate(chunk.k):
                start = 0.0
                if speed > 0:
                    start = t0 + k * dt / speed
                    if disturbance.jitter:
                        start += rng.uniform(0.0, disturbance.jitter)
                elif i % 32 == 0:
                    await asyncio.sleep(0)  # let the rest of the loop (a monitor, say) run
                # One draw per slot, sent this period or not: the stream frame_log draws.
                u = rng.random((len(slots), 3)) if disturbance.active else None
                first = True
                for j, slot in enumerate(slots):
                    if not scheduled[i, j]:
                        continue
                    if speed > 0:
                        delay = start + slot.offset / speed - loop.time()
                        if delay > _BURST or (first and delay > 0):
                            await asyncio.sleep(delay)
                    first = False
                    payload = data[i, j, : slot.dlc].tobytes()
                    if u is not None:
                        payload = _disturbed(payload, slot, u[j], disturbance, stats)
                        if payload is None:
                            continue
                    stamp = time.time() if speed > 0 else epoch0 + k * dt + slot.offset
                    await link.send(_message(slot, payload, stamp), stats)
                    stats.frames_sent += 1
                stats.samples += 1
            if on_block is not None:
                on_block(chunk, stats)
    finally:
        link.close_reopened()
    stats.elapsed = time.perf_counter() - wall0
    return stats


@dataclass(frozen=True)
class DriveLog:
    """One drive of a FrameLog: its name and node, its injected faults, its simulated run."""

    name: str
    node: int | None
    truth: list[dict]
    chunk: SimChunk


@dataclass(frozen=True)
class FrameLog:
    """A scenario's bus frames as arrays, in arrival order.

    frames : the frames (canfdi.bus.frames.FrameBlock; remote frames flagged FLAG_REMOTE,
    with the requested DLC and zero data), sample k's from k dt on; stats : what was
    injected; truth : the (first) drive's injected faults; chunk : its simulated run;
    drives : every drive's (name, node, truth, chunk), in the scenario's order; profile : the
    bus profile's name; slots : the profile's frames of one period (canfdi.firmware_sim.profiles).
    """

    frames: FrameBlock
    stats: EmitStats
    truth: list[dict]
    chunk: SimChunk
    drives: tuple[DriveLog, ...] = ()
    profile: str = "canfdi"
    slots: tuple[Slot, ...] = ()


def frame_log(scenario: Scenario, disturbance: Disturbance | None = None,
              duration: float | None = None, frame_spacing: float = FRAME_SPACING) -> FrameLog:
    """The frames ``emit`` would send for a scenario, with its disturbance, without a bus.

    Sample k's frames leave at k dt + their slot's offset (the profile's layout, frames
    ``frame_spacing`` apart; canfdi: the i-th message in ID order at i ``frame_spacing``;
    130 us is one 8-byte frame at 1 Mbit/s); jitter delays each frame independently by
    U(0, jitter) seconds, so frames of a period can arrive reordered. Drops, bad CRCs and wrong
    DLCs are drawn per frame as in ``emit``.
    """
    disturbance = disturbance or Disturbance()
    run = _Bus(scenario, frame_spacing, disturbance)
    dt = run.plant.dt
    total = run.total_samples if duration is None else round(duration / dt)
    chunks, data, clipped = run.advance(total)
    chunk = chunks[0]
    slots = run.slots
    n, m = len(chunk), len(slots)
    rng = np.random.default_rng(disturbance.seed)
    base = np.round(chunk.k * dt * 1e9).astype(np.int64)
    offsets = np.round(np.array([slot.offset for slot in slots]) * 1e9).astype(np.int64)
    t = base[:, None] + offsets
    if disturbance.jitter:
        t = t + np.round(rng.uniform(0.0, disturbance.jitter, (n, m)) * 1e9).astype(np.int64)
    ids = np.broadcast_to([slot.frame_id for slot in slots], (n, m))
    dlc = np.broadcast_to([slot.dlc for slot in slots], (n, m)).copy()
    remote = np.array([slot.remote for slot in slots])
    flags = np.broadcast_to(np.where(remote, FLAG_REMOTE, 0), (n, m))
    has_crc = np.array([slot.crc for slot in slots])
    scheduled = run.scheduled(chunk.k)
    stats = EmitStats(samples=n, clipped=clipped, profile=run.profile.name)
    u = rng.random((n, m, 3))
    keep = scheduled & (u[..., 0] >= disturbance.drop)
    bad_crc = keep & has_crc & (u[..., 1] < disturbance.bad_crc)
    data[..., 0] ^= np.where(bad_crc, 0xFF, 0).astype(np.uint8)
    wrong = keep & ~remote & (u[..., 2] < disturbance.wrong_dlc)
    dlc = np.where(wrong, np.where(dlc > 2, dlc - 1, dlc + 1), dlc)
    stats.frames_dropped = int((scheduled & ~keep).sum())
    stats.frames_bad_crc = int(bad_crc.sum())
    stats.frames_wrong_dlc = int(wrong.sum())
    stats.frames_sent = int(keep.sum())
    order = np.argsort(t[keep], kind="stable")
    frames = FrameBlock(t[keep][order], ids[keep][order], dlc[keep][order],
                        flags[keep][order], data[keep][order])
    drives = tuple(DriveLog(name=d.name, node=d.node, truth=sim.truth(), chunk=c)
                   for d, sim, c in zip(scenario.drives, run.sims, chunks, strict=True))
    return FrameLog(frames=frames, stats=stats, truth=drives[0].truth, chunk=chunk,
                    drives=drives, profile=run.profile.name, slots=slots)

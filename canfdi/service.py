"""The asyncio shell around the Monitor: bus, bridge, fault frames, heartbeat, signals.

python-can delivers frames from its own reader (a thread, or the loop's reader for socket
buses); `BusBridge` puts frames AND bus errors on an asyncio.Queue (python-can's
AsyncBufferedReader would wait forever on a dead bus). `MonitorService.run` consumes the queue,
feeds the Monitor, sends its fault frames, sends FDI_STATUS every status period (state
"degraded" while the recorder cannot write: diagnosis and fault frames go on), reopens a lost
bus with exponential backoff, and on stop closes the bus (the source) before the recorder (the
sink), so the log holds everything that was received.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import socket
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import can

from canfdi.bus.frames import FrameBlock
from canfdi.bus.traffic import TrafficChange, TrafficWatch
from canfdi.monitor import Monitor, OutFrame

__all__ = ["BusBridge", "MonitorService", "ServiceStats", "open_bus"]

log = logging.getLogger("canfdi.service")


def open_bus(interface: str, channel: str, bitrate: int | None = None,
             receive_own_messages: bool = False, **extra: Any) -> can.BusABC:
    """A python-can bus (``extra``: further keyword arguments of its interface, such as
    ``fd`` and ``data_bitrate``). python-can adds what its own configuration (``CAN_CONFIG``,
    can.conf) gives for the keys not passed here."""
    kwargs: dict = {"interface": interface, "channel": channel, **extra}
    if bitrate is not None:
        kwargs["bitrate"] = bitrate
    if receive_own_messages:
        kwargs["receive_own_messages"] = True
    bus = can.Bus(**kwargs)
    _enlarge_receive_buffer(bus)
    return bus


# A SocketCAN socket's default receive buffer (about 200 KiB) holds well under a second of a
# saturated bus; a monitor busy for a moment (GC, a slow disk, a loaded host) must not lose
# frames in the kernel.
RECEIVE_BUFFER_BYTES = 8 * 2**20


def _enlarge_receive_buffer(bus: can.BusABC) -> None:
    sock = getattr(bus, "socket", None)
    if not isinstance(sock, socket.socket):
        return
    # SO_RCVBUFFORCE passes net.core.rmem_max when privileged (CAP_NET_ADMIN); else SO_RCVBUF
    # up to it. Python's socket module does not name SO_RCVBUFFORCE: Linux's value is 33.
    force = getattr(socket, "SO_RCVBUFFORCE", 33 if sys.platform.startswith("linux") else None)
    for option in (force, socket.SO_RCVBUF):
        if option is None:
            continue
        try:
            sock.setsockopt(socket.SOL_SOCKET, option, RECEIVE_BUFFER_BYTES)
            return
        except OSError:
            continue


class BusBridge(can.Listener):
    """python-can listener that hands frames and errors to the event loop, thread-safely.

    Items are (generation, frame or exception): after a reopen, errors still queued from the
    old bus must not close the new one. python-can's Notifier re-raises a reader error in its
    thread when given an event loop, so it runs without one and this bridge does the hand-off.
    """

    def __init__(self, loop: asyncio.AbstractEventLoop, queue: asyncio.Queue,
                 generation: int) -> None:
        self.loop = loop
        self.queue = queue
        self.generation = generation
        self._errors = 0

    def on_message_received(self, msg: can.Message) -> None:
        self.loop.call_soon_threadsafe(self.queue.put_nowait, (self.generation, msg))

    def on_error(self, exc: Exception) -> None:
        self._errors += 1
        if self._errors == 1:
            self.loop.call_soon_threadsafe(self.queue.put_nowait, (self.generation, exc))
        # A dead interface fails on every read: do not spin until the service closes it.
        time.sleep(0.05)

    def stop(self) -> None:
        """Nothing to release: the queue belongs to the service."""


@dataclass
class ServiceStats:
    """What the service did (for the log and the exit summary)."""

    frames: int = 0
    sent: int = 0
    send_errors: int = 0
    bus_errors: int = 0
    bus_down_s: float = 0.0  # seconds the bus was lost, reopening (after it had been open)
    reopen_attempts: int = 0
    gave_up: bool = False  # the bus could not be opened for retry_for seconds
    started: float = field(default_factory=time.monotonic)


class MonitorService:
    """Runs a Monitor on a live bus until ``stop`` is set.

    Parameters
    ----------
    monitor : the frames-to-diagnoses pipeline.
    bus_factory : opens the bus (called again to reopen it after a loss).
    status_period : seconds between FDI_STATUS frames (0: none).
    on_event : called with each FaultEvent (printing, live view).
    on_ready : called once the bus is open and frames can flow (systemd READY=1).
    on_tick : called at least every second from the loop (systemd watchdog pings).
    max_backoff : longest wait between attempts to reopen a lost bus.
    retry_for : give up (``stats.gave_up``, `run` returns) when the bus cannot be opened for
        this many seconds in a row, at start or after a loss; None: retry forever.
    block : at most this many queued frames are handled as one block.
    small_block : fewer queued frames than this go through the per-frame path (lower
        latency); more through the block path (throughput).
    latencies : when given, gets one entry (ns) per handled block that completed samples:
        from the arrival of its last frame to the end of its handling (fault frames sent).
    clock : the drive's time now, integer ns, which the frames the monitor sends are recorded
        at: the wall clock live (the bus stamps received frames with it too); a demo passes
        the emulated time, so that the log's time is the drive's throughout.
    no_traffic : seconds without a mapped frame (canfdi.bus.traffic) after which the state is
        "no_traffic" (0: never).
    on_status : called with a line for systemd's STATUS= when the state changes (the bus
        lost, silent, monitoring again).
    """

    def __init__(self, monitor: Monitor, bus_factory: Callable[[], can.BusABC], *,
                 status_period: float = 1.0, on_event: Callable | None = None,
                 on_ready: Callable[[], None] | None = None,
                 on_tick: Callable[[], None] | None = None, max_backoff: float = 10.0,
                 retry_for: float | None = None,
                 block: int = 4096, small_block: int = 16,
                 latencies: list[int] | None = None,
                 clock: Callable[[], int] = time.time_ns, no_traffic: float = 0.0,
                 on_status: Callable[[str], None] | None = None) -> None:
        self.monitor = monitor
        self.clock = clock
        self.bus_factory = bus_factory
        self.status_period = status_period
        self.on_event = on_event
        self.on_ready = on_ready
        self.on_tick = on_tick
        self.max_backoff = max_backoff
        self.retry_for = retry_for
        self.block = block
        self.small_block = small_block
        self.latencies = latencies
        self.stats = ServiceStats()
        self.traffic = TrafficWatch(no_traffic, time.monotonic())
        self.on_status = on_status
        self.bus: can.BusABC | None = None
        self._lost_at: float | None = None  # monotonic time the bus was lost, while reopening
        self._notifier: can.Notifier | None = None
        self._queue: asyncio.Queue | None = None
        self._ready_sent = False
        self._generation = 0

    # -- bus lifecycle ----------------------------------------------------------------------
    async def _open(self, stop: asyncio.Event) -> bool:
        delay = 0.1
        first_failure: float | None = None
        while not stop.is_set():
            self.stats.reopen_attempts += 1
            try:
                self.bus = self.bus_factory()
                self._generation += 1
                bridge = BusBridge(asyncio.get_running_loop(), self._queue, self._generation)
                self._notifier = can.Notifier(self.bus, [bridge], timeout=0.1)
                log.info("bus open: %s", self.bus.channel_info)
                if not self._ready_sent and self.on_ready is not None:
                    self.on_ready()
                self._ready_sent = True
                now = time.monotonic()
                self.traffic.restart(now)
                if self._lost_at is not None:
                    down = now - self._lost_at
                    self.stats.bus_down_s += down
                    self._lost_at = None
                    log.warning("bus reopened after %.1f s down (about %d control periods "
                                "lost)", down, round(down / self.monitor.dt))
                    self._say(f"monitoring again after {down:.1f} s without the bus")
                return True
            except (can.CanError, OSError, ValueError) as exc:
                now = time.monotonic()
                first_failure = now if first_failure is None else first_failure
                if self.retry_for is not None and now - first_failure >= self.retry_for:
                    log.error("cannot open bus (%s) for %.0f s: giving up", exc,
                              now - first_failure)
                    self.stats.gave_up = True
                    return False
                if self.retry_for is not None:  # the last wait ends at the deadline
                    delay = min(delay, max(self.retry_for - (now - first_failure), 0.01))
                log.warning("cannot open bus (%s); retrying in %.1f s", exc, delay)
                if self.on_tick is not None:
                    self.on_tick()
                with contextlib.suppress(asyncio.TimeoutError):
                    await asyncio.wait_for(stop.wait(), timeout=delay)
                delay = min(delay * 2, self.max_backoff)
        return False

    def _close(self) -> None:
        if self._notifier is not None:
            with contextlib.suppress(Exception):
                self._notifier.stop(timeout=1.0)
            self._notifier = None
        if self.bus is not None:
            with contextlib.suppress(Exception):
                self.bus.shutdown()
            self.bus = None

    def send(self, frames: list[OutFrame]) -> None:
        """Send the monitor's frames; a failing send is counted and logged, never raised."""
        sink = self.monitor.sink
        for f in frames:
            if self.bus is None:
                self.stats.send_errors += 1
                continue
            msg = can.Message(arbitration_id=f.frame_id, data=f.data,
                              is_extended_id=f.extended)
            try:
                self.bus.send(msg, timeout=0.05)
                self.stats.sent += 1
                if sink is not None:
                    sink.write_frame(self.clock(), f.frame_id, f.data, "sent", f.extended)
            except (can.CanError, OSError) as exc:
                self.stats.send_errors += 1
                log.warning("could not send frame 0x%X: %s", f.frame_id, exc)

    def deliver(self, msg: can.Message) -> None:
        """Hand a frame to the service from the event loop's own thread, as the bus bridge
        would (in-process sources: the benchmark, tests)."""
        if self._queue is not None:
            self._queue.put_nowait((self._generation, msg))

    # -- main loop --------------------------------------------------------------------------
    async def run(self, stop: asyncio.Event) -> ServiceStats:
        """Monitor until ``stop`` is set; returns the statistics."""
        self._queue = asyncio.Queue()
        status_task = asyncio.create_task(self._status_loop(stop))
        try:
            while not stop.is_set():
                if self.bus is None and not await self._open(stop):
                    break
                lost = await self._consume(stop)
                if lost:
                    self.stats.bus_errors += 1
                    self._lost_at = time.monotonic()
                    self._say("bus lost: reopening")
                    self._close()
        finally:
            status_task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await status_task
            # Frames already received are still diagnosed and logged before the bus closes.
            self._drain()
            self._close()
            self.monitor.finish()
        return self.stats

    def _handle_block(self, entries: list) -> bool:
        """Process queue items (frames, maybe a bus error) in order; True when the current bus
        was lost. Consecutive frames go to the monitor as one block."""
        frames = []
        lost = False
        for generation, item in entries:
            if isinstance(item, Exception):
                if generation == self._generation:
                    log.error("bus error: %s; reopening", item)
                    lost = True
                continue
            frames.append(item)
        if frames:
            self._process(frames)
            for notice in self.monitor.clock_notices():
                log.warning("%s", notice)
        return lost

    def _process(self, frames: list) -> None:
        n = len(frames)
        if n < self.small_block:
            # A few frames: the per-frame path reacts sooner than building arrays for them
            # (numpy's fixed costs); a backlog grows the blocks past small_block and the block
            # path catches up. Both paths give the same results (the tests compare them).
            self._process_each(frames)
            return
        block = FrameBlock.from_messages(frames)
        self.stats.frames += n
        samples_before = self.monitor.samples
        replies = self.monitor.on_frames(block)
        if replies:
            self.send(replies)
        if self.latencies is not None and self.monitor.samples > samples_before:
            # Arrival of the frame that completed each sample -> the sample handled (and any
            # fault frame sent): the monitor's reaction time.
            done = time.time_ns()
            self.latencies.append(done - int(block.t_ns[-1]))

    def _process_each(self, frames: list) -> None:
        monitor = self.monitor
        samples_before = monitor.samples
        for msg in frames:
            t_ns = int(msg.timestamp * 1e9) if msg.timestamp else time.time_ns()
            replies = monitor.on_frame(t_ns, msg.arbitration_id, bytes(msg.data),
                                       is_extended=msg.is_extended_id,
                                       is_remote=msg.is_remote_frame,
                                       is_error=msg.is_error_frame,
                                       is_fd=getattr(msg, "is_fd", False))
            if replies:
                self.send(replies)
        self.stats.frames += len(frames)
        if self.latencies is not None and monitor.samples > samples_before:
            self.latencies.append(time.time_ns() - t_ns)

    async def _consume(self, stop: asyncio.Event) -> bool:
        queue = self._queue
        stop_wait = asyncio.create_task(stop.wait())
        n_events = len(self.monitor.events)
        last_tick = time.monotonic()
        try:
            while not stop.is_set():
                if queue.empty():
                    get = asyncio.create_task(queue.get())
                    done, _ = await asyncio.wait({get, stop_wait}, timeout=self._idle_wait,
                                                 return_when=asyncio.FIRST_COMPLETED)
                    if get not in done:
                        get.cancel()
                        self._tick()
                        continue
                    entries = [get.result()]
                else:
                    entries = []
                # Whatever else is already queued is handled with it, as one block.
                while len(entries) < self.block and not queue.empty():
                    entries.append(queue.get_nowait())
                lost = self._handle_block(entries)
                if self.traffic.waiting or self.traffic.silent:  # said at once, not at a tick
                    self._check_traffic()
                if len(self.monitor.events) != n_events:
                    if self.on_event is not None:
                        for event in self.monitor.events[n_events:]:
                            self.on_event(event)
                    n_events = len(self.monitor.events)
                if lost:
                    return True
                now = time.monotonic()
                if now - last_tick >= 0.25:
                    # Proof of life from the loop itself, and a chance for other tasks.
                    last_tick = now
                    self._tick()
                await asyncio.sleep(0)
        finally:
            stop_wait.cancel()
        return False

    def _tick(self) -> None:
        """Proof of life (systemd's watchdog) and the traffic check."""
        if self.on_tick is not None:
            self.on_tick()
        self._check_traffic()

    def _check_traffic(self) -> None:
        change = self.traffic.update(time.monotonic(), self.monitor.mapped_frames)
        if change is not None:
            self._traffic_changed(change)

    def _traffic_changed(self, change: TrafficChange) -> None:
        if change.kind == "first":
            log.info("receiving the drives' frames (the first %.2f s after the bus opened)",
                     change.seconds)
            self._say("monitoring")
        elif change.kind == "silent":
            log.warning("no traffic: no frame of the drives for %.1f s (FDI_STATUS says "
                        "no_traffic); check the drive, the wiring, the bit rate and the "
                        "config's bus map", change.seconds)
            self._say(f"no traffic for {change.seconds:.1f} s")
        else:
            log.warning("traffic resumed after %.1f s of silence", change.seconds)
            self._say("monitoring")

    def _say(self, status: str) -> None:
        if self.on_status is not None:
            self.on_status(status)

    def _drain(self) -> None:
        queue = self._queue
        n_events = len(self.monitor.events)
        entries = []
        while queue is not None and not queue.empty():
            entry = queue.get_nowait()
            if not isinstance(entry[1], Exception):
                entries.append(entry)
        if entries:
            self._handle_block(entries)
        if self.on_event is not None:
            for event in self.monitor.events[n_events:]:
                self.on_event(event)

    @property
    def _idle_wait(self) -> float:
        """How long an idle loop waits for a frame before its tick: 1 s, or sooner so that
        silence is said within a fifth of --no-traffic."""
        timeout = self.traffic.timeout
        return min(1.0, timeout / 5) if timeout > 0 else 1.0

    def status_frames(self) -> list[OutFrame]:
        """The FDI_STATUS frames to send now (one per drive; none when listen-only), in the
        state `condition` says, else the monitor's own."""
        return self.monitor.status_frames(self.condition)

    @property
    def condition(self) -> str | None:
        """What the bus and the log impose on the monitor's state, or None: "bus_error" while
        a lost bus is being reopened, "degraded" while the monitor's record sink is failing
        (the MCAP log is not being written: a full disk), "no_traffic" while no frame of the
        drives arrives."""
        if self._lost_at is not None:
            return "bus_error"
        if getattr(self.monitor.sink, "failing", False):
            return "degraded"
        return "no_traffic" if self.traffic.silent else None

    def _heartbeat(self) -> None:
        """Send the FDI_STATUS frames, then record the status (after them: at a time no
        earlier than theirs)."""
        frames = self.status_frames()
        if frames and self.bus is not None:
            self.send(frames)
        self.monitor.record_status(self.clock(), self.condition)

    async def _status_loop(self, stop: asyncio.Event) -> None:
        if self.status_period <= 0:
            return
        # The first heartbeat goes out as soon as the bus is open: listeners learn at once
        # that a monitor is there, not a status period later.
        while self.bus is None and not stop.is_set():
            await asyncio.sleep(0.01)
        self._heartbeat()
        while not stop.is_set():
            with contextlib.suppress(asyncio.TimeoutError):
                await asyncio.wait_for(stop.wait(), timeout=self.status_period)
            if stop.is_set():
                return
            self._heartbeat()

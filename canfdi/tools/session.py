"""One monitoring session, built in one place for `canfdi run`, `demo` and `capture`.

A session is the monitor and everything wired around it: the bus it opens (by python-can's
precedence of settings), the MCAP recorder (rotation, retention, canfdi's log lines), the live
Foxglove server, the terminal live view, systemd's notifications, teach-in, and the stop event
that SIGINT, SIGTERM or a duration set. `open_session` builds it from what a verb was asked;
`Session.serve` runs the service until the stop event; closing the session closes the recorder
and the Foxglove server. Nothing here prints: errors are exceptions (`SessionError`,
`CannotRecord`) and notices go to the caller's ``notice`` callback.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import logging
import signal
import time
from collections.abc import Awaitable, Callable
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from canfdi.config import MonitorConfig
    from canfdi.core.kernel import Kernel
    from canfdi.core.settings import RecordingConfig
    from canfdi.monitor import Monitor
    from canfdi.service import MonitorService, ServiceStats

__all__ = [
    "BUS_PRECEDENCE",
    "PRUNE_INTERVAL_S",
    "BusArgumentError",
    "BusRequest",
    "CannotRecord",
    "Recording",
    "Session",
    "SessionError",
    "StopEvent",
    "bus_factory",
    "bus_kwargs",
    "bus_settings",
    "check_bus",
    "close_recorder",
    "keep_pruning",
    "open_foxglove",
    "open_recorder",
    "open_session",
    "prune_run_logs",
    "python_can_config",
    "recording_counts",
    "remember_designs",
    "run_recording",
    "teacher",
]


class SessionError(Exception):
    """What stops a session from being built, as one line for ``canfdi VERB: LINE`` and the
    verb's exit status.

    Examples
    --------
    >>> exc = SessionError("--foxglove: port in use", 2)
    >>> exc.message, exc.status
    ('--foxglove: port in use', 2)
    """

    def __init__(self, message: str, status: int = 2) -> None:
        super().__init__(message)
        self.message = message
        self.status = status


class CannotRecord(Exception):
    """The log file ``path`` cannot be opened for writing (``error``: the OSError); each verb
    says it in its own words and exits 1.

    Examples
    --------
    >>> exc = CannotRecord(Path("/ro/run.mcap"), PermissionError(13, "Permission denied"))
    >>> exc.path.name, exc.error.strerror
    ('run.mcap', 'Permission denied')
    """

    def __init__(self, path: Path | None, error: OSError) -> None:
        super().__init__(f"{path}: {error}")
        self.path = path
        self.error = error


# -- the bus -----------------------------------------------------------------------------------

BUS_PRECEDENCE = ("the command line", "the config file's bus: section",
                  "python-can's configuration (CAN_INTERFACE, CAN_CHANNEL, CAN_BITRATE, "
                  "CAN_CONFIG, can.conf)", "canfdi's defaults (virtual, canfdi)")
"""Where interface, channel and bitrate come from, the first that gives one winning."""


class BusArgumentError(ValueError):
    """A bad --bus-kwargs entry, an unknown interface or a missing network interface."""


@dataclasses.dataclass(frozen=True)
class BusRequest:
    """The bus a command line asks for: None where it says nothing (the config's bus: section
    or python-can's configuration decides then, `BUS_PRECEDENCE`).

    Examples
    --------
    >>> BusRequest(channel="vcan0", bus_kwargs=("receive_own_messages=true",)).channel
    'vcan0'
    >>> bus_kwargs(BusRequest(fd=True, bus_kwargs=("poll_interval=0.5",)))
    {'fd': True, 'poll_interval': 0.5}
    """

    interface: str | None = None
    channel: str | None = None
    bitrate: int | None = None
    fd: bool = False
    data_bitrate: int | None = None
    bus_kwargs: tuple[str, ...] = ()
    """Further keyword arguments of the python-can interface, as KEY=VALUE texts."""


def python_can_config() -> dict[str, Any]:
    """What python-can's own configuration gives (its environment variables and config files,
    through can.util.load_config), or {} when it configures no interface."""
    import can

    try:
        found = can.util.load_config()
    except (can.CanInterfaceNotImplementedError, ValueError, OSError):
        return {}
    return {k: v for k, v in found.items() if v is not None}


def bus_kwargs(request: BusRequest) -> dict[str, Any]:
    """--fd, --data-bitrate and --bus-kwargs as keyword arguments of can.Bus (values read as
    YAML: 1, 1.5, true, text); raises BusArgumentError for an entry that is no KEY=VALUE."""
    import yaml

    extra: dict[str, Any] = {}
    if request.fd:
        extra["fd"] = True
    if request.data_bitrate is not None:
        extra["data_bitrate"] = request.data_bitrate
    for item in request.bus_kwargs:
        key, sep, text = item.partition("=")
        if not sep or not key.isidentifier():
            raise BusArgumentError(f"--bus-kwargs: expected KEY=VALUE, got {item!r}")
        try:
            extra[key] = yaml.safe_load(text) if text else ""
        except yaml.YAMLError:
            extra[key] = text
    return extra


def bus_settings(request: BusRequest, bus=None) -> tuple[str, str, int | None]:
    """(interface, channel, bitrate) by `BUS_PRECEDENCE` (``bus``: the config's BusConfig, or
    None for a verb without a config)."""
    stated = bus.stated if bus is not None else frozenset()
    defaults = {"interface": "virtual", "channel": "canfdi", "bitrate": None}
    chosen: dict[str, Any] = {}
    fallback: dict[str, Any] | None = None  # python-can's, read only when it is needed
    for key in ("interface", "channel", "bitrate"):
        given = getattr(request, key)
        if given is None and key in stated:
            given = getattr(bus, key)
        if given is None:
            fallback = python_can_config() if fallback is None else fallback
            given = fallback.get(key, defaults[key])
        chosen[key] = given
    bitrate = chosen["bitrate"]
    return (str(chosen["interface"]), str(chosen["channel"]),
            int(bitrate) if bitrate is not None else None)


def check_bus(interface: str, channel: str) -> None:
    """BusArgumentError (the verb exits 2) for an interface python-can does not know, or a
    SocketCAN channel that is no network interface of this machine: a typo, not a bus to
    wait for (a bus that exists and fails to open is retried for --retry-for seconds)."""
    import difflib
    import socket

    import can

    known = sorted(can.interfaces.VALID_INTERFACES)
    if interface not in known:
        near = difflib.get_close_matches(interface, known, n=1)
        raise BusArgumentError(
            f"unknown interface {interface!r}" + (f" (did you mean {near[0]!r}?)" if near
                                                  else "") + f"; python-can's: {', '.join(known)}")
    if interface == "socketcan":
        try:
            socket.if_nametoindex(channel)
        except OSError:
            raise BusArgumentError(
                f"no network interface {channel!r} on this machine (`ip link` lists them; a "
                f"virtual one: deploy/vcan-setup {channel})") from None


def bus_factory(request: BusRequest, bus, can_filters: list[dict] | None = None
                ) -> tuple[str, str, Callable[[], Any]]:
    """(interface, channel, opener) from the command line's ``request``, the config's BusConfig
    and python-can's configuration (`BUS_PRECEDENCE`), with receive filters ``can_filters``
    unless --bus-kwargs gives its own; raises BusArgumentError for a bad request."""
    from canfdi.service import open_bus

    interface, channel, bitrate = bus_settings(request, bus)
    check_bus(interface, channel)
    extra = bus_kwargs(request)
    if can_filters is not None:
        extra.setdefault("can_filters", can_filters)
    return interface, channel, lambda: open_bus(interface, channel, bitrate, **extra)


# -- signals -----------------------------------------------------------------------------------

class StopEvent(asyncio.Event):
    """The event a long-running verb stops on: set by SIGINT, SIGTERM or after a duration
    (`arm`). ``interrupted`` says SIGINT (Ctrl-C) set it: the verb then stops in order as for
    SIGTERM and exits with `exit_status` 130, as a shell reports an interrupted command.

    Examples
    --------
    >>> stop = StopEvent()
    >>> stop.is_set(), stop.exit_status
    (False, 0)
    """

    def __init__(self) -> None:
        super().__init__()
        self.interrupted = False

    def arm(self, duration: float | None = None) -> StopEvent:
        """Install the signal handlers on the running event loop (and the timer)."""
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, self._signalled, sig)
        if duration:
            loop.call_later(duration, self.set)
        return self

    def disarm(self) -> None:
        """Remove the signal handlers again (from the same running loop)."""
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.remove_signal_handler(sig)

    def _signalled(self, sig: int) -> None:
        self.interrupted = self.interrupted or sig == signal.SIGINT
        self.set()

    @property
    def exit_status(self) -> int:
        """130 after Ctrl-C, else 0."""
        return 130 if self.interrupted else 0


# -- recording ---------------------------------------------------------------------------------

def open_recorder(path: Path | None, metadata: dict[str, str] | None = None, *,
                  drive_clock: Callable[[], int] | None = None,
                  recording: RecordingConfig | None = None, **kwargs):
    """An MCAP recorder for ``path`` (parent directories created; None: no file, for a live
    view's ``tap`` alone), its rows in the config's ``recording.row_encoding`` when it names
    one. With ``drive_clock`` (the drive's time now, ns), the canfdi loggers' warnings are
    recorded on its ``/canfdi/log`` too, until `close_recorder`."""
    from canfdi.io.writer import McapLogHandler, McapRecorder

    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
    if recording is not None and recording.row_encoding is not None:
        kwargs["row_encoding"] = recording.row_encoding
    recorder = McapRecorder(path, metadata=metadata, **kwargs)
    if drive_clock is not None:
        logging.getLogger("canfdi").addHandler(McapLogHandler(recorder, drive_clock))
    return recorder


def close_recorder(recorder) -> None:
    """Close a recorder of `open_recorder`, and stop recording log lines into it."""
    from canfdi.io.writer import McapLogHandler

    logger = logging.getLogger("canfdi")
    for handler in list(logger.handlers):
        if isinstance(handler, McapLogHandler) and handler.recorder is recorder:
            logger.removeHandler(handler)
    recorder.close()


def recording_counts(recorder) -> dict:
    """What an McapRecorder wrote and lost, for a verb's exit summary: ``{"segments": [file
    names], "written": rows and messages, "dropped": lost to write errors, "write_errors": N,
    "last_error": str or None}``."""
    error = recorder.last_error
    return {
        "segments": [str(p) for p in recorder.paths],
        "written": recorder.messages_written,
        "dropped": recorder.messages_dropped,
        "write_errors": recorder.write_errors,
        "last_error": None if error is None else (error.strerror or str(error)),
    }


PRUNE_INTERVAL_S = 600.0
"""How often a running daemon applies recording.keep_days / keep_mib (and at start)."""


def prune_run_logs(directory: Path, name: str, keep_days: float | None, keep_bytes: int | None,
                   log: logging.Logger, current) -> None:
    """Apply the retention rule (canfdi.io.retention) to the run's logs in ``directory``,
    sparing the files ``current``; one line per pruning that removed anything, one warning
    when the directory cannot be pruned (recording goes on)."""
    from canfdi.io.retention import prune_logs

    try:
        removed = prune_logs(directory, name, time.time(), keep_days, keep_bytes, current)
    except OSError as exc:
        log.warning("cannot remove old logs in %s: %s", directory, exc)
        return
    if removed:
        log.info("removed %d old log file(s) (%.1f MiB) under recording.keep_days/keep_mib: "
                 "%s", len(removed), sum(f.size for f in removed) / 2**20,
                 ", ".join(f.path.name for f in removed[:5])
                 + (", ..." if len(removed) > 5 else ""))


async def keep_pruning(prune, recorder, stop: asyncio.Event) -> None:
    """Prune every PRUNE_INTERVAL_S until ``stop``, sparing the recorder's open segment."""
    while not stop.is_set():
        with contextlib.suppress(asyncio.TimeoutError):
            await asyncio.wait_for(stop.wait(), PRUNE_INTERVAL_S)
        if not stop.is_set():
            prune(recorder.paths[-1:])


@dataclasses.dataclass(frozen=True)
class Recording:
    """How a session records: the log file (None: no file, only a tap for the live Foxglove
    server), its rotation, whether canfdi's log lines go into it, and the retention rule to
    apply at start and every `PRUNE_INTERVAL_S` (called with the files to spare).

    Examples
    --------
    >>> Recording(Path("out.mcap"), log_lines=False).rotate_bytes is None
    True
    """

    path: Path | None
    rotate_bytes: int | None = None
    rotate_seconds: float | None = None
    log_lines: bool = True
    prune: Callable[[Any], None] | None = None


def run_recording(config: MonitorConfig, output: Path | None, log_dir: Path | None,
                  log: logging.Logger) -> Recording:
    """`canfdi run`'s recording: ``output``, else a file named after the config and the time
    in ``log_dir`` (default recording.directory), rotated by the config's recording: section
    and, for named files, pruned by its keep_days / keep_mib."""
    rec = config.recording
    directory = log_dir or Path(rec.directory)
    path = output or directory / f"{config.name}-{time.strftime('%Y%m%d-%H%M%S')}.mcap"
    prune = None
    if output is None and (rec.keep_days is not None or rec.keep_mib is not None):
        prune = partial(prune_run_logs, directory, config.name, rec.keep_days,
                        None if rec.keep_mib is None else int(rec.keep_mib * 2**20), log)
    return Recording(path, rotate_bytes=int(rec.rotate_mib * 2**20),
                     rotate_seconds=rec.rotate_minutes * 60.0, prune=prune)


# -- what the monitor starts from --------------------------------------------------------------

def remember_designs() -> None:
    """Keep what the monitor computes at start (canfdi.core.memo: the parity thresholds) in
    the cache directory (canfdi.io.memostore), so that a restarted daemon starts sooner."""
    from canfdi.core import memo
    from canfdi.io.memostore import DirectoryStore, cache_directory

    directory = cache_directory()
    if directory is not None:
        memo.install(DirectoryStore(directory))


def teacher(config: MonitorConfig, seconds: float):
    """The teach-in of ``seconds`` for the config (canfdi.tools.calibrate.Teach); raises
    SessionError when that is too few samples."""
    import math

    from canfdi.config import read_yaml
    from canfdi.core.settings import ConfigError
    from canfdi.tools.calibrate import MIN_SAMPLES, Teach

    dt = config.model.dt or 1.0
    samples = round(seconds / dt) if math.isfinite(seconds) and seconds > 0 else 0
    if samples < MIN_SAMPLES:
        raise SessionError(f"--teach: {seconds:g} s is {samples} samples at dt = {dt:g} s; "
                           f"teach-in needs at least {MIN_SAMPLES} ({MIN_SAMPLES * dt:g} s)")
    return Teach(config, read_yaml(config.path, ConfigError, "config"), samples)


def open_foxglove(address: str | None, verb: str,
                  notice: Callable[[str], None] = lambda line: None):
    """The live Foxglove server ``--foxglove`` asks for (None when it does not), said to
    ``notice``; raises SessionError for a bad address, no foxglove-sdk or a port in use."""
    if address is None:
        return None
    from canfdi.liveserver import FoxgloveServer, FoxgloveUnavailable, parse_address

    try:
        host, port = parse_address(address)
        server = FoxgloveServer(host, port, name=f"canfdi {verb}")
    except (ValueError, OSError, FoxgloveUnavailable) as exc:
        raise SessionError(f"--foxglove: {exc}") from None
    notice(f"Foxglove live on ws://{host}:{server.port} (open it in Foxglove: Open "
           "connection, Foxglove WebSocket)")
    return server


# -- the session -------------------------------------------------------------------------------

class Session:
    """A monitor and what is wired around it, until `close` (or the end of a ``with``).

    Parameters
    ----------
    monitor : canfdi.monitor.Monitor
        Records go to ``recorder`` (set as its sink here).
    recorder : McapRecorder, optional
        Closed with the session (see `open_recorder`).
    foxglove : canfdi.liveserver.FoxgloveServer, optional
        Closed with the session.
    view : canfdi.liveview.LiveView, optional
        Shown while `serve` runs; log lines print above it.
    notifier : canfdi.sdnotify.Notifier, optional
        Told ready (with ``ready_status``), the watchdog ticks, the status and stopping.
    prune : callable, optional
        The retention rule `serve` applies every `PRUNE_INTERVAL_S`.
    bus : tuple, optional
        (interface, channel, opener) of the bus `serve` opens (`bus_factory`).

    Examples
    --------
    >>> class Drive:  # a stand-in for canfdi.monitor.Monitor
    ...     sink = None
    ...     last_timestamp_ns = 7
    >>> with Session(Drive()) as session:
    ...     session.drive_time(), session.interface
    (7, None)
    """

    def __init__(self, monitor: Monitor, *, recorder=None, foxglove=None, view=None,
                 notifier=None, prune: Callable[[Any], None] | None = None,
                 bus: tuple[str, str, Callable[[], Any]] | None = None) -> None:
        self.monitor = monitor
        self.recorder = recorder
        self.foxglove = foxglove
        self.view = view
        self.notifier = notifier
        self.prune = prune
        self.recording: Recording | None = None
        """How ``recorder`` was opened (`open_session`)."""
        self.interface, self.channel, self.opener = bus if bus is not None else (None, None,
                                                                                 None)
        self.service: MonitorService | None = None
        if recorder is not None:
            monitor.sink = recorder

    def drive_time(self) -> int:
        """The drive's time now (ns): its last frame's, else the wall clock's."""
        return self.monitor.last_timestamp_ns or time.time_ns()

    def __enter__(self) -> Session:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Close the recorder, then the Foxglove server it fed."""
        try:
            if self.recorder is not None:
                close_recorder(self.recorder)
        finally:
            if self.foxglove is not None:
                self.foxglove.close()

    def discard_recording(self) -> None:
        """Remove the files the recorder wrote (a session that recorded nothing worth a log:
        no empty file that looks like one)."""
        if self.recorder is not None:
            for path in self.recorder.paths:
                path.unlink(missing_ok=True)

    async def serve(self, stop: StopEvent, *, duration: float | None = None,
                    opener: Callable[[], Any] | None = None,
                    alongside: Callable[[MonitorService, asyncio.Task], Awaitable[None]]
                    | None = None, on_ready: Callable[[], None] | None = None,
                    **service_options: Any) -> ServiceStats:
        """Run the service on the session's bus (or ``opener``'s) until ``stop`` (armed here
        for SIGINT, SIGTERM and ``duration``), with the live view, the pruning and systemd's
        notifications; returns the service's counters.

        ``alongside(service, task)``: a coroutine run beside the service (the demo's
        emulator); ``stop`` is set when it ends. ``service_options``: further keyword
        arguments of canfdi.service.MonitorService."""
        from canfdi.service import MonitorService

        notifier, view = self.notifier, self.view
        stop.arm(duration)
        try:
            pruner = (asyncio.create_task(keep_pruning(self.prune, self.recorder, stop))
                      if self.prune is not None else None)
            if notifier is not None:
                service_options.update(on_tick=notifier.watchdog, on_status=notifier.status)
            service = self.service = MonitorService(
                self.monitor, opener or self.opener, on_ready=self._ready(on_ready),
                **service_options)
            if view is not None:
                view.condition = lambda: service.condition
                # Log lines print above the view instead of tearing it.
                for handler in logging.getLogger().handlers:
                    if isinstance(handler, logging.StreamHandler):
                        handler.setStream(view.stream())
            stats = await self._run(service, stop, alongside)
            if notifier is not None:
                notifier.stopping()
            if pruner is not None:
                await pruner
            return stats
        finally:
            stop.disarm()

    def _ready(self, on_ready: Callable[[], None] | None) -> Callable[[], None] | None:
        notifier = self.notifier
        if notifier is None:
            return on_ready

        def ready() -> None:
            if on_ready is not None:
                on_ready()
            notifier.ready(f"monitoring {self.interface} {self.channel}")

        return ready

    async def _run(self, service: MonitorService, stop: StopEvent, alongside) -> ServiceStats:
        view = self.view
        task = asyncio.create_task(service.run(stop))
        refresher = None
        if view is not None:
            view.__enter__()
            refresher = asyncio.create_task(view.run(stop))
        try:
            try:
                if alongside is not None:
                    await alongside(service, task)
            finally:
                if alongside is not None:
                    stop.set()
                stats = await task
        finally:
            if view is not None:
                stop.set()
                await refresher
                view.__exit__(None, None, None)
        return stats

    def stopped(self, stats: ServiceStats) -> dict[str, Any]:
        """The counters of a served session: frames, sent, bus_errors, bus_down_s, faults,
        gave_up; "recording" when it wrote a file; "foxglove" (lagging viewers, oversize
        messages) when it served one."""
        summary = self.monitor.summary()
        counts = {"frames": stats.frames, "sent": stats.sent, "bus_errors": stats.bus_errors,
                  "bus_down_s": round(stats.bus_down_s, 3), "faults": len(summary["faults"]),
                  "gave_up": stats.gave_up}
        if self.recording is not None and self.recording.path is not None:
            counts["recording"] = recording_counts(self.recorder)
        if self.foxglove is not None:  # viewers that fell behind, messages too large to show
            counts["foxglove"] = {"lagging": self.foxglove.lagging,
                                  "oversize": self.foxglove.oversize}
        return counts


def open_session(config: MonitorConfig, verb: str, *, diagnose: bool = True,
                 teach: float | None = None, cache_designs: bool = False,
                 bus: BusRequest | None = None, filters: bool = True,
                 recording: Recording | None = None, foxglove: str | None = None,
                 view: str | None = None, systemd: bool = False,
                 truth: list[dict] | None = None, kernel: Kernel | None = None,
                 notice: Callable[[str], None] = lambda line: None) -> Session:
    """The session a verb asks for, built in this order: teach-in (``teach`` seconds), the
    design cache (``cache_designs``), the monitor (``diagnose``: False records only), the bus
    (``bus``, with the monitor's receive filters unless ``filters`` is False), the Foxglove
    server (``foxglove``: its [HOST:]PORT), the recorder (``recording``; ``truth``, the
    injected faults, goes into its metadata), systemd's notifier and the live view
    (``view``: the name in its title). ``kernel``: what the monitor's diagnosers run on
    (canfdi.core.kernel; the numpy reference by default).

    Raises SessionError (a bad --teach, config, bus or --foxglove: exit 2) or CannotRecord
    (exit 1); what was opened before is closed again. ``notice`` gets the lines to say on
    stderr (where Foxglove listens)."""
    from canfdi.monitor import Monitor

    taught = teacher(config, teach) if teach is not None else None
    if cache_designs:
        remember_designs()
    try:
        monitor = Monitor(config, diagnose=diagnose, teach=taught, kernel=kernel)
    except ValueError as exc:
        raise SessionError(f"config error: {exc}") from None
    opened = None
    if bus is not None:
        try:
            opened = bus_factory(bus, config.bus, monitor.receive_filters() if filters
                                 else None)
        except BusArgumentError as exc:
            raise SessionError(str(exc)) from None
    server = open_foxglove(foxglove, verb, notice)
    session = Session(monitor, foxglove=server, bus=opened)
    if recording is None and server is not None:
        recording = Recording(None)
    if recording is not None:
        session.recording, session.prune = recording, recording.prune
        if recording.prune is not None:
            recording.prune(())
        try:
            session.recorder = open_recorder(
                recording.path, monitor.metadata(truth),
                drive_clock=session.drive_time if recording.log_lines else None, tap=server,
                rotate_bytes=recording.rotate_bytes, rotate_seconds=recording.rotate_seconds,
                recording=config.recording)
        except OSError as exc:
            session.close()
            raise CannotRecord(recording.path, exc) from None
        monitor.sink = session.recorder
    if systemd:
        from canfdi.sdnotify import Notifier

        session.notifier = Notifier()
    if view is not None:
        from canfdi.liveview import LiveView

        where = f" on {opened[0]} {opened[1]}" if opened is not None else ""
        session.view = LiveView(monitor, title=f"canfdi {verb}: {view}{where}")
    return session

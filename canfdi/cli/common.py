"""Small pieces the verbs share: config loading with exit status 2, event lines, tables."""

from __future__ import annotations

import argparse
import asyncio
import signal
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from canfdi.core.eventtext import estimates_text
from canfdi.core.eventtext import event_line as format_event

if TYPE_CHECKING:
    from canfdi.config import MonitorConfig

__all__ = [
    "BUS_PRECEDENCE",
    "RETRY_FOR_S",
    "BusArgumentError",
    "StopEvent",
    "add_bus_overrides",
    "add_foxglove_option",
    "add_retry_option",
    "bus_factory",
    "bus_kwargs",
    "bus_settings",
    "check_bus",
    "close_recorder",
    "config_error",
    "format_event",
    "load_config_or_exit",
    "open_foxglove",
    "open_recorder",
    "print_comparison",
    "recording_counts",
]



def load_config_or_exit(path: Path | str, verb: str) -> MonitorConfig | int:
    """The config, or 2 after printing one line naming the bad field."""
    from canfdi.config import ConfigError, load_config

    try:
        return load_config(path)
    except ConfigError as exc:
        return config_error(exc, verb)


def add_bus_overrides(p: argparse.ArgumentParser, config: bool = True) -> None:
    """python-can's bus options, as its own tools spell them: -i/--interface, -c/--channel,
    -b/--bitrate, --fd, --data-bitrate and --bus-kwargs KEY=VALUE... (`BUS_PRECEDENCE`:
    over the config's bus: section when the verb reads a ``config``)."""
    def said(key: str) -> str:
        return (f"overrides the config's bus.{key}" if config else
                "default: python-can's configuration, else " + {"interface": "virtual",
                "channel": "canfdi", "bitrate": "none"}[key])

    p.add_argument("-i", "--interface", help=f"python-can interface ({said('interface')})")
    p.add_argument("-c", "--channel", help=f"bus channel ({said('channel')})")
    p.add_argument("-b", "--bitrate", type=int, help=f"bit rate ({said('bitrate')})")
    p.add_argument("--fd", action="store_true", help="open the bus in CAN FD mode")
    p.add_argument("--data-bitrate", type=int, metavar="BITRATE",
                   help="CAN FD data phase bit rate")
    p.add_argument("--bus-kwargs", nargs="+", metavar="KEY=VALUE", default=[],
                   help="further keyword arguments of the python-can interface (values read "
                        "as YAML: 1, 1.5, true, text), e.g. --bus-kwargs receive_own_messages=true")


RETRY_FOR_S = 60.0
"""How long run and capture try to open a bus that cannot be opened before they exit 1 (a
supervisor such as systemd then restarts them): --retry-for."""


def add_retry_option(p: argparse.ArgumentParser) -> None:
    """--retry-for SECONDS: give up on a bus that cannot be opened (exit 1)."""
    p.add_argument("--retry-for", type=float, default=RETRY_FOR_S, metavar="SECONDS",
                   help="exit 1 when the bus cannot be opened for this long, at start or after "
                        f"a loss (default {RETRY_FOR_S:g}; 0: retry forever)")


BUS_PRECEDENCE = ("the command line", "the config file's bus: section",
                  "python-can's configuration (CAN_INTERFACE, CAN_CHANNEL, CAN_BITRATE, "
                  "CAN_CONFIG, can.conf)", "canfdi's defaults (virtual, canfdi)")
"""Where interface, channel and bitrate come from, the first that gives one winning."""


def python_can_config() -> dict[str, Any]:
    """What python-can's own configuration gives (its environment variables and config files,
    through can.util.load_config), or {} when it configures no interface."""
    import can

    try:
        found = can.util.load_config()
    except (can.CanInterfaceNotImplementedError, ValueError, OSError):
        return {}
    return {k: v for k, v in found.items() if v is not None}


class BusArgumentError(ValueError):
    """A bad --bus-kwargs entry."""


def bus_kwargs(args: argparse.Namespace) -> dict[str, Any]:
    """--fd, --data-bitrate and --bus-kwargs as keyword arguments of can.Bus."""
    import yaml

    extra: dict[str, Any] = {}
    if getattr(args, "fd", False):
        extra["fd"] = True
    if getattr(args, "data_bitrate", None) is not None:
        extra["data_bitrate"] = args.data_bitrate
    for item in getattr(args, "bus_kwargs", []) or []:
        key, sep, text = item.partition("=")
        if not sep or not key.isidentifier():
            raise BusArgumentError(f"--bus-kwargs: expected KEY=VALUE, got {item!r}")
        try:
            extra[key] = yaml.safe_load(text) if text else ""
        except yaml.YAMLError:
            extra[key] = text
    return extra


def bus_settings(args: argparse.Namespace, bus=None) -> tuple[str, str, int | None]:
    """(interface, channel, bitrate) by `BUS_PRECEDENCE` (``bus``: the config's BusConfig, or
    None for a verb without a config)."""
    stated = bus.stated if bus is not None else frozenset()
    defaults = {"interface": "virtual", "channel": "canfdi", "bitrate": None}
    chosen: dict[str, Any] = {}
    fallback: dict[str, Any] | None = None  # python-can's, read only when it is needed
    for key in ("interface", "channel", "bitrate"):
        given = getattr(args, key, None)
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


def bus_factory(args: argparse.Namespace, bus, can_filters: list[dict] | None = None
                ) -> tuple[str, str, object]:
    """(interface, channel, opener) from the command line, the config's BusConfig and
    python-can's configuration (`BUS_PRECEDENCE`), with receive filters ``can_filters``
    unless --bus-kwargs gives its own; raises BusArgumentError for a bad --bus-kwargs."""
    from canfdi.service import open_bus

    interface, channel, bitrate = bus_settings(args, bus)
    check_bus(interface, channel)
    extra = bus_kwargs(args)
    if can_filters is not None:
        extra.setdefault("can_filters", can_filters)
    return interface, channel, lambda: open_bus(interface, channel, bitrate, **extra)


class StopEvent(asyncio.Event):
    """The event a long-running verb stops on: set by SIGINT, SIGTERM or after a duration
    (`arm`). ``interrupted`` says SIGINT (Ctrl-C) set it: the verb then stops in order as for
    SIGTERM and exits with `exit_status` 130, as a shell reports an interrupted command."""

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



def config_error(exc: Exception, verb: str) -> int:
    print(f"canfdi {verb}: config error: {exc}", file=sys.stderr)
    return 2


def open_recorder(path: Path | None, metadata: dict[str, str] | None = None, *,
                  drive_clock: Callable[[], int] | None = None, **kwargs):
    """An MCAP recorder for ``path`` (parent directories created; None: no file, for a live
    view's ``tap`` alone). With ``drive_clock`` (the drive's time now, ns), the canfdi loggers'
    warnings are recorded on its ``/canfdi/log`` too, until `close_recorder`."""
    import logging

    from canfdi.io.writer import McapLogHandler, McapRecorder

    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
    recorder = McapRecorder(path, metadata=metadata, **kwargs)
    if drive_clock is not None:
        logging.getLogger("canfdi").addHandler(McapLogHandler(recorder, drive_clock))
    return recorder


def close_recorder(recorder) -> None:
    """Close a recorder of `open_recorder`, and stop recording log lines into it."""
    import logging

    from canfdi.io.writer import McapLogHandler

    logger = logging.getLogger("canfdi")
    for handler in list(logger.handlers):
        if isinstance(handler, McapLogHandler) and handler.recorder is recorder:
            logger.removeHandler(handler)
    recorder.close()


def add_foxglove_option(p: argparse.ArgumentParser) -> None:
    """``--foxglove [HOST:]PORT``: serve the run live to Foxglove."""
    p.add_argument("--foxglove", metavar="[HOST:]PORT",
                   help="serve the log's channels live over Foxglove's WebSocket protocol on "
                        "PORT (host 127.0.0.1 unless given; 0.0.0.0 serves other machines); "
                        "needs pip install 'canfdi[foxglove]'")


def open_foxglove(address: str | None, verb: str):
    """The live Foxglove server ``--foxglove`` asks for (None when it does not), or the exit
    status 2 after one line on stderr (a bad address, no foxglove-sdk, a port in use)."""
    if address is None:
        return None
    from canfdi.liveserver import FoxgloveServer, FoxgloveUnavailable, parse_address

    try:
        host, port = parse_address(address)
        server = FoxgloveServer(host, port, name=f"canfdi {verb}")
    except (ValueError, OSError, FoxgloveUnavailable) as exc:
        print(f"canfdi {verb}: --foxglove: {exc}", file=sys.stderr)
        return 2
    print(f"canfdi {verb}: Foxglove live on ws://{host}:{server.port} (open it in Foxglove: "
          "Open connection, Foxglove WebSocket)", file=sys.stderr)
    return server


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


def print_comparison(result: dict, truth: list[dict] | None) -> None:
    """Injected faults against diagnosed ones (each with its drive's name on a bus of several),
    then the frame counters."""
    several = "drives" in result

    def who(f: dict) -> str:
        return f"{f.get('drive') or '':<8} " if several else ""

    print()
    if truth is not None:
        print("injected:")
        if not truth:
            print("  (none)")
        for f in truth:
            params = {k: f[k] for k in ("eta", "lambda", "bias", "rate", "scale", "value", "std")
                      if k in f}
            print(f"  {who(f)}{f['target']:<8} {f['index']} {f['name']:<14} {f['kind']:<10} "
                  f"onset k={f['onset_sample']:<7d} {estimates_text(params)}")
    print("diagnosed:")
    if not result["faults"]:
        print("  (none)")
    for f in result["faults"]:
        twins = ""
        if f["candidates"]:
            twins = "  (or " + ", ".join(c["name"] for c in f["candidates"][1:]) + ")"
        print(f"  {who(f)}{f['kind']:<8} {f['index']} {f['name']:<14} "
              f"onset k={f['onset_sample']:<7d}"
              f"detected k={f['detected_sample']:<7d} accepted k={f['accepted_sample']:<7d} "
              f"{estimates_text(f['estimate'])}{twins}")
    for u in result.get("unexplained", []):
        print(f"  unexplained change detected at k={u['detected_sample']}")
    fr = result["frames"]
    reasons = ", ".join(f"{k} {v}" for k, v in fr["invalid_by_reason"].items() if v)
    steps = fr.get("clock_steps", 0)
    print(f"frames: {fr['received']} received, {fr['invalid']} invalid"
          f"{f' ({reasons})' if reasons else ''}; "
          f"samples: {result['samples']} "
          f"({fr['samples_broken']} broken, {fr['samples_missing']} missing)"
          f"{f'; the clock stepped {steps} time(s), followed' if steps else ''}")
    if "no_samples" in result:
        print(result["no_samples"])

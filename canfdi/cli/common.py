"""What the verbs share to parse their arguments and print: config loading with exit status 2,
the bus options, one-line errors, event lines, the demo's comparison."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from canfdi.core.eventtext import estimates_text
from canfdi.core.eventtext import event_line as format_event
from canfdi.core.kernelchoice import NAMES as KERNEL_NAMES
from canfdi.core.kernelchoice import KernelError
from canfdi.tools.session import BusRequest

if TYPE_CHECKING:
    from canfdi.config import MonitorConfig
    from canfdi.core.kernel import Kernel

__all__ = [
    "RETRY_FOR_S",
    "add_bus_overrides",
    "add_foxglove_option",
    "add_kernel_option",
    "add_retry_option",
    "bus_request",
    "config_error",
    "fail",
    "format_event",
    "kernel_or_exit",
    "load_config_or_exit",
    "print_comparison",
    "say",
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
    -b/--bitrate, --fd, --data-bitrate and --bus-kwargs KEY=VALUE... (over the config's bus:
    section when the verb reads a ``config``: canfdi.tools.session.BUS_PRECEDENCE)."""
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


def bus_request(args: argparse.Namespace) -> BusRequest:
    """The bus the options of `add_bus_overrides` ask for (None where they say nothing)."""
    return BusRequest(interface=getattr(args, "interface", None),
                      channel=getattr(args, "channel", None),
                      bitrate=getattr(args, "bitrate", None), fd=bool(getattr(args, "fd", False)),
                      data_bitrate=getattr(args, "data_bitrate", None),
                      bus_kwargs=tuple(getattr(args, "bus_kwargs", []) or []))


def say(verb: str) -> Callable[[str], None]:
    """A line on stderr as ``canfdi VERB: LINE``."""
    return lambda line: print(f"canfdi {verb}: {line}", file=sys.stderr, flush=True)


def fail(verb: str, message: str, status: int = 2) -> int:
    """``status`` after one line ``canfdi VERB: MESSAGE`` on stderr."""
    print(f"canfdi {verb}: {message}", file=sys.stderr)
    return status


def write_text(verb: str, text: str, output: Path | None, status: int = 1) -> int | None:
    """``text`` to stdout, or to the file ``output``: None once written, else ``status`` after
    one line saying why it could not be."""
    if output is None:
        sys.stdout.write(text)
        return None
    try:
        output.write_text(text)
    except OSError as exc:
        return fail(verb, f"cannot write {output}: {exc.strerror or exc}", status)
    return None


def add_kernel_option(p: argparse.ArgumentParser) -> None:
    """--kernel: what the hot path (residuals and detectors) runs on."""
    p.add_argument("--kernel", choices=KERNEL_NAMES,
                   help="the kernel the residuals and detectors run on: c (the C core, where "
                        "the install built it) or python (numpy, the reference); default: "
                        "$CANFDI_KERNEL, else c where built (canfdi --version names it)")


def kernel_or_exit(args: argparse.Namespace, verb: str) -> Kernel | int:
    """The kernel --kernel or CANFDI_KERNEL asks for (canfdi.core.kernel.resolve), or 2 after
    one line saying why it cannot be had."""
    from canfdi.core.kernel import resolve  # numpy and the kernels: not for the parser

    try:
        return resolve(getattr(args, "kernel", None))
    except KernelError as exc:
        return fail(verb, str(exc))


def config_error(exc: Exception, verb: str) -> int:
    print(f"canfdi {verb}: config error: {exc}", file=sys.stderr)
    return 2


def add_foxglove_option(p: argparse.ArgumentParser) -> None:
    """``--foxglove [HOST:]PORT``: serve the run live to Foxglove."""
    p.add_argument("--foxglove", metavar="[HOST:]PORT",
                   help="serve the log's channels live over Foxglove's WebSocket protocol on "
                        "PORT (host 127.0.0.1 unless given; 0.0.0.0 serves other machines); "
                        "needs pip install 'canfdi[foxglove]'")


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

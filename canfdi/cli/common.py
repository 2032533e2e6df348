"""Small pieces the verbs share: config loading with exit status 2, event lines, tables."""

from __future__ import annotations

import argparse
import asyncio
import signal
import sys
from pathlib import Path

from canfdi.config import ConfigError, MonitorConfig, load_config
from canfdi.core.records import FaultEvent

__all__ = ["DEFAULT_CONFIG_DIR", "add_bus_overrides", "bus_factory", "config_error",
           "format_event", "load_config_or_exit", "open_recorder", "print_comparison",
           "recording_counts", "stop_event"]

DEFAULT_CONFIG_DIR = Path(__file__).resolve().parents[2] / "deploy" / "config"


def load_config_or_exit(path: Path | str, verb: str) -> MonitorConfig | int:
    """The config, or 2 after printing one line naming the bad field."""
    try:
        return load_config(path)
    except ConfigError as exc:
        return config_error(exc, verb)


def add_bus_overrides(p: argparse.ArgumentParser) -> None:
    """--interface, --channel, --bitrate overriding the config's bus: section."""
    p.add_argument("--interface", help="override bus.interface")
    p.add_argument("--channel", help="override bus.channel")
    p.add_argument("--bitrate", type=int, help="override bus.bitrate")


def bus_factory(args: argparse.Namespace, bus) -> tuple[str, str, object]:
    """(interface, channel, opener) from the config's BusConfig and the overrides."""
    from canfdi.service import open_bus

    interface = args.interface or bus.interface
    channel = args.channel or bus.channel
    bitrate = args.bitrate if args.bitrate is not None else bus.bitrate
    return interface, channel, lambda: open_bus(interface, channel, bitrate)


def stop_event(duration: float | None = None) -> asyncio.Event:
    """An event set by SIGINT, SIGTERM or, when given, after ``duration`` seconds (call it from
    the running event loop)."""
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    if duration:
        loop.call_later(duration, stop.set)
    return stop


def config_error(exc: Exception, verb: str) -> int:
    print(f"canfdi {verb}: config error: {exc}", file=sys.stderr)
    return 2


def open_recorder(path: Path, metadata: dict[str, str] | None = None, **kwargs):
    """An MCAP recorder for ``path`` (parent directories created)."""
    from canfdi.io.writer import McapRecorder

    path.parent.mkdir(parents=True, exist_ok=True)
    # base64 float columns: exact, and ten times cheaper to write than JSON number lists.
    kwargs.setdefault("float_encoding", "base64")
    return McapRecorder(path, metadata=metadata, **kwargs)


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


def _estimates(estimates: dict) -> str:
    return ", ".join(f"{k}={v:.4g}" for k, v in estimates.items())


def format_event(event: FaultEvent, dt: float, show_drive: bool = False) -> str:
    """One line per diagnosis, as it happens (with the drive's name when ``show_drive``: a
    monitor of several drives)."""
    t = event.sample * dt
    who = f"[{event.drive}] " if show_drive and event.drive else ""
    if event.kind == "detected":
        return (f"  t={t:8.2f} s  k={event.sample:<7d} {who}DETECTED   change near k="
                f"{event.onset_sample} in {', '.join(event.residuals)}")
    if event.kind == "accepted":
        line = (f"  t={t:8.2f} s  k={event.sample:<7d} {who}FAULT      {event.target} "
                f"{event.index} ({event.name}): {_estimates(event.estimates)}, "
                f"onset k={event.onset_sample}")
        if event.candidates:
            alts = "; ".join(f"{c['name']} {_estimates(c['estimates'])}"
                             for c in event.candidates)
            line += f"\n{'':33}indistinguishable from the bus: {alts}"
        return line
    if event.kind == "refined":
        return (f"  t={t:8.2f} s  k={event.sample:<7d} {who}REFINED    {event.target} "
                f"{event.index} ({event.name}): now {_estimates(event.estimates)} (the fault "
                f"already known, from k={event.onset_sample} on)")
    if event.kind == "taught":
        noise = ", ".join(f"{n} {v:.4g}" for n, v in event.estimates.items())
        return (f"  t={t:8.2f} s  k={event.sample:<7d} {who}TAUGHT     the drive's noise, "
                f"learned from its first samples: {noise}; monitoring with it")
    if event.kind == "teach_failed":
        reason = event.candidates[0]["reason"] if event.candidates else "?"
        return (f"  t={t:8.2f} s  k={event.sample:<7d} {who}TEACH-IN FAILED: {reason}; "
                "monitoring with the config's noise")
    if event.kind in ("mismatch", "matched"):
        ratios = ", ".join(f"{n} {v:.2f}x" for n, v in event.estimates.items())
        what = ("MISMATCH   residual noise left its calibrated value (noise or model changed; "
                "recalibrate: canfdi calibrate, run --teach): " if event.kind == "mismatch"
                else "MATCHED    residual noise back at its calibrated value: ")
        return f"  t={t:8.2f} s  k={event.sample:<7d} {who}{what}{ratios}"
    return f"  t={t:8.2f} s  k={event.sample:<7d} {who}UNEXPLAINED change detected at k=" \
           f"{event.detected_sample}: no single fault fits"


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
                  f"onset k={f['onset_sample']:<7d} {_estimates(params)}")
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
              f"{_estimates(f['estimate'])}{twins}")
    for u in result.get("unexplained", []):
        print(f"  unexplained change detected at k={u['detected_sample']}")
    fr = result["frames"]
    print(f"frames: {fr['received']} received, {fr['invalid']} invalid "
          f"{ {k: v for k, v in fr['invalid_by_reason'].items() if v} or ''}; "
          f"samples: {result['samples']} "
          f"({fr['samples_broken']} broken, {fr['samples_missing']} missing)")
    if "no_samples" in result:
        print(result["no_samples"])

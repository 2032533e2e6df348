"""The live terminal view of `canfdi run` and `canfdi demo`: what the monitor sees, refreshed.

`snapshot` reads a Monitor into plain numbers (pure, testable); `render` turns a snapshot into a
rich renderable; `LiveView` refreshes it a few times a second in a terminal (rich's Live display,
which also prints the diagnoses above the view). The view is only for a terminal: callers turn
it off when stdout is not a TTY, so logs and pipes get plain lines.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable
from typing import Any

import numpy as np

__all__ = ["LiveView", "render", "snapshot"]

_BAR = 24  # characters of a statistic / threshold bar


def snapshot(monitor: Any, condition: str | None = None) -> dict[str, Any]:
    """The monitor's state now, as plain numbers (``condition``: what the bus or the log
    imposes on the state, canfdi.service.MonitorService.condition, e.g. "no_traffic").

    Returns
    -------
    dict with ``state`` ("monitoring" / "diagnosing" / "named" / "teaching" / "checking" /
    "mismatch" /
    "quiet" (the noise watchdog's) / "capturing", or the condition: "no_traffic" /
    "bus_error" / "degraded"),
    ``residuals`` (one dict per
    residual: name, value (latest normalised residual or None), statistic, threshold),
    ``faults`` (the accepted faults being compensated), ``frames`` (the assembler's counters),
    ``samples`` and ``events`` (the last five, newest last).
    """
    dg = monitor.diagnoser
    residuals = []
    if dg is not None:
        stats = np.asarray(dg.statistics, dtype=float)
        last = dg.last_normalized
        for i, name in enumerate(dg.residual_names):
            value = None if last is None or np.isnan(last[i]) else float(last[i])
            residuals.append({"name": name, "value": value, "statistic": float(stats[i]),
                              "threshold": float(dg.thresholds[i])})
    state = condition or ("capturing" if dg is None else monitor.drives[0].state)
    faults = [c.as_dict() for c in (dg.compensation if dg is not None else [])]
    events = [e.as_dict() for e in monitor.events[-5:]]
    return {"state": state, "residuals": residuals, "faults": faults,
            "frames": dict(monitor.assembler.stats), "samples": monitor.samples,
            "events": events}


def _bar(fraction: float) -> str:
    filled = round(min(max(fraction, 0.0), 1.0) * _BAR)
    return "#" * filled + "." * (_BAR - filled)


def render(snap: dict[str, Any], title: str = "canfdi") -> Any:
    """A rich renderable of a snapshot: residual table, active faults, counters, last events."""
    from rich.console import Group
    from rich.table import Table
    from rich.text import Text

    style = {"monitoring": "green", "diagnosing": "yellow", "named": "yellow", "capturing": "cyan",
             "teaching": "cyan", "checking": "cyan", "mismatch": "magenta",
             "quiet": "blue", "no_traffic": "red",
             "bus_error": "red", "degraded": "red"}[snap["state"]]
    head = Text.assemble((f"{title}  ", "bold"), (snap["state"], f"bold {style}"),
                         f"   samples {snap['samples']:,}")
    parts: list[Any] = [head]
    if snap["residuals"]:
        table = Table(box=None, padding=(0, 1), show_edge=False)
        for column, justify in (("residual", "left"), ("r/sigma", "right"),
                                ("Page-Hinkley / threshold", "left"), ("", "right")):
            table.add_column(column, justify=justify)
        for r in snap["residuals"]:
            fraction = r["statistic"] / r["threshold"] if r["threshold"] > 0 else 0.0
            colour = "red" if fraction >= 1 else "yellow" if fraction >= 0.5 else "green"
            value = "-" if r["value"] is None else f"{r['value']:+7.2f}"
            table.add_row(r["name"], value, Text(_bar(fraction), style=colour),
                          f"{r['statistic']:.1f}/{r['threshold']:.1f}")
        parts.append(table)
    frames = snap["frames"]
    parts.append(Text(
        f"frames {frames.get('frames_received', 0):,} received, "
        f"{frames.get('frames_invalid', 0):,} invalid; samples "
        f"{frames.get('samples_complete', 0):,} complete, "
        f"{frames.get('samples_broken', 0):,} broken, "
        f"{frames.get('samples_missing', 0):,} missing"))
    if snap["faults"]:
        lines = []
        for f in snap["faults"]:
            values = ", ".join(f"{k} {v:.4g}" for k, v in f.items()
                               if k not in ("target", "index", "onset"))
            lines.append(f"  {f['target']} {f['index']} from k={f['onset']}: {values}")
        parts.append(Text("active faults (compensated):\n" + "\n".join(lines), style="bold"))
    else:
        parts.append(Text("active faults: none"))
    return Group(*parts)


class LiveView:
    """Refresh ``render(snapshot(monitor))`` in the terminal while the monitor runs.

    Use ``print`` for lines that must stay (diagnoses): they scroll above the view.
    """

    def __init__(self, monitor: Any, title: str = "canfdi", period: float = 0.25,
                 console: Any = None) -> None:
        from rich.console import Console
        from rich.live import Live

        self.monitor = monitor
        self.title = title
        self.period = period
        self.console = console or Console()
        self._live = Live(console=self.console, auto_refresh=False, transient=False)
        self._last = 0.0
        self.condition: Callable[[], str | None] = lambda: None
        """What the bus or the log imposes on the state now (the service's `condition`)."""

    def __enter__(self) -> LiveView:
        self._live.start()
        self.refresh(force=True)
        return self

    def __exit__(self, *exc: object) -> None:
        self.refresh(force=True)
        self._live.stop()

    def print(self, line: str) -> None:
        self._live.console.print(line, markup=False, highlight=False)

    def stream(self) -> _LineStream:
        """A text stream whose lines print above the view (for logging handlers, which keep
        their own reference to stderr and would otherwise tear the display)."""
        return _LineStream(self)

    def refresh(self, force: bool = False) -> None:
        now = time.monotonic()
        if force or now - self._last >= self.period:
            self._last = now
            self._live.update(render(snapshot(self.monitor, self.condition()), self.title),
                              refresh=True)

    async def run(self, stop: asyncio.Event) -> None:
        """Refresh every ``period`` seconds until ``stop`` is set."""
        while not stop.is_set():
            self.refresh()
            try:
                await asyncio.wait_for(stop.wait(), self.period)
            except TimeoutError:
                pass


class _LineStream:
    """Write-only text stream: complete lines go to ``LiveView.print``."""

    def __init__(self, view: LiveView) -> None:
        self._view = view
        self._pending = ""

    def write(self, text: str) -> int:
        self._pending += text
        *lines, self._pending = self._pending.split("\n")
        for line in lines:
            self._view.print(line)
        return len(text)

    def flush(self) -> None:
        if self._pending:
            self._view.print(self._pending)
            self._pending = ""

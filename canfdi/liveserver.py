"""A live Foxglove view of the monitor: the log's channels over Foxglove's WebSocket protocol.

`FoxgloveServer` is a recorder tap (canfdi.io.writer.Tap): every message the recorder writes
(samples, residuals, events, estimates, the log lines, frame blocks) is published on a channel
of the same topic, schema and JSON encoding, at the same (drive) time, so that Foxglove shows
live exactly what it shows from the MCAP log afterwards (the same layout, docs/foxglove-
layout.json). It serves with the ``foxglove-sdk`` package, an optional extra
(``pip install 'canfdi[foxglove]'``).

Messages reach it as the recorder writes them: frames, samples and residual rows in batches,
at least every flush interval (1 s).
"""

from __future__ import annotations

from typing import Any

__all__ = ["BACKLOG_MESSAGES", "FoxgloveServer", "FoxgloveUnavailable", "parse_address"]

BACKLOG_MESSAGES = 1 << 16
"""Messages the server queues per client before it drops the oldest (the SDK's default is
1,024): 65,536 is ten seconds of a sample row, a residual row and a frame block per period at
1 kHz, with room for a diagnosis's events and log lines."""


class FoxgloveUnavailable(RuntimeError):
    """The foxglove-sdk package is not installed."""


def parse_address(text: str) -> tuple[str, int]:
    """``"[HOST:]PORT"`` as (host, port); the host defaults to 127.0.0.1 (this machine only:
    give 0.0.0.0 to serve other machines). ValueError for anything else."""
    host, sep, port = text.rpartition(":")
    if not sep:
        host = "127.0.0.1"
    host = host.strip("[]") or "127.0.0.1"
    try:
        number = int(port)
    except ValueError:
        raise ValueError(f"expected [HOST:]PORT, got {text!r}") from None
    if not 0 <= number <= 65535:
        raise ValueError(f"port must be 0..65535, got {number}")
    return host, number


class FoxgloveServer:
    """Foxglove's WebSocket server, fed by the recorder's tap.

    Parameters
    ----------
    host, port : str, int
        Where to listen (port 0: any free port; `port` says which).
    name : str
        The server's name, shown by Foxglove.

    Raises
    ------
    FoxgloveUnavailable
        Without the foxglove-sdk package.
    OSError
        When the address cannot be bound.
    """

    def __init__(self, host: str = "127.0.0.1", port: int = 8765, name: str = "canfdi") -> None:
        try:
            import foxglove
        except ImportError:
            raise FoxgloveUnavailable(
                "live Foxglove needs the foxglove-sdk package: pip install 'canfdi[foxglove]'"
            ) from None
        self._foxglove = foxglove
        # A context of its own: channels reach this server only, not the SDK's global sinks.
        self._context = foxglove.Context()
        try:
            # The SDK keeps a bounded queue per client and drops its oldest messages when a
            # burst outruns the client: the default lost rows in the test's Python client when
            # a diagnosis burst (events, log lines, sample rows) met a busy machine. A few
            # seconds of every topic at a saturated bus's rate fit in this one.
            self._server = foxglove.start_server(name=name, host=host, port=port,
                                                 context=self._context,
                                                 message_backlog_size=BACKLOG_MESSAGES)
        except RuntimeError as exc:  # the SDK reports a failed bind as a RuntimeError
            raise OSError(f"cannot serve Foxglove on {host}:{port}: {exc}") from None
        self.host = host
        self._channels: dict[str, tuple[tuple[str, bytes], Any]] = {}

    @property
    def port(self) -> int:
        """The port it listens on."""
        return self._server.port

    def __call__(self, topic: str, schema: tuple[str, bytes], log_time_ns: int,
                 data: bytes) -> None:
        """Publish one message (the recorder's tap)."""
        entry = self._channels.get(topic)
        if entry is None or entry[0] is not schema:
            if entry is not None:  # a row topic's schema widened: advertise it anew
                entry[1].close()
            fg = self._foxglove
            channel = fg.Channel(topic, schema=fg.Schema(name=schema[0], encoding="jsonschema",
                                                         data=schema[1]),
                                 message_encoding="json", context=self._context)
            entry = self._channels[topic] = (schema, channel)
        entry[1].log(data, log_time=log_time_ns)

    def close(self) -> None:
        """Stop serving."""
        for _, channel in self._channels.values():
            channel.close()
        self._channels.clear()
        self._server.stop()

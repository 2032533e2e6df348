"""A live Foxglove view of the monitor: the log's channels over Foxglove's WebSocket protocol.

`FoxgloveServer` is a recorder tap (canfdi.io.writer.Tap): every message the recorder writes
(samples, residuals, events, estimates, the log lines, frame blocks) is published on a channel
of the same topic, schema and encoding, at the same (drive) time, so that Foxglove shows
live exactly what it shows from the MCAP log afterwards (the same layout, docs/foxglove-
layout.json). It serves with the ``foxglove-sdk`` package, an optional extra
(``pip install 'canfdi[foxglove]'``).

Messages reach it as the recorder writes them: frames, samples and residual rows in batches,
at least every flush interval (1 s).

A client that does not keep up costs bounded memory: the SDK queues at most
`BACKLOG_MESSAGES` messages per client and drops its oldest beyond, and no message published
here is larger than `LIVE_MESSAGE_BYTES` (a frame block is cut into blocks that small; another
message that large is not published, and counted), so a client's queue holds at most
`BACKLOG_BYTES`. When the SDK starts dropping a client's messages it says so on its logger
``foxglove.websocket.connected_client.send_lossy``; the server counts that client in
`lagging` and says it once. Stopping waits `STOP_WAIT_S` at most for the clients, whatever
they do.
"""

from __future__ import annotations

import logging
import threading
from typing import Any

from canfdi.io.blocks import split_frame_block
from canfdi.io.channels import SCHEMA_BYTES
from canfdi.io.schemas import TOPIC_FRAMES
from canfdi.io.segmented import Schema

__all__ = ["BACKLOG_BYTES", "BACKLOG_MESSAGES", "LIVE_MESSAGE_BYTES", "STOP_WAIT_S",
           "FoxgloveServer", "FoxgloveUnavailable", "parse_address"]

log = logging.getLogger("canfdi.liveserver")

LIVE_MESSAGE_BYTES = 16 * 1024
"""The largest message published live: a sample or residual row, an event or a log line is
well under 1 KiB; a frame block (up to a flush interval of frames, 130 KB at 100 Hz) is cut."""
BACKLOG_BYTES = 64 * 1024 * 1024
"""What a client that does not read may cost: its queue's messages times their largest."""
BACKLOG_MESSAGES = BACKLOG_BYTES // LIVE_MESSAGE_BYTES
"""Messages the server queues per client before it drops the oldest (the SDK's default is
1,024, which lost rows in the test's Python client when a diagnosis burst met a busy machine):
4,096 is 20 s of a sample row and a residual row per period at 100 Hz, 2 s at 1 kHz."""
STOP_WAIT_S = 0.5
"""How long stopping waits for the server to close its clients (the SDK's stop waits for each
client's queue to drain: 44 s with one that stopped reading)."""


_LOSSY_LOGGER = "foxglove.websocket.connected_client.send_lossy"
"""Where foxglove-sdk (through pyo3-log) says "outbox for client ADDRESS full": from then on
it drops that client's oldest messages."""


class _LaggingClients(logging.Handler):
    """Counts the clients whose outbox the SDK found full, and says each once."""

    def __init__(self) -> None:
        super().__init__(logging.INFO)
        self.clients: set[str] = set()

    def emit(self, record: logging.LogRecord) -> None:
        text = record.getMessage()
        if not text.startswith("outbox for client ") or not text.endswith(" full"):
            return
        client = text[len("outbox for client "):-len(" full")]
        if client not in self.clients:
            self.clients.add(client)
            log.warning("Foxglove: client %s does not keep up: its oldest messages are dropped "
                        "(it may queue %d messages, %d MiB)", client, BACKLOG_MESSAGES,
                        BACKLOG_BYTES // 2**20)


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
        self._lagging = _LaggingClients()
        lossy = logging.getLogger(_LOSSY_LOGGER)
        lossy.setLevel(logging.INFO)  # the SDK's line is at INFO: kept from the root handlers
        lossy.propagate = False
        lossy.addHandler(self._lagging)
        try:
            # The SDK keeps a queue per client, bounded in messages, and drops its oldest when
            # a client falls behind: with our messages bounded in size, a bound in bytes.
            self._server = foxglove.start_server(name=name, host=host, port=port,
                                                 context=self._context,
                                                 message_backlog_size=BACKLOG_MESSAGES)
        except RuntimeError as exc:  # the SDK reports a failed bind as a RuntimeError
            lossy.removeHandler(self._lagging)
            raise OSError(f"cannot serve Foxglove on {host}:{port}: {exc}") from None
        self.host = host
        self._channels: dict[str, tuple[Schema, Any]] = {}
        self.oversize = 0
        """Messages not published live for their size (`LIVE_MESSAGE_BYTES`)."""
        # Every topic of a fixed schema advertised now, not with its first message: a client
        # that connects at the start subscribes before the first event, which would otherwise
        # go out on a channel nobody has subscribed to yet (a fast run's events all do).
        for topic, schema in SCHEMA_BYTES.items():
            self._advertise(topic, schema)

    @property
    def lagging(self) -> int:
        """Clients that fell behind so far (the SDK dropped their oldest messages)."""
        return len(self._lagging.clients)

    @property
    def port(self) -> int:
        """The port it listens on."""
        return self._server.port

    def __call__(self, topic: str, schema: Schema, log_time_ns: int,
                 data: bytes) -> None:
        """Publish one message (the recorder's tap): a frame block larger than
        `LIVE_MESSAGE_BYTES` as several, another message that large not at all (counted in
        `oversize`, said once)."""
        if len(data) > LIVE_MESSAGE_BYTES:
            if topic != TOPIC_FRAMES:
                if not self.oversize:
                    log.warning("Foxglove: a %s message of %d bytes is not published live "
                                "(at most %d bytes)", topic, len(data), LIVE_MESSAGE_BYTES)
                self.oversize += 1
                return
            for t, piece in split_frame_block(data, log_time_ns, LIVE_MESSAGE_BYTES):
                self._log(topic, schema, t, piece)
            return
        self._log(topic, schema, log_time_ns, data)

    def _log(self, topic: str, schema: Schema, log_time_ns: int,
             data: bytes) -> None:
        entry = self._channels.get(topic)
        if entry is None or entry[0] is not schema:
            entry = self._advertise(topic, schema)
        entry[1].log(data, log_time=log_time_ns)

    def _advertise(self, topic: str, schema: Schema) -> tuple[Schema, Any]:
        """The topic's channel with this schema (the one before, a row topic's whose schema
        changed, closed)."""
        entry = self._channels.get(topic)
        if entry is not None:
            entry[1].close()
        fg = self._foxglove
        full = Schema(*schema)
        channel = fg.Channel(topic, schema=fg.Schema(name=full.name, encoding=full.encoding,
                                                     data=full.data),
                             message_encoding=full.message_encoding, context=self._context)
        entry = self._channels[topic] = (schema, channel)
        return entry

    def close(self) -> None:
        """Stop serving, waiting `STOP_WAIT_S` at most (the SDK's stop goes on in the
        background; it does not hold the interpreter)."""
        for _, channel in self._channels.values():
            channel.close()
        self._channels.clear()
        stopping = threading.Thread(target=self._server.stop, name="foxglove-stop", daemon=True)
        stopping.start()
        stopping.join(STOP_WAIT_S)
        if stopping.is_alive():
            log.warning("Foxglove: a client still had messages queued; stopped without "
                        "waiting for it")
        logging.getLogger(_LOSSY_LOGGER).removeHandler(self._lagging)

"""`Channel`: one topic of a recording, its rows buffered and encoded into MCAP messages.

Every topic the recorder writes is a `Channel` of a buffer (what waits: packed frames, rows of
numbers, ready messages) and an encoder (how a batch of it becomes messages, with which
schema): ``/can/frames`` a `FrameBuffer` and `FrameBlockEncoder` (a block per message), each
row topic of canfdi.io.rowtopics a `Rows` and `RowTopicEncoder` (a message per row), every
other topic a `MessageBuffer` and `MessageEncoder` (messages encoded by the caller, written at
once). `Channel.emit` hands the messages to a `Sink`: canfdi.io.writer's `McapRecorder`.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from typing import Any, Protocol

import numpy as np

from canfdi.io.blocks import Rows, encode_frame_block, unique_names
from canfdi.io.framebuffer import FrameRecords
from canfdi.io.mcapwrite import Messages
from canfdi.io.rowencodings import DEFAULT_ROW_ENCODING, row_format
from canfdi.io.rowtopics import RowLayout
from canfdi.io.schemas import GENERIC_SCHEMA, SCHEMAS, TOPIC_FRAMES
from canfdi.io.segmented import Schema

__all__ = [
    "GENERIC_SCHEMA_BYTES",
    "SCHEMA_BYTES",
    "Channel",
    "FrameBlockEncoder",
    "MessageBuffer",
    "MessageEncoder",
    "RowTopicEncoder",
    "Sink",
    "row_channel",
    "schema_bytes",
]

# Serialised once: every segment registers the same bytes.
SCHEMA_BYTES: dict[str, Schema] = {
    topic: Schema(name, json.dumps(schema).encode()) for topic, (name, schema) in SCHEMAS.items()
}
"""Every fixed-schema topic's schema as registered: (name, JSON bytes)."""
GENERIC_SCHEMA_BYTES = Schema(GENERIC_SCHEMA[0], json.dumps(GENERIC_SCHEMA[1]).encode())
"""The schema of a topic canfdi does not describe, as registered."""


def schema_bytes(topic: str) -> Schema:
    """The registered schema of a topic whose schema does not depend on the run."""
    return SCHEMA_BYTES.get(topic, GENERIC_SCHEMA_BYTES)


class Sink(Protocol):
    """Where a channel's messages go."""

    def message(self, topic: str, schema: Schema, timestamp_ns: int, data: bytes, rows: int,
                now: float) -> None:
        """One message holding ``rows`` rows."""

    def row_messages(self, topic: str, schema: Schema, t_ns: np.ndarray, data: Messages,
                     now: float) -> None:
        """One message per row, at the rows' times (a list, or an (N, size) uint8 array)."""


class Channel:
    """One topic: a buffer of rows and the encoder that turns them into messages.

    Parameters
    ----------
    topic : str
        The MCAP topic.
    buffer : object
        What waits: ``count`` rows, ``take(n)`` removes the first ``n``.
    encoder : object
        ``encode(taken)`` -> (schema, times, messages, rows per message).
    limit : int
        Rows of a full batch: `emit` with ``full_only`` writes only full batches.
    per_row : bool
        One message per row (a row topic): the messages go to `Sink.row_messages` at once.

    Examples
    --------
    >>> class Printer:
    ...     def message(self, topic, schema, t, data, rows, now):
    ...         print(topic, schema[0], t, data, rows)
    >>> channel = Channel("/x", MessageBuffer(), MessageEncoder(schema_bytes("/x")), 1)
    >>> channel.buffer.append(7, b'{"a":1}')
    >>> channel.emit(Printer(), now=0.0, full_only=True)
    /x canfdi.Json 7 b'{"a":1}' 1
    """

    __slots__ = ("buffer", "encoder", "limit", "per_row", "topic")

    def __init__(self, topic: str, buffer: Any, encoder: Any, limit: int,
                 per_row: bool = False) -> None:
        self.topic = topic
        self.buffer = buffer
        self.encoder = encoder
        self.limit = int(limit)
        self.per_row = per_row

    @property
    def full(self) -> bool:
        """A full batch is waiting."""
        return self.buffer.count >= self.limit

    def emit(self, sink: Sink, now: float, full_only: bool) -> None:
        """Write the buffered rows as messages: every full batch, and the rest unless
        ``full_only``."""
        buffer, limit = self.buffer, self.limit
        while buffer.count >= limit or (not full_only and buffer.count):
            schema, times, data, rows = self.encoder.encode(
                buffer.take(min(limit, buffer.count)))
            if self.per_row:
                sink.row_messages(self.topic, schema, times, data, now)
                continue
            for t, message in zip(times, data, strict=True):
                sink.message(self.topic, schema, t, message, rows, now)


class MessageBuffer:
    """Messages encoded by the caller, waiting: (log time, bytes)."""

    __slots__ = ("_messages",)

    def __init__(self) -> None:
        self._messages: list[tuple[int, bytes]] = []

    @property
    def count(self) -> int:
        return len(self._messages)

    def append(self, timestamp_ns: int, data: bytes) -> None:
        self._messages.append((timestamp_ns, data))

    def take(self, n: int) -> list[tuple[int, bytes]]:
        taken, self._messages = self._messages[:n], self._messages[n:]
        return taken


class MessageEncoder:
    """Messages already encoded, with a fixed schema."""

    __slots__ = ("schema",)

    def __init__(self, schema: Schema) -> None:
        self.schema = schema

    def encode(self, taken: list[tuple[int, bytes]]
               ) -> tuple[Schema, list[int], list[bytes], int]:
        return self.schema, [t for t, _ in taken], [d for _, d in taken], 1


class FrameBlockEncoder:
    """A `FrameBuffer`'s frames as one ``/can/frames`` block message."""

    __slots__ = ("schema",)

    def __init__(self) -> None:
        self.schema = schema_bytes(TOPIC_FRAMES)

    def encode(self, taken: FrameRecords) -> tuple[Schema, list[int], list[bytes], int]:
        t0, records, count, long, statuses_json = taken
        return self.schema, [t0], [encode_frame_block(records, count, t0, statuses_json,
                                                      long)], count


class RowTopicEncoder:
    """Rows of a row topic (`RowLayout`) as one message each, named by the current name lists
    and drive, in a row encoding of canfdi.io.rowencodings (``"cdr"`` by default).

    Parameters
    ----------
    layout : RowLayout
        The topic's fields.
    encoding : str
        A name of `ROW_ENCODINGS`.

    Examples
    --------
    >>> from canfdi.io.rowtopics import ROW_LAYOUTS
    >>> encoder = RowTopicEncoder(ROW_LAYOUTS["/canfdi/residuals"], "json")
    >>> encoder.rename(encoder.check_names((["r0"],)))
    >>> columns = (np.array([5]), np.array([3]), np.array([[0.5]]), np.array([[1.0]]),
    ...            np.array([[2.0]]))
    >>> schema, times, data, rows = encoder.encode(columns)
    >>> schema.name
    'canfdi.Residuals'
    >>> print(data[0].decode())
    {"timestamp":{"sec":0,"nsec":5},"k":3,"r":{"r0":0.5},...,"statistic":{"r0":2.0}}
    >>> encoder = RowTopicEncoder(ROW_LAYOUTS["/canfdi/residuals"])
    >>> encoder.rename(encoder.check_names((["r0"],)))
    >>> schema, times, data, rows = encoder.encode(columns)
    >>> schema.name, schema.message_encoding, data.shape
    ('canfdi/msg/Residuals', 'cdr', (1, 44))
    """

    __slots__ = ("_format", "drive", "given", "layout", "names")

    def __init__(self, layout: RowLayout, encoding: str = DEFAULT_ROW_ENCODING) -> None:
        self.layout = layout
        self._format = row_format(layout, encoding)
        self.names: tuple[list[str], ...] = tuple([] for _ in layout.names)
        # The caller's name lists as last given, for a cheap identity check.
        self.given: tuple[Any, ...] = (None,) * len(layout.names)
        self.drive: str | None = None

    def check_names(self, names: Sequence[Sequence[str]]) -> tuple[list[str], ...]:
        """The name lists as lists of str; ValueError if one repeats a name."""
        if len(names) != len(self.layout.names):
            raise ValueError(f"{self.layout.topic} takes {len(self.layout.names)} name lists "
                             f"({', '.join(self.layout.names)}), got {len(names)}")
        return tuple(unique_names(listed, what)
                     for listed, what in zip(names, self.layout.names, strict=True))

    def rename(self, names: tuple[list[str], ...]) -> None:
        """Name the rows from now on (the buffered ones must be written first)."""
        self.names = names
        self._format.reset()

    def set_drive(self, drive: str | None) -> None:
        """The drive of the rows from now on (the buffered ones must be written first)."""
        self.drive = drive
        self._format.reset()

    def encode(self, taken: tuple[np.ndarray, ...]) -> tuple[Schema, np.ndarray, Messages, int]:
        t_ns = taken[0]
        n, i = len(t_ns), 1 + len(self.layout.ints)
        ints = np.column_stack(taken[1:i])
        floats = np.hstack([column.reshape(n, width) for column, width in
                            zip(taken[i:], self.layout.widths(self.names), strict=True)])
        schema, data = self._format.encode(self.names, self.drive, t_ns, ints, floats)
        return schema, t_ns, data, 1


def row_channel(layout: RowLayout, limit: int, encoding: str = DEFAULT_ROW_ENCODING) -> Channel:
    """The channel of a row topic, its rows in the row encoding named."""
    return Channel(layout.topic, Rows(layout.kinds), RowTopicEncoder(layout, encoding), limit,
                   per_row=True)

"""How a row topic's rows become messages, chosen by name in one registry (`ROW_ENCODINGS`).

``"cdr"`` (the default): a ROS 2 message per row (schema encoding ``"ros2msg"``, message
encoding ``"cdr"``, canfdi.io.cdr): fixed-size records, a block encoded as one numpy array;
each set of names its own exact schema, and so its own channel (drives of the same names
share one: the drive is a field of the row).

``"json"``: a JSON message per row (schema encoding ``"jsonschema"``), the layout of logs
before the binary rows, for tools that read JSON only; its schema names every name the topic
has held (a monitor of several drives gives the union).

Both are plotted by Foxglove per message (``/canfdi/residuals.r.s_i_f`` for CDR,
``/canfdi/residuals.r["s:i_f"]`` for JSON) and read back by canfdi.io.reader, which decodes
each channel by its own encoding.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from canfdi.io.blocks import RowEncoder
from canfdi.io.cdr import (
    MESSAGE_ENCODING_CDR,
    SCHEMA_ENCODING_ROS2,
    CdrRowEncoder,
    row_definition,
)
from canfdi.io.mcapwrite import Messages
from canfdi.io.rowtopics import RowLayout
from canfdi.io.segmented import Schema

__all__ = ["DEFAULT_ROW_ENCODING", "ROW_ENCODINGS", "CdrRows", "JsonRows", "RowFormat",
           "row_format"]


class RowFormat(Protocol):
    """One row topic's rows as messages, in one encoding."""

    def reset(self) -> None:
        """The names or the drive changed (the buffered rows are written already)."""

    def encode(self, names: tuple[list[str], ...], drive: str | None, t_ns: NDArray[np.int64],
               ints: NDArray[np.int64], floats: NDArray[np.float64]) -> tuple[Schema, Messages]:
        """The schema and messages of N rows: times (N,), integer fields (N, I), floats (N, W)
        with the groups' columns side by side."""


class JsonRows:
    """A JSON message per row (canfdi.io.blocks' `RowEncoder`); the schema the union of the
    names seen so far."""

    __slots__ = ("_encoder", "_known", "layout", "schema")

    def __init__(self, layout: RowLayout) -> None:
        self.layout = layout
        self._encoder: RowEncoder | None = None
        self._known: tuple[list[str], ...] = tuple([] for _ in layout.names)
        self.schema: Schema | None = None

    def reset(self) -> None:
        self._encoder = None

    def encode(self, names: tuple[list[str], ...], drive: str | None, t_ns: NDArray[np.int64],
               ints: NDArray[np.int64], floats: NDArray[np.float64]) -> tuple[Schema, Messages]:
        encoder = self._encoder
        if encoder is None:
            extra = {} if drive is None else {"drive": drive}
            encoder = self._encoder = RowEncoder(
                self.layout.ints, [(key, names[which]) for key, which in self.layout.groups],
                extra)
            self._widen(names)
        assert self.schema is not None
        return self.schema, encoder.encode(t_ns, ints, floats)

    def _widen(self, names: tuple[list[str], ...]) -> None:
        """Add the current names to the schema's."""
        known = self._known
        if self.schema is not None and all(
                name in have for listed, have in zip(names, known, strict=True)
                for name in listed):
            return
        for listed, have in zip(names, known, strict=True):
            have.extend(name for name in listed if name not in have)
        schema = self.layout.schema(*known)
        self.schema = Schema(schema["title"], json.dumps(schema).encode())


class CdrRows:
    """A ROS 2 CDR message per row (canfdi.io.cdr); a schema per names and drive, made once."""

    __slots__ = ("_current", "_made", "layout", "type_name")

    def __init__(self, layout: RowLayout) -> None:
        self.layout = layout
        title = layout.schema(*([] for _ in layout.names)).get("title", layout.topic)
        self.type_name = title.replace(".", "/msg/", 1)  # canfdi.Sample -> canfdi/msg/Sample
        self._made: dict[tuple, tuple[Schema, CdrRowEncoder]] = {}
        self._current: tuple[Schema, CdrRowEncoder] | None = None

    def reset(self) -> None:
        self._current = None

    def encode(self, names: tuple[list[str], ...], drive: str | None, t_ns: NDArray[np.int64],
               ints: NDArray[np.int64], floats: NDArray[np.float64]) -> tuple[Schema, Messages]:
        current = self._current
        if current is None:
            key = (drive, tuple(tuple(listed) for listed in names))
            current = self._made.get(key)
            if current is None:
                current = self._made[key] = self._make(names, drive)
            self._current = current
        schema, encoder = current
        return schema, encoder.encode(t_ns, ints, floats)

    def _make(self, names: tuple[list[str], ...], drive: str | None
              ) -> tuple[Schema, CdrRowEncoder]:
        layout = self.layout
        groups = [(key, names[which], layout.names[which]) for key, which in layout.groups]
        text = row_definition(self.type_name, layout.ints, groups, drive is not None)
        schema = Schema(self.type_name, text.encode(), SCHEMA_ENCODING_ROS2,
                        MESSAGE_ENCODING_CDR)
        width = sum(len(listed) for _, listed, _ in groups)
        return schema, CdrRowEncoder(len(layout.ints), width, drive)


ROW_ENCODINGS: dict[str, Callable[[RowLayout], RowFormat]] = {"cdr": CdrRows, "json": JsonRows}
"""Every row encoding by name."""
DEFAULT_ROW_ENCODING = "cdr"


def row_format(layout: RowLayout, encoding: str) -> RowFormat:
    """The rows of ``layout`` in the encoding named; ValueError naming the known ones."""
    make = ROW_ENCODINGS.get(encoding)
    if make is None:
        raise ValueError(f"unknown row encoding {encoding!r} (known: "
                         f"{', '.join(sorted(ROW_ENCODINGS))})")
    return make(layout)


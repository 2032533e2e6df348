"""The row topics of a log, one registry: each topic's fields, JSON schema and older layout.

A row topic holds one message per row (Foxglove plots every one): the row's time, its integer
fields, its groups of named numbers (``<group>: {name: number, ...}``) and its drive, the
groups' names known only at run time (a model's inputs, a design's residuals), in a row
encoding of canfdi.io.rowencodings (ROS 2 CDR, or JSON). canfdi.io.writer's `McapRecorder`
gives every registered topic a buffered channel (`McapRecorder.write_rows`) and
canfdi.io.reader's `read_rows` reads any of them back, so that adding a topic is its JSON
schema (canfdi.io.schemas, whose title also names its ROS 2 type) and one `register_row_topic`
line.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from canfdi.io.blocks import decode_residual_block, decode_sample_block
from canfdi.io.schemas import TOPIC_RESIDUALS, TOPIC_SAMPLES, residual_schema, sample_schema

__all__ = ["ROW_LAYOUTS", "LegacyBlock", "RowLayout", "register_row_topic"]

LegacyBlock = Callable[[Mapping[str, Any]], tuple[tuple[list[str], ...], tuple[np.ndarray, ...]]]
"""Reads one block message of an older layout: (name lists, columns in `RowLayout.columns`
order)."""


@dataclass(frozen=True)
class RowLayout:
    """The fields of a row topic's messages.

    Parameters
    ----------
    topic : str
        The MCAP topic.
    ints : tuple of str
        Integer fields after ``"timestamp"``, in order (``("k", "gap")``).
    groups : tuple of (str, int)
        Objects of named numbers, in order, each with the index of the name list that names
        its members (``(("u", 0), ("z", 1))``: inputs, then outputs).
    schema : callable
        The topic's JSON schema, of the name lists (``sample_schema(inputs, outputs)``).
    names : tuple of str
        What each name list names (``("input", "output")``), for error messages.
    defaults : mapping of str to int
        Integer fields older messages may lack, and their value then.
    legacy : callable, optional
        Decodes a block message of an older layout (one that holds ``"count"`` rows).

    Examples
    --------
    >>> layout = RowLayout("/test/rows", ("k",), (("x", 0),), lambda names: {}, ("x",))
    >>> layout.columns
    ('t_ns', 'k', 'x')
    """

    topic: str
    ints: tuple[str, ...]
    groups: tuple[tuple[str, int], ...]
    schema: Callable[..., dict[str, Any]]
    names: tuple[str, ...]
    defaults: Mapping[str, int] = field(default_factory=dict)
    legacy: LegacyBlock | None = None

    @property
    def columns(self) -> tuple[str, ...]:
        """The buffered columns: the time, the integer fields, the groups."""
        return ("t_ns", *self.ints, *(key for key, _ in self.groups))

    @property
    def kinds(self) -> tuple[type, ...]:
        """Each column's dtype."""
        return (np.int64,) * (1 + len(self.ints)) + (np.float64,) * len(self.groups)

    def widths(self, names: tuple[list[str], ...]) -> tuple[int, ...]:
        """The widths of the groups' columns for these name lists."""
        return tuple(len(names[which]) for _, which in self.groups)


ROW_LAYOUTS: dict[str, RowLayout] = {}
"""Every row topic by name, in registration order (the order the recorder writes them out)."""


def register_row_topic(layout: RowLayout) -> RowLayout:
    """Add a row topic (ValueError if another layout has its name); returns ``layout``."""
    known = ROW_LAYOUTS.get(layout.topic)
    if known is not None and known != layout:
        raise ValueError(f"row topic {layout.topic} is registered already")
    ROW_LAYOUTS[layout.topic] = layout
    return layout


def _sample_block(message: Mapping[str, Any]) -> tuple[tuple[list[str], ...],
                                                         tuple[np.ndarray, ...]]:
    names = (list(message["u"]), list(message["z"]))
    k, t, gap, u, z = decode_sample_block(message, *names)
    return names, (t, k, gap, u, z)


def _residual_block(message: Mapping[str, Any]) -> tuple[tuple[list[str], ...],
                                                           tuple[np.ndarray, ...]]:
    names = list(message["names"])
    k, t, r, rn, stat = decode_residual_block(message, names)
    return (names,), (t, k, r, rn, stat)


SAMPLES = register_row_topic(RowLayout(
    TOPIC_SAMPLES, ("k", "gap"), (("u", 0), ("z", 1)), sample_schema, ("input", "output"),
    defaults={"gap": 0}, legacy=_sample_block))
RESIDUALS = register_row_topic(RowLayout(
    TOPIC_RESIDUALS, ("k",), (("r", 0), ("normalized", 0), ("statistic", 0)), residual_schema,
    ("residual",), legacy=_residual_block))

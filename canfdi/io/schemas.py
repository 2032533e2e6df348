"""The MCAP contract of a canfdi log: topics, block encodings, JSON schemas, FRAME_DTYPE.

Every log is one MCAP file per run (or a family of rotated segments, canfdi.io.segments),
zstd-compressed chunks, JSON-encoded messages described by JSON schemas (schema encoding
``"jsonschema"``, message encoding ``"json"``), so that Foxglove can open the log directly.
Every message carries a ``"timestamp": {"sec": int, "nsec": int}`` field (Foxglove's time
type); the MCAP log_time and publish_time of the message are the same instant in integer
nanoseconds since the epoch. canfdi.io.writer writes this contract, canfdi.io.reader and
canfdi.io.scan read it, canfdi.io.blocks packs and unpacks the block messages.

Topics
------
The topic names and message shapes are a contract other code (replay, dashboards) relies on.
The three busy topics are *block* topics: one MCAP message holds many rows (an MCAP message
costs the pure-Python writer about 20 us, a row of a block well under one), and its
``timestamp`` and log_time are those of its first row. Read them back with canfdi.io.reader's
`read_frames`, `read_samples` and `read_residuals`, which also read logs of the older
one-row-per-message layout.

``/can/frames`` (`TOPIC_FRAMES`), ``"encoding": "canfdi.frames.v1"`` (`FRAMES_ENCODING`)
    Every raw frame, valid or not: ``{"timestamp", "encoding", "count": N, "statuses": [str],
    "frames": base64 string, "long": {row: hex}}`` (``"long"`` only when needed). ``frames``
    packs N little-endian 24-byte records of `FRAME_DTYPE`: ``t_ns`` int64 (arrival or send
    time), ``id`` uint32, ``dlc`` uint8, ``flags`` uint8 (`FLAG_EXTENDED` = bit 0 for a 29-bit
    ID; bits 1-3 `FLAG_REMOTE`, `FLAG_ERROR`, `FLAG_FD` as in `canfdi.bus.frames`), ``status``
    uint8 (an index into the message's ``statuses``), a pad byte, and ``data`` 8 bytes (the
    payload, zero-padded). A frame's payload is its first min(dlc, 8) data bytes, unless
    ``"long"`` holds its full payload (as hex, keyed by its row in the block as a decimal
    string): CAN FD payloads and payloads whose length disagrees with the DLC. Statuses are
    ``"ok"``, ``"crc"``, ``"dlc"``, ``"unknown_id"``... (`FRAME_STATUSES`, the assembler's
    ``STATUS_NAMES``), or ``"sent"`` (``SENT``) for frames the monitor itself sent; other
    strings are recorded as given.
``/canfdi/samples`` (`TOPIC_SAMPLES`), ``"encoding": "canfdi.samples.v1"``
    Decoded samples: ``{"timestamp", "encoding", "count": N, "k": [int], "t_ns": [int],
    "gap": [int], "u": {input: [number]}, "z": {output: [number]}}``, every list N long, the
    maps in the model's input and output order.
``/canfdi/residuals`` (`TOPIC_RESIDUALS`), ``"encoding": "canfdi.residuals.v1"``
    ``{"timestamp", "encoding", "count": N, "k": [int], "t_ns": [int], "names": [residual],
    "r": {residual: [number]}, "normalized": {..}, "statistic": {..}}``: columns by residual
    name, ``names`` giving their order; the statistic is Page-Hinkley's max(g+, g-).

    The float columns of both are JSON lists by default. With ``float_encoding="base64"``
    (`McapRecorder`) each is instead a base64 string of N little-endian float64: exact, NaN
    and inf kept, and about 30 times cheaper to write (formatting a float as JSON text costs
    about 0.5 us). The readers take either.
``/canfdi/residuals_plot`` (`TOPIC_RESIDUALS_PLOT`)
    A decimated per-row copy of the residuals for plotting (Foxglove plots one value per
    message): ``{"timestamp", "k", "r": {residual: value}, "normalized": {..},
    "statistic": {..}}``, the first row of every ``1 / plot_rate`` s slot of log time.
``/canfdi/estimates`` (`TOPIC_ESTIMATES`)
    ``{"timestamp", "k", "hypothesis": str, "estimates": {..}, "variances": {..}}``.
``/canfdi/events`` (`TOPIC_EVENTS`)
    `FaultEvent.as_dict` plus ``"timestamp"``.
``/canfdi/status`` (`TOPIC_STATUS`)
    ``{"timestamp", "state": str, "samples": int, "frames": {counter: int},
    "active_faults": int}``.

Estimates, events and status are one message each (they are rare). Other topics may be written
with canfdi.io.writer's `McapRecorder.write`; they get a permissive object schema
(`GENERIC_SCHEMA`). Non-finite floats (NaN, inf),
which JSON cannot express, are written as ``null`` (read back as NaN).

Run-level information (configuration YAML, design JSON, ground truth, version: strings chosen by
the caller) goes into an MCAP metadata record named ``"canfdi"`` (`METADATA_NAME`) at the head of
every segment; canfdi.io.reader's `read_metadata` returns it.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from canfdi.bus.frames import SENT, STATUS_NAMES

__all__ = [
    "FRAMES_ENCODING",
    "FRAME_DTYPE",
    "FRAME_STATUSES",
    "GENERIC_SCHEMA",
    "MESSAGE_ENCODING",
    "METADATA_NAME",
    "RESIDUALS_ENCODING",
    "SAMPLES_ENCODING",
    "SCHEMAS",
    "SCHEMA_ENCODING",
    "TOPICS",
    "TOPIC_ESTIMATES",
    "TOPIC_EVENTS",
    "TOPIC_FRAMES",
    "TOPIC_RESIDUALS",
    "TOPIC_RESIDUALS_PLOT",
    "TOPIC_SAMPLES",
    "TOPIC_STATUS",
]

TOPIC_FRAMES = "/can/frames"
TOPIC_SAMPLES = "/canfdi/samples"
TOPIC_RESIDUALS = "/canfdi/residuals"
TOPIC_RESIDUALS_PLOT = "/canfdi/residuals_plot"
TOPIC_ESTIMATES = "/canfdi/estimates"
TOPIC_EVENTS = "/canfdi/events"
TOPIC_STATUS = "/canfdi/status"
TOPICS = (
    TOPIC_FRAMES,
    TOPIC_SAMPLES,
    TOPIC_RESIDUALS,
    TOPIC_RESIDUALS_PLOT,
    TOPIC_ESTIMATES,
    TOPIC_EVENTS,
    TOPIC_STATUS,
)
FRAMES_ENCODING = "canfdi.frames.v1"
SAMPLES_ENCODING = "canfdi.samples.v1"
RESIDUALS_ENCODING = "canfdi.residuals.v1"
FRAME_STATUSES = (*STATUS_NAMES, SENT)
"""Frame statuses the recorder knows in advance (the assembler's, and ``"sent"``)."""
FRAME_DTYPE = np.dtype(
    [
        ("t_ns", "<i8"),
        ("id", "<u4"),
        ("dlc", "u1"),
        ("flags", "u1"),
        ("status", "u1"),
        ("pad", "u1"),
        ("data", "u1", 8),
    ]
)
"""One packed record of a ``/can/frames`` block (24 bytes, little-endian, no alignment)."""
METADATA_NAME = "canfdi"
SCHEMA_ENCODING = "jsonschema"
MESSAGE_ENCODING = "json"

# ------------------------------------------------------------------------------------------
# JSON schemas
# ------------------------------------------------------------------------------------------

_TIME = {
    "type": "object",
    "title": "time",
    "properties": {
        "sec": {"type": "integer", "minimum": 0},
        "nsec": {"type": "integer", "minimum": 0, "maximum": 999_999_999},
    },
    "required": ["sec", "nsec"],
}
# Maps keyed by names known only at run time. The empty "properties" keeps schema readers that
# only walk "properties" (Foxglove's JSON schema parser) from failing on them.
_NUMBER_MAP = {
    "type": "object",
    "properties": {},
    "additionalProperties": {"type": ["number", "null"]},
}
_OPT_INT = {"type": ["integer", "null"]}
_OPT_STR = {"type": ["string", "null"]}
_INT_LIST = {"type": "array", "items": {"type": "integer"}}
_COLUMNS = {
    "type": "object",
    "properties": {},
    "description": (
        "one column of count values per name: a list of numbers (null for NaN and inf), or "
        "with float_encoding base64 a base64 string of count little-endian float64"
    ),
    "additionalProperties": {
        "oneOf": [
            {"type": "array", "items": {"type": ["number", "null"]}},
            {"type": "string", "contentEncoding": "base64"},
        ]
    },
}
_COUNT = {"type": "integer", "minimum": 0, "description": "rows in this block"}


def _object(title: str, properties: dict[str, Any], optional: Sequence[str] = ()) -> dict[str, Any]:
    props = {"timestamp": _TIME, **properties}
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": title,
        "type": "object",
        "properties": props,
        "required": [key for key in props if key not in optional],
    }


def _encoding(name: str) -> dict[str, Any]:
    return {"type": "string", "const": name, "description": "block layout and version"}


_DRIVE = {"type": "string", "description": "the drive (the monitor config's drives:) whose "
                                           "rows these are"}
_RESIDUAL_ROW = _object(
    "canfdi.Residuals",
    {
        "k": {"type": "integer"},
        "r": _NUMBER_MAP,
        "normalized": _NUMBER_MAP,
        "statistic": _NUMBER_MAP,
        "drive": _DRIVE,
    },
    optional=("drive",),
)

SCHEMAS: dict[str, tuple[str, dict[str, Any]]] = {
    TOPIC_FRAMES: (
        "canfdi.CanFrameBlock",
        _object(
            "canfdi.CanFrameBlock",
            {
                "encoding": _encoding(FRAMES_ENCODING),
                "count": _COUNT,
                "statuses": {
                    "type": "array",
                    "items": {"type": "string"},
                    "description": "status names; a frame's status byte indexes this list",
                    "examples": [list(FRAME_STATUSES)],
                },
                "frames": {
                    "type": "string",
                    "contentEncoding": "base64",
                    "description": (
                        "count packed little-endian 24-byte records: t_ns int64 (ns since the "
                        "epoch), id uint32, dlc uint8, flags uint8 (bit 0 extended ID, bit 1 "
                        "remote, bit 2 error frame, bit 3 CAN FD), status uint8 (index into "
                        "statuses), pad uint8, data 8 x uint8 (payload, zero-padded)"
                    ),
                },
                "long": {
                    "type": "object",
                    "properties": {},
                    "description": (
                        "full payload (hex) of frames whose payload is not their first "
                        "min(dlc, 8) data bytes (CAN FD), keyed by row in the block"
                    ),
                    "additionalProperties": {"type": "string"},
                },
            },
            optional=("long",),
        ),
    ),
    TOPIC_SAMPLES: (
        "canfdi.SampleBlock",
        _object(
            "canfdi.SampleBlock",
            {
                "encoding": _encoding(SAMPLES_ENCODING),
                "count": _COUNT,
                "k": _INT_LIST,
                "t_ns": _INT_LIST,
                "gap": _INT_LIST,
                "u": _COLUMNS,
                "z": _COLUMNS,
                "drive": _DRIVE,
            },
            optional=("drive",),
        ),
    ),
    TOPIC_RESIDUALS: (
        "canfdi.ResidualBlock",
        _object(
            "canfdi.ResidualBlock",
            {
                "encoding": _encoding(RESIDUALS_ENCODING),
                "count": _COUNT,
                "k": _INT_LIST,
                "t_ns": _INT_LIST,
                "names": {"type": "array", "items": {"type": "string"}},
                "r": _COLUMNS,
                "normalized": _COLUMNS,
                "statistic": _COLUMNS,
                "drive": _DRIVE,
            },
            optional=("drive",),
        ),
    ),
    TOPIC_RESIDUALS_PLOT: ("canfdi.Residuals", _RESIDUAL_ROW),
    TOPIC_ESTIMATES: (
        "canfdi.Estimates",
        _object(
            "canfdi.Estimates",
            {
                "k": {"type": "integer"},
                "hypothesis": {"type": "string"},
                "estimates": _NUMBER_MAP,
                "variances": _NUMBER_MAP,
            },
        ),
    ),
    TOPIC_EVENTS: (
        "canfdi.FaultEvent",
        _object(
            "canfdi.FaultEvent",
            {
                "kind": {"type": "string", "enum": ["detected", "accepted", "refined",
                                                    "unexplained", "mismatch", "matched",
                                                    "taught", "teach_failed"]},
                "sample": {"type": "integer"},
                "timestamp_ns": {"type": "integer"},
                "target": _OPT_STR,
                "index": _OPT_INT,
                "name": _OPT_STR,
                "estimates": _NUMBER_MAP,
                "variances": _NUMBER_MAP,
                "onset_sample": _OPT_INT,
                "detected_sample": _OPT_INT,
                "accepted_sample": _OPT_INT,
                "candidates": {"type": "array", "items": {"type": "object"}},
                "residuals": {"type": "array", "items": {"type": "string"}},
                "drive": _OPT_STR,
            },
        ),
    ),
    TOPIC_STATUS: (
        "canfdi.Status",
        _object(
            "canfdi.Status",
            {
                "state": {"type": "string"},
                "samples": {"type": "integer", "minimum": 0},
                "frames": {
                    "type": "object",
                    "properties": {},
                    "additionalProperties": {"type": "integer"},
                },
                "active_faults": {"type": "integer", "minimum": 0},
            },
        ),
    ),
}
"""Schema name and JSON schema of every known topic."""

GENERIC_SCHEMA = ("canfdi.Json", {"title": "canfdi.Json", "type": "object"})
"""Schema name and JSON schema of a topic written with `McapRecorder.write` that is not one of
`TOPICS`."""

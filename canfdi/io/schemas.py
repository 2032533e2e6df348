"""The MCAP contract of a canfdi log: topics, block encodings, JSON schemas, FRAME_DTYPE.

Every log is one MCAP file per run (or a family of rotated segments, canfdi.io.segments),
zstd-compressed chunks, JSON-encoded messages described by JSON schemas (schema encoding
``"jsonschema"``, message encoding ``"json"``), but for the row topics' rows, ROS 2 messages by
default (canfdi.io.rowencodings, canfdi.io.cdr), so that Foxglove can open the log directly.
Every JSON message carries a ``"timestamp": {"sec": int, "nsec": int}`` field (Foxglove's time
type), every ROS 2 row a ``t_ns``; the MCAP log_time and publish_time of the message are the
same instant in integer nanoseconds since the epoch: the drive's time (the time the frames
carry: the bus's receive time live, the emulated time in a demo), so that a 40 s drive spans
40 s of log time.
canfdi.io.writer writes this contract, canfdi.io.reader and canfdi.io.scan read it,
canfdi.io.blocks packs and unpacks the messages.

Topics
------
The topic names and message shapes are a contract other code (replay, dashboards) relies on.
The busiest topic, the raw frames, is a *block* topic: one MCAP message holds many frames (an
MCAP message costs the writer a few microseconds, a row of a block well under one), and its
``timestamp`` is its earliest frame's. On every topic a message's log time is its own time,
held at the one before it on its topic when that is later (canfdi.io.writer): every reader in
log-time order reads each topic in the order it was written. Samples and residuals are one message
per row, so that Foxglove plots every one. Read them back with canfdi.io.reader's
`read_frames`, `read_samples` and `read_residuals`, which also read the older layouts.

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
``/canfdi/samples`` (`TOPIC_SAMPLES`)
    One message per decoded sample, at the sample's time: ``t_ns, k, gap, u: {input: number},
    z: {output: number}, drive`` (``drive`` on a bus of several drives), the maps in the
    model's input and output order. Foxglove plots every sample by message path
    (``/canfdi/samples.z.speed``); its schema (a ROS 2 definition, canfdi.io.cdr; or, for
    JSON rows, `sample_schema`: ``"timestamp"`` for ``t_ns``, null for a value that is not
    finite) names every input and output, so each path is offered.
``/canfdi/residuals`` (`TOPIC_RESIDUALS`)
    One message per diagnosed sample: ``t_ns, k, r: {residual: number}, normalized: {..},
    statistic: {..}, drive``: raw and normalized residuals and the detection statistic
    (Page-Hinkley's max(g+, g-)); JSON rows' schema `residual_schema`.

    Older logs hold blocks of rows on these two topics
    instead (``"encoding": "canfdi.samples.v1"`` / ``"canfdi.residuals.v1"``, columns as JSON
    lists or base64 float64, canfdi.io.blocks decodes them) and a decimated
    ``/canfdi/residuals_plot``; the readers take both layouts.
``/canfdi/estimates`` (`TOPIC_ESTIMATES`)
    ``{"timestamp", "k", "hypothesis": str, "estimates": {..}, "variances": {..}}``.
``/canfdi/events`` (`TOPIC_EVENTS`)
    `FaultEvent.as_dict` plus ``"timestamp"``, without the fields that are None (so that every
    field has one JSON type).
``/canfdi/log`` (`TOPIC_LOG`)
    ``foxglove.Log`` (Foxglove's own schema, `FOXGLOVE_LOG_SCHEMA`): one line per diagnosis,
    as the CLI prints it, and the monitor's warnings; Foxglove's Log panel shows it.
``/canfdi/status`` (`TOPIC_STATUS`)
    ``{"timestamp", "state": str, "samples": int, "frames": {counter: int},
    "active_faults": int}``.

The row topics (samples, residuals: a message per row, a schema naming the run's signals) are
registered in canfdi.io.rowtopics, with their fields; the recorder registers each one's schema
in a log when it first writes a row. Estimates, events, status and log lines are one message
each (they are rare). Other topics
may be written with canfdi.io.writer's `McapRecorder.write`; they get a permissive object
schema (`GENERIC_SCHEMA`). Non-finite floats (NaN, inf),
which JSON cannot express, are written as ``null`` in JSON messages (read back as NaN).

Every schema is one that JSON-schema readers of Foxglove's lineage accept (Lichtblick's
``parseJsonSchema``, tested under node): an object's fields each have one ``"type"`` (no
unions such as ``["string", "null"]``), and maps keyed by names known only at run time have
``"properties"``.

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
    "FOXGLOVE_LOG_SCHEMA",
    "FRAMES_ENCODING",
    "FRAME_DTYPE",
    "FRAME_STATUSES",
    "GENERIC_SCHEMA",
    "LOG_LEVELS",
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
    "TOPIC_LOG",
    "TOPIC_RESIDUALS",
    "TOPIC_SAMPLES",
    "TOPIC_STATUS",
    "residual_schema",
    "sample_schema",
]

TOPIC_FRAMES = "/can/frames"
TOPIC_SAMPLES = "/canfdi/samples"
TOPIC_RESIDUALS = "/canfdi/residuals"
TOPIC_ESTIMATES = "/canfdi/estimates"
TOPIC_EVENTS = "/canfdi/events"
TOPIC_STATUS = "/canfdi/status"
TOPIC_LOG = "/canfdi/log"
TOPICS = (
    TOPIC_FRAMES,
    TOPIC_SAMPLES,
    TOPIC_RESIDUALS,
    TOPIC_ESTIMATES,
    TOPIC_EVENTS,
    TOPIC_STATUS,
    TOPIC_LOG,
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
LOG_LEVELS = {"debug": 1, "info": 2, "warning": 3, "error": 4, "fatal": 5}
"""foxglove.Log's levels by name (0 is UNKNOWN)."""

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
# Maps keyed by names known only when the log is read (estimates by parameter, frame counters
# by status). The empty "properties" keeps readers that walk only "properties" (Foxglove's JSON
# schema parser) from failing on them.
_NUMBER_MAP = {
    "type": "object",
    "properties": {},
    "additionalProperties": {"type": "number"},
}
_INT = {"type": "integer"}
_STR = {"type": "string"}
_DRIVE = {
    "type": "string",
    "description": "the drive (the monitor config's drives:) it concerns; absent for a "
                   "monitor of one drive",
}
_NOT_FINITE = "null where the value is not finite (NaN, inf)"


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


def _numbers(names: Sequence[str], what: str) -> dict[str, Any]:
    """An object of one number per name (``what`` says what they are)."""
    return {
        "type": "object",
        "description": f"{what}, by name; {_NOT_FINITE}",
        "properties": {name: {"type": "number"} for name in names},
        "required": list(names),
    }


def sample_schema(inputs: Sequence[str], outputs: Sequence[str]) -> dict[str, Any]:
    """The JSON schema of ``/canfdi/samples`` rows of a model with these inputs and outputs
    (names in column order; a monitor of several drives gives the union)."""
    return _object(
        "canfdi.Sample",
        {
            "k": {"type": "integer", "minimum": 0, "description": "sample index"},
            "gap": {"type": "integer", "minimum": 0,
                    "description": "samples lost just before this one"},
            "u": _numbers(inputs, "the inputs u (commands)"),
            "z": _numbers(outputs, "the measured outputs z"),
            "drive": _DRIVE,
        },
        optional=("drive",),
    )


def residual_schema(names: Sequence[str]) -> dict[str, Any]:
    """The JSON schema of ``/canfdi/residuals`` rows with these residuals (in order)."""
    return _object(
        "canfdi.Residuals",
        {
            "k": {"type": "integer", "minimum": 0, "description": "sample index"},
            "r": _numbers(names, "the residuals"),
            "normalized": _numbers(names, "each residual over its noise standard deviation"),
            "statistic": _numbers(names, "each residual's detection statistic "
                                         "(Page-Hinkley max(g+, g-))"),
            "drive": _DRIVE,
        },
        optional=("drive",),
    )


_CANDIDATE = {
    "type": "object",
    "description": "a channel that explains the data as well (its target, index, name and "
                   "estimates), or why teach-in failed (reason)",
    "properties": {
        "target": _STR,
        "index": _INT,
        "name": _STR,
        "estimates": _NUMBER_MAP,
        "reason": _STR,
    },
}

FOXGLOVE_LOG_SCHEMA: dict[str, Any] = {
    "title": "foxglove.Log",
    "description": "A log message",
    "$comment": "Generated by https://github.com/foxglove/foxglove-sdk",
    "type": "object",
    "properties": {
        "timestamp": {
            "type": "object",
            "title": "time",
            "properties": {
                "sec": {
                    "type": "integer",
                    "minimum": 0
                },
                "nsec": {
                    "type": "integer",
                    "minimum": 0,
                    "maximum": 999999999
                }
            },
            "description": "Timestamp of log message"
        },
        "level": {
            "title": "foxglove.LogLevel",
            "description": "Log level",
            "oneOf": [
                {
                    "title": "UNKNOWN",
                    "const": 0,
                    "description": "Unknown log level"
                },
                {
                    "title": "DEBUG",
                    "const": 1,
                    "description": "Debug log level"
                },
                {
                    "title": "INFO",
                    "const": 2,
                    "description": "Info log level"
                },
                {
                    "title": "WARNING",
                    "const": 3,
                    "description": "Warning log level"
                },
                {
                    "title": "ERROR",
                    "const": 4,
                    "description": "Error log level"
                },
                {
                    "title": "FATAL",
                    "const": 5,
                    "description": "Fatal log level"
                }
            ]
        },
        "message": {
            "type": "string",
            "description": "Log message"
        },
        "name": {
            "type": "string",
            "description": "Process or node name"
        },
        "file": {
            "type": "string",
            "description": "Filename"
        },
        "line": {
            "type": "integer",
            "minimum": 0,
            "description": "Line number in the file"
        }
    },
    "required": [
        "timestamp",
        "level",
        "message",
        "name",
        "file",
        "line"
    ]
}
"""Foxglove's ``foxglove.Log`` JSON schema: the Log panel's own message type."""

SCHEMAS: dict[str, tuple[str, dict[str, Any]]] = {
    TOPIC_FRAMES: (
        "canfdi.CanFrameBlock",
        _object(
            "canfdi.CanFrameBlock",
            {
                "encoding": _encoding(FRAMES_ENCODING),
                "count": {"type": "integer", "minimum": 0, "description": "frames in this block"},
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
    TOPIC_ESTIMATES: (
        "canfdi.Estimates",
        _object(
            "canfdi.Estimates",
            {
                "k": _INT,
                "hypothesis": _STR,
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
                "kind": {"type": "string", "enum": ["detected", "named", "accepted", "refined",
                                                    "unexplained", "mismatch", "quiet", "matched",
                                                    "taught", "teach_failed"]},
                "sample": _INT,
                "timestamp_ns": _INT,
                "target": {"type": "string", "enum": ["actuator", "sensor"]},
                "index": _INT,
                "name": _STR,
                "estimates": _NUMBER_MAP,
                "variances": _NUMBER_MAP,
                "onset_sample": _INT,
                "detected_sample": _INT,
                "accepted_sample": _INT,
                "candidates": {"type": "array", "items": _CANDIDATE},
                "residuals": {"type": "array", "items": _STR},
                "drive": _DRIVE,
                "undecided": {"type": "array", "items": {"type": "string",
                                                         "enum": ["form", "size"]}},
            },
            optional=("target", "index", "name", "onset_sample", "detected_sample",
                      "accepted_sample", "drive", "undecided"),
        ),
    ),
    TOPIC_STATUS: (
        "canfdi.Status",
        _object(
            "canfdi.Status",
            {
                "state": _STR,
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
    TOPIC_LOG: ("foxglove.Log", FOXGLOVE_LOG_SCHEMA),
}
"""Schema name and JSON schema of every topic whose schema does not depend on the run (the
row topics' come from `sample_schema` and `residual_schema`)."""

GENERIC_SCHEMA = ("canfdi.Json", {"title": "canfdi.Json", "type": "object", "properties": {}})
"""Schema name and JSON schema of a topic written with `McapRecorder.write` that is not one of
`TOPICS`."""

"""The MCAP log of a monitor run: channels, schemas, rotation, crash-safe flushing, reading back.

One MCAP file per run (or a family of rotated segments), zstd-compressed chunks, JSON-encoded
messages described by JSON schemas (schema encoding ``"jsonschema"``, message encoding
``"json"``), so that Foxglove can open the log directly. Every message carries a
``"timestamp": {"sec": int, "nsec": int}`` field (Foxglove's time type); the MCAP log_time and
publish_time of the message are the same instant in integer nanoseconds since the epoch.

Topics
------
The topic names and message shapes are a contract other code (replay, dashboards) relies on.
The three busy topics are *block* topics: one MCAP message holds many rows (an MCAP message
costs the pure-Python writer about 20 us, a row of a block well under one), and its
``timestamp`` and log_time are those of its first row. Read them back with `read_frames`,
`read_samples` and `read_residuals`, which also read logs of the older one-row-per-message
layout.

``/can/frames`` (`TOPIC_FRAMES`), ``"encoding": "canfdi.frames.v1"`` (`FRAMES_ENCODING`)
    Every raw frame, valid or not: ``{"timestamp", "encoding", "count": N, "statuses": [str],
    "frames": base64 string, "long": {row: hex}}`` (``"long"`` only when needed). ``frames``
    packs N little-endian 24-byte records of `FRAME_DTYPE`: ``t_ns`` int64 (arrival or send
    time), ``id`` uint32, ``dlc`` uint8, ``flags`` uint8 (`FLAG_EXTENDED` = bit 0 for a 29-bit
    ID; bits 1-3 `FLAG_REMOTE`, `FLAG_ERROR`, `FLAG_FD` as in `canfdi.bus.assembler`), ``status``
    uint8 (an index into the message's ``statuses``), a pad byte, and ``data`` 8 bytes (the
    payload, zero-padded). A frame's payload is its first min(dlc, 8) data bytes, unless
    ``"long"`` holds its full payload (as hex, keyed by its row in the block as a decimal
    string): CAN FD payloads and payloads whose length disagrees with the DLC. Statuses are
    ``"ok"``, ``"crc"``, ``"dlc"``, ``"unknown_id"``... (`FRAME_STATUSES`, the assembler's
    ``STATUS_NAMES``), or ``"sent"`` for frames the monitor itself sent; other strings are
    recorded as given.
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
with `McapRecorder.write`; they get a permissive object schema. Non-finite floats (NaN, inf),
which JSON cannot express, are written as ``null`` (read back as NaN).

Run-level information (configuration YAML, design JSON, ground truth, version: strings chosen by
the caller) goes into an MCAP metadata record named ``"canfdi"`` (`METADATA_NAME`) at the head of
every segment; `read_metadata` returns it.

Buffering and crash safety
--------------------------
Frames, samples and residual rows are appended to buffers inside the recorder (0.2 to 2 us a
row, no JSON) and written as one block message when a buffer holds
``block_frames``, ``block_samples`` or ``block_residuals`` rows, on every timed flush, on
`McapRecorder.flush` and on `McapRecorder.close`. The mcap writer in turn keeps the open chunk in
memory and writes it only when it exceeds ``chunk_size`` or on ``Writer.flush()``, which
finishes the open chunk (if it holds a message), writes it and flushes the output stream.
Whenever ``flush_interval`` seconds (on the injected clock) have passed since the last flush,
the recorder writes every buffer out and calls ``Writer.flush()``: the check is a single
comparison inside every write or append (no thread, no lock), and `McapRecorder.flush` forces
it. The flushed bytes are in the operating system's page cache, so a killed process (SIGKILL,
crash) loses only the rows still buffered and the messages of the chunk still open: about the
last ``flush_interval`` seconds, as long as the caller writes at least that often (the
monitor's frames and status messages do; an idle caller should call `McapRecorder.flush`).
There is no fsync: a power loss may lose what the kernel had not yet written back. Such a file
has no summary; `read_log` reads it in file order and stops at the last complete record, so a
block is read back whole or not at all.

Rotation
--------
With ``rotate_bytes`` or ``rotate_seconds``, the first message written after the segment's
file reached ``rotate_bytes`` (bytes reach the file a chunk at a time, so a segment overshoots
by at most a chunk and its summary) or the first write after the segment has been open
``rotate_seconds`` (the buffers are written into it first) finishes the segment cleanly
(summary and footer) and continues in ``<stem>-0001<suffix>``, ``<stem>-0002<suffix>``... next
to the first file, which keeps the given name. `log_segments` lists the family in order. Stale
numbered segments of the same name left by an earlier run are deleted when a recorder starts,
so that the family is this run's only.

Write errors
------------
An `OSError` while writing (typically ENOSPC: disk full) never reaches the caller of the write
methods. The recorder records it (`McapRecorder.last_error`, `McapRecorder.write_errors`), logs
one warning per episode, abandons the segment (its flushed part stays readable as a truncated
file), counts the rows of its unflushed chunk and every block or message written while failing
as dropped (`McapRecorder.messages_dropped`), and retries at most once per ``RETRY_INTERVAL``
seconds, on a later write, by opening the next segment: recording resumes in a new segment when
space returns. Rows still in the recorder's buffers when recording resumes are not lost. The
constructor raises for errors that cannot heal by themselves (a missing directory, no
permission) so that a bad path is reported at start.
"""

from __future__ import annotations

import binascii
import contextlib
import errno
import json
import logging
import math
import re
import struct
import time
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from types import TracebackType
from typing import IO, TYPE_CHECKING, Any, NamedTuple, Self

import numpy as np
from mcap.exceptions import EndOfFile
from mcap.records import Channel, Chunk, Footer, Message, Metadata
from mcap.stream_reader import StreamReader
from mcap.writer import LIBRARY_IDENTIFIER, CompressionType, Writer
from numpy.typing import ArrayLike, NDArray

from canfdi import __version__
from canfdi.bus.frames import (
    FLAG_ERROR,
    FLAG_EXTENDED,
    FLAG_FD,
    FLAG_REMOTE,
    SENT,
    STATUS_NAMES,
    FrameBlock,
)

if TYPE_CHECKING:
    from canfdi.core.records import FaultEvent, Sample

__all__ = [
    "FLAG_ERROR",
    "FLAG_EXTENDED",
    "FLAG_FD",
    "FLAG_REMOTE",
    "FRAMES_ENCODING",
    "FRAME_DTYPE",
    "FRAME_STATUSES",
    "MESSAGE_ENCODING",
    "METADATA_NAME",
    "RESIDUALS_ENCODING",
    "RETRY_INTERVAL",
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
    "FrameBlock",
    "LogReader",
    "McapRecorder",
    "ResidualArrays",
    "SampleArrays",
    "iter_frame_blocks",
    "log_segments",
    "read_frames",
    "read_log",
    "read_metadata",
    "read_residuals",
    "read_samples",
]

logger = logging.getLogger(__name__)

if not hasattr(Writer, "flush"):  # pragma: no cover - depends on the installed mcap
    # Without Writer.flush a chunk only ends when full, which breaks the crash-loss bound.
    raise ImportError("canfdi.io.recorder needs an mcap package whose Writer has flush() (1.6+)")

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
RETRY_INTERVAL = 1.0
"""Seconds (on the recorder's clock) between attempts to resume after a write error."""

_NS_PER_S = 1_000_000_000
_DEFAULT_CHUNK_SIZE = 1024 * 1024
# errno values of a failing first open that may heal (space freed), so that a monitor started
# on a full disk still monitors; anything else at start is a configuration error.
_TRANSIENT_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EIO})
_FRAME_SIZE = FRAME_DTYPE.itemsize
_PACK_FRAME = struct.Struct("<qIBBBx8s").pack
_FIRST_TIME = struct.Struct("<q").unpack_from
_MAX_STATUSES = 256  # status is a uint8 code
_MAX_DATA = 8
assert struct.calcsize("<qIBBBx8s") == _FRAME_SIZE == 24

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


_RESIDUAL_ROW = _object(
    "canfdi.Residuals",
    {
        "k": {"type": "integer"},
        "r": _NUMBER_MAP,
        "normalized": _NUMBER_MAP,
        "statistic": _NUMBER_MAP,
    },
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
            },
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
            },
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
                "kind": {"type": "string", "enum": ["detected", "accepted", "unexplained"]},
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

_GENERIC_SCHEMA = ("canfdi.Json", {"title": "canfdi.Json", "type": "object"})
# Serialised once: every segment registers the same bytes.
_SCHEMA_BYTES = {
    topic: (name, json.dumps(schema).encode()) for topic, (name, schema) in SCHEMAS.items()
}
_GENERIC_SCHEMA_BYTES = (_GENERIC_SCHEMA[0], json.dumps(_GENERIC_SCHEMA[1]).encode())

# ------------------------------------------------------------------------------------------
# encoding
# ------------------------------------------------------------------------------------------


def _json_default(obj: Any) -> Any:
    # numpy scalars and arrays (and anything else array-like).
    if hasattr(obj, "tolist"):
        return obj.tolist()
    if isinstance(obj, bytes | bytearray | memoryview):
        return bytes(obj).hex()
    if isinstance(obj, set | frozenset):
        return sorted(obj)
    raise TypeError(f"cannot record a {type(obj).__name__} as JSON")


# One encoder for the process: json.dumps with keyword arguments builds a new encoder per call.
_ENCODE = json.JSONEncoder(
    separators=(",", ":"), default=_json_default, check_circular=False
).encode


def _finite(obj: Any) -> Any:
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_finite(v) for v in obj]
    if hasattr(obj, "tolist"):
        return _finite(obj.tolist())
    return obj


def _encode(message: Mapping[str, Any]) -> bytes:
    text = _ENCODE(message)
    # JSON has no NaN or Infinity; Python writes them as bare tokens that Foxglove rejects.
    # Searching the text is far cheaper than visiting every float of every message; a string
    # that merely contains the word only costs a second, correct, pass.
    if "NaN" in text or "Infinity" in text:
        text = _ENCODE(_finite(message))
    return text.encode()


def _stamp(timestamp_ns: int) -> dict[str, int]:
    sec, nsec = divmod(int(timestamp_ns), _NS_PER_S)
    return {"sec": sec, "nsec": nsec}


def _listed(values: Any) -> list[Any]:
    return values.tolist() if hasattr(values, "tolist") else list(values)


def _named(names: Sequence[str], values: Any) -> dict[str, Any]:
    return dict(zip(names, _listed(values), strict=True))


def _columns(
    names: Sequence[str], rows: NDArray[np.float64], binary: bool
) -> dict[str, list[float | None]] | dict[str, str]:
    """``{name: column}`` of an (N, len(names)) array: lists with non-finite values as None,
    or (``binary``) base64 strings of little-endian float64."""
    if binary:
        packed = np.ascontiguousarray(rows.T, dtype="<f8")
        return {
            name: binascii.b2a_base64(column.tobytes(), newline=False).decode("ascii")
            for name, column in zip(names, packed, strict=True)
        }
    finite = np.isfinite(rows)
    if finite.all():
        columns = rows.T.tolist()
    else:
        values = rows.T.astype(object)
        values[~finite.T] = None
        columns = values.tolist()
    return dict(zip(names, columns, strict=True))


def _names(names: Sequence[str], what: str) -> list[str]:
    listed = [str(name) for name in names]
    if len(set(listed)) != len(listed):
        raise ValueError(f"duplicate {what} names: {listed}")
    return listed


_FRAMES_HEAD = (
    b'{"timestamp":{"sec":%d,"nsec":%d},"encoding":"'
    + FRAMES_ENCODING.encode()
    + b'","count":%d,"statuses":%s,"frames":"%s"'
)


class _Rows:
    """Buffered rows of one block topic, in order: single rows in per-column lists, vectorised
    writes as array chunks (copies).

    Parameters
    ----------
    kinds : tuple of numpy dtypes
        Each column's dtype; the float columns hold (N, width) arrays.
    """

    __slots__ = ("chunks", "columns", "count", "kinds")

    def __init__(self, kinds: tuple[type, ...]) -> None:
        self.kinds = kinds
        self.columns: tuple[list[Any], ...] = tuple([] for _ in kinds)
        self.chunks: list[tuple[np.ndarray, ...]] = []
        self.count = 0

    def seal(self) -> None:
        """Turn the pending single rows into a chunk."""
        if self.columns[0]:
            self.chunks.append(
                tuple(
                    np.array(c, dtype=kind)
                    for c, kind in zip(self.columns, self.kinds, strict=True)
                )
            )
            for column in self.columns:
                column.clear()

    def add(self, arrays: tuple[np.ndarray, ...]) -> None:
        self.seal()
        self.chunks.append(arrays)
        self.count += len(arrays[0])

    def take(self, n: int) -> tuple[np.ndarray, ...]:
        """Remove and return the first ``n`` rows (``n <= count``)."""
        self.seal()
        chunks = self.chunks
        if len(chunks) == 1:
            arrays = chunks[0]
        else:
            arrays = tuple(np.concatenate(parts) for parts in zip(*chunks, strict=True))
        if n < len(arrays[0]):
            self.chunks = [tuple(a[n:] for a in arrays)]
            arrays = tuple(a[:n] for a in arrays)
        else:
            self.chunks = []
        self.count -= n
        return arrays

    def clear(self) -> int:
        """Drop every row; returns how many there were."""
        n = self.count
        for column in self.columns:
            column.clear()
        self.chunks = []
        self.count = 0
        return n


def _float_row(values: Any) -> np.ndarray:
    # A copy: the diagnoser's arrays may be reused after the call.
    if type(values) is np.ndarray:
        return values.copy()
    return np.array(values, dtype=np.float64)


# ------------------------------------------------------------------------------------------
# files
# ------------------------------------------------------------------------------------------


def _open_file(path: Path) -> IO[bytes]:
    return open(path, "wb")


class _CountingFile:
    """The output stream handed to the mcap writer: counts bytes so rotation needs no syscall.

    The writer opens every file fresh, so the count is also the position it asks for in tell().
    """

    __slots__ = ("_file", "count")

    def __init__(self, file: IO[bytes]) -> None:
        self._file = file
        self.count = 0

    def write(self, data: bytes) -> int:
        self._file.write(data)
        self.count += len(data)
        return len(data)

    def tell(self) -> int:
        return self.count

    def flush(self) -> None:
        self._file.flush()

    def close(self) -> None:
        self._file.close()


class _Segment:
    """One open MCAP file: its writer and the channel id of every topic registered in it."""

    __slots__ = ("channels", "file", "generic_schema", "path", "writer")

    def __init__(self, path: Path, file: _CountingFile, writer: Writer) -> None:
        self.path = path
        self.file = file
        self.writer = writer
        self.channels: dict[str, int] = {}
        self.generic_schema = 0

    def register_known(self) -> None:
        for topic, (name, data) in _SCHEMA_BYTES.items():
            schema_id = self.writer.register_schema(name, SCHEMA_ENCODING, data)
            self.channels[topic] = self.writer.register_channel(topic, MESSAGE_ENCODING, schema_id)

    def register(self, topic: str) -> int:
        if not self.generic_schema:
            name, data = _GENERIC_SCHEMA_BYTES
            self.generic_schema = self.writer.register_schema(name, SCHEMA_ENCODING, data)
        channel_id = self.writer.register_channel(topic, MESSAGE_ENCODING, self.generic_schema)
        self.channels[topic] = channel_id
        return channel_id

    def abandon(self) -> None:
        # A full disk makes the buffered writer's flush-on-close fail too; the descriptor is
        # closed regardless, which is all that is wanted here.
        with contextlib.suppress(OSError):
            self.file.close()


def _segment_path(path: Path, index: int) -> Path:
    if index == 0:
        return path
    return path.with_name(f"{path.stem}-{index:04d}{path.suffix}")


def _numbered_segments(path: Path) -> list[tuple[int, Path]]:
    pattern = re.compile(re.escape(path.stem) + r"-(\d{4,})" + re.escape(path.suffix) + r"\Z")
    found = []
    try:
        entries = list(path.parent.iterdir())
    except FileNotFoundError:
        return []
    for entry in entries:
        match = pattern.match(entry.name)
        if match and int(match.group(1)) > 0:
            found.append((int(match.group(1)), entry))
    found.sort()
    return found


def log_segments(path: str | Path) -> list[Path]:
    """The files of a (possibly rotated) log, in recording order.

    Parameters
    ----------
    path : str or Path
        The name the log was recorded under (the first segment).

    Returns
    -------
    list of Path
        ``path`` if it exists, then ``<stem>-0001<suffix>``, ``<stem>-0002<suffix>``... that
        exist, ordered by number.
    """
    path = Path(path)
    head = [path] if path.exists() else []
    return head + [p for _, p in _numbered_segments(path)]


# ------------------------------------------------------------------------------------------
# writing
# ------------------------------------------------------------------------------------------


class McapRecorder:
    """Record a monitor run into MCAP, crash-safely, with rotation and disk-full tolerance.

    Parameters
    ----------
    path : str or Path
        The log file (the first segment); its directory must exist.
    metadata : dict of str to str, optional
        Run-level information stored in a metadata record named ``"canfdi"`` at the head of
        every segment (e.g. ``config_yaml``, ``design_json``, ``truth_json``, ``version``).
    flush_interval : float
        Seconds between timed flushes (buffers written, chunk ended): the most a killed process
        loses (see the module docstring).
    rotate_bytes : int, optional
        Start a new segment once the current file holds this many bytes.
    rotate_seconds : float, optional
        Start a new segment once the current one has been open this long.
    clock : callable
        Monotonic seconds; injected by tests to place chunk ends and rotations exactly.
    opener : callable
        Opens a segment file for binary writing; injected by tests to simulate a full disk.
    chunk_size : int
        Uncompressed bytes after which the writer ends a chunk on its own.
    block_frames, block_samples, block_residuals : int
        Rows of a full ``/can/frames``, ``/canfdi/samples`` or ``/canfdi/residuals`` block:
        a buffer holding that many rows is written as one message at once.
    plot_rate : float
        Most ``/canfdi/residuals_plot`` messages per second of log time; 0 disables the topic.
    float_encoding : {"json", "base64"}
        How the float columns of sample and residual blocks are written: JSON lists of numbers
        (readable; formatting costs about 0.5 us per value), or base64 strings of
        little-endian float64 (exact, NaN kept, about 30 times cheaper). The readers take
        both.

    Raises
    ------
    OSError
        When the first segment cannot be opened for a reason a full disk does not explain
        (missing directory, permissions). Later errors are reported, never raised.

    Notes
    -----
    Use as a context manager, or call `close`. Not thread-safe: one writer thread.
    """

    def __init__(
        self,
        path: str | Path,
        *,
        metadata: dict[str, str] | None = None,
        flush_interval: float = 1.0,
        rotate_bytes: int | None = None,
        rotate_seconds: float | None = None,
        clock: Callable[[], float] = time.monotonic,
        opener: Callable[[Path], IO[bytes]] = _open_file,
        chunk_size: int = _DEFAULT_CHUNK_SIZE,
        block_frames: int = 4096,
        block_samples: int = 1024,
        block_residuals: int = 1024,
        plot_rate: float = 20.0,
        float_encoding: str = "json",
    ) -> None:
        if flush_interval <= 0:
            raise ValueError(f"flush_interval must be > 0, got {flush_interval}")
        if rotate_bytes is not None and rotate_bytes <= 0:
            raise ValueError(f"rotate_bytes must be > 0, got {rotate_bytes}")
        if rotate_seconds is not None and rotate_seconds <= 0:
            raise ValueError(f"rotate_seconds must be > 0, got {rotate_seconds}")
        for name, value in (
            ("block_frames", block_frames),
            ("block_samples", block_samples),
            ("block_residuals", block_residuals),
        ):
            if value < 1:
                raise ValueError(f"{name} must be >= 1, got {value}")
        if not plot_rate >= 0:
            raise ValueError(f"plot_rate must be >= 0, got {plot_rate}")
        if float_encoding not in ("json", "base64"):
            raise ValueError(f"float_encoding must be 'json' or 'base64', got {float_encoding!r}")
        if metadata is not None:
            bad = [
                k for k, v in metadata.items() if not isinstance(k, str) or not isinstance(v, str)
            ]
            if bad:
                raise TypeError(f"metadata keys and values must be strings: {bad}")
        self._path = Path(path)
        self._metadata = dict(metadata) if metadata is not None else None
        self._flush_interval = float(flush_interval)
        # Infinite limits keep the hot-path test a plain comparison, with no None checks.
        self._byte_limit = rotate_bytes if rotate_bytes is not None else math.inf
        self._rotate_seconds = float(rotate_seconds) if rotate_seconds is not None else math.inf
        self._clock = clock
        self._opener = opener
        self._chunk_size = int(chunk_size)

        # Frames: packed FRAME_DTYPE records; rows whose payload the record cannot hold.
        self._frames = bytearray()
        self._frames_limit = int(block_frames) * _FRAME_SIZE
        self._long: dict[int, bytes] = {}
        self._status_codes: dict[str, int] = {}
        self._status_names: list[str] = []
        self._statuses_json = b"[]"
        self._reset_statuses()
        # Samples: k, t_ns, gap, U rows, Z rows.
        self._samples = _Rows((np.int64, np.int64, np.int64, np.float64, np.float64))
        self._block_samples = int(block_samples)
        self._inputs: list[str] = []
        self._outputs: list[str] = []
        self._inputs_given: Any = None  # the caller's objects, for a cheap identity check
        self._outputs_given: Any = None
        # Residuals: k, t_ns, R rows, normalized rows, statistic rows.
        self._residuals = _Rows((np.int64, np.int64, np.float64, np.float64, np.float64))
        self._block_residuals = int(block_residuals)
        self._residual_names: list[str] = []
        self._residual_names_given: Any = None
        self._binary_floats = float_encoding == "base64"
        self._plot_ns = round(_NS_PER_S / plot_rate) if plot_rate > 0 else 0
        self._plot_slot: int | None = None

        self._seg: _Segment | None = None
        self._next_index = 0
        self._paths: list[Path] = []
        self._closed = False
        self._messages_written = 0
        self._messages_dropped = 0
        self._pending = 0  # rows accepted into the open chunk since the last successful flush
        self._bytes_done = 0  # bytes of segments no longer open
        self._write_errors = 0
        self._last_error: OSError | None = None
        self._failing = False
        self._next_retry = -math.inf
        self._next_flush = math.inf
        self._rotate_at = math.inf
        # The next instant a write must look up from the hot path: the earlier of the timed
        # flush and the rotation while a segment is open, the next retry while failing.
        self._deadline = math.inf

        for _, stale in _numbered_segments(self._path):
            logger.info("removing %s, a segment of an earlier recording under this name", stale)
            stale.unlink()

        now = clock()
        try:
            self._open_segment(now, raise_errors=True)
        except OSError as exc:
            if exc.errno not in _TRANSIENT_ERRNOS:
                raise
            self._fail(exc, now)

    # -- context manager -------------------------------------------------------------------

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    # -- properties ------------------------------------------------------------------------

    @property
    def paths(self) -> list[Path]:
        """Segment files started so far, in order (an abandoned segment stays listed)."""
        return list(self._paths)

    @property
    def messages_written(self) -> int:
        """Rows (frames, samples, residual rows) and single messages (estimates, events, status,
        `write`) handed to a segment and not known to be lost. Rows still buffered in the
        recorder are not counted yet (`buffered`); ``/canfdi/residuals_plot`` copies never."""
        return self._messages_written

    @property
    def messages_dropped(self) -> int:
        """Rows and messages lost to write errors: refused while failing, in an unflushed
        chunk, or still buffered at `close` while failing."""
        return self._messages_dropped

    @property
    def buffered(self) -> int:
        """Frames, samples and residual rows waiting in the recorder's buffers."""
        return len(self._frames) // _FRAME_SIZE + self._samples.count + self._residuals.count

    @property
    def bytes_written(self) -> int:
        """Bytes handed to the segment files (compressed chunks, indexes, summaries)."""
        seg = self._seg
        return self._bytes_done + (seg.file.count if seg is not None else 0)

    @property
    def write_errors(self) -> int:
        """Number of OSErrors met (each failed write, flush, rotation or retry counts once)."""
        return self._write_errors

    @property
    def last_error(self) -> OSError | None:
        """The most recent OSError, or None if there never was one."""
        return self._last_error

    @property
    def failing(self) -> bool:
        """True while messages are being dropped (no segment open after a write error)."""
        return self._failing

    @property
    def closed(self) -> bool:
        """True once `close` has been called."""
        return self._closed

    # -- writing ---------------------------------------------------------------------------

    def write(self, topic: str, timestamp_ns: int, message: Mapping[str, Any]) -> None:
        """Record one message, unbuffered.

        Parameters
        ----------
        topic : str
            Any topic: one of `TOPICS` (the message must then have that topic's shape) or
            another one (registered with a generic object schema).
        timestamp_ns : int
            Log time, integer nanoseconds since the epoch.
        message : mapping
            JSON-serialisable; numpy values are converted. A ``"timestamp"`` field is added
            from ``timestamp_ns`` when the message has none (the caller's mapping is not
            modified).

        Raises
        ------
        ValueError
            After `close`.
        TypeError
            If the message cannot be expressed in JSON (a programming error, not an I/O one).
        """
        if "timestamp" not in message:
            message = {"timestamp": _stamp(timestamp_ns), **message}
        self._write_now(topic, timestamp_ns, _encode(message))

    def _begin_write(self) -> float:
        """Refuse writes after close; run the timed flush when it is due; the clock's now."""
        if self._closed:
            raise ValueError("write to a closed McapRecorder")
        now = self._clock()
        if now >= self._deadline:
            self._tick(now)
        return now

    def write_frame(
        self,
        timestamp_ns: int,
        frame_id: int,
        data: bytes,
        status: str,
        extended: bool = False,
        dlc: int | None = None,
        flags: int = 0,
    ) -> None:
        """Buffer a raw CAN frame for `TOPIC_FRAMES` (a cheap append).

        Parameters
        ----------
        timestamp_ns : int
            Arrival (or send) time, ns since the epoch.
        frame_id : int
            Arbitration id.
        data : bytes
            Payload (any length; more than 8 bytes are kept in the block's ``"long"`` map).
        status : str
            One of `FRAME_STATUSES` (or another short label).
        extended : bool
            29-bit identifier (sets `FLAG_EXTENDED`).
        dlc : int, optional
            Data length code when it differs from ``len(data)``.
        flags : int
            More `FLAG_REMOTE`, `FLAG_ERROR`, `FLAG_FD` bits.

        Raises
        ------
        ValueError
            After `close`.
        """
        now = self._begin_write()
        code = self._status_codes.get(status)
        if code is None:
            code = self._new_status(status)
        if type(data) is not bytes:
            data = bytes(data)
        n = len(data)
        if dlc is None and n <= _MAX_DATA:
            self._frames += _PACK_FRAME(timestamp_ns, frame_id, n, flags | extended, code, data)
        else:
            dlc = n if dlc is None else dlc
            if n != min(dlc, _MAX_DATA):
                self._long[len(self._frames) // _FRAME_SIZE] = data
            self._frames += _PACK_FRAME(timestamp_ns, frame_id, dlc, flags | extended, code, data)
        if len(self._frames) >= self._frames_limit:
            self._emit_frames(now, full_only=True)

    def write_frames(
        self,
        block: FrameBlock,
        statuses: str | Sequence[str] | ArrayLike | None = None,
        status_names: Sequence[str] | None = None,
    ) -> None:
        """Buffer a block of raw CAN frames for `TOPIC_FRAMES`, vectorised.

        Parameters
        ----------
        block : FrameBlock
            The frames (canfdi.bus.frames); the payload padding beyond each DLC is recorded as
            given.
        statuses : str, sequence of str, (N,) array of str, or (N,) integer array, optional
            Every frame's status (one string: all of them); integer codes index
            ``status_names`` (e.g. the assembler's codes into canfdi.bus.frames'
            ``STATUS_NAMES``: the fastest form). Default: the block's own ``status``.
        status_names : sequence of str, optional
            The names of integer ``statuses``.

        Raises
        ------
        ValueError
            After `close`, or for a block with no statuses given or held.
        """
        now = self._begin_write()
        n = block.size
        if statuses is None:
            if block.status is None:
                raise ValueError("write_frames: the block holds no statuses and none are given")
            statuses = block.status
        records = np.zeros(n, dtype=FRAME_DTYPE)
        records["t_ns"] = block.t_ns
        records["id"] = block.id
        records["dlc"] = block.dlc
        records["data"] = block.data
        records["flags"] = block.flags
        records["status"] = self._status_array(statuses, n, status_names)
        if not n:
            return
        self._frames += records.tobytes()
        if len(self._frames) >= self._frames_limit:
            self._emit_frames(now, full_only=True)

    def write_sample(
        self, sample: Sample, input_names: Sequence[str], output_names: Sequence[str]
    ) -> None:
        """Buffer a decoded sample for `TOPIC_SAMPLES` (a cheap append).

        Parameters
        ----------
        sample : Sample
            The sample; ``u`` and ``z`` are named by ``input_names`` and ``output_names``. Its
            arrays are kept until the block is written, so they must not be modified (a
            Sample is a frozen record).
        input_names, output_names : sequence of str
            The model's input and output names, in the sample's order. A change of names
            writes the buffered samples first.

        Raises
        ------
        ValueError
            After `close`, or if ``u`` or ``z`` does not match the names.
        """
        now = self._begin_write()
        if input_names is not self._inputs_given or output_names is not self._outputs_given:
            self._sample_names(input_names, output_names)
        u, z = sample.u, sample.z
        if len(u) != len(self._inputs) or len(z) != len(self._outputs):
            raise ValueError(
                f"sample has {len(u)} inputs and {len(z)} outputs for names "
                f"{self._inputs} and {self._outputs}"
            )
        rows = self._samples
        k_col, t_col, gap_col, u_col, z_col = rows.columns
        k_col.append(sample.k)
        t_col.append(sample.timestamp_ns)
        gap_col.append(sample.gap)
        u_col.append(u)
        z_col.append(z)
        rows.count += 1
        if rows.count >= self._block_samples:
            self._emit_samples(now, full_only=True)

    def write_samples(
        self,
        k: ArrayLike,
        t_ns: ArrayLike,
        U: ArrayLike,
        Z: ArrayLike,
        gap: ArrayLike,
        input_names: Sequence[str],
        output_names: Sequence[str],
    ) -> None:
        """Buffer a block of decoded samples for `TOPIC_SAMPLES`, vectorised (copied).

        Parameters
        ----------
        k : (N,) int
            Sample indices.
        t_ns : (N,) int
            Sample times, ns since the epoch.
        U : (N, p) float
            Inputs, named by ``input_names``.
        Z : (N, q) float
            Outputs, named by ``output_names``.
        gap : (N,) int
            Samples lost just before each one.
        input_names, output_names : sequence of str
            The model's input and output names.

        Raises
        ------
        ValueError
            After `close`, or for arrays of the wrong shape.
        """
        now = self._begin_write()
        if input_names is not self._inputs_given or output_names is not self._outputs_given:
            self._sample_names(input_names, output_names)
        n = len(np.asarray(k))
        arrays = (
            _column(k, n, "k").astype(np.int64),
            _column(t_ns, n, "t_ns").astype(np.int64),
            _column(gap, n, "gap").astype(np.int64),
            _matrix(U, n, len(self._inputs), "U"),
            _matrix(Z, n, len(self._outputs), "Z"),
        )
        if not n:
            return
        self._samples.add(arrays)
        if self._samples.count >= self._block_samples:
            self._emit_samples(now, full_only=True)

    def write_residuals(
        self,
        timestamp_ns: int,
        k: int,
        names: Sequence[str],
        r: ArrayLike,
        normalized: ArrayLike,
        statistic: ArrayLike,
    ) -> None:
        """Buffer one sample's residuals for `TOPIC_RESIDUALS` (a cheap append, copied).

        Also writes the row to `TOPIC_RESIDUALS_PLOT` when it is the first of its plot slot.

        Parameters
        ----------
        timestamp_ns : int
            Time of the sample.
        k : int
            Sample index.
        names : sequence of str
            Residual names; ``r``, ``normalized`` and ``statistic`` are in this order. A
            change of names writes the buffered rows first.
        r : array_like
            Raw residual values.
        normalized : array_like
            Residuals divided by their standard deviation.
        statistic : array_like
            Page-Hinkley statistic max(g+, g-) of every residual.

        Raises
        ------
        ValueError
            After `close`, or if a row does not match the names.
        """
        now = self._begin_write()
        if names is not self._residual_names_given:
            self._set_residual_names(names)
        r, normalized, statistic = _float_row(r), _float_row(normalized), _float_row(statistic)
        m = len(self._residual_names)
        if len(r) != m or len(normalized) != m or len(statistic) != m:
            raise ValueError(f"residual rows do not match the {m} names {self._residual_names}")
        rows = self._residuals
        k_col, t_col, r_col, n_col, s_col = rows.columns
        k_col.append(k)
        t_col.append(timestamp_ns)
        r_col.append(r)
        n_col.append(normalized)
        s_col.append(statistic)
        rows.count += 1
        if self._plot_ns:
            slot = timestamp_ns // self._plot_ns
            if slot != self._plot_slot:
                self._plot_slot = slot
                self._write_plot(timestamp_ns, k, r, normalized, statistic, now)
        if rows.count >= self._block_residuals:
            self._emit_residuals(now, full_only=True)

    def write_residual_rows(
        self,
        k: ArrayLike,
        t_ns: ArrayLike,
        names: Sequence[str],
        R: ArrayLike,
        Rn: ArrayLike,
        stat: ArrayLike,
    ) -> None:
        """Buffer many samples' residuals for `TOPIC_RESIDUALS`, vectorised (copied).

        Also writes the first row of every plot slot to `TOPIC_RESIDUALS_PLOT`.

        Parameters
        ----------
        k : (N,) int
            Sample indices.
        t_ns : (N,) int
            Sample times, ns since the epoch.
        names : sequence of str
            The m residual names.
        R, Rn, stat : (N, m) float
            Raw residuals, normalized residuals, Page-Hinkley statistics.

        Raises
        ------
        ValueError
            After `close`, or for arrays of the wrong shape.
        """
        now = self._begin_write()
        if names is not self._residual_names_given:
            self._set_residual_names(names)
        n = len(np.asarray(k))
        m = len(self._residual_names)
        arrays = (
            _column(k, n, "k").astype(np.int64),
            _column(t_ns, n, "t_ns").astype(np.int64),
            _matrix(R, n, m, "R"),
            _matrix(Rn, n, m, "Rn"),
            _matrix(stat, n, m, "stat"),
        )
        if not n:
            return
        self._residuals.add(arrays)
        if self._plot_ns:
            slots = arrays[1] // self._plot_ns
            previous = np.empty(n, dtype=np.int64)
            previous[1:] = slots[:-1]
            keep = slots != previous
            keep[0] = self._plot_slot is None or int(slots[0]) != self._plot_slot
            self._plot_slot = int(slots[-1])
            ks, ts = arrays[0].tolist(), arrays[1].tolist()
            for i in np.flatnonzero(keep).tolist():
                self._write_plot(ts[i], ks[i], arrays[2][i], arrays[3][i], arrays[4][i], now)
        if self._residuals.count >= self._block_residuals:
            self._emit_residuals(now, full_only=True)

    def write_estimates(
        self,
        timestamp_ns: int,
        k: int,
        hypothesis: str,
        estimates: Mapping[str, float],
        variances: Mapping[str, float],
    ) -> None:
        """Record a hypothesis' running estimates on `TOPIC_ESTIMATES`.

        Parameters
        ----------
        timestamp_ns : int
            Time of the sample.
        k : int
            Sample index.
        hypothesis : str
            Which fault hypothesis the estimates belong to (e.g. ``"actuator:torque"``).
        estimates, variances : mapping of str to float
            The estimates and their variances, same keys.
        """
        message = {
            "timestamp": _stamp(timestamp_ns),
            "k": k,
            "hypothesis": hypothesis,
            "estimates": dict(estimates),
            "variances": dict(variances),
        }
        self._write_now(TOPIC_ESTIMATES, timestamp_ns, _encode(message))

    def write_event(self, event: FaultEvent) -> None:
        """Record a diagnoser conclusion on `TOPIC_EVENTS` (at ``event.timestamp_ns``)."""
        message = {"timestamp": _stamp(event.timestamp_ns), **event.as_dict()}
        self._write_now(TOPIC_EVENTS, event.timestamp_ns, _encode(message))

    def write_status(
        self,
        timestamp_ns: int,
        state: str,
        samples: int,
        frames: Mapping[str, int],
        active_faults: int,
    ) -> None:
        """Record the monitor's periodic status on `TOPIC_STATUS`.

        Parameters
        ----------
        timestamp_ns : int
            Time of the report.
        state : str
            The monitor's state (e.g. ``"running"``).
        samples : int
            Samples decoded so far.
        frames : mapping of str to int
            Frame counters by kind (e.g. ``{"ok": .., "crc": ..}``).
        active_faults : int
            Faults currently accepted and compensated.
        """
        message = {
            "timestamp": _stamp(timestamp_ns),
            "state": state,
            "samples": samples,
            "frames": dict(frames),
            "active_faults": active_faults,
        }
        self._write_now(TOPIC_STATUS, timestamp_ns, _encode(message))

    def flush(self) -> None:
        """Write the buffered rows, end the open chunk and push everything written so far to
        the operating system.

        Also restarts the ``flush_interval`` timer. Errors are handled as in `write`; while
        failing the rows stay buffered.
        """
        if self._seg is not None:
            now = self._clock()
            self._emit_all(now)
            if self._seg is not None:
                self._flush_segment(now)

    def close(self) -> None:
        """Write the buffered rows, finish the current segment (summary, footer) and close it.

        Idempotent, never raises an OSError (it is recorded as in `write`); rows buffered while
        failing count as dropped.
        """
        if self._closed:
            return
        now = self._clock()
        try:
            self._emit_all(now)
        finally:
            self._closed = True
            self._deadline = math.inf
        seg = self._seg
        if seg is None:
            return
        try:
            self._finish_segment(seg)
        except OSError as exc:
            self._fail(exc, now)

    # -- internals: buffers ----------------------------------------------------------------

    def _reset_statuses(self) -> None:
        self._status_names = list(FRAME_STATUSES)
        self._status_codes = {name: code for code, name in enumerate(self._status_names)}
        self._statuses_json = json.dumps(self._status_names, separators=(",", ":")).encode()

    def _new_status(self, status: str) -> int:
        if not isinstance(status, str):
            raise TypeError(f"a frame status must be a str, got {type(status).__name__}")
        if len(self._status_names) >= _MAX_STATUSES:
            # Codes are bytes: the buffered frames keep the full table, the rest starts anew.
            self._emit_frames(self._clock(), full_only=False)
            self._reset_statuses()
        code = len(self._status_names)
        self._status_names.append(status)
        self._status_codes[status] = code
        self._statuses_json = json.dumps(self._status_names, separators=(",", ":")).encode()
        return code

    def _status_array(
        self, statuses: Any, n: int, status_names: Sequence[str] | None
    ) -> NDArray[np.uint8]:
        """uint8 codes into the status table of ``n`` frames' statuses."""
        if isinstance(statuses, str):
            names, index = [statuses], np.zeros(n, dtype=np.intp)
        else:
            values = np.asarray(statuses)
            if values.shape != (n,):
                raise ValueError(f"statuses must be ({n},), got shape {values.shape}")
            if values.dtype.kind in "iu":
                if status_names is None:
                    raise ValueError("integer statuses need status_names")
                names, index = list(status_names), values
            elif n:
                unique, index = np.unique(values, return_inverse=True)
                names = unique.tolist()
            else:
                names, index = [], values.astype(np.intp)
        missing = {name for name in names if name not in self._status_codes}
        if len(self._status_names) + len(missing) > _MAX_STATUSES:
            # Codes are bytes: the buffered frames keep the full table, the rest starts anew.
            self._emit_frames(self._clock(), full_only=False)
            self._reset_statuses()
            missing = {name for name in names if name not in self._status_codes}
            if len(self._status_names) + len(missing) > _MAX_STATUSES:
                raise ValueError(f"more than {_MAX_STATUSES} frame statuses in one call")
        codes = self._status_codes
        table = np.array(
            [codes[name] if name in codes else self._new_status(name) for name in names],
            dtype=np.uint8,
        )
        return table[index] if len(table) else np.zeros(n, dtype=np.uint8)

    def _sample_names(self, input_names: Sequence[str], output_names: Sequence[str]) -> None:
        inputs, outputs = _names(input_names, "input"), _names(output_names, "output")
        if inputs != self._inputs or outputs != self._outputs:
            self._emit_samples(self._clock(), full_only=False)
            self._inputs, self._outputs = inputs, outputs
        self._inputs_given, self._outputs_given = input_names, output_names

    def _set_residual_names(self, names: Sequence[str]) -> None:
        listed = _names(names, "residual")
        if listed != self._residual_names:
            self._emit_residuals(self._clock(), full_only=False)
            self._residual_names = listed
        self._residual_names_given = names

    def _emit_all(self, now: float) -> None:
        self._emit_frames(now, full_only=False)
        self._emit_samples(now, full_only=False)
        self._emit_residuals(now, full_only=False)

    def _emit_frames(self, now: float, full_only: bool) -> None:
        frames = self._frames
        size = len(frames)
        limit = self._frames_limit
        start = 0
        while size - start >= limit or (not full_only and start < size):
            end = min(start + limit, size)
            first = start // _FRAME_SIZE
            count = (end - start) // _FRAME_SIZE
            t0 = _FIRST_TIME(frames, start)[0]
            sec, nsec = divmod(t0, _NS_PER_S)
            text = _FRAMES_HEAD % (
                sec,
                nsec,
                count,
                self._statuses_json,
                binascii.b2a_base64(frames[start:end], newline=False),
            )
            if self._long:
                long = {
                    str(row - first): data.hex()
                    for row, data in self._long.items()
                    if first <= row < first + count
                }
                if long:
                    text += b',"long":' + _ENCODE(long).encode()
            self._write(TOPIC_FRAMES, t0, text + b"}", count, now)
            start = end
        if start:
            del frames[:start]
            if self._long:
                shift = start // _FRAME_SIZE
                self._long = {row - shift: d for row, d in self._long.items() if row >= shift}

    def _emit_samples(self, now: float, full_only: bool) -> None:
        rows, limit = self._samples, self._block_samples
        binary = self._binary_floats
        while rows.count >= limit or (not full_only and rows.count):
            k, t, gap, u, z = rows.take(min(limit, rows.count))
            message = {
                "timestamp": _stamp(t[0]),
                "encoding": SAMPLES_ENCODING,
                "count": len(k),
                "k": k.tolist(),
                "t_ns": t.tolist(),
                "gap": gap.tolist(),
                "u": _columns(self._inputs, u.reshape(len(k), len(self._inputs)), binary),
                "z": _columns(self._outputs, z.reshape(len(k), len(self._outputs)), binary),
            }
            self._write(TOPIC_SAMPLES, int(t[0]), _ENCODE(message).encode(), len(k), now)

    def _emit_residuals(self, now: float, full_only: bool) -> None:
        rows, limit = self._residuals, self._block_residuals
        names = self._residual_names
        binary = self._binary_floats
        while rows.count >= limit or (not full_only and rows.count):
            k, t, r, normalized, statistic = rows.take(min(limit, rows.count))
            shape = (len(k), len(names))
            message = {
                "timestamp": _stamp(t[0]),
                "encoding": RESIDUALS_ENCODING,
                "count": len(k),
                "k": k.tolist(),
                "t_ns": t.tolist(),
                "names": names,
                "r": _columns(names, r.reshape(shape), binary),
                "normalized": _columns(names, normalized.reshape(shape), binary),
                "statistic": _columns(names, statistic.reshape(shape), binary),
            }
            self._write(TOPIC_RESIDUALS, int(t[0]), _ENCODE(message).encode(), len(k), now)

    def _write_plot(
        self,
        timestamp_ns: int,
        k: int,
        r: np.ndarray,
        normalized: np.ndarray,
        statistic: np.ndarray,
        now: float,
    ) -> None:
        names = self._residual_names
        message = {
            "timestamp": _stamp(timestamp_ns),
            "k": k,
            "r": _named(names, r),
            "normalized": _named(names, normalized),
            "statistic": _named(names, statistic),
        }
        self._write(TOPIC_RESIDUALS_PLOT, timestamp_ns, _encode(message), 0, now)

    # -- internals: segments ---------------------------------------------------------------

    def _write_now(self, topic: str, timestamp_ns: int, data: bytes) -> None:
        now = self._begin_write()
        self._write(topic, timestamp_ns, data, 1, now)

    def _tick(self, now: float) -> None:
        """The deadline passed: retry while failing, else write the buffers and end the chunk
        (timed flush) or the segment (rotation)."""
        if self._seg is None:
            if not self._closed and now >= self._next_retry:
                self._open_segment(now)
            return
        self._emit_all(now)
        seg = self._seg
        if seg is None:
            return
        if now >= self._rotate_at:
            self._rotate(seg, now)
        else:
            self._flush_segment(now)

    def _write(self, topic: str, timestamp_ns: int, data: bytes, rows: int, now: float) -> None:
        """Add one message of ``rows`` rows to the open segment (or count them dropped)."""
        seg = self._seg
        if seg is not None and seg.file.count >= self._byte_limit:
            self._rotate(seg, now)
            seg = self._seg
        if seg is None:
            self._messages_dropped += rows
            return
        try:
            channel_id = seg.channels.get(topic)
            if channel_id is None:
                channel_id = seg.register(topic)
            seg.writer.add_message(channel_id, timestamp_ns, data, timestamp_ns)
        except OSError as exc:
            self._messages_dropped += rows
            self._fail(exc, now)
            return
        self._messages_written += rows
        self._pending += rows

    def _rotate(self, seg: _Segment, now: float) -> None:
        try:
            self._finish_segment(seg)
        except OSError as exc:
            self._fail(exc, now)
            return
        self._open_segment(now)

    def _flush_segment(self, now: float) -> None:
        seg = self._seg
        assert seg is not None
        try:
            seg.writer.flush()
        except OSError as exc:
            self._fail(exc, now)
            return
        self._pending = 0
        self._next_flush = now + self._flush_interval
        self._deadline = min(self._next_flush, self._rotate_at)

    def _finish_segment(self, seg: _Segment) -> None:
        seg.writer.finish()
        seg.file.flush()
        seg.file.close()
        self._pending = 0
        self._bytes_done += seg.file.count
        self._seg = None

    def _open_segment(self, now: float, raise_errors: bool = False) -> bool:
        index = self._next_index
        path = _segment_path(self._path, index)
        file: _CountingFile | None = None
        try:
            file = _CountingFile(self._opener(path))
            writer = Writer(file, chunk_size=self._chunk_size, compression=CompressionType.ZSTD)
            writer.start(profile="", library=f"canfdi/{__version__}; {LIBRARY_IDENTIFIER}")
            if self._metadata is not None:
                writer.add_metadata(METADATA_NAME, self._metadata)
            seg = _Segment(path, file, writer)
            # Up front, so that the hot path only looks a channel id up. The records wait in
            # the open chunk and reach the file with its first message.
            seg.register_known()
            writer.flush()
        except OSError as exc:
            if file is not None:
                with contextlib.suppress(OSError):
                    file.close()
                # Nothing useful made it into the file; the next attempt reuses the name.
                with contextlib.suppress(OSError):
                    path.unlink()
            if raise_errors:
                raise
            self._fail(exc, now)
            return False
        self._seg = seg
        self._paths.append(path)
        self._next_index = index + 1
        self._next_flush = now + self._flush_interval
        self._rotate_at = now + self._rotate_seconds
        self._deadline = min(self._next_flush, self._rotate_at)
        if self._failing:
            self._failing = False
            logger.warning(
                "MCAP recording resumed in %s (%d messages dropped so far)",
                path,
                self._messages_dropped,
            )
        return True

    def _fail(self, exc: OSError, now: float) -> None:
        self._write_errors += 1
        self._last_error = exc
        if not self._failing:
            self._failing = True
            logger.warning(
                "MCAP recording to %s failed (%s); dropping messages, retrying every %.0f s",
                self._seg.path
                if self._seg is not None
                else _segment_path(self._path, self._next_index),
                exc,
                RETRY_INTERVAL,
            )
        # The open chunk never reached the file: its rows are lost with the segment.
        self._messages_dropped += self._pending
        self._messages_written -= self._pending
        self._pending = 0
        seg = self._seg
        if seg is not None:
            seg.abandon()
            self._bytes_done += seg.file.count
            self._seg = None
        self._next_retry = now + RETRY_INTERVAL
        self._deadline = self._next_retry if not self._closed else math.inf


def _column(values: ArrayLike, n: int, name: str) -> np.ndarray:
    array = np.asarray(values)
    if array.shape != (n,):
        raise ValueError(f"{name} must be ({n},), got shape {array.shape}")
    return array


def _matrix(values: ArrayLike, n: int, width: int, name: str) -> NDArray[np.float64]:
    array = np.array(values, dtype=np.float64)  # a copy: the caller may reuse its array
    if array.shape != (n, width):
        raise ValueError(f"{name} must be ({n}, {width}), got shape {array.shape}")
    return array


# ------------------------------------------------------------------------------------------
# reading
# ------------------------------------------------------------------------------------------


class _ExactReader:
    """A file view whose read(n) returns n bytes or raises EndOfFile.

    mcap's ReadDataStream only fails on an empty read, so a record cut short by truncation
    would be parsed from too few bytes (a garbled message, or a zstd error on a partial
    chunk). Failing on any short read makes every incomplete record an EndOfFile.
    """

    __slots__ = ("_read",)

    def __init__(self, file: IO[bytes]) -> None:
        self._read = file.read

    def read(self, n: int) -> bytes:
        data = self._read(n)
        if len(data) != n:
            raise EndOfFile()
        return data


class LogReader:
    """Messages of one MCAP file in file order: an iterator of (topic, log_time ns, message).

    Streams the file (no seeking, no sorting, no summary needed), so it reads a file cut short
    by a killed writer as well as a complete one: it stops at the last complete record without
    raising. After iteration, `messages_read`, `complete` and `truncated` describe what was
    found. Use `read_log` to make one.

    Parameters
    ----------
    path : str or Path
        The MCAP file.
    topics : iterable of str, optional
        Only these topics (all when None).

    Raises
    ------
    mcap.exceptions.InvalidMagic
        While iterating, if the file is not an MCAP file.
    """

    def __init__(self, path: str | Path, topics: Iterable[str] | None = None) -> None:
        self.path = Path(path)
        self._topics = frozenset(topics) if topics is not None else None
        self.messages_read = 0
        self.complete = False
        self.truncated = False
        self._iterator = self._iterate()

    def __iter__(self) -> Iterator[tuple[str, int, dict[str, Any]]]:
        return self

    def __next__(self) -> tuple[str, int, dict[str, Any]]:
        return next(self._iterator)

    def close(self) -> None:
        """Stop early and close the file."""
        self._iterator.close()

    def _iterate(self) -> Iterator[tuple[str, int, dict[str, Any]]]:
        topics = self._topics
        wanted: dict[int, str] = {}
        loads = json.loads
        with open(self.path, "rb") as file:
            records = StreamReader(_ExactReader(file)).records
            try:
                for record in records:
                    if isinstance(record, Message):
                        topic = wanted.get(record.channel_id)
                        if topic is not None:
                            self.messages_read += 1
                            yield topic, record.log_time, loads(record.data)
                    elif isinstance(record, Channel):
                        if topics is None or record.topic in topics:
                            wanted[record.id] = record.topic
                    elif isinstance(record, Footer):
                        self.complete = True
            except EndOfFile:
                self.truncated = True
                logger.info(
                    "%s ends early (killed writer?): read %d messages up to the last complete "
                    "record",
                    self.path,
                    self.messages_read,
                )


def read_log(path: str | Path, topics: Iterable[str] | None = None) -> LogReader:
    """Read back one log file's messages, tolerating a truncated end.

    Parameters
    ----------
    path : str or Path
        One MCAP file (for a rotated log, read each of `log_segments` in turn).
    topics : iterable of str, optional
        Only these topics (all when None).

    Returns
    -------
    LogReader
        An iterator of ``(topic, log_time_ns, message)`` in file order; its ``messages_read``,
        ``complete`` and ``truncated`` attributes tell what was found once it is exhausted.
    """
    return LogReader(path, topics)


def read_metadata(path: str | Path) -> dict[str, str]:
    """The run-level metadata (records named ``"canfdi"``) of one log file.

    Streams the file and stops at the first chunk after the metadata, where the recorder puts
    it; a truncated file is fine.

    Parameters
    ----------
    path : str or Path
        One MCAP file.

    Returns
    -------
    dict of str to str
        The metadata (merged in file order if there are several records); empty if none.
    """
    found: dict[str, str] = {}
    seen = False
    with open(path, "rb") as file:
        # emit_chunks: the message data is not needed, so it is not decompressed.
        records = StreamReader(_ExactReader(file), emit_chunks=True).records
        try:
            for record in records:
                if isinstance(record, Metadata) and record.name == METADATA_NAME:
                    found.update(record.metadata)
                    seen = True
                elif seen and isinstance(record, Chunk):
                    break
        except EndOfFile:
            pass
    return found


# ------------------------------------------------------------------------------------------
# reading rows back
# ------------------------------------------------------------------------------------------


class SampleArrays(NamedTuple):
    """Decoded samples of a log: ``(k, t_ns, gap, U, Z, input_names, output_names)``.

    ``k``, ``t_ns``, ``gap`` are (N,) int64; ``U`` (N, p) and ``Z`` (N, q) float64 with NaN
    where the log holds null; the names are the model's, in column order.
    """

    k: NDArray[np.int64]
    t_ns: NDArray[np.int64]
    gap: NDArray[np.int64]
    U: NDArray[np.float64]
    Z: NDArray[np.float64]
    input_names: list[str]
    output_names: list[str]


class ResidualArrays(NamedTuple):
    """Residuals of a log: ``(k, t_ns, names, R, Rn, stat)``.

    ``k``, ``t_ns`` are (N,) int64; ``R`` (raw), ``Rn`` (normalized), ``stat`` (Page-Hinkley)
    are (N, m) float64 with NaN where the log holds null, columns in ``names`` order.
    """

    k: NDArray[np.int64]
    t_ns: NDArray[np.int64]
    names: list[str]
    R: NDArray[np.float64]
    Rn: NDArray[np.float64]
    stat: NDArray[np.float64]


def _segments(path: str | Path, segments: bool) -> list[Path]:
    if not segments:
        if not Path(path).exists():
            raise FileNotFoundError(errno.ENOENT, "no such log", str(path))
        return [Path(path)]
    segments_found = log_segments(path)
    if not segments_found:
        raise FileNotFoundError(errno.ENOENT, "no such log", str(path))
    return segments_found


def _check_block(message: Mapping[str, Any], encoding: str, topic: str) -> int:
    found = message.get("encoding")
    if found != encoding:
        raise ValueError(f"unsupported {topic} block encoding {found!r} (expected {encoding!r})")
    return int(message["count"])


def _frame_block(message: Mapping[str, Any]) -> FrameBlock:
    count = _check_block(message, FRAMES_ENCODING, TOPIC_FRAMES)
    records = np.frombuffer(binascii.a2b_base64(message["frames"]), dtype=FRAME_DTYPE)
    if len(records) != count:
        raise ValueError(f"a {TOPIC_FRAMES} block holds {len(records)} frames, says {count}")
    names = np.array(message["statuses"], dtype=str)
    codes = records["status"]
    if count and int(codes.max()) >= len(names):
        raise ValueError(f"a {TOPIC_FRAMES} block has a status code beyond its statuses")
    return FrameBlock(
        records["t_ns"].copy(),
        records["id"].copy(),
        records["dlc"].copy(),
        records["flags"].copy(),
        records["data"].copy(),
        status=names[codes] if count else np.empty(0, dtype=str),
        long={int(row): bytes.fromhex(data) for row, data in message.get("long", {}).items()},
    )


def _frame_rows(rows: list[tuple[int, Mapping[str, Any]]]) -> FrameBlock:
    """Frames of the one-frame-per-message layout: ``{"id", "extended", "dlc", "data": hex,
    "status"}`` at the message's log time."""
    n = len(rows)
    payloads = [bytes.fromhex(m["data"]) for _, m in rows]
    dlc = [int(m.get("dlc", len(p))) for (_, m), p in zip(rows, payloads, strict=True)]
    extended = np.array([bool(m.get("extended", False)) for _, m in rows], dtype=bool)
    return FrameBlock(
        np.array([t for t, _ in rows], dtype=np.int64),
        np.array([m["id"] for _, m in rows], dtype=np.uint32),
        np.array(dlc, dtype=np.uint8),
        extended.astype(np.uint8),
        np.frombuffer(
            b"".join(p[:_MAX_DATA].ljust(_MAX_DATA, b"\0") for p in payloads), dtype=np.uint8
        ).reshape(n, _MAX_DATA),
        status=np.array([str(m.get("status", "ok")) for _, m in rows], dtype=str),
        long={i: p for i, (p, d) in enumerate(zip(payloads, dlc, strict=True))
              if len(p) != min(d, 8)},
    )


def _no_frames() -> FrameBlock:
    empty = FrameBlock.empty()
    return FrameBlock(empty.t_ns, empty.id, empty.dlc, empty.flags, empty.data,
                      status=np.empty(0, dtype=str))


_OLD_ROWS_PER_BLOCK = 4096


def iter_frame_blocks(path: str | Path, *, segments: bool = True) -> Iterator[FrameBlock]:
    """The raw frames of a log, a block at a time: constant memory for any log length.

    Reads the segments in order, tolerating a truncated end as `read_log` does (a block cut
    short is dropped whole). Logs of the older one-frame-per-message layout
    are read too, in blocks of up to 4096 frames.

    Parameters
    ----------
    path : str or Path
        The log's name (its first segment).
    segments : bool
        Also read the rotated segments that follow ``path`` (`log_segments`); False reads
        ``path`` alone.

    Yields
    ------
    FrameBlock
        The frames of one block, in recording order.

    Raises
    ------
    FileNotFoundError
        If no segment of the log exists.
    ValueError
        For a ``/can/frames`` message of an unknown layout.
    """
    rows: list[tuple[int, Mapping[str, Any]]] = []
    for segment in _segments(path, segments):
        for _, log_time, message in read_log(segment, topics=[TOPIC_FRAMES]):
            if "frames" in message:
                if rows:
                    yield _frame_rows(rows)
                    rows = []
                yield _frame_block(message)
            elif "id" in message and "data" in message:
                rows.append((log_time, message))
                if len(rows) >= _OLD_ROWS_PER_BLOCK:
                    yield _frame_rows(rows)
                    rows = []
            else:
                raise ValueError(f"unrecognised {TOPIC_FRAMES} message in {segment}")
    if rows:
        yield _frame_rows(rows)


def read_frames(path: str | Path, *, segments: bool = True) -> FrameBlock:
    """Every raw frame of a log, as arrays.

    Parameters
    ----------
    path : str or Path
        The log's name (its first segment); read as by `iter_frame_blocks`.
    segments : bool
        Also read the rotated segments that follow ``path`` (`log_segments`); False reads
        ``path`` alone.

    Returns
    -------
    FrameBlock
        All the frames in recording order (including the monitor's own, status ``"sent"``).

    Raises
    ------
    FileNotFoundError
        If no segment of the log exists.
    ValueError
        For a ``/can/frames`` message of an unknown layout.
    """
    blocks = list(iter_frame_blocks(path, segments=segments))
    return FrameBlock.concat(blocks) if blocks else _no_frames()


def _block_floats(columns: Mapping[str, Any], names: list[str], n: int) -> np.ndarray:
    parts = []
    for name in names:
        column = columns[name]
        if isinstance(column, str):
            parts.append(np.frombuffer(binascii.a2b_base64(column), dtype="<f8"))
        else:
            parts.append(np.array(column, dtype=np.float64))
        if parts[-1].shape != (n,):
            raise ValueError(f"column {name!r} holds {len(parts[-1])} values in a block of {n}")
    return np.array(parts, dtype=np.float64).reshape(len(names), n).T


def _same_names(found: Any, names: Any, topic: str, path: str | Path) -> Any:
    if names is not None and found != names:
        raise ValueError(f"{topic} of {path} changes names: {names} then {found}")
    return found


def _gathered(rows: _Rows, widths: Sequence[int]) -> list[np.ndarray]:
    if not rows.count:
        return [np.empty(0, dtype=np.int64) for _ in range(len(rows.kinds) - len(widths))] + [
            np.empty((0, w)) for w in widths
        ]
    return [np.ascontiguousarray(a) for a in rows.take(rows.count)]


def read_samples(path: str | Path, *, segments: bool = True) -> SampleArrays:
    """Every decoded sample of a log (``/canfdi/samples``), as arrays.

    Reads every segment in order, tolerating a truncated end as `read_log` does, and logs of
    the older one-sample-per-message layout.

    Parameters
    ----------
    path : str or Path
        The log's name (its first segment).
    segments : bool
        Also read the rotated segments that follow ``path`` (`log_segments`); False reads
        ``path`` alone.

    Returns
    -------
    SampleArrays
        ``(k, t_ns, gap, U, Z, input_names, output_names)``; empty arrays (and no names) when
        the log holds no sample.

    Raises
    ------
    FileNotFoundError
        If no segment of the log exists.
    ValueError
        For a block of an unknown layout, or names that change within the log.
    """
    rows = _Rows((np.int64, np.int64, np.int64, np.float64, np.float64))
    k_col, t_col, gap_col, u_col, z_col = rows.columns
    names: tuple[list[str], list[str]] | None = None
    for segment in _segments(path, segments):
        for _, log_time, msg in read_log(segment, topics=[TOPIC_SAMPLES]):
            found = (list(msg["u"]), list(msg["z"]))
            names = _same_names(found, names, TOPIC_SAMPLES, path)
            if "count" in msg:
                n = _check_block(msg, SAMPLES_ENCODING, TOPIC_SAMPLES)
                rows.add(
                    (
                        np.array(msg["k"], dtype=np.int64),
                        np.array(msg["t_ns"], dtype=np.int64),
                        np.array(msg["gap"], dtype=np.int64),
                        _block_floats(msg["u"], found[0], n),
                        _block_floats(msg["z"], found[1], n),
                    )
                )
            else:
                k_col.append(msg["k"])
                t_col.append(log_time)
                gap_col.append(msg.get("gap", 0))
                u_col.append(list(msg["u"].values()))
                z_col.append(list(msg["z"].values()))
                rows.count += 1
    inputs, outputs = names if names is not None else ([], [])
    k, t, gap, u, z = _gathered(rows, (len(inputs), len(outputs)))
    n = len(k)
    return SampleArrays(
        k, t, gap, u.reshape(n, len(inputs)), z.reshape(n, len(outputs)), inputs, outputs
    )


def read_residuals(path: str | Path, *, segments: bool = True) -> ResidualArrays:
    """Every residual row of a log (``/canfdi/residuals``), as arrays.

    Reads every segment in order, tolerating a truncated end as `read_log` does, and logs of
    the older one-row-per-message layout. (``/canfdi/residuals_plot`` is not read: it only
    repeats some of these rows.)

    Parameters
    ----------
    path : str or Path
        The log's name (its first segment).
    segments : bool
        Also read the rotated segments that follow ``path`` (`log_segments`); False reads
        ``path`` alone.

    Returns
    -------
    ResidualArrays
        ``(k, t_ns, names, R, Rn, stat)``; empty arrays (and no names) when the log holds no
        residuals.

    Raises
    ------
    FileNotFoundError
        If no segment of the log exists.
    ValueError
        For a block of an unknown layout, or names that change within the log.
    """
    rows = _Rows((np.int64, np.int64, np.float64, np.float64, np.float64))
    k_col, t_col, r_col, n_col, s_col = rows.columns
    names: list[str] | None = None
    for segment in _segments(path, segments):
        for _, log_time, msg in read_log(segment, topics=[TOPIC_RESIDUALS]):
            if "count" in msg:
                n = _check_block(msg, RESIDUALS_ENCODING, TOPIC_RESIDUALS)
                found = list(msg["names"])
                names = _same_names(found, names, TOPIC_RESIDUALS, path)
                rows.add(
                    (
                        np.array(msg["k"], dtype=np.int64),
                        np.array(msg["t_ns"], dtype=np.int64),
                        _block_floats(msg["r"], found, n),
                        _block_floats(msg["normalized"], found, n),
                        _block_floats(msg["statistic"], found, n),
                    )
                )
            else:
                found = list(msg["r"])
                names = _same_names(found, names, TOPIC_RESIDUALS, path)
                k_col.append(msg["k"])
                t_col.append(log_time)
                r_col.append(list(msg["r"].values()))
                n_col.append([msg["normalized"][name] for name in found])
                s_col.append([msg["statistic"][name] for name in found])
                rows.count += 1
    names = names if names is not None else []
    m = len(names)
    k, t, r, rn, stat = _gathered(rows, (m, m, m))
    n = len(k)
    return ResidualArrays(k, t, names, r.reshape(n, m), rn.reshape(n, m), stat.reshape(n, m))

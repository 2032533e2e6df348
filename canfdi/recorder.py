"""The MCAP log of a monitor run: channels, schemas, rotation, crash-safe flushing, reading back.

One MCAP file per run (or a family of rotated segments), zstd-compressed chunks, JSON-encoded
messages described by JSON schemas (schema encoding ``"jsonschema"``, message encoding
``"json"``), so that Foxglove can open and plot the log directly. Every message carries a
``"timestamp": {"sec": int, "nsec": int}`` field (Foxglove's time type); the MCAP log_time and
publish_time of the message are the same instant in integer nanoseconds since the epoch.

Topics
------
The topic names and message shapes are a contract other code (replay, dashboards) relies on.

``/can/frames`` (`TOPIC_FRAMES`)
    Every raw frame, valid or not: ``{"timestamp", "id": int, "extended": bool, "dlc": int,
    "data": hex string, "status": str}``. ``status`` is ``"ok"``, ``"crc"``, ``"dlc"``,
    ``"unknown_id"``, ``"monitor"``, or ``"sent"`` for frames the monitor itself sent
    (`FRAME_STATUSES`; other strings are recorded as given).
``/canfdi/samples`` (`TOPIC_SAMPLES`)
    Decoded samples: ``{"timestamp", "k": int, "gap": int, "u": {name: value},
    "z": {name: value}}``.
``/canfdi/residuals`` (`TOPIC_RESIDUALS`)
    ``{"timestamp", "k", "r": {residual: value}, "normalized": {residual: value},
    "statistic": {residual: value}}``; the statistic is Page-Hinkley's max(g+, g-).
``/canfdi/estimates`` (`TOPIC_ESTIMATES`)
    ``{"timestamp", "k", "hypothesis": str, "estimates": {..}, "variances": {..}}``.
``/canfdi/events`` (`TOPIC_EVENTS`)
    `FaultEvent.as_dict` plus ``"timestamp"``.
``/canfdi/status`` (`TOPIC_STATUS`)
    ``{"timestamp", "state": str, "samples": int, "frames": {counter: int},
    "active_faults": int}``.

Other topics may be written with `McapRecorder.write`; they get a permissive object schema.
Non-finite floats (NaN, inf), which JSON cannot express, are written as ``null``.

Run-level information (configuration YAML, design JSON, ground truth, version: strings chosen by
the caller) goes into an MCAP metadata record named ``"canfdi"`` (`METADATA_NAME`) at the head of
every segment; `read_metadata` returns it.

Crash safety
------------
The mcap writer keeps the open chunk in memory and writes it only when it exceeds ``chunk_size``
or on ``Writer.flush()``, which finishes the open chunk (if it holds a message), writes it and
flushes the output stream. The recorder calls ``Writer.flush()`` whenever ``flush_interval``
seconds (on the injected clock) have passed since the last flush: the check is a single
comparison inside every `McapRecorder.write` (no thread, no lock), and `McapRecorder.flush`
forces it. The flushed bytes are in the operating system's page cache, so a killed process
(SIGKILL, crash) loses only the messages of the chunk still open: about the last
``flush_interval`` seconds, as long as the caller writes at least that often (the monitor's
frames and status messages do; an idle caller should call `McapRecorder.flush`). There is no
fsync: a power loss may lose what the kernel had not yet written back. Such a file has no
summary; `read_log` reads it in file order and stops at the last complete record.

Rotation
--------
With ``rotate_bytes`` or ``rotate_seconds``, the first write after the segment's file reached
``rotate_bytes`` (bytes reach the file a chunk at a time, so a segment overshoots by at most a
chunk and its summary) or after the segment has been open ``rotate_seconds`` finishes the segment
cleanly (summary and footer) and continues in ``<stem>-0001<suffix>``, ``<stem>-0002<suffix>``...
next to the first file, which keeps the given name. `log_segments` lists the family in order.
Stale numbered segments of the same name left by an earlier run are deleted when a recorder
starts, so that the family is this run's only.

Write errors
------------
An `OSError` while writing (typically ENOSPC: disk full) never reaches the caller of the write
methods. The recorder records it (`McapRecorder.last_error`, `McapRecorder.write_errors`), logs
one warning per episode, abandons the segment (its flushed part stays readable as a truncated
file), counts the messages of its unflushed chunk and every message written while failing as
dropped (`McapRecorder.messages_dropped`), and retries at most once per ``RETRY_INTERVAL``
seconds, on a later write, by opening the next segment: recording resumes in a new segment when
space returns. The constructor raises for errors that cannot heal by themselves (a missing
directory, no permission) so that a bad path is reported at start.
"""

from __future__ import annotations

import contextlib
import errno
import json
import logging
import math
import re
import time
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from types import TracebackType
from typing import IO, TYPE_CHECKING, Any, Self

from mcap.exceptions import EndOfFile
from mcap.records import Channel, Chunk, Footer, Message, Metadata
from mcap.stream_reader import StreamReader
from mcap.writer import LIBRARY_IDENTIFIER, CompressionType, Writer

from canfdi import __version__

if TYPE_CHECKING:
    from canfdi.core.records import FaultEvent, Sample

__all__ = [
    "FRAME_STATUSES",
    "MESSAGE_ENCODING",
    "METADATA_NAME",
    "RETRY_INTERVAL",
    "SCHEMAS",
    "SCHEMA_ENCODING",
    "TOPICS",
    "TOPIC_ESTIMATES",
    "TOPIC_EVENTS",
    "TOPIC_FRAMES",
    "TOPIC_RESIDUALS",
    "TOPIC_SAMPLES",
    "TOPIC_STATUS",
    "LogReader",
    "McapRecorder",
    "log_segments",
    "read_log",
    "read_metadata",
]

logger = logging.getLogger(__name__)

if not hasattr(Writer, "flush"):  # pragma: no cover - depends on the installed mcap
    # Without Writer.flush a chunk only ends when full, which breaks the crash-loss bound.
    raise ImportError("canfdi.recorder needs an mcap package whose Writer has flush() (1.6+)")

TOPIC_FRAMES = "/can/frames"
TOPIC_SAMPLES = "/canfdi/samples"
TOPIC_RESIDUALS = "/canfdi/residuals"
TOPIC_ESTIMATES = "/canfdi/estimates"
TOPIC_EVENTS = "/canfdi/events"
TOPIC_STATUS = "/canfdi/status"
TOPICS = (
    TOPIC_FRAMES,
    TOPIC_SAMPLES,
    TOPIC_RESIDUALS,
    TOPIC_ESTIMATES,
    TOPIC_EVENTS,
    TOPIC_STATUS,
)
FRAME_STATUSES = ("ok", "crc", "dlc", "unknown_id", "monitor", "sent")
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
_NUMBER_MAP = {"type": "object", "additionalProperties": {"type": ["number", "null"]}}
_OPT_INT = {"type": ["integer", "null"]}
_OPT_STR = {"type": ["string", "null"]}


def _object(title: str, properties: dict[str, Any]) -> dict[str, Any]:
    props = {"timestamp": _TIME, **properties}
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": title,
        "type": "object",
        "properties": props,
        "required": list(props),
    }


SCHEMAS: dict[str, tuple[str, dict[str, Any]]] = {
    TOPIC_FRAMES: (
        "canfdi.CanFrame",
        _object(
            "canfdi.CanFrame",
            {
                "id": {"type": "integer", "minimum": 0},
                "extended": {"type": "boolean"},
                "dlc": {"type": "integer", "minimum": 0},
                "data": {"type": "string", "description": "payload bytes as lowercase hex"},
                "status": {"type": "string", "examples": list(FRAME_STATUSES)},
            },
        ),
    ),
    TOPIC_SAMPLES: (
        "canfdi.Sample",
        _object(
            "canfdi.Sample",
            {
                "k": {"type": "integer"},
                "gap": {"type": "integer", "minimum": 0},
                "u": _NUMBER_MAP,
                "z": _NUMBER_MAP,
            },
        ),
    ),
    TOPIC_RESIDUALS: (
        "canfdi.Residuals",
        _object(
            "canfdi.Residuals",
            {
                "k": {"type": "integer"},
                "r": _NUMBER_MAP,
                "normalized": _NUMBER_MAP,
                "statistic": _NUMBER_MAP,
            },
        ),
    ),
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
                "frames": {"type": "object", "additionalProperties": {"type": "integer"}},
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
    # numpy scalars and arrays (and anything else array-like) without importing numpy here.
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


_FRAME_JSON = (
    '{"timestamp":{"sec":%d,"nsec":%d},"id":%d,"extended":%s,"dlc":%d,"data":"%s","status":%s}'
)
_STATUS_JSON: dict[str, str] = {s: json.dumps(s) for s in FRAME_STATUSES}
_STATUS_CACHE_LIMIT = 64

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
        Seconds between chunk ends: the most a killed process loses (see the module docstring).
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
    ) -> None:
        if flush_interval <= 0:
            raise ValueError(f"flush_interval must be > 0, got {flush_interval}")
        if rotate_bytes is not None and rotate_bytes <= 0:
            raise ValueError(f"rotate_bytes must be > 0, got {rotate_bytes}")
        if rotate_seconds is not None and rotate_seconds <= 0:
            raise ValueError(f"rotate_seconds must be > 0, got {rotate_seconds}")
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

        self._seg: _Segment | None = None
        self._next_index = 0
        self._paths: list[Path] = []
        self._closed = False
        self._messages_written = 0
        self._messages_dropped = 0
        self._pending = 0  # messages accepted since the last successful flush
        self._bytes_done = 0  # bytes of segments no longer open
        self._write_errors = 0
        self._last_error: OSError | None = None
        self._failing = False
        self._next_retry = -math.inf
        self._next_flush = math.inf
        self._rotate_at = math.inf
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
        """Messages handed to a segment and not known to be lost."""
        return self._messages_written

    @property
    def messages_dropped(self) -> int:
        """Messages lost to write errors: refused while failing, or in an unflushed chunk."""
        return self._messages_dropped

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
        """Record one message.

        Parameters
        ----------
        topic : str
            One of `TOPICS`, or any other topic (registered with a generic object schema).
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
        self._write(topic, timestamp_ns, _encode(message))

    def write_frame(
        self,
        timestamp_ns: int,
        frame_id: int,
        data: bytes,
        status: str,
        extended: bool = False,
        dlc: int | None = None,
    ) -> None:
        """Record a raw CAN frame on `TOPIC_FRAMES`.

        Parameters
        ----------
        timestamp_ns : int
            Arrival (or send) time, ns since the epoch.
        frame_id : int
            Arbitration id.
        data : bytes
            Payload.
        status : str
            One of `FRAME_STATUSES` (or another short label).
        extended : bool
            29-bit identifier.
        dlc : int, optional
            Data length code when it differs from ``len(data)``.
        """
        # The busiest topic: formatted directly, skipping the dict and the generic encoder.
        status_json = _STATUS_JSON.get(status)
        if status_json is None:
            status_json = json.dumps(status)
            if len(_STATUS_JSON) < _STATUS_CACHE_LIMIT:
                _STATUS_JSON[status] = status_json
        sec, nsec = divmod(timestamp_ns, _NS_PER_S)
        text = _FRAME_JSON % (
            sec,
            nsec,
            frame_id,
            "true" if extended else "false",
            len(data) if dlc is None else dlc,
            data.hex(),
            status_json,
        )
        self._write(TOPIC_FRAMES, timestamp_ns, text.encode())

    def write_sample(
        self, sample: Sample, input_names: Sequence[str], output_names: Sequence[str]
    ) -> None:
        """Record a decoded sample on `TOPIC_SAMPLES`.

        Parameters
        ----------
        sample : Sample
            The sample; ``u`` and ``z`` are named by ``input_names`` and ``output_names``.
        input_names, output_names : sequence of str
            The model's input and output names, in the sample's order.
        """
        message = {
            "timestamp": _stamp(sample.timestamp_ns),
            "k": sample.k,
            "gap": sample.gap,
            "u": _named(input_names, sample.u),
            "z": _named(output_names, sample.z),
        }
        self._write(TOPIC_SAMPLES, sample.timestamp_ns, _encode(message))

    def write_residuals(
        self,
        timestamp_ns: int,
        k: int,
        names: Sequence[str],
        r: Sequence[float],
        normalized: Sequence[float],
        statistic: Sequence[float],
    ) -> None:
        """Record one sample's residuals on `TOPIC_RESIDUALS`.

        Parameters
        ----------
        timestamp_ns : int
            Time of the sample.
        k : int
            Sample index.
        names : sequence of str
            Residual names; ``r``, ``normalized`` and ``statistic`` are in this order.
        r : array_like
            Raw residual values.
        normalized : array_like
            Residuals divided by their standard deviation.
        statistic : array_like
            Page-Hinkley statistic max(g+, g-) of every residual.
        """
        message = {
            "timestamp": _stamp(timestamp_ns),
            "k": k,
            "r": _named(names, r),
            "normalized": _named(names, normalized),
            "statistic": _named(names, statistic),
        }
        self._write(TOPIC_RESIDUALS, timestamp_ns, _encode(message))

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
        self._write(TOPIC_ESTIMATES, timestamp_ns, _encode(message))

    def write_event(self, event: FaultEvent) -> None:
        """Record a diagnoser conclusion on `TOPIC_EVENTS` (at ``event.timestamp_ns``)."""
        message = {"timestamp": _stamp(event.timestamp_ns), **event.as_dict()}
        self._write(TOPIC_EVENTS, event.timestamp_ns, _encode(message))

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
        self._write(TOPIC_STATUS, timestamp_ns, _encode(message))

    def flush(self) -> None:
        """End the open chunk and push everything written so far to the operating system.

        Also restarts the ``flush_interval`` timer. Errors are handled as in `write`.
        """
        if self._seg is not None:
            self._flush_segment(self._clock())

    def close(self) -> None:
        """Finish the current segment (summary, footer) and close it. Idempotent, never raises
        an OSError (it is recorded as in `write`)."""
        if self._closed:
            return
        self._closed = True
        seg = self._seg
        if seg is None:
            return
        try:
            self._finish_segment(seg)
        except OSError as exc:
            self._fail(exc, self._clock())

    # -- internals -------------------------------------------------------------------------

    def _write(self, topic: str, timestamp_ns: int, data: bytes) -> None:
        seg = self._seg
        now = self._clock()
        if seg is None:
            if self._closed:
                raise ValueError("write to a closed McapRecorder")
            if now < self._next_retry or not self._open_segment(now):
                self._messages_dropped += 1
                return
            seg = self._seg
        elif now >= self._deadline or seg.file.count >= self._byte_limit:
            self._on_deadline(seg, now)
            seg = self._seg
            if seg is None:
                self._messages_dropped += 1
                return
        assert seg is not None
        try:
            channel_id = seg.channels.get(topic)
            if channel_id is None:
                channel_id = seg.register(topic)
            seg.writer.add_message(channel_id, timestamp_ns, data, timestamp_ns)
        except OSError as exc:
            self._messages_dropped += 1
            self._fail(exc, now)
            return
        self._messages_written += 1
        self._pending += 1

    def _on_deadline(self, seg: _Segment, now: float) -> None:
        if now >= self._rotate_at or seg.file.count >= self._byte_limit:
            try:
                self._finish_segment(seg)
            except OSError as exc:
                self._fail(exc, now)
                return
            self._open_segment(now)
        elif now >= self._next_flush:
            self._flush_segment(now)

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
        # The open chunk never reached the file: its messages are lost with the segment.
        self._messages_dropped += self._pending
        self._messages_written -= self._pending
        self._pending = 0
        seg = self._seg
        if seg is not None:
            seg.abandon()
            self._bytes_done += seg.file.count
            self._seg = None
        self._next_retry = now + RETRY_INTERVAL
        self._deadline = math.inf


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

"""The messages of a canfdi log to and from arrays, and the JSON encoding of every message.

``/can/frames`` holds many frames per MCAP message: `encode_frame_block` packs them,
`decode_frames` unpacks them (`decode_frame_rows` the older one-frame-per-message layout).
``/canfdi/samples`` and ``/canfdi/residuals`` hold one row per message, formatted fast by
`RowEncoder`; `decode_sample_block` and `decode_residual_block` read the blocks of rows older
logs hold. `Rows` buffers rows until the writer emits them, and `encode_message` encodes any
message as Foxglove-compatible JSON (NaN and inf as null). It does no I/O: canfdi.io.writer
and canfdi.io.reader do.
"""

from __future__ import annotations

import json
import math
import struct
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import orjson
import pybase64
from numpy.typing import ArrayLike, NDArray

from canfdi.bus.frames import MAX_DATA, FrameBlock
from canfdi.io.schemas import (
    FRAME_DTYPE,
    FRAMES_ENCODING,
    RESIDUALS_ENCODING,
    SAMPLES_ENCODING,
    TOPIC_FRAMES,
    TOPIC_RESIDUALS,
    TOPIC_SAMPLES,
)

__all__ = [
    "FRAMES_HEAD",
    "FRAME_SIZE",
    "NS_PER_S",
    "RowEncoder",
    "Rows",
    "check_block",
    "check_column",
    "check_matrix",
    "decode_floats",
    "decode_frame_rows",
    "decode_frames",
    "decode_residual_block",
    "decode_sample_block",
    "earliest_time",
    "encode_frame_block",
    "encode_json",
    "encode_message",
    "float_row",
    "gathered",
    "no_frames",
    "pack_frame",
    "split_frame_block",
    "stamp",
    "unique_names",
]

NS_PER_S = 1_000_000_000
FRAME_SIZE = FRAME_DTYPE.itemsize
"""Bytes of one packed frame record (24)."""
pack_frame = struct.Struct("<qIBBBx8s").pack
"""Pack (t_ns, id, dlc, flags, status code, 8 data bytes) as one `FRAME_DTYPE` record."""


def earliest_time(records: bytes | bytearray | memoryview) -> int:
    """The earliest t_ns of packed `FRAME_DTYPE` records (at least one): a block's timestamp.

    Not the first frame's: `canfdi run` records the frames it sends at the wall clock's now,
    ahead of the received frames still queued behind them, and a block that began with one
    would be stamped later than the block after it.
    """
    return int(np.frombuffer(records, dtype=FRAME_DTYPE)["t_ns"].min())

assert struct.calcsize("<qIBBBx8s") == FRAME_SIZE == 24

# ------------------------------------------------------------------------------------------
# JSON
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
encode_json = json.JSONEncoder(
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


def encode_message(message: Mapping[str, Any]) -> bytes:
    """A message as compact JSON bytes, non-finite floats as null."""
    text = encode_json(message)
    # JSON has no NaN or Infinity; Python writes them as bare tokens that Foxglove rejects.
    # Searching the text is far cheaper than visiting every float of every message; a string
    # that merely contains the word only costs a second, correct, pass.
    if "NaN" in text or "Infinity" in text:
        text = encode_json(_finite(message))
    return text.encode()


def stamp(timestamp_ns: int) -> dict[str, int]:
    """Foxglove's time: ``{"sec", "nsec"}`` of integer nanoseconds since the epoch."""
    sec, nsec = divmod(int(timestamp_ns), NS_PER_S)
    return {"sec": sec, "nsec": nsec}


def unique_names(names: Sequence[str], what: str) -> list[str]:
    """``names`` as a list of str; ValueError naming ``what`` if one repeats."""
    listed = [str(name) for name in names]
    if len(set(listed)) != len(listed):
        raise ValueError(f"duplicate {what} names: {listed}")
    return listed


# ------------------------------------------------------------------------------------------
# blocks: encoding
# ------------------------------------------------------------------------------------------

FRAMES_HEAD = (
    b'{"timestamp":{"sec":%d,"nsec":%d},"encoding":"'
    + FRAMES_ENCODING.encode()
    + b'","count":%d,"statuses":%s,"frames":"%s"'
)


class Rows:
    """Buffered rows of one block topic, in order: single rows as they come, vectorised writes
    as array chunks (copies).

    Parameters
    ----------
    kinds : tuple of numpy dtypes
        Each column's dtype; the float columns hold (N, width) arrays.
    """

    __slots__ = ("chunks", "count", "kinds", "pending")

    def __init__(self, kinds: tuple[type, ...]) -> None:
        self.kinds = kinds
        self.pending: list[Sequence[Any]] = []
        self.chunks: list[tuple[np.ndarray, ...]] = []
        self.count = 0

    def seal(self) -> None:
        """Turn the pending single rows into a chunk."""
        if self.pending:
            self.chunks.append(
                tuple(
                    np.array(c, dtype=kind)
                    for c, kind in zip(zip(*self.pending, strict=True), self.kinds, strict=True)
                )
            )
            self.pending = []

    def append(self, values: Sequence[Any]) -> int:
        """Add one row: a value per column (a row of numbers for a float column), kept as
        given until the rows are sealed; returns the rows buffered."""
        self.pending.append(values)
        self.count += 1
        return self.count

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
        self.pending = []
        self.chunks = []
        self.count = 0
        return n


def float_row(values: Any) -> np.ndarray:
    """A float64 copy of one row."""
    # A copy: the diagnoser's arrays may be reused after the call.
    if type(values) is np.ndarray:
        return values.copy()
    return np.array(values, dtype=np.float64)


def check_column(values: ArrayLike, n: int, name: str) -> np.ndarray:
    """``values`` as an (n,) array; ValueError naming ``name`` otherwise."""
    array = np.asarray(values)
    if array.shape != (n,):
        raise ValueError(f"{name} must be ({n},), got shape {array.shape}")
    return array


def check_matrix(values: ArrayLike, n: int, width: int, name: str) -> NDArray[np.float64]:
    """A float64 copy of ``values``, checked (n, width); ValueError naming ``name``."""
    array = np.array(values, dtype=np.float64)  # a copy: the caller may reuse its array
    if array.shape != (n, width):
        raise ValueError(f"{name} must be ({n}, {width}), got shape {array.shape}")
    return array


def encode_frame_block(
    records: bytes | bytearray | memoryview,
    count: int,
    t0: int,
    statuses_json: bytes,
    long: Mapping[int, bytes] | None = None,
) -> bytes:
    """One ``/can/frames`` message of ``count`` packed `FRAME_DTYPE` records.

    Parameters
    ----------
    records : bytes
        ``count * FRAME_SIZE`` bytes of packed records.
    count : int
        Frames in the block.
    t0 : int
        The block's timestamp: its earliest frame's t_ns (`earliest_time`), or later.
    statuses_json : bytes
        The JSON list of status names the records' status codes index.
    long : mapping of int to bytes, optional
        Full payloads by row in this block (CAN FD, or lengths that disagree with the DLC).
    """
    sec, nsec = divmod(t0, NS_PER_S)
    text = FRAMES_HEAD % (
        sec,
        nsec,
        count,
        statuses_json,
        pybase64.b64encode(records),
    )
    if long:
        text += b',"long":' + encode_json({str(row): d.hex() for row, d in long.items()}).encode()
    return text + b"}"


def split_frame_block(data: bytes, t_ns: int, max_bytes: int) -> list[tuple[int, bytes]]:
    """A ``/can/frames`` message cut into messages of at most about ``max_bytes`` each.

    Parameters
    ----------
    data : bytes
        One block message (`encode_frame_block`'s form).
    t_ns : int
        Its timestamp.
    max_bytes : int
        The size each piece keeps within: its records' base64 plus the block's head and
        statuses (a full CAN FD payload of a piece's frames may add to it).

    Returns
    -------
    list of (int, bytes)
        (timestamp ns, message) of each piece, in order: the frames of ``data``, each once,
        with their statuses. ``data`` alone when it is small enough already. A piece's
        timestamp is its earliest frame's, never earlier than ``t_ns`` or the piece before.
    """
    if len(data) <= max_bytes:
        return [(t_ns, data)]
    message = orjson.loads(data)
    records = pybase64.b64decode(message["frames"], validate=True)
    count = len(records) // FRAME_SIZE
    statuses = encode_json(message["statuses"]).encode()
    long = {int(row): bytes.fromhex(d) for row, d in message.get("long", {}).items()}
    room = max(FRAME_SIZE * 2, max_bytes - len(FRAMES_HEAD) - len(statuses) - 64)
    # Each frame's share of a piece: its record in base64, and its full payload in hex.
    cost = np.full(count, FRAME_SIZE * 4 / 3)
    for row, payload in long.items():
        if 0 <= row < count:
            cost[row] += 2 * len(payload) + 16
    cuts = np.searchsorted(np.cumsum(cost), room * np.arange(1, cost.sum() // room + 2),
                           side="right")
    pieces = []
    start, t0 = 0, t_ns
    for stop in sorted({int(c) for c in cuts if 0 < c < count} | {count}):
        piece = records[start * FRAME_SIZE: stop * FRAME_SIZE]
        t0 = max(t0, earliest_time(piece))
        mine = {row - start: d for row, d in long.items() if start <= row < stop}
        pieces.append((t0, encode_frame_block(piece, stop - start, t0, statuses, mine)))
        start = stop
    return pieces


def _cells(values: NDArray) -> list[bytes]:
    """The JSON text of every cell of an (N, W) numeric array, row by row, as N*W bytes
    (orjson's: the shortest text that reads back the same float, null for NaN and inf)."""
    n, w = values.shape
    if not (n and w):
        return []
    text = orjson.dumps(np.ascontiguousarray(values), option=orjson.OPT_SERIALIZE_NUMPY)
    return text[2:-2].replace(b"],[", b",").split(b",")


class RowEncoder:
    """One JSON message per row, for the row topics (``/canfdi/samples``,
    ``/canfdi/residuals``): a %-template made once per layout, filled per row.

    The numbers are formatted by orjson in C for a whole block at once (exact: the shortest
    text that reads back the same float; null for NaN and inf), then placed into the block's
    templates by one %-operation: well under 1 us for a row of 9 values, where Python's own
    float formatting takes 3 us.

    Parameters
    ----------
    ints : sequence of str
        Top-level integer fields after ``"timestamp"``, in order (``("k", "gap")``).
    groups : sequence of (str, sequence of str)
        Objects of named floats, in order (``(("u", inputs), ("z", outputs))``).
    extra : mapping, optional
        Constant fields appended to every row (``{"drive": "left"}``).
    """

    __slots__ = ("_groups", "_ints", "_row", "_template", "_width", "extra")

    def __init__(self, ints: Sequence[str], groups: Sequence[tuple[str, Sequence[str]]],
                 extra: Mapping[str, Any] | None = None) -> None:
        self._ints = list(ints)
        self._groups = [(key, list(names)) for key, names in groups]
        self.extra = dict(extra) if extra else {}
        self._width = sum(len(names) for _, names in self._groups)

        def quoted(name: str) -> str:  # a JSON string, safe inside a %-template
            return json.dumps(name).replace("%", "%%")

        parts = ['{"timestamp":{"sec":%s,"nsec":%s}']
        parts += [f",{quoted(key)}:%s" for key in self._ints]
        for key, names in self._groups:
            fields = ",".join(f"{quoted(name)}:%s" for name in names)
            parts.append(f",{quoted(key)}:{{{fields}}}")
        parts += [f",{quoted(key)}:{encode_json(v).replace('%', '%%')}"
                  for key, v in self.extra.items()]
        self._template = "".join(parts) + "}"
        self._row = (self._template + "\n").encode()  # bytes %-formatting: no str round trip

    def encode(self, t_ns: NDArray[np.int64], ints: NDArray[np.int64],
               floats: NDArray[np.float64]) -> list[bytes]:
        """The messages of N rows: times (N,), integer fields (N, len(ints)), floats (N, W)
        with the groups' columns side by side."""
        n = len(t_ns)
        if not n:
            return []
        floats = np.asarray(floats, dtype=np.float64).reshape(n, self._width)
        sec, nsec = np.divmod(np.asarray(t_ns, dtype=np.int64), NS_PER_S)
        heads = np.column_stack([sec, nsec, np.asarray(ints, dtype=np.int64).reshape(n, -1)])
        # One %-operation for the whole block: the row templates joined by newlines (a JSON
        # message has none: names are escaped), filled with every cell, split again.
        width = heads.shape[1] + self._width
        cells: list[bytes | None] = [None] * (n * width)
        for offset, part in ((0, heads), (heads.shape[1], floats)):
            text_cells, w = _cells(part), part.shape[1]
            for j in range(w):  # strided list copies, C speed: a column at a time
                cells[offset + j :: width] = text_cells[j::w]
        return (self._row * n % tuple(cells)).split(b"\n")[:-1]

    def message(self, t_ns: int, ints: Sequence[int], floats: Sequence[float]) -> dict[str, Any]:
        """One row as a dict (the slow path, and the reference the template is tested
        against)."""
        message: dict[str, Any] = {"timestamp": stamp(t_ns)}
        message.update(zip(self._ints, ints, strict=True))
        start = 0
        for key, names in self._groups:
            message[key] = dict(zip(names, floats[start : start + len(names)], strict=True))
            start += len(names)
        message.update(self.extra)
        return message


# ------------------------------------------------------------------------------------------
# blocks: decoding
# ------------------------------------------------------------------------------------------


def check_block(message: Mapping[str, Any], encoding: str, topic: str) -> int:
    """The row count of a block message, checked to be of ``encoding``."""
    found = message.get("encoding")
    if found != encoding:
        raise ValueError(f"unsupported {topic} block encoding {found!r} (expected {encoding!r})")
    return int(message["count"])


def decode_frames(message: Mapping[str, Any]) -> FrameBlock:
    """The frames of one ``/can/frames`` block message, with their statuses."""
    count = check_block(message, FRAMES_ENCODING, TOPIC_FRAMES)
    records = np.frombuffer(pybase64.b64decode(message["frames"], validate=True),
                            dtype=FRAME_DTYPE)
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


def decode_frame_rows(rows: list[tuple[int, Mapping[str, Any]]]) -> FrameBlock:
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
            b"".join(p[:MAX_DATA].ljust(MAX_DATA, b"\0") for p in payloads), dtype=np.uint8
        ).reshape(n, MAX_DATA),
        status=np.array([str(m.get("status", "ok")) for _, m in rows], dtype=str),
        long={i: p for i, (p, d) in enumerate(zip(payloads, dlc, strict=True))
              if len(p) != min(d, 8)},
    )


def no_frames() -> FrameBlock:
    """A block of no frames, with an (empty) status column."""
    empty = FrameBlock.empty()
    return FrameBlock(empty.t_ns, empty.id, empty.dlc, empty.flags, empty.data,
                      status=np.empty(0, dtype=str))


def decode_floats(columns: Mapping[str, Any], names: list[str], n: int) -> np.ndarray:
    """(n, len(names)) float64 of a block's columns (JSON lists, null as NaN, or base64)."""
    parts = []
    for name in names:
        column = columns[name]
        if isinstance(column, str):
            parts.append(np.frombuffer(pybase64.b64decode(column, validate=True), dtype="<f8"))
        else:
            parts.append(np.array(column, dtype=np.float64))
        if parts[-1].shape != (n,):
            raise ValueError(f"column {name!r} holds {len(parts[-1])} values in a block of {n}")
    return np.array(parts, dtype=np.float64).reshape(len(names), n).T


def gathered(rows: Rows, widths: Sequence[int]) -> list[np.ndarray]:
    """Every row of ``rows`` as contiguous arrays; empty arrays (float columns of
    ``widths``) when there is none."""
    if not rows.count:
        return [np.empty(0, dtype=np.int64) for _ in range(len(rows.kinds) - len(widths))] + [
            np.empty((0, w)) for w in widths
        ]
    return [np.ascontiguousarray(a) for a in rows.take(rows.count)]


def decode_sample_block(
    message: Mapping[str, Any], inputs: list[str], outputs: list[str]
) -> tuple[np.ndarray, ...]:
    """(k, t_ns, gap, U, Z) of one ``/canfdi/samples`` block message."""
    n = check_block(message, SAMPLES_ENCODING, TOPIC_SAMPLES)
    return (
        np.array(message["k"], dtype=np.int64),
        np.array(message["t_ns"], dtype=np.int64),
        np.array(message["gap"], dtype=np.int64),
        decode_floats(message["u"], inputs, n),
        decode_floats(message["z"], outputs, n),
    )


def decode_residual_block(message: Mapping[str, Any], names: list[str]) -> tuple[np.ndarray, ...]:
    """(k, t_ns, R, Rn, stat) of one ``/canfdi/residuals`` block message."""
    n = check_block(message, RESIDUALS_ENCODING, TOPIC_RESIDUALS)
    return (
        np.array(message["k"], dtype=np.int64),
        np.array(message["t_ns"], dtype=np.int64),
        decode_floats(message["r"], names, n),
        decode_floats(message["normalized"], names, n),
        decode_floats(message["statistic"], names, n),
    )

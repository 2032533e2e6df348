"""FrameBlock: the one record a block of CAN frames travels in.

Frames go from the bus (python-can messages), or from a log, through the assembler to the
recorder and back out of a log reader in blocks: N frames as parallel arrays, never one Python
object per frame on the hot path. Every producer (`FrameBlock.from_messages`, the log readers of
canfdi.io, the emulator's encoder) and every consumer (`SampleAssembler.push_batch`,
`Monitor.on_frames`, the recorder) speaks this record.

>>> import can
>>> block = FrameBlock.from_messages([can.Message(timestamp=1.5, arbitration_id=0x104,
...                                               data=b"\\x01\\x02", is_extended_id=False)])
>>> block.size, int(block.t_ns[0]), block.payloads()
(1, 1500000000, [b'\\x01\\x02'])
"""

from __future__ import annotations

import operator
import time
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from canfdi.core._check import check_shape

__all__ = ["FLAG_ERROR", "FLAG_EXTENDED", "FLAG_FD", "FLAG_REMOTE", "MAX_DATA", "SENT",
           "STATUS_CODES", "STATUS_NAMES", "VALID_STATUSES", "FrameBlock", "frame_counters"]

# Bits of a frame's ``flags`` (python-can's Message booleans).
FLAG_EXTENDED = 1
FLAG_REMOTE = 2
FLAG_ERROR = 4
FLAG_FD = 8

# What FrameBlock.from_messages reads of a python-can Message, one C-level map per field.
_GET = {name: operator.attrgetter(name) for name in (
    "timestamp", "arbitration_id", "dlc", "is_extended_id", "is_remote_frame", "is_error_frame",
    "is_fd", "data")}

STATUS_NAMES: tuple[str, ...] = (
    "ok", "monitor", "unused", "unknown_id", "extended", "remote", "error_frame", "fd", "dlc",
    "crc", "duplicate", "stale", "jump", "time_jump", "implausible", "saturated",
)
"""What the assembler found of each received frame (canfdi.bus.assembler explains each)."""
STATUS_CODES: dict[str, int] = {name: code for code, name in enumerate(STATUS_NAMES)}
VALID_STATUSES: frozenset[str] = frozenset({"ok", "monitor", "unused"})
_INVALID_NAMES = tuple(name for name in STATUS_NAMES if name not in VALID_STATUSES)
SENT = "sent"
"""The status of a frame the monitor itself sent (a log holds both directions)."""


def frame_counters(counts, complete: int, broken: int, missing: int,
                   clock_steps: int = 0) -> dict:
    """The counters of a sample clock (and of the monitor) from its per-status frame counts.

    Parameters
    ----------
    counts : (len(STATUS_NAMES),) frames seen with each status code.
    complete, broken, missing : samples complete, broken (delivered with NaN for the signals of
        their missing messages) and missing (no valid frame at all).
    clock_steps : steps of the drive's clock followed (canfdi.bus.timegate).

    Returns
    -------
    dict with frames_received, frames_valid, frames_invalid, invalid_by_reason (every invalid
    status -> count, zeros included), samples_complete, samples_broken, samples_missing,
    duplicates, clock_steps.
    """
    invalid = {name: int(counts[STATUS_CODES[name]]) for name in _INVALID_NAMES}
    valid = sum(int(counts[STATUS_CODES[name]]) for name in VALID_STATUSES)
    return {
        "frames_received": valid + sum(invalid.values()),
        "frames_valid": valid,
        "frames_invalid": sum(invalid.values()),
        "invalid_by_reason": invalid,
        "samples_complete": complete,
        "samples_broken": broken,
        "samples_missing": missing,
        "duplicates": int(counts[STATUS_CODES["duplicate"]]),
        "clock_steps": int(clock_steps),
    }

MAX_DATA = 8
"""Bytes of payload held in ``data``; a longer (CAN FD) payload is kept whole in ``long``."""


@dataclass(frozen=True, eq=False)
class FrameBlock:
    """N CAN frames as arrays, row i the i-th frame in arrival (or log) order.

    Attributes
    ----------
    t_ns : (N,) int64
        Arrival (or send) times, ns since the epoch.
    id : (N,) uint32
        Arbitration IDs.
    dlc : (N,) uint8
        Payload lengths in bytes (0..64).
    flags : (N,) uint8
        `FLAG_EXTENDED`, `FLAG_REMOTE`, `FLAG_ERROR`, `FLAG_FD` bits.
    data : (N, 8) uint8
        Payloads, zero-padded (the first 8 bytes of a longer payload).
    status : (N,) str or None
        Each frame's status as a log recorded it (``"ok"``, ``"crc"``, ``"sent"``...); None for
        frames not yet judged (straight from a bus).
    long : dict of int to bytes
        The whole payload of the rows longer than 8 bytes (CAN FD); usually empty. `payloads`
        gives every frame's bytes.

    Examples
    --------
    >>> empty = FrameBlock.empty()
    >>> empty.size, empty.data.shape
    (0, (0, 8))
    """

    t_ns: NDArray[np.int64]
    id: NDArray[np.uint32]
    dlc: NDArray[np.uint8]
    flags: NDArray[np.uint8]
    data: NDArray[np.uint8]
    status: NDArray[np.str_] | None = None
    long: Mapping[int, bytes] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for name in ("id", "dlc", "flags"):
            values = np.asarray(getattr(self, name))
            if values.size and values.dtype.kind == "i" and values.min() < 0:
                raise ValueError(f"{name}: must be >= 0, got {values.min()}")
        t_ns = check_shape("t_ns", self.t_ns, ("N",), integer=True, dtype=np.int64)
        n = len(t_ns)
        set_ = object.__setattr__
        set_(self, "t_ns", t_ns)
        set_(self, "id", check_shape("id", self.id, (n,), integer=True, dtype=np.uint32))
        set_(self, "dlc", check_shape("dlc", self.dlc, (n,), integer=True, dtype=np.uint8))
        set_(self, "flags", check_shape("flags", self.flags, (n,), integer=True,
                                        dtype=np.uint8))
        set_(self, "data", check_shape("data", self.data, (n, MAX_DATA), integer=True,
                                       dtype=np.uint8))
        if self.status is not None:
            set_(self, "status", check_shape("status", self.status, (n,)).astype(str))

    # -- construction -----------------------------------------------------------------------
    @classmethod
    def empty(cls) -> FrameBlock:
        """A block of no frames."""
        none = np.zeros(0, dtype=np.int64)
        return cls(none, none, none, none, np.zeros((0, MAX_DATA), dtype=np.uint8))

    @classmethod
    def from_messages(cls, messages: Sequence, now: float | None = None) -> FrameBlock:
        """python-can Messages as a block. One C-level attribute fetch per message
        (operator.attrgetter) and numpy for the rest: a Python expression per message per field
        cost about 1 us a frame, as much as decoding, assembling and diagnosing it. A message
        without a timestamp (None or 0) gets ``now`` (default: the wall clock)."""
        n = len(messages)
        now = time.time() if now is None else now
        if n == 0:
            return cls.empty()

        def column(name: str, dtype: type) -> np.ndarray:
            return np.fromiter(map(_GET[name], messages), dtype, n)

        stamp = column("timestamp", np.float64)  # None reads as NaN
        t_ns = (np.where((stamp == 0.0) | np.isnan(stamp), now, stamp) * 1e9).astype(np.int64)
        ids = column("arbitration_id", np.int64)
        flags = (column("is_extended_id", np.int64) | (column("is_remote_frame", np.int64) << 1)
                 | (column("is_error_frame", np.int64) << 2) | (column("is_fd", np.int64) << 3))
        payloads = list(map(_GET["data"], messages))
        lengths = np.fromiter(map(len, payloads), np.int64, n)
        # A remote request has no data: its DLC is the length it asks for.
        remote = (flags & FLAG_REMOTE) != 0
        dlc = np.where(remote, column("dlc", np.int64), lengths)
        joined = np.frombuffer(b"".join(payloads), dtype=np.uint8)
        starts = np.cumsum(lengths) - lengths
        data = np.zeros((n, MAX_DATA), dtype=np.uint8)
        for j in range(MAX_DATA):  # columns, not messages
            has = lengths > j
            data[has, j] = joined[starts[has] + j]
        long = ({int(i): bytes(payloads[i]) for i in np.flatnonzero(lengths > MAX_DATA)}
                if int(lengths.max()) > MAX_DATA else {})
        return cls(t_ns, ids, dlc, flags, data, long=long)

    @classmethod
    def concat(cls, blocks: Iterable[FrameBlock]) -> FrameBlock:
        """The frames of several blocks, in order (a status column only if every block has
        one)."""
        parts = list(blocks)
        if not parts:
            return cls.empty()
        if len(parts) == 1:
            return parts[0]
        long: dict[int, bytes] = {}
        offset = 0
        for b in parts:
            long.update({offset + row: data for row, data in b.long.items()})
            offset += b.size
        status = (np.concatenate([b.status for b in parts])
                  if all(b.status is not None for b in parts) else None)
        return cls(*(np.concatenate([getattr(b, f) for b in parts])
                     for f in ("t_ns", "id", "dlc", "flags", "data")), status=status, long=long)

    # -- views ------------------------------------------------------------------------------
    @property
    def size(self) -> int:
        """Number of frames."""
        return len(self.t_ns)

    @property
    def extended(self) -> NDArray[np.bool_]:
        """(N,) bool: 29-bit identifiers."""
        return (self.flags & FLAG_EXTENDED) != 0

    def payloads(self) -> list[bytes]:
        """Every frame's payload bytes, in order (empty for a remote frame, whose DLC is the
        length it requests, not data it carries)."""
        flat = np.ascontiguousarray(self.data).tobytes()
        lengths = np.where(self.flags & FLAG_REMOTE, 0, np.minimum(self.dlc, MAX_DATA)).tolist()
        out = [flat[MAX_DATA * i: MAX_DATA * i + n] for i, n in enumerate(lengths)]
        for row, data in self.long.items():
            out[row] = data
        return out

    def select(self, rows: ArrayLike) -> FrameBlock:
        """The frames of a boolean mask or of integer row indices, in that order."""
        index = np.asarray(rows)
        if index.dtype == np.bool_:
            index = np.flatnonzero(index)
        long: dict[int, bytes] = {}
        if self.long:
            long = {new: self.long[old] for new, old in enumerate(index.tolist())
                    if old in self.long}
        return FrameBlock(self.t_ns[index], self.id[index], self.dlc[index], self.flags[index],
                          self.data[index],
                          status=None if self.status is None else self.status[index], long=long)

    def payload_matrix(self, rows: ArrayLike, length: int) -> NDArray[np.uint8]:
        """(len(rows), length) uint8: the payloads of those rows, zero-padded (or cut) to
        ``length`` bytes; rows longer than 8 bytes come from ``long``."""
        rows = np.asarray(rows, dtype=np.intp)
        if length <= MAX_DATA:
            if self.data.flags.c_contiguous and self.data.shape[1:] == (MAX_DATA,) == (8,):
                # A row is one 8-byte word: one gather of words, not of rows of bytes.
                got = self.data.view(np.uint64)[rows, 0].view(np.uint8).reshape(-1, 8)
                return got if length == 8 else np.ascontiguousarray(got[:, :length])
            return self.data[rows, :length]
        out = np.zeros((len(rows), length), dtype=np.uint8)
        out[:, :MAX_DATA] = self.data[rows]
        if self.long:
            for i, row in enumerate(rows.tolist()):
                data = self.long.get(row)
                if data is not None:
                    out[i, : min(len(data), length)] = np.frombuffer(data[:length], np.uint8)
        return out

    def to_messages(self, count: int | None = None) -> list:
        """The first ``count`` frames (default all) as python-can Messages."""
        import can

        n = self.size if count is None else min(count, self.size)
        payloads = self.payloads()
        return [can.Message(timestamp=int(self.t_ns[i]) / 1e9, arbitration_id=int(self.id[i]),
                            data=payloads[i],
                            is_extended_id=bool(self.flags[i] & FLAG_EXTENDED),
                            is_remote_frame=bool(self.flags[i] & FLAG_REMOTE),
                            is_error_frame=bool(self.flags[i] & FLAG_ERROR),
                            is_fd=bool(self.flags[i] & FLAG_FD), dlc=int(self.dlc[i]),
                            check=False)
                for i in range(n)]

    def received(self) -> FrameBlock:
        """The frames the monitor received: without its own transmissions (status "sent"),
        which a live monitor does not hear."""
        if self.status is None:
            return self
        keep = self.status != "sent"
        return self if keep.all() else self.select(keep)

    def slice(self, start: int, stop: int) -> FrameBlock:
        """Rows start..stop-1 (views of this block's arrays, not copies)."""
        rows = slice(start, min(stop, self.size))
        long: dict[int, bytes] = {}
        if self.long:
            long = {row - start: data for row, data in self.long.items()
                    if start <= row < rows.stop}
        return FrameBlock(self.t_ns[rows], self.id[rows], self.dlc[rows], self.flags[rows],
                          self.data[rows],
                          status=None if self.status is None else self.status[rows], long=long)

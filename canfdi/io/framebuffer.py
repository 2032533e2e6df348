"""`FrameBuffer`: raw CAN frames waiting for their ``/can/frames`` block, packed as they come.

Frames are packed `FRAME_DTYPE` records in one bytearray (a cheap append), payloads the record
cannot hold are kept by row, and each status string is a one-byte code into the buffer's
status table, which the block message lists (canfdi.io.schemas).
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from canfdi.bus.frames import MAX_DATA, FrameBlock
from canfdi.io.blocks import FRAME_SIZE, earliest_time, pack_frame
from canfdi.io.schemas import FRAME_DTYPE, FRAME_STATUSES

__all__ = ["MAX_STATUSES", "FrameBuffer", "FrameRecords"]

MAX_STATUSES = 256
"""Statuses one table holds: a frame's status is a uint8 code."""

FrameRecords = tuple[int, bytes, int, dict[int, bytes] | None, bytes]
"""What `FrameBuffer.take` returns: (the earliest frame's t_ns, packed records, count, full
payloads by row or None, JSON list of the status names the codes index)."""


class FrameBuffer:
    """Raw frames buffered for ``/can/frames``.

    Parameters
    ----------
    block_frames : int
        Frames of a full block (`append` and `extend` say when the buffer holds one).
    make_room : callable
        Called before the status table starts anew (it is full): it must take every buffered
        frame, which the old table describes.

    Examples
    --------
    >>> buffer = FrameBuffer(2, make_room=lambda: None)
    >>> buffer.append(1_000, 0x123, b"\\x01\\x02", "ok")
    False
    >>> buffer.append(2_000, 0x124, b"", "sent")
    True
    >>> t0, records, count, long, statuses = buffer.take(2)
    >>> t0, len(records), count, long, buffer.count
    (1000, 48, 2, None, 0)
    """

    __slots__ = ("_codes", "_full", "_long", "_make_room", "_names", "_records",
                 "statuses_json")

    def __init__(self, block_frames: int, make_room: Callable[[], None]) -> None:
        self._full = int(block_frames) * FRAME_SIZE  # bytes of a full block
        self._make_room = make_room
        self._records = bytearray()
        self._long: dict[int, bytes] = {}
        self._codes: dict[str, int] = {}
        self._names: list[str] = []
        self.statuses_json = b"[]"
        self._reset_statuses()

    @property
    def count(self) -> int:
        """Frames buffered."""
        return len(self._records) // FRAME_SIZE

    def append(self, timestamp_ns: int, frame_id: int, data: bytes, status: str,
               extended: bool = False, dlc: int | None = None, flags: int = 0) -> bool:
        """Buffer one frame (`McapRecorder.write_frame`'s arguments); whether the buffer
        holds a full block."""
        code = self._codes.get(status)
        if code is None:
            code = self._new_status(status)
        if type(data) is not bytes:
            data = bytes(data)
        n = len(data)
        if dlc is None and n <= MAX_DATA:
            self._records += pack_frame(timestamp_ns, frame_id, n, flags | extended, code, data)
        else:
            dlc = n if dlc is None else dlc
            if n != min(dlc, MAX_DATA):
                self._long[self.count] = data
            self._records += pack_frame(timestamp_ns, frame_id, dlc, flags | extended, code,
                                        data)
        return len(self._records) >= self._full

    def extend(self, block: FrameBlock, statuses: Any, status_names: Sequence[str] | None
               ) -> bool:
        """Buffer a block of frames (`McapRecorder.write_frames`'s arguments, ``statuses``
        given or the block's); whether the buffer holds a full block."""
        n = block.size
        records = np.zeros(n, dtype=FRAME_DTYPE)
        records["t_ns"] = block.t_ns
        records["id"] = block.id
        records["dlc"] = block.dlc
        records["data"] = block.data
        records["flags"] = block.flags
        records["status"] = self._status_array(statuses, n, status_names)
        if not n:
            return len(self._records) >= self._full
        if block.long:  # (after _status_array, which may have made room)
            base = self.count
            dlc = block.dlc
            for row, data in block.long.items():
                if len(data) != min(int(dlc[row]), MAX_DATA):
                    self._long[base + row] = bytes(data)
        self._records += records.tobytes()
        return len(self._records) >= self._full

    def take(self, n: int) -> FrameRecords:
        """Remove and return the first ``n`` frames (``0 < n <= count``)."""
        end = n * FRAME_SIZE
        records = bytes(self._records[:end])
        long = None
        if self._long:
            long = {row: data for row, data in self._long.items() if row < n}
            self._long = {row - n: d for row, d in self._long.items() if row >= n}
        del self._records[:end]
        return earliest_time(records), records, n, long, self.statuses_json

    # -- the status table ------------------------------------------------------------------

    def _reset_statuses(self) -> None:
        self._names = list(FRAME_STATUSES)
        self._codes = {name: code for code, name in enumerate(self._names)}
        self.statuses_json = json.dumps(self._names, separators=(",", ":")).encode()

    def _new_status(self, status: str) -> int:
        if not isinstance(status, str):
            raise TypeError(f"a frame status must be a str, got {type(status).__name__}")
        if len(self._names) >= MAX_STATUSES:
            # Codes are bytes: the buffered frames keep the full table, the rest starts anew.
            self._make_room()
            self._reset_statuses()
        code = len(self._names)
        self._names.append(status)
        self._codes[status] = code
        self.statuses_json = json.dumps(self._names, separators=(",", ":")).encode()
        return code

    def _status_array(self, statuses: ArrayLike | str, n: int,
                      status_names: Sequence[str] | None) -> NDArray[np.uint8]:
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
        missing = {name for name in names if name not in self._codes}
        if len(self._names) + len(missing) > MAX_STATUSES:
            # Codes are bytes: the buffered frames keep the full table, the rest starts anew.
            self._make_room()
            self._reset_statuses()
            missing = {name for name in names if name not in self._codes}
            if len(self._names) + len(missing) > MAX_STATUSES:
                raise ValueError(f"more than {MAX_STATUSES} frame statuses in one call")
        codes = self._codes
        table = np.array(
            [codes[name] if name in codes else self._new_status(name) for name in names],
            dtype=np.uint8,
        )
        return table[index] if len(table) else np.zeros(n, dtype=np.uint8)

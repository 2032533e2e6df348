"""mcap's `Writer` as canfdi's recorder drives it: chunks at `ZSTD_LEVEL`, and the messages of a
row topic added to the open chunk a batch at a time (`add_messages`).

Both reach into mcap 1.x's Writer (its ``zstandard`` module, its open chunk and statistics) and
fall back to its public API where those are missing; third-party readers check the files
(tests/integration/test_third_party_readers.py).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from mcap.opcode import Opcode
from mcap.records import MessageIndex
from mcap.writer import Writer
from numpy.typing import NDArray

__all__ = ["ZSTD_LEVEL", "Messages", "add_messages"]

Messages = Sequence[bytes] | NDArray[np.uint8]
"""The messages of a row channel: a list, or an (N, size) uint8 array of N messages of one size
(a fixed layout encoded a block at a time)."""

if not hasattr(Writer, "flush"):  # pragma: no cover - depends on the installed mcap
    # Without Writer.flush a chunk only ends when full, which breaks the crash-loss bound.
    raise ImportError("canfdi.io.writer needs an mcap package whose Writer has flush() (1.6+)")

ZSTD_LEVEL = -1
"""The zstd level of the logs' chunks. mcap's Python Writer compresses each chunk with
``zstandard.compress`` at its default level 3 and has no option for it (its Go writer records
at the fastest level by default, for the same reason). With the row topics in binary CDR
(canfdi.io.cdr), zstd is the recorder's largest cost, and level -1 (one of zstd's fast
levels: the same format, inflated by every reader) compresses a monitor log's chunks twice as
fast as level 1 (and level 3), for chunks 5 % larger (ratio 2.05 against 2.15 and 2.44 on
dc_motor's bus, 131 bytes a frame before compression). The level is given to the
``zstandard`` that mcap.writer calls (below): every MCAP this process writes gets it."""


class _Zstandard:
    """``zstandard`` as mcap.writer uses it, compressing at `ZSTD_LEVEL`."""

    def __init__(self, module: Any) -> None:
        self._module = module

    def compress(self, data: bytes, level: int = ZSTD_LEVEL) -> bytes:
        return self._module.compress(data, level)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._module, name)


def _use_zstd_level() -> None:
    import mcap.writer as mcap_writer

    module = getattr(mcap_writer, "zstandard", None)
    if module is not None and not isinstance(module, _Zstandard):
        mcap_writer.zstandard = _Zstandard(module)


_use_zstd_level()

# A Message record's head: opcode, record length, channel id, sequence, log and publish time.
_MESSAGE_HEAD = np.dtype([("op", "u1"), ("length", "<u8"), ("channel", "<u2"),
                          ("sequence", "<u4"), ("log_time", "<u8"), ("publish_time", "<u8")])
_HEAD_SIZE = _MESSAGE_HEAD.itemsize  # 31: packed, no alignment
_OP_MESSAGE = 0x05


class _RowIndex(MessageIndex):
    """A row channel's message index in the open chunk: its ``records`` are (N, 2) arrays of
    (log time, offset), one per batch, packed by numpy when the chunk ends (mcap's holds a
    tuple per message and writes each with two struct calls: a fifth of a capture's time)."""

    def write(self, stream: Any) -> None:
        entries = np.concatenate(self.records).astype("<u8").tobytes()
        stream.start_record(Opcode.MESSAGE_INDEX)
        stream.write2(self.channel_id)
        stream.write4(len(entries))
        stream.write(entries)
        stream.finish_record()


def add_messages(writer: Writer, channel_id: int, times: np.ndarray, data: Messages,
                  first_sequence: int) -> None:
    """Add N messages of one channel to the writer's open chunk at once, as N calls of
    ``Writer.add_message`` would (the same records, message index and statistics).

    A row topic writes a message per sample, and ``add_message`` costs about 3.5 us each in
    Python objects; here the record heads are one numpy array and the records one join (or,
    for messages of one size, heads and messages one record array). It uses the attributes of
    mcap's Writer that hold the open chunk and the statistics (mcap 1.x); without them it falls
    back to ``add_message``. The files are checked by third-party readers
    (tests/integration/test_third_party_readers.py).
    """
    builder = getattr(writer, "_Writer__chunk_builder", None)
    stats = getattr(writer, "_Writer__statistics", None)
    finalize = getattr(writer, "_Writer__maybe_finalize_chunk", None)
    n = len(data)
    fixed = isinstance(data, np.ndarray)
    if builder is None or stats is None or finalize is None:
        for i, (t, d) in enumerate(zip(times.tolist(), data, strict=True)):
            writer.add_message(channel_id, t, bytes(d), t, first_sequence + i)
        return
    if not n:
        return
    if fixed:
        size = data.shape[1]
        records = np.empty(n, dtype=[("head", _MESSAGE_HEAD), ("data", "u1", (size,))])
        head = records["head"]
        sizes = np.full(n, size, dtype=np.int64)
    else:
        sizes = np.fromiter(map(len, data), dtype=np.int64, count=n)
        head = np.empty(n, dtype=_MESSAGE_HEAD)
    head["op"] = _OP_MESSAGE
    head["length"] = sizes + (_HEAD_SIZE - 9)
    head["channel"] = channel_id
    head["sequence"] = (first_sequence + np.arange(n)) & 0xFFFFFFFF
    head["log_time"] = times
    head["publish_time"] = times
    start = builder.count
    offsets = np.empty(n, dtype=np.int64)
    offsets[0] = start
    np.cumsum(sizes[:-1] + _HEAD_SIZE, out=offsets[1:])
    offsets[1:] += start
    if fixed:
        records["data"] = data
        builder.record_writer.write(records.tobytes())
    else:
        raw = head.tobytes()
        heads = [raw[i : i + _HEAD_SIZE] for i in range(0, n * _HEAD_SIZE, _HEAD_SIZE)]
        builder.record_writer.write(b"".join(
            [part for pair in zip(heads, data, strict=True) for part in pair]))
    index = builder.message_indices.get(channel_id)
    if index is None:
        index = builder.message_indices[channel_id] = _RowIndex(channel_id=channel_id,
                                                                 records=[])
    index.records.append(np.column_stack([times, offsets]))
    t_min, t_max = int(times.min()), int(times.max())
    builder.message_start_time = (t_min if builder.num_messages == 0
                                  else min(builder.message_start_time, t_min))
    builder.message_end_time = max(builder.message_end_time, t_max)
    builder.num_messages += n
    stats.message_start_time = (t_min if stats.message_count == 0
                                else min(stats.message_start_time, t_min))
    stats.message_end_time = max(stats.message_end_time, t_max)
    stats.channel_message_counts[channel_id] += n
    stats.message_count += n
    finalize()

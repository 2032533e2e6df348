"""A minimal MCAP scanner that pulls one topic's messages out of a log, fast.

mcap's reader parses every record in Python (about 3 us each). A canfdi log holds far more
records than frame blocks (residual plot rows, sample and residual blocks, message indexes),
so replay spent most of its time reading records it then threw away. MCAP's framing is
simple: after the 8-byte magic, records are (opcode u8, length u64, body); a Chunk record holds
compressed records in the same framing. This scanner walks records by their lengths, maps
channel ids to topics, decompresses chunks and decodes only Message records of the wanted
topic. It stops quietly at a truncated record, as a killed writer leaves one.

Anything it does not know (a compression other than zstd or none) raises UnsupportedLog, and
callers fall back to the full reader (canfdi.io.reader). A file that is not MCAP raises
NotMcap. A chunk that does not inflate (a damaged file) is skipped with a warning, its
messages lost, and the scan goes on with the next record.
"""

from __future__ import annotations

import json
import logging
import struct
from collections.abc import Iterator
from pathlib import Path

__all__ = ["NotMcap", "UnsupportedLog", "scan_topic"]

logger = logging.getLogger(__name__)

MAGIC = b"\x89MCAP0\r\n"
OP_CHANNEL, OP_MESSAGE, OP_CHUNK = 0x04, 0x05, 0x06
_U16 = struct.Struct("<H")
_U32 = struct.Struct("<I")
_U64 = struct.Struct("<Q")
_HEAD = struct.Struct("<BQ")
_MESSAGE = struct.Struct("<HIQQ")


class UnsupportedLog(ValueError):
    """The scanner cannot read this file; use canfdi.io.reader's readers instead."""


class NotMcap(ValueError):
    """The file is not an MCAP file (its first bytes are not MCAP's magic)."""


def _string(buf: memoryview, pos: int) -> tuple[str, int]:
    (n,) = _U32.unpack_from(buf, pos)
    pos += 4
    return bytes(buf[pos : pos + n]).decode(), pos + n


def _records(buf: memoryview, pos: int, end: int) -> Iterator[tuple[int, int, int]]:
    """(opcode, body start, body end) of the complete records in buf[pos:end]."""
    while pos + 9 <= end:
        op, length = _HEAD.unpack_from(buf, pos)
        start = pos + 9
        stop = start + length
        if stop > end:
            return
        yield op, start, stop
        pos = stop


def scan_topic(path: str | Path, topic: str) -> Iterator[tuple[int, dict]]:
    """(log_time ns, decoded JSON) of every message on ``topic``, in file order."""
    data = Path(path).read_bytes()
    if not data.startswith(MAGIC):
        if MAGIC.startswith(data):  # cut short before its first record: nothing in it
            return
        raise NotMcap(f"{path}: not an MCAP file")
    buf = memoryview(data)
    channels: set[int] = set()
    decompressor = None
    yield from _scan(buf, len(MAGIC), len(buf), topic, channels, decompressor)


def _scan(buf: memoryview, pos: int, end: int, topic: str, channels: set[int],
          decompressor) -> Iterator[tuple[int, dict]]:
    for op, start, stop in _records(buf, pos, end):
        if op == OP_CHANNEL:
            (channel_id,) = _U16.unpack_from(buf, start)
            name, _ = _string(buf, start + 4)
            if name == topic:
                channels.add(channel_id)
        elif op == OP_MESSAGE:
            channel_id, _, log_time, _ = _MESSAGE.unpack_from(buf, start)
            if channel_id in channels:
                yield log_time, json.loads(bytes(buf[start + _MESSAGE.size : stop]))
        elif op == OP_CHUNK:
            # start time, end time, uncompressed size, uncompressed crc, compression, records
            p = start + 24
            (size,) = _U64.unpack_from(buf, start + 16)
            compression, p = _string(buf, p + 4)
            (length,) = _U64.unpack_from(buf, p)
            p += 8
            if p + length > stop:
                return
            payload = buf[p : p + length]
            if compression == "zstd":
                import zstandard

                if decompressor is None:
                    decompressor = zstandard.ZstdDecompressor()
                try:
                    inner = memoryview(
                        decompressor.decompress(bytes(payload), max_output_size=size)
                    )
                except zstandard.ZstdError as exc:
                    logger.warning("skipped a damaged chunk of %d bytes: %s", length, exc)
                    continue
            elif compression == "":
                inner = payload
            else:
                raise UnsupportedLog(f"chunk compression {compression!r}")
            yield from _scan(inner, 0, len(inner), topic, channels, decompressor)

"""The one MCAP record walker every reader of canfdi's logs goes through: checked, resynchronised.

MCAP's framing is simple: after the 8-byte magic, records are (opcode u8, length u64, body);
a Chunk record holds zstd-compressed records in the same framing, with the CRC-32 of its
uncompressed bytes. `McapFile` walks a file's records by their lengths (the file is mapped,
not read: constant memory for any log), and trusts nothing it has not checked:

* a record is *sound* when its opcode is one of MCAP's and its body parses exactly to its
  length (strings, maps and arrays inside it included), within the file;
* a chunk is read when its compression is known, its uncompressed size is at most
  `MAX_CHUNK_BYTES` and agrees with its zstd frame's, it inflates, and the CRC of what came out
  matches its ``uncompressed_crc`` (when that is not 0). Nothing is allocated from a length
  that was not checked: a damaged length field costs nothing;
* the data section's CRC (DataEnd), when the writer wrote one, is checked over the bytes read.

What is not sound is skipped, and reading resynchronises at the next record it can trust: the
next chunk offset of the summary's ChunkIndex records when the summary is intact (its CRC
checks), else the next place whose bytes frame a Chunk that inflates and passes its CRC (found
by its compression string), or the DataEnd record; the intact records just before it (the lost
chunk's MessageIndex records, a metadata record) are read too. Each skipped region goes into a
canfdi.io.damage `FileDamage` (bytes, chunks, log times, messages per topic from the
MessageIndex records of a lost chunk), which the caller owns and prints: nothing here prints.

Chunks come in log-time order (canfdi.io.chunkorder, from one walk of the record headers): the
order the intact summary lists them, each matched to its entry by its header (a summary that
bytes inserted before it moved is found after the last DataEnd record and taken when its CRC
checks), else each topic's chunks in the order of their MessageIndex times. A chunk out of
that order is held back as an offset and inflated when its turn comes; a chunk the intact
summary does not list (another recording's) is skipped and noted.

A file cut short (a killed writer) is read up to its last sound record; a file whose first
bytes are not MCAP's (and that does not go on as an MCAP file) raises `NotMcap`. Channels come
from the Channel records in the chunks and, when the summary is intact, from its copies there,
so that a lost first chunk does not lose every topic.

`scan_topic` gives one topic's decoded messages; canfdi.io.reader builds the log readers
(messages, metadata, frames, samples, residuals) on `McapFile`.
"""

from __future__ import annotations

import contextlib
import functools
import json
import mmap
import os
import struct
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import orjson

from canfdi.io.cdr import MESSAGE_ENCODING_CDR, SCHEMA_ENCODING_ROS2, CdrDecoder
from canfdi.io.chunkorder import ChunkKey, ChunkOrder, ChunkSeen, HeldChunks, order_chunks
from canfdi.io.damage import Damage, FileDamage, LostRegion
from canfdi.io.schemas import MESSAGE_ENCODING

try:  # the same CRC-32, ten times faster (python-isal: installed with canfdi[mf4]'s asammdf)
    from isal.isal_zlib import crc32 as _crc32
except ImportError:  # pragma: no cover - depends on what is installed
    from zlib import crc32 as _crc32

__all__ = ["MAGIC", "MAX_CHUNK_BYTES", "McapFile", "NotMcap", "UnsupportedLog", "decode_json",
           "scan_topic"]

MAGIC = b"\x89MCAP0\r\n"
MAX_CHUNK_BYTES = 256 * 1024 * 1024
"""A chunk declaring more uncompressed bytes than this is taken as damaged (canfdi writes
chunks of about 1 MiB)."""

OP_HEADER, OP_FOOTER, OP_SCHEMA, OP_CHANNEL = 0x01, 0x02, 0x03, 0x04
OP_MESSAGE, OP_CHUNK = 0x05, 0x06
OP_MESSAGE_INDEX, OP_CHUNK_INDEX, OP_ATTACHMENT, OP_ATTACHMENT_INDEX = 0x07, 0x08, 0x09, 0x0A
OP_STATISTICS, OP_METADATA, OP_METADATA_INDEX, OP_SUMMARY_OFFSET = 0x0B, 0x0C, 0x0D, 0x0E
OP_DATA_END = 0x0F

_U16 = struct.Struct("<H")
_U32 = struct.Struct("<I")
_U64 = struct.Struct("<Q")
_HEAD = struct.Struct("<BQ")
_MESSAGE_START = struct.Struct("<BQH")  # a record's opcode and length, a message's channel
_FIXED = {"B": struct.Struct("<B"), "H": _U16, "I": _U32, "Q": _U64}

# Each record's body, field by field (mcap.records): B/H/I/Q integers, s a u32-prefixed UTF-8
# string, b u32-prefixed bytes, L u64-prefixed bytes, m a u32-sized map of strings, a<n> a
# u32-sized array of n-byte entries, r the rest of the body.
_SPECS: dict[int, tuple[str, ...]] = {
    OP_HEADER: ("s", "s"),
    OP_FOOTER: ("Q", "Q", "I"),
    OP_SCHEMA: ("H", "s", "s", "b"),
    OP_CHANNEL: ("H", "H", "s", "s", "m"),
    OP_MESSAGE: ("H", "I", "Q", "Q", "r"),
    OP_CHUNK: ("Q", "Q", "Q", "I", "s", "L"),
    OP_MESSAGE_INDEX: ("H", "a16"),
    OP_CHUNK_INDEX: ("Q", "Q", "Q", "Q", "a10", "Q", "s", "Q", "Q"),
    OP_ATTACHMENT: ("Q", "Q", "s", "s", "L", "I"),
    OP_ATTACHMENT_INDEX: ("Q", "Q", "Q", "Q", "Q", "s", "s"),
    OP_STATISTICS: ("Q", "H", "I", "I", "I", "I", "Q", "Q", "a10"),
    OP_METADATA: ("s", "m"),
    OP_METADATA_INDEX: ("Q", "Q", "s"),
    OP_SUMMARY_OFFSET: ("B", "Q", "Q"),
    OP_DATA_END: ("I",),
}
_NAMES = {OP_HEADER: "Header", OP_FOOTER: "Footer", OP_SCHEMA: "Schema", OP_CHANNEL: "Channel",
          OP_MESSAGE: "Message", OP_CHUNK: "Chunk", OP_MESSAGE_INDEX: "MessageIndex",
          OP_CHUNK_INDEX: "ChunkIndex", OP_ATTACHMENT: "Attachment",
          OP_ATTACHMENT_INDEX: "AttachmentIndex", OP_STATISTICS: "Statistics",
          OP_METADATA: "Metadata", OP_METADATA_INDEX: "MetadataIndex",
          OP_SUMMARY_OFFSET: "SummaryOffset", OP_DATA_END: "DataEnd"}
_COMPRESSIONS = ("zstd", "", "lz4")
_CHUNK_HEAD = struct.Struct("<QQQI")  # start time, end time, uncompressed size, crc
# The compression string of a chunk sits 37 bytes into its record: what resync looks for.
_COMPRESSION_AT = 9 + _CHUNK_HEAD.size
_CHUNK_PATTERNS = (b"\x04\x00\x00\x00zstd", b"\x03\x00\x00\x00lz4")
_DATA_END_PATTERN = b"\x0f\x04\x00\x00\x00\x00\x00\x00\x00"
_CHAIN_WINDOW = 1 << 20  # bytes before a resync point searched for the intact records there
_MESSAGE_HEAD = 22  # channel u16, sequence u32, log_time u64, publish_time u64
_DAY_NS = 86_400 * 10**9  # a lost chunk's header times further than this from its neighbours'
# are taken as damaged too


class UnsupportedLog(ValueError):
    """A file canfdi cannot read although it is not damaged (an lz4 chunk without the lz4
    package)."""


class NotMcap(ValueError):
    """The file is not an MCAP file (its first bytes are not MCAP's magic, nor followed by an
    MCAP header)."""


def decode_json(data: bytes) -> Any:
    """A message's JSON, by orjson (four times faster than Python's json on a frame block);
    what orjson refuses and Python's json reads (the NaN and Infinity tokens of older canfdi
    logs) by Python's json. Raises ValueError for text that is not JSON, or not UTF-8."""
    try:
        return orjson.loads(data)
    except orjson.JSONDecodeError:
        return json.loads(data)


def _refusing(reason: str) -> Callable[[bytes], Any]:
    """A decoder that refuses every message, saying why (each counted as bad)."""
    def refuse(data: bytes) -> Any:
        raise ValueError(reason)
    return refuse


@functools.lru_cache(maxsize=64)
def _cdr_decoder(schema_name: str, schema_encoding: str, data: bytes) -> Callable[[bytes], Any]:
    if schema_encoding != SCHEMA_ENCODING_ROS2:
        return _refusing(f"messages encoded as 'cdr' with a {schema_encoding!r} schema are "
                         "not read")
    try:
        return CdrDecoder(data.decode())
    except (ValueError, UnicodeDecodeError) as error:
        return _refusing(f"the ROS 2 schema {schema_name} cannot be read: {error}")


MESSAGE_DECODERS: dict[str, Callable[[str, str, bytes], Callable[[bytes], Any]]] = {
    MESSAGE_ENCODING: lambda name, encoding, data: decode_json,
    MESSAGE_ENCODING_CDR: _cdr_decoder,
}
"""How a channel's messages decode, by its message encoding, made of its schema (name,
encoding, data): a message that does not decode raises ValueError (counted as bad)."""


def message_decoder(message_encoding: str, schema: tuple[str, str, bytes] | None
                    ) -> Callable[[bytes], Any]:
    """The decoder of a channel's messages (`MESSAGE_DECODERS`); one that refuses every
    message for an encoding canfdi does not read."""
    make = MESSAGE_DECODERS.get(message_encoding)
    if make is None:
        return _refusing(f"messages encoded as {message_encoding!r} are not read")
    return make(*(schema if schema is not None else ("", "", b"")))


def _parse(buf: Any, start: int, stop: int, spec: tuple[str, ...]) -> list | None:
    """The fields of a record body ``buf[start:stop]`` by ``spec``; None unless they fill it
    exactly (strings UTF-8, maps whole)."""
    out: list[Any] = []
    p = start
    try:
        for kind in spec:
            fixed = _FIXED.get(kind)
            if fixed is not None:
                if p + fixed.size > stop:
                    return None
                out.append(fixed.unpack_from(buf, p)[0])
                p += fixed.size
            elif kind == "r":
                out.append((p, stop))
                p = stop
            else:
                width = 8 if kind == "L" else 4
                if p + width > stop:
                    return None
                (n,) = (_U64 if width == 8 else _U32).unpack_from(buf, p)
                p += width
                if n > stop - p:
                    return None
                if kind == "s":
                    out.append(bytes(buf[p : p + n]).decode())
                elif kind == "m":
                    out.append(_map(buf, p, p + n))
                elif kind[0] == "a":
                    if n % int(kind[1:]):
                        return None
                    out.append((p, p + n))
                else:
                    out.append((p, p + n))
                p += n
    except (UnicodeDecodeError, ValueError):
        return None
    return out if p == stop else None


def _map(buf: Any, p: int, stop: int) -> dict[str, str]:
    """A map of u32-prefixed strings filling ``buf[p:stop]``; ValueError if it does not."""
    out = {}
    while p < stop:
        pair = []
        for _ in range(2):
            if p + 4 > stop:
                raise ValueError("map entry cut")
            (n,) = _U32.unpack_from(buf, p)
            p += 4
            if n > stop - p:
                raise ValueError("map entry cut")
            pair.append(bytes(buf[p : p + n]).decode())
            p += n
        out[pair[0]] = pair[1]
    return out


@dataclass(frozen=True)
class _IndexedChunk:
    """A chunk as the summary's ChunkIndex records say: its offset, record length, times,
    the offsets of its MessageIndex records and the channels they index."""

    offset: int
    length: int
    start_ns: int
    end_ns: int
    index_offsets: tuple[int, ...]
    index_channels: frozenset[int]


@dataclass
class _Walk:
    """What a `McapFile.records` walk carries from record to record."""

    crc: int | None  # the data section's CRC so far (None: it cannot be checked)
    clean: bool  # nothing lost so far: the data CRC can judge the file
    order: ChunkOrder | None  # the chunks' reading order (inflating walks)
    held: HeldChunks | None = None  # chunks waiting for their turn (out of order)
    tail: LostRegion | None = None  # the lost region the MessageIndex records here count
    whole: bool = False  # and they follow its one lost chunk directly: they count it whole


class McapFile:
    """One MCAP file, walked record by record with every check; a context manager.

    Parameters
    ----------
    path : str or Path
        The file.
    damage : Damage, optional
        Where what is skipped is recorded (`damage` is this file's `FileDamage` in it); a
        private one when None.

    Raises
    ------
    NotMcap
        The file is not MCAP (not even with a damaged magic: no MCAP header follows).
    OSError
        The file cannot be opened.

    Attributes
    ----------
    channels : dict of int to str
        Channel id to topic, as learnt so far (the summary's from the start when it is
        intact).
    complete : bool
        After a whole walk: the file ends with its footer and magic.
    truncated : bool
        After a whole walk: it does not (cut short, or damaged at its end).
    """

    def __init__(self, path: str | Path, damage: Damage | None = None) -> None:
        self.path = Path(path)
        with open(self.path, "rb") as file:
            size = os.fstat(file.fileno()).st_size
            self._map = mmap.mmap(file.fileno(), 0, access=mmap.ACCESS_READ) if size else None
        self._raw: Any = self._map if self._map is not None else b""
        self._buf = memoryview(self._raw)
        self.size = size
        self.damage: FileDamage = (damage if damage is not None else Damage()).file(path, size)
        self.channels: dict[int, str] = {}
        self.decoders: dict[int, Callable[[bytes], Any]] = {}  # by channel id
        self._schemas: dict[int, tuple[str, str, bytes]] = {}  # (name, encoding, data) by id
        self._summary_channels = False  # every channel known from an intact summary
        self._index_of: dict[int, _IndexedChunk] | None = None  # its ChunkIndex by offset
        self.complete = False
        self.truncated = False
        self._cache: tuple[int, bytes] | None = None
        self._decompressor: Any = None
        self._last_chunk: tuple[int, int] | None = None  # (start, end) ns of the last intact
        self._waiting: list[LostRegion] = []  # regions whose after_ns is the next intact chunk
        self._indexed: list[_IndexedChunk] = []
        self._stats: tuple[int, int] | None = None
        self._data_end: int | None = None
        self._past_data = False  # the walk is past the DataEnd record
        self._listed_chunks: list[tuple[int, ChunkKey]] | None = None  # the summary's entries
        self._order: ChunkOrder | None = None
        try:
            self._first = self._check_magic()
            if self._first < size:
                self._read_summary()
        except BaseException:
            self.close()
            raise

    # -- context manager -------------------------------------------------------------------

    def __enter__(self) -> McapFile:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Unmap the file (left to the garbage collector while a view of it is still held)."""
        self._cache = None
        self._buf.release()
        if self._map is not None:
            with contextlib.suppress(BufferError):
                self._map.close()

    def fields(self, op: int, start: int, stop: int) -> list:
        """The fields of the sound record ``op`` whose body is ``start``..``stop`` (as
        `records` gives it), in mcap.records' order; strings decoded, maps as dicts, byte
        fields as (start, stop) offsets."""
        fields = _parse(self._buf, start, stop, _SPECS[op])
        if fields is None:
            raise ValueError(f"{self.path}: no sound {_NAMES.get(op, op)} record at {start - 9}")
        return fields

    # -- the magic and the summary ---------------------------------------------------------

    def _check_magic(self) -> int:
        head = bytes(self._buf[:8])
        if head == MAGIC:
            return 8
        if self.size < 8 and MAGIC.startswith(head):  # nothing was written yet
            self.damage.lost(0, self.size, "cut short inside the magic" if self.size
                             else "an empty file", cut=True, exact=True)
            return self.size
        found = self._sound(8) if self.size > 8 else None
        if found is None or found[0] != OP_HEADER:
            raise NotMcap(f"{self.path}: not an MCAP file")
        self.damage.bad_magic = True
        return 8

    def _read_summary(self) -> None:
        """Channels, chunk offsets and times from the summary, when its footer is sound, its
        CRC checks (without one: every record of it is sound) and it points inside the
        file. A summary not where the footer says (bytes inserted into or cut from the data
        section) is looked for right after the last DataEnd record, and taken when its CRC
        checks."""
        buf, size = self._buf, self.size
        footer = size - 8 - 9 - 20
        if footer < self._first or bytes(buf[size - 8 :]) != MAGIC:
            return
        found = self._sound(footer)
        if found is None or found[0] != OP_FOOTER:
            return
        declared, _, crc = _parse(buf, footer + 9, footer + 29, _SPECS[OP_FOOTER]) or (0, 0, 0)
        if self._summary_at(declared, footer, crc, moved=False):
            return
        end = self._raw.rfind(_DATA_END_PATTERN, self._first, footer)
        if crc and end >= 0 and end + 13 != declared \
                and self._summary_at(end + 13, footer, crc, moved=True):
            self._note(f"the summary is at byte {end + 13}, not at byte {declared} where the "
                       "footer says: bytes were inserted into or cut from the data section")

    def _summary_at(self, summary_start: int, footer: int, crc: int, moved: bool) -> bool:
        """Read the summary from ``summary_start`` when it checks (see `_read_summary`);
        whether it did. ``moved``: the footer does not point there, so the chunk offsets it
        lists are not checked against it (the chunks are matched by their headers)."""
        buf = self._buf
        if not self._first < summary_start <= footer:
            return False
        if crc and crc != _crc32(buf[footer : footer + 25], _crc32(buf[summary_start:footer])):
            return False
        channels: list[list] = []
        schemas: dict[int, tuple[str, str, bytes]] = {}
        indexed: list[_IndexedChunk] = []
        listed: list[tuple[int, ChunkKey]] = []
        stats = None
        pos = summary_start
        while pos < footer:
            found = self._sound(pos)
            if found is None or found[2] > footer:
                return False
            op, start, stop = found
            fields = _parse(buf, start, stop, _SPECS[op])
            assert fields is not None
            if op == OP_CHANNEL:
                channels.append(fields)
            elif op == OP_SCHEMA:
                schemas[fields[0]] = (fields[1], fields[2], bytes(buf[slice(*fields[3])]))
            elif op == OP_CHUNK_INDEX:
                t0, t1, offset, length, (a, b) = fields[:5]
                if not moved and not self._first <= offset < offset + length <= summary_start:
                    return False
                offsets = tuple(_U64.unpack_from(buf, p + 2)[0] for p in range(a, b, 10))
                ids = frozenset(_U16.unpack_from(buf, p)[0] for p in range(a, b, 10))
                indexed.append(_IndexedChunk(offset, length, t0, t1, offsets, ids))
                listed.append((offset, (length, t0, t1, fields[8], fields[7])))
            elif op == OP_STATISTICS:
                stats = (fields[6], fields[7])
            pos = stop
        self._schemas.update(schemas)
        for fields in channels:
            self._learn_channel(fields)
        self._summary_channels = True
        self._indexed = sorted(indexed, key=lambda c: c.offset)
        self._listed_chunks = listed
        self._stats = stats
        if stats is not None and stats[0] <= stats[1] and indexed:
            self.damage.saw_times(*stats)
        end = summary_start - 13
        found = self._sound(end) if end >= self._first else None
        if found is not None and found[0] == OP_DATA_END:
            self._data_end = end
        return True

    def _reading_order(self) -> ChunkOrder:
        """The chunks' reading order (canfdi.io.chunkorder), from one walk of the record
        headers (cached). The intact summary's index entries are moved to where their chunks
        are in the file; a foreign chunk has no entry, so it is not indexed."""
        if self._order is not None:
            return self._order
        buf, seen, last = self._buf, [], None
        by_times = self._listed_chunks is None  # the indexes' times: only without a summary
        pos = self._first
        while pos < self.size:
            found = self._sound(pos)
            if found is None:
                last, pos = None, self._next_chunk(pos)
                if pos is None:
                    break
                continue
            op, start, stop = found
            if op == OP_CHUNK:
                t0, t1, size, _, _, (a, b) = self.fields(OP_CHUNK, start, stop)
                last = ChunkSeen(pos, (stop - pos, t0, t1, size, b - a))
                seen.append(last)
            elif op == OP_MESSAGE_INDEX and by_times and last is not None \
                    and stop - start > 6:
                (channel,) = _U16.unpack_from(buf, start)
                times = np.frombuffer(buf, dtype="<u8", offset=start + 6,
                                      count=(stop - start - 6) // 8)[0::2]
                t = int(times.min())
                if last.key[1] <= t <= int(times.max()) <= last.key[2]:
                    # (an index is not CRC-checked: one outside its chunk's times is not used)
                    last.earliest[channel] = min(t, last.earliest.get(channel, t))
            elif op == OP_DATA_END:
                break
            elif op != OP_MESSAGE_INDEX:
                last = None
            pos = stop
        self._order = order_chunks(seen, self._listed_chunks)
        if self._listed_chunks is not None:
            listed_at = self._order.listed_at
            by_offset = {c.offset: c for c in self._indexed}
            moved = []
            for at, offset in listed_at.items():
                c = by_offset[offset]
                shift = at - offset
                moved.append(_IndexedChunk(at, c.length, c.start_ns, c.end_ns,
                                           tuple(p + shift for p in c.index_offsets),
                                           c.index_channels))
            # A listed chunk no sound record matched keeps its offset (it is damaged there),
            # unless a matched chunk now lies over it.
            kept = set(listed_at.values())
            spans = [(m.offset, m.offset + m.length) for m in moved]
            moved += [c for c in self._indexed if c.offset not in kept
                      and not any(a <= c.offset < b for a, b in spans)]
            self._indexed = sorted(moved, key=lambda c: c.offset)
            self._index_of = None
        return self._order

    def _next_chunk(self, pos: int) -> int | None:
        """The next place after ``pos`` where a sound Chunk or DataEnd record starts,
        found by its bytes (not by the summary's offsets, which may be shifted)."""
        for where in self._candidates(pos, by_pattern=True):
            found = self._sound(where)
            if found is not None and found[0] in (OP_CHUNK, OP_DATA_END):
                return where
        return None

    # -- records ---------------------------------------------------------------------------

    def _sound(self, pos: int) -> tuple[int, int, int] | None:
        """(opcode, body start, body stop) of a sound record at ``pos``, else None."""
        if pos + 9 > self.size:
            return None
        op, length = _HEAD.unpack_from(self._buf, pos)
        spec = _SPECS.get(op)
        if spec is None or length > self.size - pos - 9:
            return None
        start = pos + 9
        if op == OP_MESSAGE_INDEX:  # the most frequent: checked without the general parser
            if length < 6:
                return None
            (n,) = _U32.unpack_from(self._buf, start + 2)
            return (op, start, start + length) if n == length - 6 and n % 16 == 0 else None
        fields = _parse(self._buf, start, start + length, spec)
        if fields is None or (op == OP_CHUNK and fields[4] not in _COMPRESSIONS):
            return None
        return op, start, start + length

    def _why(self, pos: int) -> tuple[str, bool]:
        """Why no sound record is at ``pos``, and whether it is a record cut by the end of
        the file."""
        if pos + 9 > self.size:
            return "cut short", True
        op, length = _HEAD.unpack_from(self._buf, pos)
        if op not in _SPECS:
            return f"no MCAP record at byte {pos} (opcode 0x{op:02x})", False
        if length > self.size - pos - 9:
            return f"a {_NAMES[op]} record longer than the rest of the file", True
        return f"a malformed {_NAMES[op]} record", False

    def _chunk_head(self, pos: int) -> tuple[int, int] | None:
        """The (start, end) ns of the chunk header at ``pos`` when readable and plausible."""
        if pos + 9 + 16 > self.size or self._buf[pos] != OP_CHUNK:
            return None
        t0, t1 = struct.unpack_from("<QQ", self._buf, pos + 9)
        if not 0 <= t1 - t0 <= _DAY_NS:
            return None
        if self._stats is not None and not self._stats[0] <= t0 <= t1 <= self._stats[1]:
            return None
        if self._last_chunk is not None and abs(t0 - self._last_chunk[0]) > _DAY_NS:
            return None
        return t0, t1

    def _inflate(self, pos: int, start: int, stop: int) -> tuple[bytes | None, str]:
        """The uncompressed records of the sound chunk at ``pos``, or (None, why not)."""
        if self._cache is not None and self._cache[0] == pos:
            return self._cache[1], ""
        buf = self._buf
        _, _, size, crc = _CHUNK_HEAD.unpack_from(buf, start)
        (n,) = _U32.unpack_from(buf, start + _CHUNK_HEAD.size)
        compression = bytes(buf[start + 32 : start + 32 + n]).decode()
        data = buf[start + 32 + n + 8 : stop]
        if size > MAX_CHUNK_BYTES:
            return None, f"a chunk declaring {size} bytes uncompressed"
        if compression == "zstd":
            import zstandard

            if self._decompressor is None:
                self._decompressor = zstandard.ZstdDecompressor()
            try:
                declared = zstandard.frame_content_size(data)
                if declared not in (-1, size):
                    return None, "a chunk whose zstd frame disagrees with its size"
                inner = self._decompressor.decompress(data, max_output_size=size) if size else b""
            except zstandard.ZstdError as exc:
                return None, f"a chunk that does not inflate (zstd: {exc})"
        elif compression == "":
            inner = bytes(data)
        else:
            try:
                import lz4.frame
            except ImportError:
                raise UnsupportedLog(f"{self.path}: lz4-compressed chunks need the lz4 package "
                                     "(pip install lz4)") from None
            try:
                inner = lz4.frame.LZ4FrameDecompressor().decompress(bytes(data), max_length=size)
            except RuntimeError as exc:
                return None, f"a chunk that does not inflate (lz4: {exc})"
        if len(inner) != size:
            return None, "a chunk whose uncompressed size is wrong"
        if crc and _crc32(inner) != crc:
            return None, "a chunk whose CRC does not match"
        self._cache = (pos, inner)
        return inner, ""

    # -- resynchronising -------------------------------------------------------------------

    def _candidates(self, pos: int, by_pattern: bool = False) -> Iterator[int]:
        """Ascending places after ``pos`` where a chunk or the DataEnd record may start: the
        summary's chunk offsets when it has them (unless ``by_pattern``), else where their
        bytes are found."""
        if self._indexed and not by_pattern:
            later = [c.offset for c in self._indexed if c.offset > pos]
            if self._data_end is not None and self._data_end > pos:
                later.append(self._data_end)
            yield from sorted(later)
            return
        raw = self._raw
        finds = [(pattern, _COMPRESSION_AT) for pattern in _CHUNK_PATTERNS]
        finds.append((_DATA_END_PATTERN, 0))
        heads = []
        for pattern, back in finds:
            hit = raw.find(pattern, pos + 1 + back)
            if hit >= 0:
                heads.append([hit - back, pattern, back])
        while heads:
            heads.sort()
            where, pattern, back = heads[0]
            yield where
            hit = raw.find(pattern, where + back + 1)
            if hit >= 0:
                heads[0][0] = hit - back
            else:
                heads.pop(0)

    def _resync(self, pos: int) -> tuple[int | None, list[int]]:
        """(where reading resumes after the unsound bytes at ``pos`` (None: nowhere), the
        offsets of the damaged chunks found on the way)."""
        lost_at: list[int] = []
        for where in self._candidates(pos):
            found = self._sound(where)
            if found is None:
                continue
            if found[0] == OP_DATA_END:
                after = self._sound(found[2])
                if found[2] != self.size and after is None:
                    continue
            elif found[0] != OP_CHUNK:
                continue
            elif self._inflate(where, found[1], found[2])[0] is None:
                lost_at.append(where)
                continue
            return self._chain_start(pos, where), lost_at
        return None, lost_at

    def _chain_start(self, pos: int, anchor: int) -> int:
        """The first place after ``pos`` from which sound records other than chunks run
        exactly up to ``anchor`` (the lost chunk's MessageIndex records, a metadata record);
        ``anchor`` when there is none."""
        raw = self._raw
        low = max(pos + 1, anchor - _CHAIN_WINDOW)
        hits = []
        for op in (b"\x07", b"\x0c"):
            at = raw.find(op, low, anchor)
            while at >= 0:
                hits.append(at)
                at = raw.find(op, at + 1, anchor)
        for start in sorted(hits):
            p = start
            while p < anchor:
                found = self._sound(p)
                if found is None or found[0] == OP_CHUNK or found[2] > anchor:
                    break
                p = found[2]
            if p == anchor:
                return start
        return anchor

    def _lose(self, pos: int, resume: int | None, lost_at: Sequence[int] = ()
              ) -> LostRegion:
        """Record the unsound bytes from ``pos`` to ``resume`` (None: the end), in which the
        chunks at ``lost_at`` were found damaged."""
        end = self.size if resume is None else resume
        why, cut = self._why(pos)
        cut = cut and resume is None
        chunks: dict[int, tuple[int, int] | None] = {}
        if self._past_data:
            why += " (in the summary: no message there)"
        elif not self._indexed:
            # The damaged chunks found on the way, and one at pos when its header is
            # plausible or it is the one cut short.
            chunks = {at: self._chunk_head(at) for at in lost_at}
            head = self._chunk_head(pos)
            if pos not in chunks and self._buf[pos] == OP_CHUNK and (cut or head is not None):
                chunks[pos] = head
        # Exact: the summary's index says which chunks the bytes held; past the data section
        # there are none; a cut region is the one record cut short.
        exact = bool(self._indexed) or self._past_data or cut
        region = self.damage.lost(pos, end, "cut short" if cut else why, chunks=chunks, cut=cut,
                                  exact=exact,
                                  before_ns=self._last_chunk[1] if self._last_chunk else None)
        if self._indexed and not self._past_data:
            # The summary's index says which chunks the region (with what it merged) held, and
            # where their MessageIndex records are: the counts are whole where all are sound.
            inside = [c for c in self._indexed if region.start <= c.offset < region.end]
            region.lost_chunks.update({c.offset: (c.start_ns, c.end_ns) for c in inside})
            found = [self._count_index(region, at) for c in inside for at in c.index_offsets]
            region.indexed = all(found) and all(c.index_offsets for c in inside)
        else:
            region.indexed = False  # garbage may have taken some MessageIndex records
        self._waiting.append(region)
        return region

    def _count_index(self, region: LostRegion, offset: int) -> bool:
        """Add the MessageIndex record at ``offset`` to a lost region's counts; False when
        there is no sound one there."""
        found = self._sound(offset)
        if found is None or found[0] != OP_MESSAGE_INDEX:
            return False
        channel, (a, b) = _parse(self._buf, found[1], found[2], _SPECS[OP_MESSAGE_INDEX])
        topic = self.channels.get(channel, f"channel {channel}")
        region.add_index(offset, topic, (b - a) // 16)
        return True

    def _intact(self, start: int) -> None:
        """An intact chunk: its times bound the regions lost before it."""
        t0, t1 = struct.unpack_from("<QQ", self._buf, start)
        for region in self._waiting:
            region.after_ns = t0 if region.after_ns is None else region.after_ns
            for at, t in region.lost_chunks.items():
                if t is not None and not (t[1] <= t1 + _DAY_NS and abs(t0 - t[0]) <= _DAY_NS):
                    region.lost_chunks[at] = None
        self._waiting = []
        self._last_chunk = (t0, t1)
        self.damage.saw_times(t0, t1)

    # -- the walk --------------------------------------------------------------------------

    def records(self, inflate: bool = True, skip: Callable[[int, int], bool] | None = None
                ) -> Iterator[tuple[int, int, int, Any]]:
        """(opcode, body start, body stop, inflated chunk or None) of every sound top-level
        record in file order, damaged ones skipped and recorded.

        With ``inflate``, chunks come with their checked uncompressed records (a chunk that
        fails is skipped and recorded; its MessageIndex records count what it lost), and the
        data section's CRC is checked. Without, chunks come unchecked (None), for a walk
        that only needs what lies between them. ``skip(start, stop)`` true for a chunk's
        body: that chunk comes unchecked and not inflated (None) too.
        """
        buf, size = self._buf, self.size
        pos = self._first
        walk = self._start_walk(inflate)
        seen: dict[bytes, int] = {}  # a checked chunk's header -> where it was first read
        while pos < size:
            found = self._sound(pos)
            if found is None:
                resume, lost_at = self._resync(pos)
                walk.tail, walk.whole = self._lose(pos, resume, lost_at), False
                walk.crc, walk.clean = None, False
                if resume is None:
                    break
                pos = resume
                continue
            op, start, stop = found
            if walk.crc is not None and op != OP_DATA_END:
                walk.crc = _crc32(buf[pos:stop], walk.crc)
            if op == OP_MESSAGE_INDEX:
                if walk.tail is not None:
                    self._count_index(walk.tail, pos)
                    walk.tail.indexed = walk.tail.indexed or (walk.whole
                                                              and walk.tail.chunks == 1)
                pos = stop
                continue
            walk.tail, walk.whole = None, False
            if op == OP_CHUNK and inflate:
                yield from self._walk_chunk(walk, pos, start, stop, skip, seen)
                pos = stop
                continue
            if op == OP_DATA_END:
                if walk.held is not None:
                    yield from self._release(walk.held, None, skip, seen)
                self._past_data_end(walk, start, inflate)
            yield op, start, stop, None
            pos = stop
            if op == OP_FOOTER:
                self._after_footer(pos)
                break
        if walk.held is not None:  # a file cut short before its DataEnd
            yield from self._release(walk.held, None, skip, seen)
        self.truncated = not self.complete

    def _start_walk(self, inflate: bool) -> _Walk:
        """The state of a `records` walk from the first record: the data CRC so far, and the
        reading order of the chunks (when inflating)."""
        crc = _crc32(MAGIC) if self._first == 8 and not self.damage.bad_magic else None
        clean = not self.damage.regions
        self.complete = False
        self._last_chunk, self._waiting, self._past_data = None, [], False
        order = self._reading_order() if inflate else None
        walk = _Walk(crc, clean, order)
        if order is not None and not order.in_file_order:
            walk.held = HeldChunks(order)
            self._note("chunks out of log-time order, read in the order "
                       + ("the summary lists them" if self._listed_chunks is not None
                          else "of their messages' times"))
        return walk

    def _walk_chunk(self, walk: _Walk, pos: int, start: int, stop: int,
                    skip: Callable[[int, int], bool] | None, seen: dict[bytes, int]
                    ) -> Iterator[tuple[int, int, int, Any]]:
        """The chunk at ``pos`` in a `records` walk that inflates: given (checked), held for
        its turn, or skipped as foreign, a copy or damaged."""
        order, held = walk.order, walk.held
        if order is not None and pos in order.foreign:
            # Its bytes are sound, but the summary (intact) lists no such chunk: it is
            # another recording's, inserted. The data CRC cannot judge the rest.
            self._note(f"a chunk at byte {pos} that the summary does not list (not "
                       "this recording's), skipped")
            walk.clean = False
        elif held is not None and order is not None and pos in order.rank:
            walk.clean = False  # the data CRC is over file order: it cannot match
            held.hold(pos, start, stop)
            yield from self._release(held, stop, skip, seen)
        else:
            give, inner, region = self._take_chunk(pos, start, stop, skip, seen)
            if region is not None:
                walk.clean, walk.tail, walk.whole = False, region, region.start == pos
            elif not give:
                walk.clean = False
            else:
                yield OP_CHUNK, start, stop, inner

    def _past_data_end(self, walk: _Walk, start: int, inflate: bool) -> None:
        """Past the data section: check its CRC (a sound, inflated walk's)."""
        self._past_data = True
        (stored,) = _U32.unpack_from(self._buf, start)
        if inflate and walk.clean and walk.crc is not None and stored and stored != walk.crc:
            self.damage.data_crc = True
        walk.crc = None

    def _after_footer(self, pos: int) -> None:
        """The footer ends the walk: the file is complete if the closing magic follows."""
        rest = bytes(self._buf[pos:])
        if rest == MAGIC:
            self.complete = True
        elif not MAGIC.startswith(rest):
            self._lose(pos, None)

    def _note(self, text: str) -> None:
        """A note on the file's damage, said once however many walks meet it."""
        if text not in self.damage.notes:
            self.damage.notes.append(text)

    def _take_chunk(self, pos: int, start: int, stop: int,
                    skip: Callable[[int, int], bool] | None, seen: dict[bytes, int]
                    ) -> tuple[bool, Any, LostRegion | None]:
        """Check the chunk at ``pos`` (body ``start``..``stop``) as `records` gives it:
        (whether to give it, its records or None, the region it was lost in or None).

        A chunk with the same times, size and CRC as one already read (its first place in
        ``seen``) is a copy (a damaged copy of a log, a careless concatenation): not given,
        read once."""
        head = bytes(self._buf[start: start + _CHUNK_HEAD.size])
        first = seen.get(head, pos) if _CHUNK_HEAD.unpack_from(head)[3] else pos
        if first != pos:
            self._note(f"a copy of the chunk at byte {first} at byte {pos}, skipped")
            return False, None, None
        inner = None
        if skip is None or not skip(start, stop):
            inner, why = self._inflate(pos, start, stop)
            if inner is None:
                region = self.damage.lost(pos, stop, why, exact=True,
                                          chunks={pos: self._chunk_head(pos)},
                                          before_ns=self._last_chunk[1] if self._last_chunk
                                          else None)
                self._waiting.append(region)
                return False, None, region
        seen[head] = pos
        self._intact(start)
        return True, inner, None

    def _release(self, held: HeldChunks, walked: int | None,
                 skip: Callable[[int, int], bool] | None, seen: dict[bytes, int]
                 ) -> Iterator[tuple[int, int, int, Any]]:
        """The held chunks whose turn has come once the walk reached ``walked`` (None: its
        end), as `records` gives them: the walk is past their MessageIndex records, so a lost
        one is counted from the summary's."""
        for pos, start, stop in held.ready(walked):
            give, inner, region = self._take_chunk(pos, start, stop, skip, seen)
            if give:
                yield OP_CHUNK, start, stop, inner
            elif region is not None:
                listed = self._listed(start, stop)
                offsets = listed.index_offsets if listed is not None else ()
                counted = [self._count_index(region, at) for at in offsets]
                region.indexed = bool(offsets) and all(counted) and region.chunks == 1

    def _learn(self, op: int, inner: bytes, start: int, stop: int, wanted: dict[int, str],
               topics: frozenset[str] | None) -> bool:
        """Take a Channel or Schema record of a chunk (a channel on ``topics`` is wanted);
        False when it does not parse."""
        fields = _parse(inner, start, stop, _SPECS[op])
        if fields is None:
            return False
        if op == OP_SCHEMA:
            self._schemas[fields[0]] = (fields[1], fields[2], bytes(inner[slice(*fields[3])]))
            return True
        self._learn_channel(fields)
        if topics is None or fields[2] in topics:
            wanted[fields[0]] = fields[2]
        return True

    def _learn_channel(self, fields: list) -> None:
        """A Channel record's fields: its topic, and the decoder of its messages (by its
        message encoding and schema)."""
        cid, schema_id, topic, encoding = fields[:4]
        self.channels[cid] = topic
        self.decoders[cid] = message_decoder(encoding, self._schemas.get(schema_id))

    def messages(self, topics: Iterable[str] | None = None
                 ) -> Iterator[tuple[str, int, Any]]:
        """(topic, log_time ns, decoded JSON message) of the messages on ``topics`` (all when
        None), in file order; what does not decode is counted in the damage, not raised."""
        wanted_topics = frozenset(topics) if topics is not None else None
        wanted = {cid: topic for cid, topic in self.channels.items()
                  if wanted_topics is None or topic in wanted_topics}
        by_index = wanted_topics is not None and bool(self._summary_channels)
        skip = partial(self._none_wanted, wanted) if by_index else None
        for op, start, stop, inner in self.records(skip=skip):
            if op == OP_CHUNK:
                if inner is None:
                    continue
                at = self._indexed_at(start, stop, inner, wanted) if by_index else None
                if at is not None:
                    yield from self._messages_at(start - 9, inner, at, wanted)
                else:
                    yield from self._chunk_messages(start - 9, stop, inner, wanted,
                                                    wanted_topics)
            elif op == OP_MESSAGE or op == OP_CHANNEL or op == OP_SCHEMA:
                record = bytes(self._buf[start - 9 : stop])
                yield from self._chunk_messages(start - 9, stop, record, wanted,
                                                wanted_topics)

    def _none_wanted(self, wanted: dict[int, str], start: int, stop: int) -> bool:
        """Whether the intact summary's ChunkIndex lists the chunk whose body is
        ``start``..``stop`` with MessageIndex records, none of a wanted channel: a chunk of
        frames when samples are read, or of samples when frames are (canfdi writes frames
        in chunks of their own)."""
        chunk = self._listed(start, stop)
        return (chunk is not None and bool(chunk.index_channels)
                and chunk.index_channels.isdisjoint(wanted))

    def _listed(self, start: int, stop: int) -> _IndexedChunk | None:
        """The intact summary's ChunkIndex entry of the chunk whose body is
        ``start``..``stop``; None when it lists no chunk there, or one of another length."""
        if self._index_of is None:
            self._index_of = {c.offset: c for c in self._indexed}
        chunk = self._index_of.get(start - 9)
        return chunk if chunk is not None and chunk.length == stop - start + 9 else None

    def _indexed_at(self, start: int, stop: int, inner: bytes, wanted: dict[int, str]
                    ) -> list[int] | None:
        """Where the wanted messages of the chunk whose body is ``start``..``stop`` lie in its
        records ``inner``, in file order, from its MessageIndex records; None when the walk
        must find them: the chunk has no CRC (its records might not frame), the intact
        summary's ChunkIndex does not list it with its MessageIndex records, one of those is
        not sound or names a channel the summary does not (the walk counts it), or an entry
        is no message of a wanted channel inside the chunk.

        A chunk of a capture holds a message per sample and a frame block now and then: the
        index spares reading frames a walk over every sample record (most of a replay's read).
        """
        if not _CHUNK_HEAD.unpack_from(self._buf, start)[3]:
            return None
        chunk = self._listed(start, stop)
        if chunk is None or not chunk.index_offsets:
            return None
        at: list[int] = []
        for pos in chunk.index_offsets:
            found = self._sound(pos)
            if found is None or found[0] != OP_MESSAGE_INDEX:
                return None
            _, body, end = found
            (channel,) = _U16.unpack_from(self._buf, body)
            if channel not in self.channels:
                return None
            if channel in wanted:
                entries = np.frombuffer(self._buf, dtype="<u8", offset=body + 6,
                                        count=(end - body - 6) // 8)
                at += entries[1::2].tolist()
        at.sort()
        n, last = len(inner), -1
        for p in at:  # each a message of a wanted channel within the chunk, once
            if p <= last or p + 11 > n:
                return None
            op, length, channel = _MESSAGE_START.unpack_from(inner, p)
            if op != OP_MESSAGE or channel not in wanted or length < _MESSAGE_HEAD \
                    or p + 9 + length > n:
                return None
            last = p + 8 + length
        return at

    def _messages_at(self, where: int, inner: bytes, at: list[int], wanted: dict[int, str]
                     ) -> Iterator[tuple[str, int, Any]]:
        """The messages at offsets ``at`` (checked by `_indexed_at`) of the records
        ``inner`` of the chunk at byte ``where``, as `_chunk_messages` gives them."""
        decoders = self.decoders
        for p in at:
            _, length, channel = _MESSAGE_START.unpack_from(inner, p)
            start = p + 9
            topic = wanted[channel]
            (log_time,) = _U64.unpack_from(inner, start + 6)
            try:
                message = decoders.get(channel, decode_json)(
                    inner[start + _MESSAGE_HEAD : start + length])
            except ValueError:  # JSONDecodeError, UnicodeDecodeError, CDR
                self.damage.bad_messages[(where, p)] = topic
            else:
                yield topic, log_time, message

    def _chunk_messages(self, where: int, stop_at: int, inner: bytes, wanted: dict[int, str],
                        topics: frozenset[str] | None) -> Iterator[tuple[str, int, Any]]:
        """The wanted messages of the records ``inner`` of the chunk (or record) at bytes
        ``where``..``stop_at`` of the file."""
        head, message_head = _HEAD.unpack_from, _MESSAGE_START.unpack_from
        channels, decoders = self.channels, self.decoders
        unknown: dict[int, int] = {}
        n = len(inner)
        p = 0
        while p + 9 <= n:
            if p + 11 <= n:  # opcode, length and a message's channel id in one unpack
                op, length, cid = message_head(inner, p)
            else:
                op, length = head(inner, p)
            start = p + 9
            stop = start + length
            if stop > n or (op == OP_MESSAGE and length < _MESSAGE_HEAD):
                break
            if op == OP_MESSAGE:
                topic = wanted.get(cid)
                if topic is not None:
                    (log_time,) = _U64.unpack_from(inner, start + 6)
                    try:
                        message = decoders.get(cid, decode_json)(
                            inner[start + _MESSAGE_HEAD : stop])
                    except ValueError:  # JSONDecodeError, UnicodeDecodeError, CDR
                        self.damage.bad_messages[(where, p)] = topic
                    else:
                        yield topic, log_time, message
                elif cid not in channels:
                    unknown[cid] = unknown.get(cid, 0) + 1
            elif (op == OP_CHANNEL or op == OP_SCHEMA) and not self._learn(
                    op, inner, start, stop, wanted, topics):
                break
            p = stop
        if p != n:  # only a chunk without a CRC gets here: its records do not frame
            self.damage.lost(where, stop_at, f"a chunk whose records do not frame (the rest "
                             f"from byte {p} of its {n} uncompressed bytes was skipped)",
                             chunks={where: self._chunk_head(where)}, exact=True)
        for cid, count in unknown.items():
            self.damage.unknown_channels[(where, cid)] = count


def scan_topic(path: str | Path, topic: str, damage: Damage | None = None
               ) -> Iterator[tuple[int, dict]]:
    """(log_time ns, decoded JSON) of every message on ``topic``, in file order.

    Damaged parts are skipped and recorded in ``damage``; raises NotMcap for a file that is
    not MCAP."""
    with McapFile(path, damage) as file:
        for _, log_time, message in file.messages([topic]):
            yield log_time, message

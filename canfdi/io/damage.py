"""What a damaged log lost: one accumulator the readers fill and the verbs print.

canfdi.io.scan's record walker skips what it cannot trust in an MCAP file (a chunk whose CRC or
zstd frame fails, bytes that are no record, a record cut short at the end) and goes on with the
next sound record; each skipped region goes into the `FileDamage` of its file in a `Damage`,
with what is known of it: its bytes, the chunks in it, their log times (a chunk header's
message_start_time/end_time where it is readable and plausible, else the times of the intact
chunks around it) and the messages lost per topic (from the MessageIndex records that follow a
chunk, where they are intact). The readers never print: a verb passes one `Damage` to every
read of a log, prints `Damage.lines` and puts `Damage.as_dict` into its JSON.

Reading the same file twice (a verb reads samples, then residuals) records each region once:
regions are keyed by their first byte, message counts by their MessageIndex record's offset.

>>> damage = Damage()
>>> f = damage.file("run.mcap", 30000)
>>> f.saw_times(0, 9_000_000_000)
>>> region = f.lost(10240, 20480, "a chunk whose CRC does not match", exact=True,
...                 chunks={10240: (3_400_000_000, 4_000_000_000),
...                         15000: (4_000_000_000, 4_600_000_000)})
>>> region.add_index(20480, "/can/frames", 3)
>>> region.add_index(20530, "/canfdi/residuals", 412)
>>> region.indexed = True
>>> print(damage.lines()[0])  # doctest: +NORMALIZE_WHITESPACE
run.mcap: damaged: skipped 2 chunks (bytes 10240-20480), lost about 1.2 s (t=3.4-4.6 s of
the log), 3 /can/frames, 412 /canfdi/residuals messages; the rest was read
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

__all__ = ["Damage", "FileDamage", "LostRegion"]

_NS = 1_000_000_000


def _seconds(s: float) -> str:
    return f"{s:.1f} s" if s >= 0.05 or s == 0 else f"{s:.3f} s"


@dataclass
class LostRegion:
    """Bytes ``start`` to ``end`` of a file that were skipped, and what they held.

    Attributes
    ----------
    start, end : int
        The region's bytes (``end`` excluded): where the damage begins, where reading resumed
        (the file's size when nothing after it could be read).
    reason : str
        What was wrong first, for people (``"a chunk whose CRC does not match"``...).
    lost_chunks : dict of int to (int, int) or None
        The chunks known to be lost in it, by offset: their (message_start_time,
        message_end_time) ns where the header is readable and plausible, else None. Empty:
        no chunk known (damaged bytes between records, or chunks that garbage hides).
    before_ns, after_ns : int or None
        The end of the last intact chunk before the region and the start of the first one
        after it: the bounds of the lost time where the chunk headers are not readable.
    indexes : dict of int to (str, int)
        Messages lost, per MessageIndex record (by its offset in the file): (topic, count);
        the topic is ``"channel N"`` when the channel's definition is unknown.
    indexed : bool
        ``indexes`` count every lost chunk's messages (else the counts are a lower bound).
    cut : bool
        The region is the file's end, cut inside a record (a killed writer, a short copy).
    exact : bool
        ``lost_chunks`` are all the chunks the region held (a chunk that failed its check, the
        summary's index of a garbled region, a region outside the data): its time is theirs.
        False: garbage may hide more chunks, so the lost time runs from ``before_ns`` to
        ``after_ns``.
    """

    start: int
    end: int
    reason: str
    lost_chunks: dict[int, tuple[int, int] | None] = field(default_factory=dict)
    before_ns: int | None = None
    after_ns: int | None = None
    indexes: dict[int, tuple[str, int]] = field(default_factory=dict)
    indexed: bool = False
    cut: bool = False
    exact: bool = False

    @property
    def chunks(self) -> int:
        """Chunks known to be lost in the region."""
        return len(self.lost_chunks)

    @property
    def times(self) -> list[tuple[int, int]]:
        """The known (start, end) ns of the lost chunks."""
        return [t for t in self.lost_chunks.values() if t is not None]

    def add_index(self, offset: int, topic: str, count: int) -> None:
        """``count`` messages of ``topic`` lost, says the MessageIndex record at ``offset``."""
        self.indexes[offset] = (topic, count)

    @property
    def messages(self) -> dict[str, int]:
        """Messages lost per topic, as far as the indexes tell."""
        out: dict[str, int] = {}
        for topic, n in self.indexes.values():
            out[topic] = out.get(topic, 0) + n
        return out

    def time_range(self) -> tuple[int | None, int | None]:
        """(first, last) log time ns the region lost: an `exact` region's chunks' header
        times (None, None for one without chunks), else the neighbouring intact chunks'
        times widened by the header times that are known (None: unbounded on that side)."""
        times = self.times
        if self.exact and len(times) == self.chunks:
            if not times:
                return None, None
            return min(t for t, _ in times), max(t for _, t in times)
        first, last = self.before_ns, self.after_ns
        if times:
            lo, hi = min(t for t, _ in times), max(t for _, t in times)
            first = lo if first is None else min(first, lo)
            last = hi if last is None else max(last, hi)
        return first, last

    def as_dict(self, t0: int | None) -> dict[str, Any]:
        """JSON-able: bytes, reason, chunks, times (ns and s from ``t0``), messages, cut."""
        first, last = self.time_range()
        return {
            "bytes": [self.start, self.end], "reason": self.reason, "chunks": self.chunks,
            "t_ns": [first, last], "t_s": [_rel(first, t0), _rel(last, t0)],
            "messages": self.messages, "messages_complete": self.indexed, "cut": self.cut,
        }


def _rel(t: int | None, t0: int | None) -> float | None:
    return None if t is None or t0 is None else round((t - t0) / _NS, 3)


@dataclass
class FileDamage:
    """What one file lost: its skipped regions and the odd things found while reading it.

    Attributes
    ----------
    path : str
        The file.
    size : int
        Its size in bytes.
    regions : dict of int to LostRegion
        Skipped regions by first byte.
    bad_magic : bool
        The file's first 8 bytes are not MCAP's magic, but an MCAP header follows.
    data_crc : bool
        The data section's CRC (DataEnd) does not match its bytes: something outside the
        chunks (metadata, indexes) is damaged where no other check saw it.
    unknown_channels : dict of (int, int) to int
        Messages of channels whose Channel record was lost, by (chunk offset, channel id).
    bad_messages : dict of (int, int) to str
        Messages that are not JSON, by (chunk offset, offset in the chunk): their topic.
    first_ns, last_ns : int or None
        The log time span of the intact chunks read (the origin of ``t=`` in `line`).
    notes : list of str
        What a format without chunks found wrong (a BLF shorter than its header says).
    """

    path: str
    size: int
    regions: dict[int, LostRegion] = field(default_factory=dict)
    bad_magic: bool = False
    data_crc: bool = False
    unknown_channels: dict[tuple[int, int], int] = field(default_factory=dict)
    bad_messages: dict[tuple[int, int], str] = field(default_factory=dict)
    first_ns: int | None = None
    last_ns: int | None = None
    notes: list[str] = field(default_factory=list)
    _last: LostRegion | None = field(default=None, repr=False, compare=False)

    def __bool__(self) -> bool:
        return bool(self.regions or self.bad_magic or self.data_crc or self.unknown_channels
                    or self.bad_messages or self.notes)

    def lost(self, start: int, end: int, reason: str, *,
             chunks: dict[int, tuple[int, int] | None] | None = None,
             before_ns: int | None = None, cut: bool = False, exact: bool = False
             ) -> LostRegion:
        """Record bytes ``start`` to ``end`` as lost, with the chunks known in them (offset:
        header times or None) and whether they are all it held (`LostRegion.exact`). A
        region that already holds ``start`` (recorded by an earlier read of the file, or
        ending where this one begins) takes them in instead: the region is returned either
        way."""
        # A reader records regions in file order: the one to merge with is the one it
        # recorded last, or the one an earlier read recorded at the same byte.
        region = self.regions.get(start, self._last)
        if region is not None and region.start <= start <= region.end:
            if start > region.start or end > region.end:
                region.exact = region.exact and exact
            region.end = max(region.end, end)
            region.lost_chunks.update(chunks or {})
            region.cut = region.cut or cut
        else:
            region = LostRegion(start, end, reason, dict(chunks or {}), before_ns, cut=cut,
                                exact=exact)
            self.regions[start] = region
        self._last = region
        return region

    def saw_times(self, first: int, last: int) -> None:
        """An intact chunk spans log times ``first`` to ``last`` ns."""
        self.first_ns = first if self.first_ns is None else min(self.first_ns, first)
        self.last_ns = last if self.last_ns is None else max(self.last_ns, last)

    def t0(self) -> int | None:
        """The log's first time known (ns): the origin of the relative times."""
        starts = [t for r in self.regions.values() for t, _ in r.times]
        if self.first_ns is not None:
            starts.append(self.first_ns)
        return min(starts) if starts else None

    def lost_seconds(self) -> float:
        """Log time lost, about: the regions whose time range is known on both sides."""
        total = 0
        for region in self.regions.values():
            first, last = region.time_range()
            if first is not None and last is not None and last > first:
                total += last - first
        return total / _NS

    def line(self) -> str:
        """One line for people: what was skipped, the time and the messages lost."""
        regions = sorted(self.regions.values(), key=lambda r: r.start)
        damaged = [r for r in regions if not r.cut]
        parts = []
        if self.bad_magic:
            parts.append("its first 8 bytes are not MCAP's magic")
        if damaged:
            chunks = sum(r.chunks for r in damaged)
            spans = ", ".join(f"{r.start}-{r.end}" for r in damaged[:4])
            spans += ", ..." if len(damaged) > 4 else ""
            what = (f"{chunks} chunk{'s' if chunks != 1 else ''}" if chunks
                    else "damaged bytes")
            parts.append(f"skipped {what} (bytes {spans})")
        parts += [f"cut short at byte {r.start} of {self.size} inside a record" if self.size
                  else "empty (nothing was written into it)" for r in regions if r.cut]
        parts += self._lost(regions)
        unknown = sum(self.unknown_channels.values())
        if unknown:
            parts.append(f"{unknown} messages of channels whose definition was lost")
        if self.bad_messages:
            parts.append(f"{len(self.bad_messages)} messages that are not JSON")
        if self.data_crc:
            parts.append("the data section's CRC does not match (a record outside the chunks, "
                         "metadata or an index, is damaged)")
        parts += self.notes
        rest = "; the rest was read" if self.size else ""
        return f"{self.path}: damaged: {', '.join(parts)}{rest}"

    def _lost(self, regions: list[LostRegion]) -> list[str]:
        t0 = self.t0()
        ranges = []
        for region in regions:
            a, b = (_rel(t, t0) for t in region.time_range())
            if a is not None and b is not None:
                ranges.append(f"{a:.1f}-{b:.1f} s" if f"{a:.1f}" != f"{b:.1f}" else f"{a:.1f} s")
            elif a is not None:
                ranges.append(f"{a:.1f} s on")
            elif b is not None:
                ranges.append(f"up to {b:.1f} s")
        out = []
        seconds = self.lost_seconds()
        shown = ", ".join(ranges[:4]) + (", ..." if len(ranges) > 4 else "")
        if ranges and seconds:
            out.append(f"lost about {_seconds(seconds)} (t={shown} of the log)")
        elif ranges:
            out.append(f"lost the log's messages at t={shown}")
        counts: dict[str, int] = {}
        for region in regions:
            for topic, n in region.messages.items():
                counts[topic] = counts.get(topic, 0) + n
        partial = any(r.chunks and not r.indexed for r in regions)
        if counts:
            listed = ", ".join(f"{n} {topic}" for topic, n in sorted(counts.items()))
            out.append(("at least " if partial else "") + f"{listed} messages")
        elif any(r.chunks for r in regions):
            out.append("messages per topic unknown (their indexes are lost too)")
        return out


@dataclass
class Damage:
    """The loss of every file read in one go: the accumulator the readers fill.

    Pass one to the readers (``damage=``) of canfdi.io.reader, canfdi.io.scan and
    canfdi.io.logs; after reading, it is false when nothing was damaged, else `lines` says
    what was lost (one line per damaged file) and `as_dict` gives the same for JSON.
    """

    files: dict[str, FileDamage] = field(default_factory=dict)

    def file(self, path: str | Path, size: int) -> FileDamage:
        """The record of one file (created on first use)."""
        key = str(path)
        found = self.files.get(key)
        if found is None:
            found = self.files[key] = FileDamage(key, size)
        return found

    def __bool__(self) -> bool:
        return any(self.files.values())

    def lines(self) -> list[str]:
        """One line per damaged file, in the order the files were read."""
        return [f.line() for f in self.files.values() if f]

    def lost_seconds(self) -> float:
        """Log time lost over every file, about."""
        return sum(f.lost_seconds() for f in self.files.values() if f)

    def as_dict(self) -> list[dict[str, Any]]:
        """Per damaged file: ``{"path", "size", "lost_s", "regions": [{"bytes", "reason",
        "chunks", "t_ns", "t_s", "messages", "messages_complete", "cut"}], "bad_magic",
        "data_crc", "unknown_channel_messages", "bad_messages", "notes", "line"}``; [] when
        nothing was damaged."""
        out = []
        for f in self.files.values():
            if not f:
                continue
            t0 = f.t0()
            out.append({
                "path": f.path, "size": f.size, "lost_s": round(f.lost_seconds(), 3),
                "regions": [r.as_dict(t0) for r in sorted(f.regions.values(),
                                                          key=lambda r: r.start)],
                "bad_magic": f.bad_magic, "data_crc": f.data_crc,
                "unknown_channel_messages": sum(f.unknown_channels.values()),
                "bad_messages": len(f.bad_messages), "notes": list(f.notes), "line": f.line(),
            })
        return out

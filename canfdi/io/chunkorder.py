"""In which order a log's chunks are read, and which chunks are not the log's own.

A writer puts its chunks in log-time order. A careless copy, a concatenation or damage may
not: two chunks swapped, a chunk of another recording inserted. Every reader wants each
topic's messages in log-time order and only the recording's own. These are pure functions over
what a walk of the chunk headers found (canfdi.io.scan.McapFile does the walk). They use two
sources, the better first:

* **The summary's ChunkIndex records** (when the summary is intact: its CRC checks). They list
  the chunks the writer wrote, in the order it wrote them. A chunk is matched to its entry by
  its length, times and sizes, not by its offset, because bytes inserted or moved before it
  shift it. A chunk that no entry lists is *foreign* and is skipped. A chunk that matches an
  entry already taken is a copy: it is read right after the original, whose copy the walk then
  recognises and reads once.
* **Each chunk's MessageIndex records**, when there is no summary (a writer killed before its
  end). For every channel, the chunks holding it are read in the order of their earliest
  message on it. The order is the topological one, ties broken by file position, so a log in
  order keeps its file order exactly. When those constraints contradict each other, or no
  chunk has MessageIndex records, the order is the file's. Without a summary a foreign chunk
  cannot be told from the log's own.
"""

from __future__ import annotations

import heapq
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from itertools import pairwise

__all__ = ["ChunkOrder", "ChunkSeen", "HeldChunks", "order_chunks"]

ChunkKey = tuple[int, int, int, int, int]
"""(record length, start ns, end ns, uncompressed size, compressed size): what a ChunkIndex
entry and its chunk's header both say."""


@dataclass
class ChunkSeen:
    """A sound chunk record as a walk of the headers found it.

    Attributes
    ----------
    pos : int
        Its offset in the file.
    key : ChunkKey
        Its length, times and sizes.
    earliest : dict of int to int
        Channel id -> the earliest log time (ns) its MessageIndex records give (empty when
        none follows the chunk).
    """

    pos: int
    key: ChunkKey
    earliest: dict[int, int] = field(default_factory=dict)


@dataclass(frozen=True)
class ChunkOrder:
    """Where each chunk stands in reading order.

    Attributes
    ----------
    rank : dict of int to tuple of (int, int)
        Chunk offset -> its sort key in reading order, for every chunk to be read.
    foreign : frozenset of int
        Offsets of the chunks the intact summary does not list: skipped.
    listed_at : dict of int to int
        Chunk offset -> the offset its summary entry gives, for the listed chunks.
    """

    rank: dict[int, tuple[int, int]]
    foreign: frozenset[int]
    listed_at: dict[int, int]

    @property
    def in_file_order(self) -> bool:
        """Whether reading order is file order (then nothing needs holding back)."""
        keys = [self.rank[pos] for pos in sorted(self.rank)]
        return all(a < b for a, b in pairwise(keys))


def order_chunks(seen: Sequence[ChunkSeen],
                 listed: Sequence[tuple[int, ChunkKey]] | None) -> ChunkOrder:
    """The reading order of the chunks ``seen`` (in file order).

    Parameters
    ----------
    seen : sequence of ChunkSeen
        The sound chunk records, in file order.
    listed : sequence of (offset, ChunkKey), or None
        The intact summary's ChunkIndex entries; None without an intact summary.

    Returns
    -------
    ChunkOrder

    Examples
    --------
    Two chunks of one channel, swapped in the file, are read in log-time order:

    >>> a = ChunkSeen(100, (50, 20, 29, 9, 9), {1: 20})
    >>> b = ChunkSeen(150, (50, 10, 19, 9, 9), {1: 10})
    >>> order = order_chunks([a, b], None)
    >>> sorted(order.rank, key=order.rank.get), order.in_file_order
    ([150, 100], False)
    """
    if listed is not None:
        return _by_summary(seen, listed)
    return ChunkOrder(_by_message_times(seen), frozenset(), {})


def _by_summary(seen: Sequence[ChunkSeen], listed: Sequence[tuple[int, ChunkKey]]
                ) -> ChunkOrder:
    entries = sorted(listed)  # the writer's order
    free = set(range(len(entries)))
    at_offset = {offset: index for index, (offset, _) in enumerate(entries)}
    taken: dict[int, int] = {}  # chunk offset -> its entry

    def take(chunk: ChunkSeen, index: int | None) -> None:
        if index is not None and index in free:
            free.discard(index)
            taken[chunk.pos] = index

    # An entry is matched in place first, then by its header wherever it moved, then in place
    # again with a damaged header (whose inflation then fails: a loss, not a stranger).
    for chunk in seen:
        index = at_offset.get(chunk.pos)
        if index is not None and entries[index][1] == chunk.key:
            take(chunk, index)
    with_key: dict[ChunkKey, list[int]] = {}
    for index in sorted(free, reverse=True):
        with_key.setdefault(entries[index][1], []).append(index)
    for chunk in seen:
        if chunk.pos not in taken:
            stack = with_key.get(chunk.key, [])
            while stack and stack[-1] not in free:
                stack.pop()
            take(chunk, stack[-1] if stack else None)
    for chunk in seen:
        if chunk.pos not in taken:
            take(chunk, at_offset.get(chunk.pos))
    by_key = {entries[index][1]: index for index in sorted(taken.values(), reverse=True)}
    rank: dict[int, tuple[int, int]] = {}
    foreign: set[int] = set()
    for chunk in seen:
        index = taken.get(chunk.pos, by_key.get(chunk.key))  # a copy: right after its original
        if index is None:
            foreign.add(chunk.pos)
        else:
            rank[chunk.pos] = (index, chunk.pos)
    return ChunkOrder(rank, frozenset(foreign),
                      {pos: entries[index][0] for pos, index in taken.items()})


def _by_message_times(seen: Sequence[ChunkSeen]) -> dict[int, tuple[int, int]]:
    file_order = {chunk.pos: (i, chunk.pos) for i, chunk in enumerate(seen)}
    after: dict[int, list[int]] = {chunk.pos: [] for chunk in seen}
    waiting = dict.fromkeys(after, 0)
    channels: dict[int, list[tuple[int, int]]] = {}
    for chunk in seen:
        for channel, t in chunk.earliest.items():
            channels.setdefault(channel, []).append((t, chunk.pos))
    for holders in channels.values():
        holders.sort()
        for (_, a), (_, b) in pairwise(holders):
            after[a].append(b)
            waiting[b] += 1
    ready = [pos for pos, n in waiting.items() if n == 0]
    heapq.heapify(ready)
    order: list[int] = []
    while ready:
        pos = heapq.heappop(ready)
        order.append(pos)
        for nxt in after[pos]:
            waiting[nxt] -= 1
            if waiting[nxt] == 0:
                heapq.heappush(ready, nxt)
    if len(order) != len(seen):  # the channels' times contradict each other
        return file_order
    return {pos: (i, pos) for i, pos in enumerate(order)}


class HeldChunks:
    """Chunks met out of reading order, held (as offsets: nothing is inflated) until every
    chunk before them in that order has been read or passed."""

    def __init__(self, order: ChunkOrder) -> None:
        self._rank = order.rank
        self._unmet = sorted((rank, pos) for pos, rank in order.rank.items())
        heapq.heapify(self._unmet)
        self._met: set[int] = set()
        self._held: list[tuple[tuple[int, int], int, int, int]] = []

    def hold(self, pos: int, start: int, stop: int) -> None:
        """Hold the chunk at ``pos`` (its body ``start``..``stop``), met by the walk."""
        self._met.add(pos)
        heapq.heappush(self._held, (self._rank[pos], pos, start, stop))

    def ready(self, walked: int | None) -> Iterator[tuple[int, int, int]]:
        """(offset, body start, body stop) of the held chunks whose turn has come once the
        walk reached byte ``walked`` (None: the walk is over), in reading order."""
        unmet, met = self._unmet, self._met
        while self._held:
            while unmet and (unmet[0][1] in met
                             or (walked is None or unmet[0][1] < walked)):
                heapq.heappop(unmet)  # read, or passed without a sound record there
            if unmet and unmet[0][0] < self._held[0][0]:
                return
            _, pos, start, stop = heapq.heappop(self._held)
            yield pos, start, stop

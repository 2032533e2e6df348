"""The reading order of a log's chunks (canfdi.io.chunkorder): the summary's, else their
messages' times; foreign chunks and copies (issue 27)."""

from __future__ import annotations

from canfdi.io.chunkorder import ChunkSeen, order_chunks


def _chunk(pos: int, t0: int, **earliest: int) -> ChunkSeen:
    return ChunkSeen(pos, (10, t0, t0 + 9, 5, 5), {int(c[1:]): t for c, t in earliest.items()})


def _read(order) -> list[int]:
    return sorted(order.rank, key=order.rank.get)


def test_a_log_in_order_keeps_its_file_order_from_either_source():
    chunks = [_chunk(100, 0, c1=0), _chunk(110, 0, c2=0), _chunk(120, 10, c1=10)]
    listed = [(c.pos, c.key) for c in chunks]
    for order in (order_chunks(chunks, listed), order_chunks(chunks, None)):
        assert _read(order) == [100, 110, 120] and order.in_file_order
        assert not order.foreign


def test_the_summary_gives_the_writers_order_and_names_a_foreign_chunk():
    a, b, c = _chunk(100, 0), _chunk(110, 10), _chunk(120, 20)
    listed = [(100, a.key), (110, b.key), (120, c.key)]
    # In the file: c, then a chunk of another recording, then a, then b; all shifted.
    stranger = ChunkSeen(140, (10, 15, 24, 5, 5))
    found = [ChunkSeen(100, c.key), stranger, ChunkSeen(150, a.key), ChunkSeen(160, b.key)]
    order = order_chunks(found, listed)
    assert _read(order) == [150, 160, 100] and not order.in_file_order
    assert order.foreign == {140}
    assert order.listed_at == {150: 100, 160: 110, 100: 120}


def test_a_copy_is_read_right_after_its_original():
    a, b = _chunk(100, 0), _chunk(110, 10)
    found = [a, b, ChunkSeen(120, a.key)]
    order = order_chunks(found, [(100, a.key), (110, b.key)])
    assert _read(order) == [100, 120, 110] and not order.foreign


def test_without_a_summary_each_channel_is_read_in_time_order():
    # Frames chunks (channel 1) and sample chunks (channel 2) interleaved; two frames chunks
    # swapped. A chunk with no MessageIndex keeps its place.
    found = [_chunk(100, 0, c1=0), _chunk(110, 0, c2=0), _chunk(120, 20, c1=20),
             _chunk(130, 10, c2=10), _chunk(140, 10, c1=10), ChunkSeen(150, (10, 5, 6, 5, 5))]
    order = order_chunks(found, None)
    assert _read(order) == [100, 110, 130, 140, 120, 150]


def test_contradicting_message_times_fall_back_to_file_order():
    found = [_chunk(100, 0, c1=0, c2=10), _chunk(110, 0, c1=5, c2=2)]
    assert _read(order_chunks(found, None)) == [100, 110]

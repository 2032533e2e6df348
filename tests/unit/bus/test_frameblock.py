"""FrameBlock.from_messages: every field of python-can's Message, as one message at a time
would read it."""

from __future__ import annotations

import can
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from canfdi.bus.frames import FLAG_ERROR, FLAG_EXTENDED, FLAG_FD, FLAG_REMOTE, MAX_DATA, FrameBlock

message = st.builds(
    lambda ts, ident, ext, remote, error, fd, data, dlc: can.Message(
        timestamp=ts, arbitration_id=ident & (0x1FFFFFFF if ext else 0x7FF),
        is_extended_id=ext, is_remote_frame=remote and not fd, is_error_frame=error,
        is_fd=fd, data=None if remote and not fd else data,
        dlc=dlc if remote and not fd else None, check=False),
    st.one_of(st.just(0.0), st.floats(1e-3, 2e9, allow_nan=False)),
    st.integers(0, 0x1FFFFFFF), st.booleans(), st.booleans(), st.booleans(), st.booleans(),
    st.binary(max_size=64), st.integers(0, 8))


def _one_by_one(messages, now):
    """The reference: each field read message by message."""
    rows = []
    for m in messages:
        flags = (m.is_extended_id * FLAG_EXTENDED | m.is_remote_frame * FLAG_REMOTE
                 | m.is_error_frame * FLAG_ERROR | m.is_fd * FLAG_FD)
        data = bytes(m.data)
        rows.append((int((m.timestamp or now) * 1e9), m.arbitration_id,
                     m.dlc if m.is_remote_frame else len(data), flags,
                     data[:MAX_DATA].ljust(MAX_DATA, b"\0"), data))
    return rows


@settings(max_examples=200, deadline=None)
@given(st.lists(message, max_size=40))
def test_from_messages_reads_every_field(messages):
    now = 1_700_000_000.25
    block = FrameBlock.from_messages(messages, now=now)
    expected = _one_by_one(messages, now)
    assert block.size == len(messages)
    assert block.t_ns.tolist() == [r[0] for r in expected]
    assert block.id.tolist() == [r[1] for r in expected]
    assert block.dlc.tolist() == [r[2] for r in expected]
    assert block.flags.tolist() == [r[3] for r in expected]
    assert [bytes(row) for row in block.data] == [r[4] for r in expected]
    assert block.long == {i: r[5] for i, r in enumerate(expected) if len(r[5]) > MAX_DATA}


def test_a_message_without_timestamp_gets_now():
    msg = can.Message(arbitration_id=1, data=b"\x01")
    msg.timestamp = None
    block = FrameBlock.from_messages([msg, can.Message(timestamp=2.0, arbitration_id=2)],
                                     now=5.0)
    assert block.t_ns.tolist() == [5_000_000_000, 2_000_000_000]
    assert FrameBlock.from_messages([]).size == 0
    assert np.array_equal(FrameBlock.from_messages([msg], now=1.0).data[0, :2], [1, 0])


def test_payload_matrix_gives_the_rows_bytes_cut_or_padded():
    rng = np.random.default_rng(3)
    n = 50
    data = rng.integers(0, 256, (n, MAX_DATA), dtype=np.uint8)
    block = FrameBlock(np.arange(n, dtype=np.int64), np.arange(n), np.full(n, 8),
                       np.zeros(n, dtype=np.int64), data, long={7: bytes(range(12))})
    rows = np.array([7, 3, 3, 40, 0])
    for view in (block, block.select(np.arange(n)[::-1]).select(np.arange(n)[::-1])):
        for length in (2, 5, 8):
            got = view.payload_matrix(rows, length)
            assert got.shape == (5, length) and got.flags.c_contiguous
            assert np.array_equal(got, data[rows, :length])
    wide = block.payload_matrix(rows, 12)
    assert bytes(wide[0]) == bytes(range(12)) and np.array_equal(wide[1, :8], data[3])
    assert not wide[1, 8:].any()
    strided = FrameBlock(block.t_ns, block.id, block.dlc, block.flags,
                         np.zeros((n, 16), dtype=np.uint8)[:, ::2])
    assert np.array_equal(strided.payload_matrix(rows, 8), np.zeros((5, 8)))


def test_a_frame_block_cut_for_live_keeps_every_frame_once_within_the_size():
    import orjson

    from canfdi.io.blocks import decode_frames, encode_frame_block, pack_frame, split_frame_block

    records = b"".join(pack_frame(1000 + i, 0x100 + i % 5, 8, 0, i % 2, bytes(8))
                       for i in range(5000))
    for long in ({}, {7: bytes(64), 4999: bytes(12)}, {i: bytes(64) for i in range(0, 5000, 2)}):
        block = encode_frame_block(records, 5000, 1000, b'["ok","crc"]', long)
        assert split_frame_block(block, 1000, len(block)) == [(1000, block)]
        pieces = split_frame_block(block, 1000, 16384)
        assert len(pieces) > 1 and max(len(p) for _, p in pieces) <= 16384
        blocks = [decode_frames(orjson.loads(p)) for _, p in pieces]
        assert [t for t, _ in pieces] == [int(b.t_ns[0]) for b in blocks]
        t = np.concatenate([b.t_ns for b in blocks])
        assert t.tolist() == list(range(1000, 6000))
        status = np.concatenate([b.status for b in blocks])
        assert status.tolist() == ["ok", "crc"] * 2500
        found = {int(b.t_ns[row]) - 1000: d for b in blocks for row, d in b.long.items()}
        assert found == long

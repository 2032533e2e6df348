"""Tests of canfdi's MCAP log (canfdi.io.writer's McapRecorder, canfdi.io.reader, .blocks,
.segments): round trip of every topic, truncation, kill -9, rotation, disk full, and reading
the older layouts (one frame per message; blocks of samples and residual rows)."""

from __future__ import annotations

import errno
import json
import logging
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import can
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader
from mcap.records import Footer
from mcap.stream_reader import StreamReader
from mcap.writer import Writer

from canfdi.bus.frames import FLAG_EXTENDED, FLAG_FD, FrameBlock
from canfdi.core.records import FaultEvent, Sample
from canfdi.io.reader import (
    iter_frame_blocks,
    mcap_frame_blocks,
    read_frames,
    read_log,
    read_metadata,
    read_residuals,
    read_samples,
)
from canfdi.io.rowencodings import ROW_ENCODINGS
from canfdi.io.scan import McapFile
from canfdi.io.schemas import (
    FRAME_DTYPE,
    FRAMES_ENCODING,
    MESSAGE_ENCODING,
    METADATA_NAME,
    RESIDUALS_ENCODING,
    SAMPLES_ENCODING,
    SCHEMA_ENCODING,
    TOPIC_ESTIMATES,
    TOPIC_EVENTS,
    TOPIC_FRAMES,
    TOPIC_LOG,
    TOPIC_RESIDUALS,
    TOPIC_SAMPLES,
    TOPIC_STATUS,
    TOPICS,
)
from canfdi.io.segments import log_segments
from canfdi.io.writer import McapRecorder

REPO = Path(__file__).resolve().parents[3]
T0 = 1_700_000_000_123_456_789
METADATA = {"config_yaml": "name: test\n", "design_json": '{"a": 1}', "version": "0.1.0"}
INPUTS, OUTPUTS = ["voltage", "load"], ["speed", "current"]
RESIDUALS = ["r0", "r1"]


class FakeClock:
    """A monotonic clock the test moves by hand."""

    def __init__(self, t: float = 0.0) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t


def stamp(ns: int) -> dict[str, int]:
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def write_frames(rec: McapRecorder, start: int, stop: int) -> None:
    """Frames numbered start..stop-1, one write_frame each: frame i carries i in its payload."""
    for i in range(start, stop):
        rec.write_frame(T0 + i * 1000, i & 0x7FF, i.to_bytes(4, "big"), "ok")


def _block(t, ids, dlc, payloads, extended=None, flags=None) -> FrameBlock:
    """A FrameBlock of the old write_frames arguments."""
    t = np.atleast_1d(np.asarray(t))
    bits = np.zeros(len(t), dtype=np.uint8)
    if extended is not None:
        bits |= np.asarray(extended, dtype=bool).astype(np.uint8)
    if flags is not None:
        bits |= np.asarray(flags).astype(np.uint8)
    return FrameBlock(t, np.asarray(ids).astype(np.int64), np.asarray(dlc).astype(np.int64),
                      bits, np.asarray(payloads).astype(np.uint8))


def indices(frames: FrameBlock) -> list[int]:
    return [int.from_bytes(p, "big") for p in frames.payloads()]


def frame_indices(path: Path, segments: bool = True) -> list[int]:
    """The numbers of the frames of a log (every segment, or this file alone)."""
    return indices(read_frames(path, segments=segments))


def data_section_end(path: Path) -> int:
    with open(path, "rb") as f:
        for record in StreamReader(f, emit_chunks=True).records:
            if isinstance(record, Footer):
                return record.summary_start
    raise AssertionError(f"{path} has no footer")


def topic_messages(path: Path, topic: str) -> list[tuple[int, dict]]:
    return [(t, m) for _, t, m in read_log(path, topics=[topic])]


# --------------------------------------------------------------------------------------
# round trip
# --------------------------------------------------------------------------------------


def event() -> FaultEvent:
    return FaultEvent(
        kind="accepted",
        sample=310,
        timestamp_ns=T0 + 9,
        target="actuator",
        index=0,
        name="voltage",
        estimates={"eta": 0.8, "lambda": 0.01},
        variances={"eta": 1e-4, "lambda": 1e-6},
        onset_sample=301,
        detected_sample=305,
        accepted_sample=310,
        candidates=({"target": "actuator", "index": 0, "name": "voltage"},),
        residuals=("r0", "r1"),
    )


def test_round_trip_every_topic(tmp_path: Path) -> None:
    """Every topic in the JSON row layout (the CDR rows: tests/unit/io/test_cdr_rows.py)."""
    path = tmp_path / "run.mcap"
    sample = Sample(
        k=300, timestamp_ns=T0 + 5, u=np.array([12.0, 0.5]), z=np.array([3.25, -1.0]), gap=2
    )
    fd_payload = bytes(range(64))
    block_t = T0 + 100 + np.arange(3)
    block_payloads = np.arange(24, dtype=np.uint8).reshape(3, 8)
    with McapRecorder(path, metadata=METADATA, row_encoding="json") as rec:
        rec.write_frame(T0, 0x123, b"\x01\x02\xff", "ok")
        rec.write_frame(T0 + 1, 0x1ABCDEF0, b"", "unknown_id", extended=True)
        rec.write_frame(T0 + 2, 0x7FF, bytes(8), "crc", dlc=9)
        rec.write_frame(T0 + 3, 0x10, bytearray(b"\x00"), 'we"ird\n')
        rec.write_frame(T0 + 4, 0x11, b"\xaa", "sent")
        rec.write_frame(T0 + 5, 0x12, fd_payload, "fd", flags=FLAG_FD)
        rec.write_frames(
            _block(block_t, [0x100, 0x101, 0x18000000], [8, 2, 8], block_payloads,
                   extended=np.array([False, False, True])),
            np.array(["ok", "dlc", "extended"]),
        )
        rec.write_frames(_block(block_t + 10, [1, 2, 3], [1, 1, 1], np.ones((3, 8))), "ok")
        rec.write_frames(
            _block(block_t + 20, [4, 5, 6], [8, 8, 8], np.zeros((3, 8))),
            np.array([2, 0, 1], dtype=np.int8),
            status_names=["ok", "monitor", "stale"],
        )
        rec.write_sample(sample, INPUTS, OUTPUTS)
        rec.write_samples(
            [301, 302],
            [T0 + 6, T0 + 7],
            [[1.0, 2.0], [np.nan, 4.0]],
            np.array([[5.0, 6.0], [7.0, np.inf]]),
            [0, 1],
            tuple(INPUTS),
            tuple(OUTPUTS),
        )
        rec.write_residuals(
            T0 + 6,
            300,
            RESIDUALS,
            np.array([0.5, np.nan]),
            [1.5, np.float32(2.0)],
            [0.0, np.inf],
        )
        rec.write_residual_rows(
            [301, 302],
            [T0 + 7, T0 + 8],
            RESIDUALS,
            np.array([[1.0, 2.0], [3.0, 4.0]]),
            np.array([[5.0, 6.0], [7.0, 8.0]]),
            np.array([[0.0, 0.1], [0.2, -np.inf]]),
        )
        rec.write_estimates(T0 + 7, 301, "actuator:voltage", {"eta": np.float64(0.9)}, {"eta": 0.1})
        rec.write_event(event())
        rec.write_status(T0 + 10, "running", 311, {"ok": 1000, "crc": 2}, np.int64(1))
        rec.write("/custom/thing", T0 + 11, {"value": np.int64(7), "list": np.arange(3)})
        rec.write_log(T0 + 12, "warning", "bus error: reopening", "canfdi.service",
                      "service.py", 7)
        assert rec.buffered == 15 + 3 + 3
        # 6 single messages (estimates, event and its estimates, status, custom, log line)
        assert rec.messages_written == 6
    assert rec.messages_written == 6 + 15 + 3 + 3 and rec.buffered == 0

    frames = read_frames(path)
    assert frames.t_ns.tolist() == [T0 + i for i in range(6)] + (
        block_t.tolist() + (block_t + 10).tolist() + (block_t + 20).tolist()
    )
    ids = [0x123, 0x1ABCDEF0, 0x7FF, 0x10, 0x11, 0x12, 0x100, 0x101, 0x18000000, 1, 2, 3, 4, 5, 6]
    assert frames.id.tolist() == ids
    assert frames.dlc.tolist() == [3, 0, 9, 1, 1, 64, 8, 2, 8, 1, 1, 1, 8, 8, 8]
    assert frames.extended.tolist() == [False, True] + [False] * 6 + [True] + [False] * 6
    assert frames.flags.tolist() == [0, FLAG_EXTENDED, 0, 0, 0, FLAG_FD, 0, 0, 1] + [0] * 6
    assert frames.status.tolist() == [
        "ok",
        "unknown_id",
        "crc",
        'we"ird\n',
        "sent",
        "fd",
        "ok",
        "dlc",
        "extended",
        "ok",
        "ok",
        "ok",
        "stale",
        "ok",
        "monitor",
    ]
    assert frames.payloads() == [
        b"\x01\x02\xff",
        b"",
        bytes(8),
        b"\x00",
        b"\xaa",
        fd_payload,
        bytes(range(8)),
        bytes(range(8, 10)),
        bytes(range(16, 24)),
        b"\x01",
        b"\x01",
        b"\x01",
        bytes(8),
        bytes(8),
        bytes(8),
    ]
    assert frames.data.shape == (15, 8) and frames.data[5].tobytes() == fd_payload[:8]
    assert frames.long == {5: fd_payload}
    assert frames.size == 15

    samples = read_samples(path)
    assert samples.input_names == INPUTS and samples.output_names == OUTPUTS
    assert samples.k.tolist() == [300, 301, 302]
    assert samples.t_ns.tolist() == [T0 + 5, T0 + 6, T0 + 7]
    assert samples.gap.tolist() == [2, 0, 1]
    np.testing.assert_array_equal(samples.U, [[12.0, 0.5], [1.0, 2.0], [np.nan, 4.0]])
    # JSON has no inf: non-finite values are null, read back as NaN.
    np.testing.assert_array_equal(samples.Z, [[3.25, -1.0], [5.0, 6.0], [7.0, np.nan]])

    k, t_ns, names, r, rn, stat = read_residuals(path)
    assert k.tolist() == [300, 301, 302] and t_ns.tolist() == [T0 + 6, T0 + 7, T0 + 8]
    assert names == RESIDUALS
    np.testing.assert_array_equal(r, [[0.5, np.nan], [1.0, 2.0], [3.0, 4.0]])
    np.testing.assert_array_equal(rn, [[1.5, 2.0], [5.0, 6.0], [7.0, 8.0]])
    np.testing.assert_array_equal(stat, [[0.0, np.nan], [0.0, 0.1], [0.2, np.nan]])

    # The frame block, stamped with its first frame; one message per sample and residual row,
    # at its own time, every value plottable by message path (null for NaN and inf).
    (frame_block,) = [(t, m) for t, m in topic_messages(path, TOPIC_FRAMES)]
    log_time, block = frame_block
    assert log_time == T0 and block["timestamp"] == stamp(T0)
    assert block["encoding"] == FRAMES_ENCODING and block["count"] == 15
    assert block["statuses"][frames_code(block, "sent")] == "sent"
    assert block["long"] == {"5": fd_payload.hex()}
    assert len(block["frames"]) == (15 * FRAME_DTYPE.itemsize + 2) // 3 * 4
    assert topic_messages(path, TOPIC_SAMPLES) == [
        (T0 + 5, {"timestamp": stamp(T0 + 5), "k": 300, "gap": 2,
                  "u": {"voltage": 12.0, "load": 0.5}, "z": {"speed": 3.25, "current": -1.0}}),
        (T0 + 6, {"timestamp": stamp(T0 + 6), "k": 301, "gap": 0,
                  "u": {"voltage": 1.0, "load": 2.0}, "z": {"speed": 5.0, "current": 6.0}}),
        (T0 + 7, {"timestamp": stamp(T0 + 7), "k": 302, "gap": 1,
                  "u": {"voltage": None, "load": 4.0}, "z": {"speed": 7.0, "current": None}}),
    ]  # fmt: skip
    assert topic_messages(path, TOPIC_RESIDUALS) == [
        (T0 + 6, {"timestamp": stamp(T0 + 6), "k": 300, "r": {"r0": 0.5, "r1": None},
                  "normalized": {"r0": 1.5, "r1": 2.0}, "statistic": {"r0": 0.0, "r1": None}}),
        (T0 + 7, {"timestamp": stamp(T0 + 7), "k": 301, "r": {"r0": 1.0, "r1": 2.0},
                  "normalized": {"r0": 5.0, "r1": 6.0}, "statistic": {"r0": 0.0, "r1": 0.1}}),
        (T0 + 8, {"timestamp": stamp(T0 + 8), "k": 302, "r": {"r0": 3.0, "r1": 4.0},
                  "normalized": {"r0": 7.0, "r1": 8.0}, "statistic": {"r0": 0.2, "r1": None}}),
    ]  # fmt: skip

    event_fields = {k: v for k, v in event().as_dict().items() if v is not None}
    singles = [
        (TOPIC_ESTIMATES, T0 + 7, {"timestamp": stamp(T0 + 7), "k": 301,
                                   "hypothesis": "actuator:voltage",
                                   "estimates": {"eta": 0.9}, "variances": {"eta": 0.1}}),
        (TOPIC_EVENTS, T0 + 9, {"timestamp": stamp(T0 + 9), **event_fields}),
        # an accepted fault's estimates, on their own topic too
        (TOPIC_ESTIMATES, T0 + 9, {"timestamp": stamp(T0 + 9), "k": 310,
                                   "hypothesis": "actuator:voltage",
                                   "estimates": {"eta": 0.8, "lambda": 0.01},
                                   "variances": {"eta": 1e-4, "lambda": 1e-6}}),
        (TOPIC_STATUS, T0 + 10, {"timestamp": stamp(T0 + 10), "state": "running",
                                 "samples": 311, "frames": {"ok": 1000, "crc": 2},
                                 "active_faults": 1}),
        ("/custom/thing", T0 + 11, {"timestamp": stamp(T0 + 11), "value": 7, "list": [0, 1, 2]}),
        (TOPIC_LOG, T0 + 12, {"timestamp": stamp(T0 + 12), "level": 3,
                              "message": "bus error: reopening", "name": "canfdi.service",
                              "file": "service.py", "line": 7}),
    ]  # fmt: skip
    assert event_fields["kind"] == "accepted" and "drive" not in event_fields
    bulk_topics = {TOPIC_FRAMES, TOPIC_SAMPLES, TOPIC_RESIDUALS}
    reader = read_log(path)
    got = list(reader)
    assert [m for m in got if m[0] not in bulk_topics] == singles
    assert reader.complete and not reader.truncated
    assert reader.messages_read == len(singles) + 1 + 3 + 3
    assert stamp(T0) == {"sec": 1_700_000_000, "nsec": 123_456_789}
    assert list(read_log(path, topics=[TOPIC_STATUS])) == [singles[3]]
    assert read_metadata(path) == METADATA

    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        topics = {c.topic: c for c in summary.channels.values()}
        assert set(TOPICS) | {"/custom/thing"} == set(topics)
        for channel in topics.values():
            assert channel.message_encoding == MESSAGE_ENCODING == "json"
            schema = summary.schemas[channel.schema_id]
            assert schema.encoding == SCHEMA_ENCODING == "jsonschema"
            body = json.loads(schema.data)
            assert body["type"] == "object"
        frame_schema = json.loads(summary.schemas[topics[TOPIC_FRAMES].schema_id].data)
        assert set(frame_schema["properties"]["timestamp"]["properties"]) == {"sec", "nsec"}
        assert frame_schema["properties"]["encoding"]["const"] == FRAMES_ENCODING
        assert "long" not in frame_schema["required"] and "frames" in frame_schema["required"]
        assert summary.chunk_indexes
        assert {c.compression for c in summary.chunk_indexes} == {"zstd"}
        assert summary.statistics is not None
        assert summary.statistics.message_count == len(singles) + 7
        sample_schema = json.loads(summary.schemas[topics[TOPIC_SAMPLES].schema_id].data)
        assert list(sample_schema["properties"]["u"]["properties"]) == INPUTS
        assert list(sample_schema["properties"]["z"]["properties"]) == OUTPUTS
        residual_schema = json.loads(summary.schemas[topics[TOPIC_RESIDUALS].schema_id].data)
        assert list(residual_schema["properties"]["statistic"]["properties"]) == RESIDUALS
        log_schema = summary.schemas[topics[TOPIC_LOG].schema_id]
        assert log_schema.name == "foxglove.Log"
    with open(path, "rb") as f:
        (meta,) = make_reader(f).iter_metadata()
        assert meta.name == METADATA_NAME and meta.metadata == METADATA
    with open(path, "rb") as f:
        seeking = [
            (c.topic, m.log_time, json.loads(m.data)) for _, c, m in make_reader(f).iter_messages()
        ]
    assert sorted(seeking, key=repr) == sorted(got, key=repr)


def frames_code(block: dict, status: str) -> int:
    return block["statuses"].index(status)


def test_blocks_fill_to_block_size_and_carry_their_first_time(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    clock = FakeClock()
    with McapRecorder(path, block_frames=4, block_samples=3, clock=clock) as rec:
        write_frames(rec, 0, 5)
        assert rec.buffered == 1 and rec.messages_written == 4
        n = 9
        rec.write_frames(
            _block(T0 + (5 + np.arange(n)) * 1000, 5 + np.arange(n), np.full(n, 4),
                   np.zeros((n, 8), np.uint8)),
            ["ok"] * n,
        )
        # 1 + 9 buffered: two full blocks written, 2 frames wait for close.
        assert rec.buffered == 2 and rec.messages_written == 12
        for i in range(7):
            rec.write_sample(
                Sample(k=i, timestamp_ns=T0 + i, u=np.array([i, 0.0]), z=np.zeros(2)),
                INPUTS,
                OUTPUTS,
            )
        assert rec.buffered == 2 + 1
    blocks = topic_messages(path, TOPIC_FRAMES)
    assert [m["count"] for _, m in blocks] == [4, 4, 4, 2]
    assert [t for t, _ in blocks] == [T0 + i * 1000 for i in (0, 4, 8, 12)]
    assert [m["timestamp"] for _, m in blocks] == [stamp(t) for t, _ in blocks]
    assert [b.size for b in iter_frame_blocks(path)] == [4, 4, 4, 2]
    assert read_frames(path).id.tolist() == list(range(14))
    samples = topic_messages(path, TOPIC_SAMPLES)
    assert [t for t, _ in samples] == [T0 + i for i in range(7)]
    assert read_samples(path).U[:, 0].tolist() == list(range(7))


def test_a_row_after_the_flush_deadline_starts_the_next_interval(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    clock = FakeClock()
    rec = McapRecorder(path, flush_interval=1.0, clock=clock)
    write_frames(rec, 0, 3)
    clock.t = 1.0
    write_frames(rec, 3, 4)  # the timed flush writes frames 0-2, frame 3 waits
    assert frame_indices(path) == [0, 1, 2]
    assert rec.buffered == 1
    rec.flush()
    assert frame_indices(path) == [0, 1, 2, 3]
    rec.close()


@pytest.mark.parametrize("row_encoding", sorted(ROW_ENCODINGS))
def test_float_rows_round_trip_exactly(tmp_path: Path, row_encoding: str) -> None:
    rng = np.random.default_rng(3)
    U, Z = rng.standard_normal((50, 2)), rng.standard_normal((50, 2)) * 10.0 ** rng.integers(
        -300, 300, (50, 2))
    Z[3, 1] = np.nan
    R = rng.standard_normal((50, 3, 2))
    R[7, 2, 0] = -np.inf
    R[8, 0, 1] = -0.0
    k, t = np.arange(50), T0 + np.arange(50) * 1000
    path = tmp_path / "rows.mcap"
    with McapRecorder(path, block_samples=16, row_encoding=row_encoding) as rec:
        rec.write_samples(k, t, U, Z, np.zeros(50, int), INPUTS, OUTPUTS)
        rec.write_residual_rows(k, t, RESIDUALS, R[:, 0], R[:, 1], R[:, 2])
    samples = read_samples(path)
    np.testing.assert_array_equal(samples.U, U)
    np.testing.assert_array_equal(samples.Z, Z)
    _, _, names, r, rn, stat = read_residuals(path)
    assert names == RESIDUALS
    np.testing.assert_array_equal(r, R[:, 0])
    assert np.signbit(r[8, 1])
    np.testing.assert_array_equal(rn, R[:, 1])
    expected = R[:, 2].copy()
    if row_encoding == "json":
        expected[7, 0] = np.nan  # JSON has no inf: null
    np.testing.assert_array_equal(stat, expected)


def _legacy_log(path: Path, binary: bool) -> None:
    """A log of the older layout: blocks of samples and of residual rows (canfdi.*.v1)."""
    import base64

    def column(values: np.ndarray) -> object:
        if binary:
            return base64.b64encode(np.asarray(values, "<f8").tobytes()).decode()
        return [None if not np.isfinite(v) else float(v) for v in values]

    k = [5, 6, 7]
    t = [T0 + 5, T0 + 6, T0 + 7]
    U, Z = np.array([[1.0, 2.0], [3.0, np.nan], [5.0, 6.0]]), np.array([[7.0, 8.0]] * 3)
    R = np.array([[0.5, -np.inf], [1.5, 2.5], [3.5, 4.5]])
    samples = {"timestamp": stamp(T0 + 5), "encoding": SAMPLES_ENCODING, "count": 3, "k": k,
               "t_ns": t, "gap": [0, 0, 1],
               "u": {n: column(U[:, i]) for i, n in enumerate(INPUTS)},
               "z": {n: column(Z[:, i]) for i, n in enumerate(OUTPUTS)}}
    residuals = {"timestamp": stamp(T0 + 5), "encoding": RESIDUALS_ENCODING, "count": 3, "k": k,
                 "t_ns": t, "names": RESIDUALS,
                 **{key: {n: column(R[:, i] * f) for i, n in enumerate(RESIDUALS)}
                    for key, f in (("r", 1.0), ("normalized", 2.0), ("statistic", 3.0))}}
    with open(path, "wb") as f:
        writer = Writer(f)
        writer.start()
        schema = writer.register_schema("canfdi.Json", "jsonschema", b'{"type":"object"}')
        for topic, message in ((TOPIC_SAMPLES, samples), (TOPIC_RESIDUALS, residuals)):
            channel = writer.register_channel(topic, "json", schema)
            writer.add_message(channel, T0 + 5, json.dumps(message).encode(), T0 + 5)
        writer.finish()


@pytest.mark.parametrize("binary", [False, True], ids=["json-lists", "base64"])
def test_reads_the_block_layout_of_older_logs(tmp_path: Path, binary: bool) -> None:
    path = tmp_path / "old.mcap"
    _legacy_log(path, binary)
    samples = read_samples(path)
    assert samples.k.tolist() == [5, 6, 7] and samples.gap.tolist() == [0, 0, 1]
    assert samples.t_ns.tolist() == [T0 + 5, T0 + 6, T0 + 7]
    np.testing.assert_array_equal(samples.U, [[1.0, 2.0], [3.0, np.nan], [5.0, 6.0]])
    _, _, names, r, rn, stat = read_residuals(path)
    assert names == RESIDUALS
    np.testing.assert_array_equal(rn[1:], [[3.0, 5.0], [7.0, 9.0]])
    inf = -np.inf if binary else np.nan  # base64 kept -inf, JSON lists could not
    np.testing.assert_array_equal(r, [[0.5, inf], [1.5, 2.5], [3.5, 4.5]])
    np.testing.assert_array_equal(stat, [[1.5, inf], [4.5, 7.5], [10.5, 13.5]])


def test_many_statuses_and_name_changes(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    statuses = [f"status-{i}" for i in range(600)]
    with McapRecorder(path) as rec:
        for i, status in enumerate(statuses):
            rec.write_frame(T0 + i, i, b"", status)
        rec.write_frames(
            _block(T0 + 600 + np.arange(200), np.arange(200), np.zeros(200, int),
                   np.zeros((200, 8), np.uint8)),
            statuses[:200],
        )
        with pytest.raises(ValueError, match="256"):
            rec.write_frames(
                _block(np.zeros(300, np.int64), np.zeros(300), np.zeros(300),
                       np.zeros((300, 8))),
                [f"other-{i}" for i in range(300)],
            )
        rec.write_sample(
            Sample(k=0, timestamp_ns=T0, u=np.zeros(2), z=np.zeros(2)), INPUTS, OUTPUTS
        )
        rec.write_sample(Sample(k=1, timestamp_ns=T0, u=np.zeros(1), z=np.zeros(2)), ["a"], OUTPUTS)
        with pytest.raises(ValueError, match="inputs"):
            rec.write_sample(
                Sample(k=2, timestamp_ns=T0, u=np.zeros(2), z=np.zeros(2)), ["a"], OUTPUTS
            )
        with pytest.raises(ValueError, match="duplicate"):
            rec.write_residuals(T0, 0, ["r", "r"], [0.0, 0.0], [0.0, 0.0], [0.0, 0.0])
        with pytest.raises(ValueError, match="data: expected shape"):
            rec.write_frames(_block([T0], [1], [8], np.zeros((1, 4))), "ok")
    assert read_frames(path).status.tolist() == statuses + statuses[:200]
    samples = [m for _, m in topic_messages(path, TOPIC_SAMPLES)]
    assert [list(m["u"]) for m in samples] == [INPUTS, ["a"]]
    with pytest.raises(ValueError, match="changes names"):
        read_samples(path)


def test_write_after_close_raises_and_close_is_idempotent(tmp_path: Path) -> None:
    rec = McapRecorder(tmp_path / "run.mcap")
    rec.close()
    rec.close()
    sample = Sample(k=0, timestamp_ns=T0, u=np.zeros(2), z=np.zeros(2))
    for write in [
        lambda: write_frames(rec, 0, 1),
        lambda: rec.write_frames(_block([T0], [1], [0], np.zeros((1, 8))), "ok"),
        lambda: rec.write_sample(sample, INPUTS, OUTPUTS),
        lambda: rec.write_samples([0], [T0], [[0, 0]], [[0, 0]], [0], INPUTS, OUTPUTS),
        lambda: rec.write_residuals(T0, 0, RESIDUALS, [0, 0], [0, 0], [0, 0]),
        lambda: rec.write_residual_rows([0], [T0], RESIDUALS, [[0, 0]], [[0, 0]], [[0, 0]]),
        lambda: rec.write_event(event()),
    ]:
        with pytest.raises(ValueError, match="closed"):
            write()


def test_missing_directory_is_reported_at_start(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError):
        McapRecorder(tmp_path / "nowhere" / "run.mcap")
    with pytest.raises(FileNotFoundError):
        read_frames(tmp_path / "nowhere.mcap")


# --------------------------------------------------------------------------------------
# the older one-row-per-message layout
# --------------------------------------------------------------------------------------


def write_old_layout(path: Path, n_frames: int) -> None:
    """A log as the recorder wrote it before blocks: one message per frame, sample, row."""
    with open(path, "wb") as f:
        writer = Writer(f)
        writer.start()
        schema = writer.register_schema("canfdi.Json", "jsonschema", b'{"type":"object"}')
        frames, samples, residuals = (
            writer.register_channel(topic, "json", schema)
            for topic in (TOPIC_FRAMES, TOPIC_SAMPLES, TOPIC_RESIDUALS)
        )

        def add(channel: int, t: int, message: dict) -> None:
            writer.add_message(
                channel, t, json.dumps({"timestamp": stamp(t), **message}).encode(), t
            )

        for i in range(n_frames):
            add(frames, T0 + i * 1000, {"id": i & 0x7FF, "extended": i % 7 == 0, "dlc": 4,
                                        "data": i.to_bytes(4, "big").hex(),
                                        "status": "sent" if i % 5 == 0 else "ok"})  # fmt: skip
        fd = {"id": 1, "extended": False, "dlc": 64, "data": bytes(range(64)).hex(), "status": "fd"}
        add(frames, T0 + n_frames * 1000, fd)
        for k in range(3):
            add(samples, T0 + k, {"k": k, "gap": k, "u": {"voltage": float(k), "load": None},
                                  "z": {"speed": 1.0, "current": -1.0}})  # fmt: skip
            add(residuals, T0 + k, {"k": k, "r": {"r0": k, "r1": None},
                                    "normalized": {"r0": 1.0, "r1": 2.0},
                                    "statistic": {"r0": 0.0, "r1": 3.0}})  # fmt: skip
        writer.finish()


def received_tuples(path: Path) -> list[tuple[int, int, bytes, bool, bool]]:
    """(t_ns, id, payload, extended, error frame) of the frames replay reads from a log."""
    return [
        (t, i, d, x, s == "error_frame")
        for block in mcap_frame_blocks(path)
        for t, i, d, x, s in zip(
            block.t_ns.tolist(), block.id.tolist(), block.payloads(), block.extended.tolist(),
            block.status.tolist(), strict=True,
        )
    ]


def test_reads_the_one_frame_per_message_layout(tmp_path: Path) -> None:
    path = tmp_path / "old.mcap"
    n = 5000  # more than one block of old rows
    write_old_layout(path, n)
    frames = read_frames(path)
    assert frames.size == n + 1
    assert indices(frames)[:n] == list(range(n))
    assert frames.t_ns.tolist() == [T0 + i * 1000 for i in range(n + 1)]
    assert frames.id.tolist()[:n] == [i & 0x7FF for i in range(n)]
    assert frames.extended.tolist()[:n] == [i % 7 == 0 for i in range(n)]
    assert frames.status.tolist()[:n] == ["sent" if i % 5 == 0 else "ok" for i in range(n)]
    assert frames.dlc.tolist() == [4] * n + [64]
    assert frames.long == {n: bytes(range(64))}
    assert [b.size for b in iter_frame_blocks(path)] == [4096, n + 1 - 4096]

    samples = read_samples(path)
    assert samples.k.tolist() == [0, 1, 2] and samples.gap.tolist() == [0, 1, 2]
    assert samples.t_ns.tolist() == [T0, T0 + 1, T0 + 2]
    assert samples.input_names == INPUTS and samples.output_names == OUTPUTS
    np.testing.assert_array_equal(samples.U, [[0.0, np.nan], [1.0, np.nan], [2.0, np.nan]])
    k, t_ns, names, r, rn, stat = read_residuals(path)
    assert k.tolist() == [0, 1, 2] and t_ns.tolist() == [T0, T0 + 1, T0 + 2]
    assert names == RESIDUALS and rn.tolist() == [[1.0, 2.0]] * 3
    np.testing.assert_array_equal(r, [[0.0, np.nan], [1.0, np.nan], [2.0, np.nan]])
    np.testing.assert_array_equal(stat, [[0.0, 3.0]] * 3)

    # Replay reads both layouts the same way, without the monitor's own frames.
    new = tmp_path / "new.mcap"
    with McapRecorder(new, block_frames=1000) as rec:
        for i in range(n):
            rec.write_frame(T0 + i * 1000, i & 0x7FF, i.to_bytes(4, "big"),
                            "sent" if i % 5 == 0 else "ok", i % 7 == 0)  # fmt: skip
        rec.write_frame(T0 + n * 1000, 1, bytes(range(64)), "fd")
    old_tuples, new_tuples = received_tuples(path), received_tuples(new)
    assert old_tuples == new_tuples
    expected = [
        (T0 + i * 1000, i & 0x7FF, i.to_bytes(4, "big"), i % 7 == 0, False)
        for i in range(n)
        if i % 5
    ] + [(T0 + n * 1000, 1, bytes(range(64)), False, False)]
    assert old_tuples == expected
    arrays = FrameBlock.concat(mcap_frame_blocks(new))
    assert arrays.t_ns.tolist() == [t for t, *_ in expected]
    assert arrays.payloads() == [d for _, _, d, _, _ in expected]
    assert "sent" not in set(arrays.status.tolist())


def test_vectorised_frames_keep_their_can_fd_payloads(tmp_path: Path) -> None:
    # FrameBlock.long (payloads over 8 bytes) used to be dropped by write_frames: only the
    # first 8 bytes of a CAN FD frame reached the log.
    path = tmp_path / "fd.mcap"
    payloads = [bytes(range(n)) for n in (0, 8, 12, 64, 3)]
    messages = [can.Message(timestamp=T0 / 1e9 + i, arbitration_id=0x100 + i, data=p,
                            is_fd=len(p) > 8, is_extended_id=False)
                for i, p in enumerate(payloads)]
    block = FrameBlock.from_messages(messages)
    assert set(block.long) == {2, 3}
    with McapRecorder(path, block_frames=2) as rec:
        rec.write_frame(T0, 0x7FF, bytes(20), "fd", dlc=20)  # a row before the block
        rec.write_frames(block, "fd")
    frames = read_frames(path)
    assert frames.payloads() == [bytes(20), *payloads]
    assert frames.dlc.tolist() == [20, 0, 8, 12, 64, 3]
    assert [b.size for b in iter_frame_blocks(path)] == [2, 2, 2]


def test_empty_log_reads_as_empty_arrays(tmp_path: Path) -> None:
    path = tmp_path / "empty.mcap"
    McapRecorder(path).close()
    frames = read_frames(path)
    assert frames.size == 0 and frames.data.shape == (0, 8) and frames.long == {}
    samples = read_samples(path)
    assert samples.U.shape == (0, 0) and samples.k.shape == (0,) and samples.input_names == []
    assert read_residuals(path).R.shape == (0, 0)
    assert received_tuples(path) == []


# --------------------------------------------------------------------------------------
# truncation and crash safety
# --------------------------------------------------------------------------------------

N_FRAMES = 5000
BURST = 50  # frames between timed flushes
BLOCK = 16  # frames per block: a chunk holds blocks of 16, 16, 16 and 2 frames


def write_bursts(rec: McapRecorder, clock: FakeClock, start: int, stop: int) -> None:
    """Every BURST frames the clock jumps past flush_interval, so the write of frame i (i a
    multiple of BURST) writes the buffered frames and ends the chunk holding frames
    i - BURST .. i - 1 before it buffers frame i."""
    for i in range(start, stop):
        if i % BURST == 0:
            clock.t += 1.0
        rec.write_frame(T0 + i * 1000, i & 0x7FF, i.to_bytes(4, "big"), "ok")


def test_truncated_files_read_back_a_prefix_of_whole_blocks(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    clock = FakeClock()
    with McapRecorder(
        path, metadata=METADATA, flush_interval=0.5, clock=clock, block_frames=BLOCK
    ) as rec:
        write_bursts(rec, clock, 0, N_FRAMES)
    data = path.read_bytes()
    with open(path, "rb") as f:
        chunks = make_reader(f).get_summary().chunk_indexes
    assert len(chunks) == N_FRAMES // BURST
    blocks = topic_messages(path, TOPIC_FRAMES)
    assert [m["count"] for _, m in blocks[:5]] == [BLOCK] * 3 + [BURST % BLOCK, BLOCK]
    expected = list(range(N_FRAMES))

    # Every chunk end (exactly the frames of the blocks up to it), every chunk middle (the
    # same prefix as the previous end: the block messages of a cut chunk are dropped whole),
    # one byte short of every chunk end, and a spread of other offsets.
    starts = [(c.message_start_time - T0) // 1000 for c in chunks]  # first frame of a chunk
    assert starts == list(range(0, N_FRAMES, BURST))
    cut_expect: dict[int, int | None] = {}
    for j, c in enumerate(chunks[::9]):
        j *= 9
        start, end = c.chunk_start_offset, c.chunk_start_offset + c.chunk_length
        n_through = starts[j + 1] if j + 1 < len(starts) else N_FRAMES
        cut_expect[start + c.chunk_length // 2] = starts[j]
        cut_expect[end - 1] = starts[j]
        cut_expect[end] = n_through
    for cut in [0, 1, 7, 8, 20, 40, *range(50, len(data), 2003), len(data) - 1, len(data)]:
        cut_expect.setdefault(cut, None)

    trunc = tmp_path / "trunc.mcap"
    previous_count = -1
    for cut in sorted(cut_expect):
        trunc.write_bytes(data[:cut])
        reader = read_log(trunc)
        list(reader)  # must not raise
        got = frame_indices(trunc)  # must not raise either
        assert got == expected[: len(got)], f"not a prefix at byte {cut}"
        assert len(got) % BURST == 0 or len(got) == N_FRAMES, f"a block cut at byte {cut}"
        assert len(got) >= previous_count, f"fewer frames at byte {cut} than before it"
        previous_count = len(got)
        if cut_expect[cut] is not None:
            assert len(got) == cut_expect[cut], f"cut at {cut}"
        assert reader.truncated == (cut < len(data))
        if cut >= 8:
            # The metadata record follows the header, before any chunk.
            meta = read_metadata(trunc)
            assert meta in ({}, METADATA)
    assert previous_count == N_FRAMES


def test_killed_writer_keeps_everything_before_the_last_timed_flush(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    clock = FakeClock()
    rec = McapRecorder(path, metadata=METADATA, flush_interval=0.5, clock=clock, block_frames=BLOCK)
    snapshots = []
    done = 0
    for stop in (1, 49, 50, 51, 1234, 2500, 4999, N_FRAMES):
        write_bursts(rec, clock, done, stop)
        done = stop
        # What a SIGKILL now would leave: the bytes in the file, without close().
        snapshots.append((stop, path.read_bytes()))
    assert rec.messages_written + rec.buffered == N_FRAMES
    for stop, data in snapshots:
        flushed = ((stop - 1) // BURST) * BURST  # frames before the last chunk-ending write
        killed = tmp_path / f"killed-{stop}.mcap"
        killed.write_bytes(data)
        reader = read_log(killed)
        list(reader)
        got = frame_indices(killed)
        assert reader.truncated and not reader.complete
        assert len(got) >= flushed, f"lost flushed frames after {stop} writes"
        assert got == list(range(len(got)))
        assert read_metadata(killed) == METADATA
    rec.close()
    assert frame_indices(path) == list(range(N_FRAMES))


def test_explicit_flush_writes_the_buffers_and_ends_the_chunk(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    rec = McapRecorder(path, flush_interval=3600.0, clock=FakeClock())
    write_frames(rec, 0, 10)
    rec.write_sample(Sample(k=0, timestamp_ns=T0, u=np.zeros(2), z=np.zeros(2)), INPUTS, OUTPUTS)
    rec.write_residuals(T0, 0, RESIDUALS, [0.0, 1.0], [0.0, 1.0], [0.0, 1.0])
    assert frame_indices(path) == []
    assert rec.buffered == 12
    rec.flush()
    assert rec.buffered == 0
    assert frame_indices(path) == list(range(10))
    assert read_samples(path).k.tolist() == [0] and read_residuals(path).k.tolist() == [0]
    rec.close()


SECOND = 1_000_000_000
AHEAD = 1_500_000_000  # how far the monitor's now runs ahead of the frames still queued


def record_a_run(rec: McapRecorder, clock: FakeClock, seconds: int, sent_in: set[int]
                 ) -> tuple[list[int], list[int]]:
    """What `canfdi run` records (issue 40): received frames at the bus's time, 300 a second,
    and the frames it sends stamped with the wall clock's now, AHEAD of the received frames
    still waiting in its queue. A timed flush ends the chunk each second; in the seconds of
    ``sent_in`` the monitor sends right after the flush, so the next chunk begins with a frame
    whose time is later than the following chunk's first frame. Returns the payload numbers of
    the received and the sent frames, in the order written."""
    received, sent = [], []
    n = 0
    for second in range(seconds):
        clock.t += 1.0  # the next write finds the flush due
        t = T0 + second * SECOND
        if second in sent_in:
            rec.write_frame(t + AHEAD, 0x080, (10**6 + n).to_bytes(4, "big"), "sent")
            sent.append(10**6 + n)
        for i in range(300):
            rec.write_frame(t + i * 3_333_333, 0x100 + i % 7, n.to_bytes(4, "big"), "ok")
            received.append(n)
            n += 1
    return received, sent


def test_a_log_cut_before_its_summary_reads_what_the_bus_carried_in_order(tmp_path: Path
                                                                           ) -> None:
    """Issue 40: a chunk that begins with a frame the monitor sent must not be read after the
    chunk that follows it. Before the fix its log time was that frame's (1.5 s late), and a
    file without a summary was read in the order of its chunks' message times: a second of
    received frames came back after the next one."""
    path = tmp_path / "run.mcap"
    clock = FakeClock()
    rec = McapRecorder(path, flush_interval=1.0, clock=clock)
    received, sent = record_a_run(rec, clock, 8, {2, 3, 5})
    killed = tmp_path / "killed.mcap"
    killed.write_bytes(path.read_bytes())  # what a SIGKILL now leaves: no summary
    rec.close()

    reader = read_log(killed)
    list(reader)
    assert reader.truncated and not reader.complete
    frames = read_frames(killed)
    got = frames.select(frames.status != "sent")
    # Seven whole seconds were flushed; the eighth is lost with the kill.
    assert indices(got) == received[: 7 * 300]
    assert indices(frames.select(frames.status == "sent")) == sent
    assert frames.t_ns[frames.status != "sent"].tolist() == sorted(got.t_ns.tolist())
    # The complete file reads the same, through canfdi's reader and mcap's own in log-time
    # order (as Foxglove reads); the blocks' log times never go back.
    assert indices(read_frames(path).received()) == received
    with open(path, "rb") as f:
        blocks = [(m.log_time, json.loads(m.data)) for _, _, m in
                  make_reader(f).iter_messages(topics=[TOPIC_FRAMES], log_time_order=True)]
    times = [t for t, _ in blocks]
    assert times == sorted(times)
    records = np.concatenate([np.frombuffer(__import__("base64").b64decode(m["frames"]),
                                            dtype=FRAME_DTYPE) for _, m in blocks])
    kept = records["status"] != blocks[0][1]["statuses"].index("sent")
    assert [int.from_bytes(bytes(d[:4]), "big") for d in records["data"][kept]] == received
    # A block's timestamp is its earliest frame's (the received one after the sent one).
    assert [m["timestamp"] for _, m in blocks[2:4]] == [stamp(T0 + 2 * SECOND),
                                                        stamp(T0 + 3 * SECOND)]


def test_rows_keep_their_own_times_when_the_log_time_is_held(tmp_path: Path) -> None:
    """A drive's clock that steps back: the samples' log times are held at the latest (so
    every reader reads them in the order written), and each sample keeps its own time."""
    path = tmp_path / "run.mcap"
    clock = FakeClock()
    times = [T0 + 10 * SECOND, T0 + 11 * SECOND, T0, T0 + SECOND, T0 + 12 * SECOND]
    with McapRecorder(path, flush_interval=1.0, clock=clock) as rec:
        for k, t in enumerate(times):
            clock.t += 1.0  # a chunk per sample
            rec.write_sample(Sample(k=k, timestamp_ns=t, u=np.zeros(2), z=np.zeros(2)),
                             INPUTS, OUTPUTS)
        clock.t += 1.0
        rec.flush()
        killed = path.read_bytes()
    (tmp_path / "killed.mcap").write_bytes(killed)
    for log in (path, tmp_path / "killed.mcap"):
        samples = read_samples(log)
        assert samples.k.tolist() == [0, 1, 2, 3, 4]
        assert samples.t_ns.tolist() == times
    logged = [t for t, _ in topic_messages(path, TOPIC_SAMPLES)]
    assert logged == [times[0], times[1], times[1], times[1], times[4]]


CHILD = """
import sys, time
from canfdi.io.writer import McapRecorder

rec = McapRecorder(sys.argv[1], flush_interval=0.2)
i = 0
while True:
    rec.write_frame(time.time_ns(), i & 0x7FF, i.to_bytes(4, "big"), "ok")
    i += 1
    if i % 10 == 0:
        print(i, flush=True)
        time.sleep(0.01)  # ~1000 frames/s: far from filling a 4096-frame block in 2 s
"""


@pytest.mark.skipif(not hasattr(signal, "SIGKILL"), reason="needs SIGKILL")
def test_sigkilled_child_loses_at_most_the_last_flush_interval(tmp_path: Path) -> None:
    path = tmp_path / "child.mcap"
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.Popen(
        [sys.executable, "-c", CHILD, str(path)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        bufsize=1,
        cwd=REPO,
        env=env,
    )
    reports: list[tuple[float, int]] = []
    try:
        assert proc.stdout is not None
        first = None
        for line in proc.stdout:
            # Received no earlier than written: a conservative time for "written by then".
            now = time.monotonic()
            first = now if first is None else first
            reports.append((now, int(line)))
            if now - first >= 2.0:
                break
        kill_time = time.monotonic()
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert reports and reports[-1][0] - reports[0][0] >= 2.0, proc.stderr.read()
    assert proc.returncode == -signal.SIGKILL
    must_have = max(n for t, n in reports if t < kill_time - 0.5)
    assert must_have > 100
    reader = read_log(path)
    list(reader)
    got = frame_indices(path)
    assert reader.truncated
    assert got == list(range(len(got)))
    assert len(got) >= must_have


# --------------------------------------------------------------------------------------
# rotation
# --------------------------------------------------------------------------------------


def test_a_segment_of_an_earlier_recording_is_never_deleted(tmp_path: Path) -> None:
    # Its segments would read as this recording's: the recorder refuses, and deletes nothing.
    path = tmp_path / "run.mcap"
    stale = tmp_path / "run-0009.mcap"
    stale.write_bytes(b"from an earlier run")
    with pytest.raises(FileExistsError, match=r"run-0009\.mcap exists"):
        McapRecorder(path, metadata=METADATA, clock=FakeClock())
    assert stale.read_bytes() == b"from an earlier run" and not path.exists()


def test_rotation_by_bytes(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    unrelated = tmp_path / "run-x-0001.mcap"
    unrelated.write_bytes(b"not ours")
    limit = 8_000
    rec = McapRecorder(
        path,
        metadata=METADATA,
        rotate_bytes=limit,
        chunk_size=2048,
        block_frames=64,
        clock=FakeClock(),
    )
    assert unrelated.exists()
    write_frames(rec, 0, 6000)
    rec.close()

    names = [p.name for p in rec.paths]
    assert len(names) >= 4
    assert rec.segments == len(names)
    assert names == ["run.mcap"] + [f"run-{i:04d}.mcap" for i in range(1, len(names))]
    assert log_segments(path) == rec.paths
    assert rec.bytes_written == sum(p.stat().st_size for p in rec.paths)
    got = []
    for seg in rec.paths:
        reader = read_log(seg)
        list(reader)
        assert reader.complete, seg
        got += frame_indices(seg, segments=False)
        assert read_metadata(seg) == METADATA
        with open(seg, "rb") as f:
            summary = make_reader(f).get_summary()
            assert summary is not None and summary.statistics.message_count > 0
        # The data section overshoots by at most one chunk (one 64-frame block: 2 KiB of
        # base64 before compression) and its message index; the summary comes on top.
        assert limit <= data_section_end(seg) < limit + 4096 or seg == rec.paths[-1]
    assert got == list(range(6000))
    assert frame_indices(path) == list(range(6000))  # read_frames reads every segment


def test_rotation_by_seconds(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    clock = FakeClock(100.0)
    rec = McapRecorder(path, metadata=METADATA, rotate_seconds=10.0, clock=clock)
    for i in range(70):  # one frame and one sample every 0.5 s for 35 s
        clock.t = 100.0 + 0.5 * i
        write_frames(rec, i, i + 1)
        rec.write_sample(
            Sample(k=i, timestamp_ns=T0 + i, u=np.zeros(2), z=np.zeros(2)), INPUTS, OUTPUTS
        )
    rec.close()
    assert [p.name for p in rec.paths] == [
        "run.mcap",
        "run-0001.mcap",
        "run-0002.mcap",
        "run-0003.mcap",
    ]
    assert log_segments(path) == rec.paths
    for j, seg in enumerate(rec.paths):
        reader = read_log(seg)
        list(reader)
        assert reader.complete
        # The rows buffered when the segment's time is up are written into it.
        expected = list(range(20 * j, min(20 * j + 20, 70)))
        assert frame_indices(seg, segments=False) == expected
        assert read_samples(seg, segments=False).k.tolist() == expected
        assert read_metadata(seg) == METADATA
    assert frame_indices(path) == list(range(70))
    assert read_samples(path).k.tolist() == list(range(70))


# --------------------------------------------------------------------------------------
# write errors
# --------------------------------------------------------------------------------------


class Disk:
    """Opens real files whose writes fail with ENOSPC while ``full`` is set."""

    def __init__(self, full: bool = False) -> None:
        self.full = full
        self.opened: list[Path] = []

    def open(self, path: Path) -> FlakyFile:
        self.opened.append(path)
        return FlakyFile(open(path, "wb"), self)


class FlakyFile:
    def __init__(self, file, disk: Disk) -> None:
        self.file = file
        self.disk = disk

    def write(self, data: bytes) -> int:
        if self.disk.full:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return self.file.write(data)

    def flush(self) -> None:
        if self.disk.full:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        self.file.flush()

    def close(self) -> None:
        self.file.close()


@pytest.mark.parametrize(
    ("flush_interval", "chunk_size", "block_frames"),
    [
        (0.5, 1024 * 1024, 4096),  # the error strikes in a timed flush
        (1000.0, 1024, 8),  # ... in a block write that ends a full chunk
    ],
)
def test_disk_full_drops_then_resumes(
    tmp_path: Path,
    caplog: pytest.LogCaptureFixture,
    flush_interval: float,
    chunk_size: int,
    block_frames: int,
) -> None:
    path = tmp_path / "run.mcap"
    clock = FakeClock()
    disk = Disk()
    rec = McapRecorder(
        path,
        metadata=METADATA,
        flush_interval=flush_interval,
        chunk_size=chunk_size,
        block_frames=block_frames,
        clock=clock,
        opener=disk.open,
    )
    caplog.set_level(logging.WARNING, logger="canfdi.io.writer")

    def frames(start: int, stop: int) -> None:
        for i in range(start, stop):
            clock.t = 0.1 * i
            write_frames(rec, i, i + 1)  # never raises

    frames(0, 100)
    rec.flush()
    disk.full = True
    frames(100, 200)
    assert rec.failing
    assert rec.last_error is not None and rec.last_error.errno == errno.ENOSPC
    assert rec.write_errors >= 5  # the first failure and about one retry per second
    failures = [r for r in caplog.records if "failed" in r.getMessage()]
    assert len(failures) == 1  # one warning per episode, not per error
    assert len(disk.opened) >= 5

    disk.full = False
    frames(200, 300)
    assert not rec.failing
    rec.close()
    assert [r for r in caplog.records if "resumed" in r.getMessage()]

    assert rec.paths == [path, tmp_path / "run-0001.mcap"]
    assert log_segments(path) == rec.paths  # failed retries left no files behind
    assert rec.segments == 2  # the abandoned segment and the one recording resumed in
    got = frame_indices(path)
    assert got[:100] == list(range(100))  # flushed before the disk filled
    assert got == sorted(got) and set(got) <= set(range(300))
    assert set(range(211, 300)) <= set(got)  # a retry happens within a second of recovery
    assert len(got) < 300  # the unflushed chunk was lost with the failing segment
    assert rec.messages_written == len(got)
    assert rec.messages_written + rec.messages_dropped == 300
    assert read_metadata(rec.paths[-1]) == METADATA
    last = read_log(rec.paths[-1])
    list(last)
    assert last.complete


def test_disk_full_at_start_does_not_raise(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    clock = FakeClock()
    disk = Disk(full=True)
    rec = McapRecorder(path, metadata=METADATA, clock=clock, opener=disk.open)
    assert rec.failing and rec.write_errors == 1 and rec.paths == []
    assert rec.segments == 0
    write_frames(rec, 0, 5)
    assert rec.buffered == 5 and rec.messages_dropped == 0  # buffered, not yet lost
    disk.full = False
    clock.t = 1.0
    write_frames(rec, 5, 10)
    rec.close()
    assert rec.paths == [path]
    assert frame_indices(path) == list(range(10))  # the buffer outlived the failure
    assert read_metadata(path) == METADATA


def test_rows_buffered_at_close_while_failing_are_dropped(tmp_path: Path) -> None:
    clock = FakeClock()
    disk = Disk(full=True)
    rec = McapRecorder(tmp_path / "run.mcap", clock=clock, opener=disk.open, block_frames=4)
    write_frames(rec, 0, 10)  # two full blocks refused, two frames buffered
    assert rec.messages_dropped == 8 and rec.buffered == 2
    rec.close()
    assert rec.messages_dropped == 10 and rec.messages_written == 0


@settings(max_examples=60, deadline=None)
@given(
    names=st.lists(st.text(min_size=1, max_size=6), min_size=1, max_size=4, unique=True),
    values=st.lists(st.floats(allow_nan=True, allow_infinity=True), min_size=8, max_size=8),
    drive=st.one_of(st.none(), st.text(max_size=5)),
)
def test_row_template_writes_what_json_would(names, values, drive) -> None:
    """The fast %-template gives the same JSON as encoding the row's dict, whatever the names
    (quotes, percent signs, unicode) and values (NaN, inf, -0.0, extremes)."""
    from canfdi.io.blocks import RowEncoder, encode_message

    m = len(names)
    encoder = RowEncoder(("k", "gap"), (("u", names), ("z", names)),
                         None if drive is None else {"drive": drive})
    floats = np.resize(np.array(values), (2, 2 * m))
    t = np.array([T0, T0 + 1])
    ints = np.array([[3, 0], [4, 2]])
    got = encoder.encode(t, ints, floats)
    for i in range(2):
        expected = json.loads(encode_message(encoder.message(int(t[i]), ints[i].tolist(),
                                                             floats[i].tolist())))
        assert json.loads(got[i]) == expected
        assert list(json.loads(got[i])["z"]) == names


def test_batched_messages_are_the_bytes_add_message_writes() -> None:
    """The row topics' batch path writes the file mcap's own add_message would, record for
    record: chunks, message indexes, statistics, summary."""
    import io

    from mcap.writer import CompressionType

    from canfdi.io.mcapwrite import add_messages

    rng = np.random.default_rng(5)
    times = T0 + np.cumsum(rng.integers(0, 10**7, 3000))
    data = [bytes(rng.integers(0, 256, rng.integers(0, 300)).astype(np.uint8)) for _ in times]
    files = []
    for batched in (False, True):
        out = io.BytesIO()
        # Chunks end where the recorder ends them (flush), not where a size is crossed.
        writer = Writer(out, chunk_size=10**9, compression=CompressionType.ZSTD,
                        enable_data_crcs=True)
        writer.start()
        schema = writer.register_schema("s", "jsonschema", b"{}")
        channels = [writer.register_channel(f"/t{i}", "json", schema) for i in range(2)]
        for part in range(0, len(times), 700):
            for channel in channels:
                t, d = times[part : part + 700], data[part : part + 700]
                if batched:
                    add_messages(writer, channel, t, d, part)
                else:
                    for i, (ti, di) in enumerate(zip(t.tolist(), d, strict=True)):
                        writer.add_message(channel, ti, di, ti, part + i)
            writer.flush()
        writer.finish()
        files.append(out.getvalue())
    assert files[0] == files[1]


def test_frames_have_chunks_of_their_own_and_reading_frames_inflates_no_other(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "capture.mcap"
    rec = McapRecorder(path, clock=FakeClock(), chunk_size=32 * 1024, block_frames=256,
                       block_samples=64)
    for i in range(0, 6000, 300):
        write_frames(rec, i, i + 300)
        for k in range(i // 3, (i + 300) // 3):
            rec.write_sample(Sample(k=k, timestamp_ns=T0 + k * 3000, u=np.zeros(2),
                                    z=np.ones(2)), INPUTS, OUTPUTS)
        if i == 3000:
            rec.write_event(event())
            rec.flush()  # both open chunks end
    rec.close()
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    frames = next(c.id for c in summary.channels.values() if c.topic == TOPIC_FRAMES)
    kinds = [set(index.message_index_offsets) for index in summary.chunk_indexes]
    assert all(kind == {frames} or frames not in kind for kind in kinds)
    frame_chunks = sum(kind == {frames} for kind in kinds)
    assert 2 < frame_chunks < len(kinds) - 2

    inflated: list[int] = []
    inflate = McapFile._inflate
    monkeypatch.setattr(McapFile, "_inflate",
                        lambda self, pos, *args: inflated.append(pos) or inflate(self, pos, *args))
    assert frame_indices(path) == list(range(6000))
    assert len(inflated) == frame_chunks
    inflated.clear()
    assert read_samples(path).k.tolist() == list(range(2000))
    assert len(inflated) == len(kinds) - frame_chunks
    assert [m["kind"] for _, m in topic_messages(path, TOPIC_EVENTS)] == ["accepted"]
    # mcap's own reader, in log-time order across the interleaved chunks
    with open(path, "rb") as f:
        times = [m.log_time for _, _, m in make_reader(f).iter_messages(log_time_order=True)]
    assert times == sorted(times) and len(times) == summary.statistics.message_count


def test_message_json_beyond_strict_json_still_reads(tmp_path: Path) -> None:
    # Older canfdi logs wrote non-finite floats as bare NaN / Infinity tokens.
    path = tmp_path / "old.mcap"
    with open(path, "wb") as f:
        writer = Writer(f)
        writer.start()
        schema = writer.register_schema("canfdi.Json", "jsonschema", b'{"type":"object"}')
        channel = writer.register_channel("/x", "json", schema)
        writer.add_message(channel, T0, b'{"a": NaN, "b": -Infinity, "c": 1}', T0)
        writer.finish()
    ((_, a),) = topic_messages(path, "/x")
    assert math.isnan(a["a"]) and a["b"] == -math.inf and a["c"] == 1


def test_chunks_are_zstd_at_the_recorders_level(tmp_path):
    """mcap's Writer has no compression level: the recorder's chunks are zstd at ZSTD_LEVEL
    (each recompresses to the very bytes written), and every reader inflates them."""
    import zstandard
    from mcap.records import Chunk

    from canfdi.io.mcapwrite import ZSTD_LEVEL

    path = tmp_path / "level.mcap"
    n = 5000
    block = FrameBlock(1_700_000_000_000_000_000 + np.arange(n) * 1_000_000,
                       np.arange(n) % 0x7FF, np.full(n, 8), np.zeros(n, np.uint8),
                       np.random.default_rng(3).integers(0, 256, (n, 8)).astype(np.uint8))
    with McapRecorder(path) as rec:
        rec.write_frames(block, "ok")
    with open(path, "rb") as f:
        chunks = [r for r in StreamReader(f, emit_chunks=True).records if isinstance(r, Chunk)]
    assert chunks and all(c.compression == "zstd" for c in chunks)
    for c in chunks:
        raw = zstandard.decompress(c.data, c.uncompressed_size)
        assert zstandard.compress(raw, ZSTD_LEVEL) == c.data
    assert ZSTD_LEVEL == -1 and zstandard.compress(raw, 3) != c.data  # the level is seen
    with open(path, "rb") as f:
        assert len(list(make_reader(f).iter_messages())) > 0

"""Tests of canfdi.recorder: MCAP round trip, truncation, kill -9, rotation, disk full."""

from __future__ import annotations

import errno
import json
import logging
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.records import Footer
from mcap.stream_reader import StreamReader

from canfdi.core.records import FaultEvent, Sample
from canfdi.recorder import (
    MESSAGE_ENCODING,
    METADATA_NAME,
    SCHEMA_ENCODING,
    TOPIC_ESTIMATES,
    TOPIC_EVENTS,
    TOPIC_FRAMES,
    TOPIC_RESIDUALS,
    TOPIC_SAMPLES,
    TOPIC_STATUS,
    TOPICS,
    McapRecorder,
    log_segments,
    read_log,
    read_metadata,
)

REPO = Path(__file__).resolve().parents[2]
T0 = 1_700_000_000_123_456_789
METADATA = {"config_yaml": "name: test\n", "design_json": '{"a": 1}', "version": "0.1.0"}


class FakeClock:
    """A monotonic clock the test moves by hand."""

    def __init__(self, t: float = 0.0) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t


def stamp(ns: int) -> dict[str, int]:
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def frame_message(ns: int, i: int) -> dict:
    return {
        "timestamp": stamp(ns),
        "id": i & 0x7FF,
        "extended": False,
        "dlc": 4,
        "data": i.to_bytes(4, "big").hex(),
        "status": "ok",
    }


def write_frames(rec: McapRecorder, start: int, stop: int) -> None:
    for i in range(start, stop):
        rec.write_frame(T0 + i * 1000, i & 0x7FF, i.to_bytes(4, "big"), "ok")


def frame_indices(messages) -> list[int]:
    return [int(m["data"], 16) for topic, _, m in messages if topic == TOPIC_FRAMES]


def data_section_end(path: Path) -> int:
    with open(path, "rb") as f:
        for record in StreamReader(f, emit_chunks=True).records:
            if isinstance(record, Footer):
                return record.summary_start
    raise AssertionError(f"{path} has no footer")


def read_all(path: Path) -> list[tuple[str, int, dict]]:
    return [m for seg in log_segments(path) for m in read_log(seg)]


# --------------------------------------------------------------------------------------
# round trip
# --------------------------------------------------------------------------------------


def test_round_trip_every_topic(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    inputs, outputs = ["voltage", "load"], ["speed", "current"]
    sample = Sample(
        k=300, timestamp_ns=T0 + 5, u=np.array([12.0, 0.5]), z=np.array([3.25, -1.0]), gap=2
    )
    event = FaultEvent(
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
    with McapRecorder(path, metadata=METADATA) as rec:
        rec.write_frame(T0, 0x123, b"\x01\x02\xff", "ok")
        rec.write_frame(T0 + 1, 0x1ABCDEF0, b"", "unknown_id", extended=True)
        rec.write_frame(T0 + 2, 0x7FF, bytes(8), "crc", dlc=9)
        rec.write_frame(T0 + 3, 0x10, b"\x00", 'we"ird\n')
        rec.write_frame(T0 + 4, 0x11, b"\xaa", "sent")
        rec.write_sample(sample, inputs, outputs)
        rec.write_residuals(
            T0 + 6,
            300,
            ["r0", "r1"],
            np.array([0.5, np.nan]),
            [1.5, np.float32(2.0)],
            [0.0, np.inf],
        )
        rec.write_estimates(T0 + 7, 301, "actuator:voltage", {"eta": np.float64(0.9)}, {"eta": 0.1})
        rec.write_event(event)
        rec.write_status(T0 + 10, "running", 311, {"ok": 1000, "crc": 2}, np.int64(1))
        rec.write("/custom/thing", T0 + 11, {"value": np.int64(7), "list": np.arange(3)})
        assert rec.messages_written == 11

    expected = [
        (TOPIC_FRAMES, T0, {"timestamp": stamp(T0), "id": 0x123, "extended": False, "dlc": 3,
                            "data": "0102ff", "status": "ok"}),
        (TOPIC_FRAMES, T0 + 1, {"timestamp": stamp(T0 + 1), "id": 0x1ABCDEF0, "extended": True,
                                "dlc": 0, "data": "", "status": "unknown_id"}),
        (TOPIC_FRAMES, T0 + 2, {"timestamp": stamp(T0 + 2), "id": 0x7FF, "extended": False,
                                "dlc": 9, "data": "00" * 8, "status": "crc"}),
        (TOPIC_FRAMES, T0 + 3, {"timestamp": stamp(T0 + 3), "id": 0x10, "extended": False,
                                "dlc": 1, "data": "00", "status": 'we"ird\n'}),
        (TOPIC_FRAMES, T0 + 4, {"timestamp": stamp(T0 + 4), "id": 0x11, "extended": False,
                                "dlc": 1, "data": "aa", "status": "sent"}),
        (TOPIC_SAMPLES, T0 + 5, {"timestamp": stamp(T0 + 5), "k": 300, "gap": 2,
                                 "u": {"voltage": 12.0, "load": 0.5},
                                 "z": {"speed": 3.25, "current": -1.0}}),
        (TOPIC_RESIDUALS, T0 + 6, {"timestamp": stamp(T0 + 6), "k": 300,
                                   "r": {"r0": 0.5, "r1": None},
                                   "normalized": {"r0": 1.5, "r1": 2.0},
                                   "statistic": {"r0": 0.0, "r1": None}}),
        (TOPIC_ESTIMATES, T0 + 7, {"timestamp": stamp(T0 + 7), "k": 301,
                                   "hypothesis": "actuator:voltage",
                                   "estimates": {"eta": 0.9}, "variances": {"eta": 0.1}}),
        (TOPIC_EVENTS, T0 + 9, {"timestamp": stamp(T0 + 9), **event.as_dict()}),
        (TOPIC_STATUS, T0 + 10, {"timestamp": stamp(T0 + 10), "state": "running",
                                 "samples": 311, "frames": {"ok": 1000, "crc": 2},
                                 "active_faults": 1}),
        ("/custom/thing", T0 + 11, {"timestamp": stamp(T0 + 11), "value": 7, "list": [0, 1, 2]}),
    ]  # fmt: skip
    reader = read_log(path)
    got = list(reader)
    assert got == expected
    assert reader.complete and not reader.truncated and reader.messages_read == len(expected)
    assert stamp(T0) == {"sec": 1_700_000_000, "nsec": 123_456_789}
    assert list(read_log(path, topics=[TOPIC_STATUS, TOPIC_SAMPLES])) == [expected[5], expected[9]]
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
        assert summary.chunk_indexes
        assert {c.compression for c in summary.chunk_indexes} == {"zstd"}
        assert summary.statistics is not None
        assert summary.statistics.message_count == len(expected)
    with open(path, "rb") as f:
        (meta,) = make_reader(f).iter_metadata()
        assert meta.name == METADATA_NAME and meta.metadata == METADATA
    with open(path, "rb") as f:
        seeking = [
            (c.topic, m.log_time, json.loads(m.data)) for _, c, m in make_reader(f).iter_messages()
        ]
    assert seeking == expected


def test_write_after_close_raises_and_close_is_idempotent(tmp_path: Path) -> None:
    rec = McapRecorder(tmp_path / "run.mcap")
    rec.close()
    rec.close()
    with pytest.raises(ValueError, match="closed"):
        write_frames(rec, 0, 1)


def test_missing_directory_is_reported_at_start(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError):
        McapRecorder(tmp_path / "nowhere" / "run.mcap")


# --------------------------------------------------------------------------------------
# truncation and crash safety
# --------------------------------------------------------------------------------------

N_FRAMES = 5000
BURST = 50  # frames between timed flushes


def write_bursts(rec: McapRecorder, clock: FakeClock, start: int, stop: int) -> None:
    """Every BURST frames the clock jumps past flush_interval, so the write of frame i (i a
    multiple of BURST) ends the chunk holding frames i - BURST .. i - 1 before it is added."""
    for i in range(start, stop):
        if i % BURST == 0:
            clock.t += 1.0
        rec.write_frame(T0 + i * 1000, i & 0x7FF, i.to_bytes(4, "big"), "ok")


def test_truncated_files_read_back_a_prefix(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    clock = FakeClock()
    with McapRecorder(path, metadata=METADATA, flush_interval=0.5, clock=clock) as rec:
        write_bursts(rec, clock, 0, N_FRAMES)
    data = path.read_bytes()
    with open(path, "rb") as f:
        chunks = make_reader(f).get_summary().chunk_indexes
    assert len(chunks) == N_FRAMES // BURST
    expected = list(range(N_FRAMES))

    # Every chunk end (exactly the messages up to it), every chunk middle (the same prefix as
    # the previous end), one byte short of every chunk end, and a spread of other offsets.
    cut_expect: dict[int, int | None] = {}
    before = 0
    for c in chunks[::9]:
        start, end = c.chunk_start_offset, c.chunk_start_offset + c.chunk_length
        n_before = (c.message_start_time - T0) // 1000
        n_through = (c.message_end_time - T0) // 1000 + 1
        cut_expect[start + c.chunk_length // 2] = n_before
        cut_expect[end - 1] = n_before
        cut_expect[end] = n_through
        before = n_through
    assert before > 0
    for cut in [0, 1, 7, 8, 20, 40, *range(50, len(data), 2003), len(data) - 1, len(data)]:
        cut_expect.setdefault(cut, None)

    trunc = tmp_path / "trunc.mcap"
    previous_count = -1
    for cut in sorted(cut_expect):
        trunc.write_bytes(data[:cut])
        reader = read_log(trunc)
        got = frame_indices(reader)  # must not raise
        assert got == expected[: len(got)], f"not a prefix at byte {cut}"
        assert len(got) >= previous_count, f"fewer messages at byte {cut} than before it"
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
    rec = McapRecorder(path, metadata=METADATA, flush_interval=0.5, clock=clock)
    snapshots = []
    done = 0
    for stop in (1, 49, 50, 51, 1234, 2500, 4999, N_FRAMES):
        write_bursts(rec, clock, done, stop)
        done = stop
        # What a SIGKILL now would leave: the bytes in the file, without close().
        snapshots.append((stop, path.read_bytes()))
    assert rec.messages_written == N_FRAMES
    for stop, data in snapshots:
        flushed = ((stop - 1) // BURST) * BURST  # frames before the last chunk-ending write
        killed = tmp_path / f"killed-{stop}.mcap"
        killed.write_bytes(data)
        reader = read_log(killed)
        got = frame_indices(reader)
        assert reader.truncated and not reader.complete
        assert len(got) >= flushed, f"lost flushed frames after {stop} writes"
        assert got == list(range(len(got)))
        assert read_metadata(killed) == METADATA
    rec.close()
    assert frame_indices(read_log(path)) == list(range(N_FRAMES))


def test_explicit_flush_ends_the_chunk(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    rec = McapRecorder(path, flush_interval=3600.0, clock=FakeClock())
    write_frames(rec, 0, 10)
    assert frame_indices(read_log(path)) == []
    rec.flush()
    assert frame_indices(read_log(path)) == list(range(10))
    rec.close()


CHILD = """
import sys, time
from canfdi.recorder import McapRecorder

rec = McapRecorder(sys.argv[1], flush_interval=0.2)
i = 0
while True:
    rec.write_frame(time.time_ns(), i & 0x7FF, i.to_bytes(4, "big"), "ok")
    i += 1
    if i % 10 == 0:
        print(i, flush=True)
        time.sleep(0.01)  # ~1000 frames/s: far from filling a 1 MiB chunk in 2 s
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
    got = frame_indices(reader)
    assert reader.truncated
    assert got == list(range(len(got)))
    assert len(got) >= must_have


# --------------------------------------------------------------------------------------
# rotation
# --------------------------------------------------------------------------------------


def test_rotation_by_bytes(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    stale = tmp_path / "run-0009.mcap"
    stale.write_bytes(b"from an earlier run")
    unrelated = tmp_path / "run-x-0001.mcap"
    unrelated.write_bytes(b"not ours")
    limit = 20_000
    rec = McapRecorder(
        path, metadata=METADATA, rotate_bytes=limit, chunk_size=2048, clock=FakeClock()
    )
    assert not stale.exists() and unrelated.exists()
    write_frames(rec, 0, 6000)
    rec.close()

    names = [p.name for p in rec.paths]
    assert len(names) >= 4
    assert names == ["run.mcap"] + [f"run-{i:04d}.mcap" for i in range(1, len(names))]
    assert log_segments(path) == rec.paths
    assert rec.bytes_written == sum(p.stat().st_size for p in rec.paths)
    got = []
    for seg in rec.paths:
        reader = read_log(seg)
        got += frame_indices(reader)
        assert reader.complete, seg
        assert read_metadata(seg) == METADATA
        with open(seg, "rb") as f:
            summary = make_reader(f).get_summary()
            assert summary is not None and summary.statistics.message_count > 0
        # The data section overshoots by at most one chunk (2 KiB before compression) and its
        # message index; the summary comes on top.
        assert limit <= data_section_end(seg) < limit + 4096 or seg == rec.paths[-1]
    assert got == list(range(6000))


def test_rotation_by_seconds(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    clock = FakeClock(100.0)
    rec = McapRecorder(path, metadata=METADATA, rotate_seconds=10.0, clock=clock)
    for i in range(70):  # one frame every 0.5 s for 35 s
        clock.t = 100.0 + 0.5 * i
        write_frames(rec, i, i + 1)
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
        assert frame_indices(reader) == list(range(20 * j, min(20 * j + 20, 70)))
        assert reader.complete
        assert read_metadata(seg) == METADATA
    assert frame_indices(read_all(path)) == list(range(70))


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
    ("flush_interval", "chunk_size"),
    [
        (0.5, 1024 * 1024),  # the error strikes in a timed flush
        (1000.0, 1024),  # ... in a write that ends a full chunk
    ],
)
def test_disk_full_drops_then_resumes(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, flush_interval: float, chunk_size: int
) -> None:
    path = tmp_path / "run.mcap"
    clock = FakeClock()
    disk = Disk()
    rec = McapRecorder(
        path,
        metadata=METADATA,
        flush_interval=flush_interval,
        chunk_size=chunk_size,
        clock=clock,
        opener=disk.open,
    )
    caplog.set_level(logging.WARNING, logger="canfdi.recorder")

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
    got = frame_indices(read_all(path))
    assert got[:100] == list(range(100))  # flushed before the disk filled
    assert got == sorted(got) and set(got) <= set(range(300))
    assert set(range(211, 300)) <= set(got)  # a retry happens within a second of recovery
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
    write_frames(rec, 0, 5)
    assert rec.messages_dropped == 5
    disk.full = False
    clock.t = 1.0
    write_frames(rec, 5, 10)
    rec.close()
    assert rec.paths == [path]
    assert frame_indices(read_log(path)) == list(range(5, 10))
    assert read_metadata(path) == METADATA

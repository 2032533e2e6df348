"""Tests of canfdi.io.formats, the log-format registry (and canfdi.io.pycan, canfdi.io.logs):
suffix dispatch, a round trip through every writable format, damaged and missing files, and
python-can's own test logs read frame for frame as python-can reads them."""

from __future__ import annotations

import gzip
import json
import shutil
from pathlib import Path

import can
import numpy as np
import pytest

from canfdi.bus.frames import FLAG_ERROR, FLAG_EXTENDED, FLAG_FD, FLAG_REMOTE, SENT, FrameBlock
from canfdi.io.formats import (
    LogFormat,
    LogFormatError,
    LogReadError,
    format_named,
    format_of,
    formats,
    register,
)
from canfdi.io.logs import frame_blocks, metadata_of, truth_of, write_frames
from canfdi.io.pycan import RX, TX
from canfdi.io.reader import read_frames
from canfdi.io.writer import McapRecorder
from tests.conftest import REPO

T0 = 1_795_000_000_123_456_000
PYTHON_CAN_DATA = REPO / "tests" / "data" / "python-can"
WRITABLE = [f.name for f in formats() if f.writable]


def frames(n: int = 600, seed: int = 0) -> FrameBlock:
    """Drive-like frames with every odd kind: extended IDs, DLC 0-8, remote, error and CAN FD
    frames (up to 64 bytes), and statuses as the monitor records them (the monitor's own
    frames "sent")."""
    rng = np.random.default_rng(seed)
    t = T0 + np.cumsum(rng.integers(1_000, 3_000_000, n))  # whole microseconds
    ids = rng.choice([0x104, 0x105, 0x106, 0x082, 0x7FF, 0x1ABCDEF, 0x18FF1234], n)
    flags = np.where(ids > 0x7FF, FLAG_EXTENDED, 0).astype(np.uint8)
    dlc = rng.integers(0, 9, n)
    data = rng.integers(0, 256, (n, 8), dtype=np.uint8)
    data[np.arange(8)[None, :] >= dlc[:, None]] = 0  # python-can keeps no padding
    kind = rng.random(n)
    remote = kind < 0.03
    error = (kind >= 0.03) & (kind < 0.05)
    fd = (kind >= 0.05) & (kind < 0.08)
    flags[remote] |= FLAG_REMOTE
    data[remote] = 0
    dlc[remote] = 0
    flags[error] = FLAG_ERROR
    ids[error] = 0
    data[error] = 0
    dlc[error] = 0
    flags[fd] |= FLAG_FD
    long = {}
    for row in np.flatnonzero(fd).tolist():
        size = int(rng.choice([12, 16, 24, 32, 48, 64]))
        payload = rng.integers(0, 256, size, dtype=np.uint8).tobytes()
        long[row] = payload
        dlc[row] = size
        data[row] = np.frombuffer(payload[:8], dtype=np.uint8)
    status = rng.choice(["ok", "crc", "dlc", SENT, "unknown_id"], n)
    return FrameBlock(t, ids, dlc, flags, data, status=status, long=long)


def held(block: FrameBlock, fmt: LogFormat) -> np.ndarray:
    """(N,) bool: the frames ``fmt`` can write."""
    keep = np.ones(block.size, dtype=bool)
    for kind, flag in (("remote", FLAG_REMOTE), ("error", FLAG_ERROR), ("fd", FLAG_FD)):
        if kind not in fmt.holds:
            keep &= (block.flags & flag) == 0
    return keep


def usable(fmt: LogFormat) -> None:
    missing = fmt.missing()
    if missing is not None:
        pytest.skip(missing)


# ------------------------------------------------------------------------------------------
# dispatch by suffix
# ------------------------------------------------------------------------------------------


@pytest.mark.parametrize(("name", "expected"), [
    ("run.mcap", "mcap"), ("run-0001.mcap", "mcap"), ("RUN.MCAP", "mcap"),
    ("drive.asc", "asc"), ("drive.ASC", "asc"), ("drive.asc.gz", "asc.gz"),
    ("drive.2024-05-01.asc.gz", "asc.gz"), ("a.b.c.log.GZ", "log.gz"), ("x.blf", "blf"),
    ("x.blf.gz", "blf.gz"), ("x.trc", "trc"), ("x.trc.gz", "trc.gz"), ("x.csv", "csv"),
    ("x.csv.gz", "csv.gz"), ("x.db", "db"), ("x.mf4", "mf4"), ("candump-2024.log", "log"),
])
def test_a_name_maps_to_its_format(name, expected):
    assert format_of(name).name == expected
    assert format_of(Path("/some/dir") / name).name == expected


@pytest.mark.parametrize("name", ["x.xyz", "x.gz", "x.mf4.gz", "x.db.gz", "mcap", ".asc",
                                  "x", "x.mcap.bak"])
def test_an_unknown_suffix_names_the_known_ones(name):
    with pytest.raises(LogFormatError) as info:
        format_of(name)
    message = str(info.value)
    assert "\n" not in message
    for fmt in formats():
        assert fmt.suffix in message
    with pytest.raises(LogFormatError):
        frame_blocks(name)
    assert truth_of(name) is None


def test_format_names_and_capabilities():
    assert format_named("ASC").suffix == ".asc"
    with pytest.raises(LogFormatError, match="known: mcap, asc"):
        format_named("pcap")
    # Every format python-can reads and writes, and ours.
    assert {f.suffix for f in formats()} >= {".mcap", ".asc", ".blf", ".log", ".trc", ".csv",
                                             ".db", ".mf4", ".asc.gz", ".log.gz", ".trc.gz",
                                             ".csv.gz", ".blf.gz"}
    assert {"mcap", "blf", "asc", "log", "csv"} <= set(WRITABLE)
    assert not format_named("blf.gz").writable
    with pytest.raises(LogFormatError, match=r"cannot write \.blf\.gz"):
        format_named("blf.gz").check(write=True)
    assert [f.name for f in formats() if f.records] == ["mcap"]


def test_a_format_that_needs_a_missing_package_says_how_to_install_it(tmp_path):
    fmt = LogFormat("demo", ".demo", "a demo format", lambda p, n, r: iter(()),
                    requires="no_such_module_canfdi", extra="demo")
    assert "pip install 'canfdi[demo]'" in fmt.missing()
    with pytest.raises(LogFormatError, match="no_such_module_canfdi"):
        fmt.frame_blocks(tmp_path / "x.demo")
    mf4 = format_named("mf4")
    assert mf4.requires == "asammdf" and mf4.extra == "mf4"


def test_register_adds_a_format_by_suffix(tmp_path):
    path = tmp_path / "x.canfditest"
    path.write_text("3\n")

    def read(p, n, received):
        count = int(Path(p).read_text())
        none = np.zeros(count, dtype=np.uint8)
        yield FrameBlock(np.arange(count), np.arange(count), none, none,
                         np.zeros((count, 8), dtype=np.uint8))

    register(LogFormat("canfditest", ".canfditest", "a test format", read))
    try:
        assert [b.size for b in frame_blocks(path)] == [3]
        assert metadata_of(path) == {} and truth_of(path) is None
    finally:
        from canfdi.io import formats as registry

        registry._FORMATS.pop("canfditest")
    with pytest.raises(ValueError, match="lower case"):
        register(LogFormat("bad", "BAD", "bad", read))


# ------------------------------------------------------------------------------------------
# round trips
# ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", WRITABLE)
def test_every_writable_format_round_trips_through_the_registry(tmp_path, name):
    fmt = format_named(name)
    usable(fmt)
    src = frames()
    path = tmp_path / f"frames{fmt.suffix}"
    keep = held(src, fmt)
    written = write_frames(path, [src.slice(0, 250), src.slice(250, src.size)])
    assert written.frames == keep.sum() and written.skipped == (~keep).sum()
    assert format_of(path) is fmt
    back = FrameBlock.concat(list(frame_blocks(path, 100, received=False)))
    src = src.select(keep)
    assert back.size == src.size

    error = (src.flags & FLAG_ERROR) != 0
    if name == "mcap":  # ours keeps everything, statuses included
        np.testing.assert_array_equal(back.id, src.id)
        np.testing.assert_array_equal(back.flags, src.flags)
        np.testing.assert_array_equal(back.dlc, src.dlc)
        assert back.status.tolist() == src.status.tolist()
    else:  # a bus error frame has no identifier in some formats
        np.testing.assert_array_equal(back.id[~error], src.id[~error])
        np.testing.assert_array_equal(back.extended[~error], src.extended[~error])
        np.testing.assert_array_equal((back.flags & FLAG_ERROR) != 0, error)
        np.testing.assert_array_equal(back.flags & FLAG_REMOTE, src.flags & FLAG_REMOTE)
    assert back.payloads() == src.payloads()

    t_back, t_src = back.t_ns, src.t_ns
    if not fmt.absolute_time:
        t_back, t_src = t_back - t_back[0], t_src - t_src[0]
    # python-can carries time as float seconds since the epoch: 0.24 us of rounding
    slack = 0 if fmt.resolution_ns == 1 else 250
    np.testing.assert_allclose(t_back, t_src, rtol=0, atol=fmt.resolution_ns + slack)

    if fmt.directions and name != "mcap":  # python-can writes error frames without one
        sent = src.status == SENT
        assert back.status[~error].tolist() == np.where(sent, TX, RX)[~error].tolist()
    elif name != "mcap":
        assert set(back.status.tolist()) == {RX}


def test_received_frames_leave_out_the_monitors_own_in_mcap_only(tmp_path):
    src = frames(200)
    sent = int((src.status == SENT).sum())
    assert sent
    for name in ("mcap", "asc", "log"):
        path = tmp_path / f"x.{name}"
        write_frames(path, [src])
        received = FrameBlock.concat(list(frame_blocks(path)))
        everything = FrameBlock.concat(list(frame_blocks(path, received=False)))
        assert everything.size == src.size
        # A python-can log's Tx frames were sent on the bus by the node that logged them.
        assert received.size == (src.size - sent if name == "mcap" else src.size)


def test_python_can_blocks_hold_frames_per_block(tmp_path):
    path = tmp_path / "x.log"
    write_frames(path, [frames(1000)])
    assert [b.size for b in frame_blocks(path, 300)] == [300, 300, 300, 100]


def test_a_gzipped_blf_is_read_and_cannot_be_written(tmp_path):
    src = frames(300)
    plain = tmp_path / "x.blf"
    write_frames(plain, [src])
    packed = tmp_path / "x.blf.gz"
    with open(plain, "rb") as f, gzip.open(packed, "wb") as g:
        shutil.copyfileobj(f, g)
    a = FrameBlock.concat(list(frame_blocks(plain)))
    b = FrameBlock.concat(list(frame_blocks(packed)))
    assert a.size == b.size == 300 and a.payloads() == b.payloads()
    np.testing.assert_array_equal(a.t_ns, b.t_ns)
    with pytest.raises(LogFormatError):
        write_frames(tmp_path / "y.blf.gz", [src])


def test_writing_replaces_an_existing_sqlite_log(tmp_path):
    path = tmp_path / "x.db"
    write_frames(path, [frames(100)])
    write_frames(path, [frames(50)])
    assert sum(b.size for b in frame_blocks(path)) == 50


def test_metadata_and_truth_where_the_format_has_them(tmp_path):
    truth = [{"target": "actuator", "index": 0, "onset_sample": 100, "eta": 2.0}]
    path = tmp_path / "demo.mcap"
    with McapRecorder(path, metadata={"truth_json": json.dumps(truth), "version": "x"}) as rec:
        rec.write_frames(frames(10), None)
    assert metadata_of(path)["version"] == "x"
    assert truth_of(path) == truth
    asc = tmp_path / "demo.asc"
    write_frames(asc, frame_blocks(path, received=False))
    assert metadata_of(asc) == {} and truth_of(asc) is None


# ------------------------------------------------------------------------------------------
# missing and damaged logs
# ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("fmt", formats(), ids=lambda f: f.name)
def test_a_missing_log_is_file_not_found(tmp_path, fmt):
    usable(fmt)
    path = tmp_path / f"missing{fmt.suffix}"
    with pytest.raises(FileNotFoundError):
        list(fmt.frame_blocks(path))
    assert not path.exists()  # python-can's SQLite reader would have created it


@pytest.mark.parametrize("fmt", formats(), ids=lambda f: f.name)
def test_random_bytes_are_one_read_error_in_every_format(tmp_path, fmt):
    usable(fmt)
    path = tmp_path / f"damaged{fmt.suffix}"
    path.write_bytes(np.random.default_rng(3).integers(0, 256, 5000, dtype=np.uint8).tobytes())
    with pytest.raises(LogReadError) as info:
        list(frame_blocks(path))
    message = str(info.value)
    assert "\n" not in message and str(path) in message and fmt.suffix in message
    assert truth_of(path) is None


def test_a_truncated_mcap_reads_its_complete_blocks(tmp_path):
    path = tmp_path / "cut.mcap"
    with McapRecorder(path, block_frames=100, chunk_size=4096) as rec:
        rec.write_frames(frames(1000), None)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    back = list(frame_blocks(path, received=False))
    assert 0 < sum(b.size for b in back) < 1000


# ------------------------------------------------------------------------------------------
# python-can's own test logs
# ------------------------------------------------------------------------------------------

PYTHON_CAN_LOGS = sorted(p for p in PYTHON_CAN_DATA.iterdir() if p.suffix != ".md")


def test_the_python_can_logs_are_here():
    assert {format_of(p).name for p in PYTHON_CAN_LOGS} == {"asc", "asc.gz", "blf", "trc"}
    assert sum(p.stat().st_size for p in PYTHON_CAN_LOGS) < 200_000


def _message_tuple(m: can.Message) -> tuple:
    return (round(m.timestamp * 1e6), m.arbitration_id, bytes(m.data), m.is_extended_id,
            m.is_remote_frame, m.is_error_frame, m.is_fd, m.is_rx)


def _frame_tuples(block: FrameBlock) -> list[tuple]:
    return [(round(t / 1e3), i, d, bool(f & FLAG_EXTENDED), bool(f & FLAG_REMOTE),
             bool(f & FLAG_ERROR), bool(f & FLAG_FD), s == RX)
            for t, i, d, f, s in zip(block.t_ns.tolist(), block.id.tolist(), block.payloads(),
                                     block.flags.tolist(), block.status.tolist(), strict=True)]


@pytest.mark.parametrize("path", PYTHON_CAN_LOGS, ids=lambda p: p.name)
def test_python_can_test_logs_read_every_frame_as_python_can_does(path):
    with can.LogReader(str(path)) as reader:
        expected = [_message_tuple(m) for m in reader]
    got = _frame_tuples(FrameBlock.concat(list(frame_blocks(path, 5))))
    assert len(got) == len(expected) > 0
    assert got[0] == expected[0] and got[-1] == expected[-1]
    assert got == expected


def test_the_gzipped_python_can_log_reads_as_its_plain_twin(tmp_path):
    packed = PYTHON_CAN_DATA / "test_CanMessage.asc.gz"
    plain = tmp_path / "test_CanMessage.asc"
    plain.write_bytes(gzip.decompress(packed.read_bytes()))
    assert _frame_tuples(FrameBlock.concat(list(frame_blocks(packed)))) == \
        _frame_tuples(FrameBlock.concat(list(frame_blocks(plain))))


def test_an_exported_mcap_reads_back_as_the_mcap(tmp_path):
    src = frames(500)
    path = tmp_path / "run.mcap"
    with McapRecorder(path, block_frames=64) as rec:
        rec.write_frames(src, None)
    out = tmp_path / "run.trc.gz"
    written = write_frames(out, frame_blocks(path, received=False))
    keep = held(src, format_of(out))
    assert written == (keep.sum(), (~keep).sum())
    back = FrameBlock.concat(list(frame_blocks(out)))
    assert back.payloads() == read_frames(path).select(keep).payloads()

"""python-can reads and writes canfdi's MCAP logs through its plug-in entry points
(canfdi.io.pycan_mcap): `can.LogReader`, `can.logconvert` and `can.player` in a fresh
interpreter, as a user runs them, against canfdi's own readers, python-can's BLF reader and
python-can's own test logs."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import can
import numpy as np
import pytest

from canfdi.bus.frames import FLAG_ERROR, FLAG_EXTENDED, FLAG_FD, FLAG_REMOTE, SENT, FrameBlock
from canfdi.io.formats import format_of
from canfdi.io.logs import frame_blocks, metadata_of
from canfdi.io.pycan import RX, TX
from canfdi.io.pycan_mcap import McapReader, McapWriter
from canfdi.io.reader import read_frames
from canfdi.io.segments import log_segments
from canfdi.io.writer import McapRecorder
from tests.conftest import REPO

T0 = 1_795_000_000_000_000_000
PYTHON_CAN_DATA = REPO / "tests" / "data" / "python-can"
PYTHON_CAN_LOGS = sorted(p for p in PYTHON_CAN_DATA.iterdir() if p.suffix != ".md")

SHORT_DEMO = """\
name: plugin_short
description: DC motor, actuator fault at 1 s, 4 s long (python-can plug-in tests)
plant: dc_motor
duration: 4.0
seed: 1
noise: {measurement: 0.01, process: 0.0}
faults:
  - {target: actuator, index: 0, onset: 1.0, eta: 2.0, lambda: 10.0}
"""

# Every message of a log as python-can gives it, in a fresh interpreter: the entry points
# installed with canfdi are what finds the reader.
DUMP = """\
import json, sys, can
with can.LogReader(sys.argv[1]) as reader:
    rows = [[m.timestamp, m.arbitration_id, m.is_extended_id, m.is_remote_frame,
             m.is_error_frame, m.is_fd, m.dlc, bytes(m.data).hex(), m.is_rx, m.channel]
            for m in reader]
print(type(reader).__module__ + "." + type(reader).__name__)
print(json.dumps(rows))
"""


def run(*args: str | Path, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, cwd=REPO)


def expected_rows(block: FrameBlock) -> list[list]:
    """What python-can should give for the frames of a canfdi log."""
    rx = ~np.isin(block.status, [SENT, TX])
    return [[t / 1e9, i, bool(f & FLAG_EXTENDED), bool(f & FLAG_REMOTE), bool(f & FLAG_ERROR),
             bool(f & FLAG_FD), d, p.hex(), bool(r), None]
            for t, i, f, d, p, r in zip(block.t_ns.tolist(), block.id.tolist(),
                                        block.flags.tolist(), block.dlc.tolist(),
                                        block.payloads(), rx.tolist(), strict=True)]


def dumped(path: Path) -> tuple[str, list[list]]:
    res = run("-c", DUMP, path)
    assert res.returncode == 0, res.stderr
    kind, rows = res.stdout.splitlines()
    return kind, json.loads(rows)


@pytest.fixture(scope="module")
def demo_log(tmp_path_factory) -> Path:
    """A monitor run (canfdi demo): the drive's frames and the monitor's own "sent" ones."""
    tmp = tmp_path_factory.mktemp("plugin_demo")
    scenario = tmp / "short.yaml"
    scenario.write_text(SHORT_DEMO)
    path = tmp / "demo.mcap"
    res = subprocess.run([sys.executable, "-m", "canfdi", "demo", "--no-live", "--scenario",
                          str(scenario), "-o", str(path)], capture_output=True, text=True,
                         timeout=180, cwd=REPO)
    assert res.returncode == 0, res.stderr
    return path


@pytest.fixture(scope="module")
def odd_log(tmp_path_factory) -> Path:
    """A rotated log (several segments) with every kind of frame: extended, remote, error,
    CAN FD up to 64 bytes, statuses of the monitor (and "tx", a converted log's)."""
    path = tmp_path_factory.mktemp("plugin_odd") / "odd.mcap"
    rng = np.random.default_rng(1)
    n = 2000
    t = T0 + np.cumsum(rng.integers(1, 3_000_000, n))  # any nanosecond
    ids = rng.choice([0x104, 0x105, 0x082, 0x7FF, 0x1ABCDEF, 0x18FF1234], n)
    dlc = rng.integers(0, 9, n)
    data = rng.integers(0, 256, (n, 8), dtype=np.uint8)
    flags = np.where(ids > 0x7FF, FLAG_EXTENDED, 0).astype(np.uint8)
    kind = rng.random(n)
    flags[kind < 0.03] |= FLAG_REMOTE
    flags[(kind >= 0.03) & (kind < 0.05)] = FLAG_ERROR
    long = {}
    for row in np.flatnonzero(kind >= 0.95).tolist():
        size = int(rng.choice([12, 16, 32, 64]))
        long[row] = rng.integers(0, 256, size, dtype=np.uint8).tobytes()
        dlc[row] = size
        flags[row] |= FLAG_FD
    status = rng.choice(["ok", "crc", "dlc", SENT, TX], n)
    block = FrameBlock(t, ids, dlc, flags, data, status=status, long=long)
    with McapRecorder(path, block_frames=100, chunk_size=4096, rotate_bytes=20_000) as rec:
        for start in range(0, n, 250):
            rec.write_frames(block.slice(start, start + 250))
    return path


# ------------------------------------------------------------------------------------------
# reading: can.LogReader
# ------------------------------------------------------------------------------------------


def test_python_can_finds_the_plugin_and_canfdi_keeps_mcap_its_own():
    res = run("-c", "import can.io.logger as w, can.io.player as r\n"
                    "r._update_reader_plugins(); w._update_writer_plugins()\n"
                    "print(r.MESSAGE_READERS['.mcap'].__name__, "
                    "w.MESSAGE_WRITERS['.mcap'].__name__)")
    assert res.returncode == 0, res.stderr
    assert res.stdout.split() == ["McapReader", "McapWriter"]
    fmt = format_of("run.mcap")  # canfdi's registry: its own reader, not python-can's
    assert fmt.name == "mcap" and fmt.records and fmt.segments


def test_log_reader_gives_every_frame_of_a_monitor_run(demo_log):
    kind, rows = dumped(demo_log)
    assert kind == "canfdi.io.pycan_mcap.McapReader"
    src = read_frames(demo_log)
    assert (src.status == SENT).sum() >= 1 and (src.status == "ok").sum() > 100
    assert rows == expected_rows(src)
    assert sum(not r[8] for r in rows) == (src.status == SENT).sum()  # is_rx False: sent


def test_log_reader_reads_every_segment_and_every_kind_of_frame(odd_log):
    assert len(log_segments(odd_log)) >= 3
    _, rows = dumped(odd_log)
    src = read_frames(odd_log)
    assert len(rows) == src.size == 2000
    assert rows == expected_rows(src)
    assert {(r[3], r[4], r[5]) for r in rows} == {(False, False, False), (True, False, False),
                                                  (False, True, False), (False, False, True)}
    assert max(len(r[7]) for r in rows) == 128  # a 64-byte CAN FD payload, whole


def test_a_reader_left_early_stops_and_a_missing_log_says_so(odd_log, tmp_path):
    reader = McapReader(odd_log, channel="can0")  # a canfdi log does not record the bus
    first = next(iter(reader))
    assert first.timestamp == read_frames(odd_log).t_ns[0] / 1e9 and first.channel == "can0"
    reader.stop()  # ends the read-ahead thread
    with pytest.raises(FileNotFoundError):
        McapReader(tmp_path / "none.mcap")
    with pytest.raises(TypeError, match="file name"), open(odd_log, "rb") as file:
        McapReader(file)


# ------------------------------------------------------------------------------------------
# can.logconvert and can.player
# ------------------------------------------------------------------------------------------


def test_logconvert_to_blf_keeps_every_frame_and_its_direction(demo_log, tmp_path):
    blf = tmp_path / "demo.blf"
    res = run("-m", "can.logconvert", demo_log, blf)
    assert res.returncode == 0, res.stderr
    src = read_frames(demo_log)
    with can.BLFReader(str(blf)) as reader:
        back = list(reader)
    assert len(back) == src.size
    assert [m.arbitration_id for m in back] == src.id.tolist()
    assert [bytes(m.data) for m in back] == src.payloads()
    assert [m.is_rx for m in back] == (src.status != SENT).tolist()
    times = np.array([round(m.timestamp * 1e9) for m in back])
    np.testing.assert_allclose(times, src.t_ns, rtol=0, atol=1000)  # BLF: ns, via floats


def test_player_plays_every_frame_on_a_virtual_bus(demo_log):
    res = run("-m", "can.player", "-i", "virtual", "--ignore-timestamps", "-v", demo_log)
    assert res.returncode == 0, res.stderr
    played = [line for line in res.stdout.splitlines() if line.startswith("Timestamp:")]
    src = read_frames(demo_log)
    assert len(played) == src.size
    assert [int(line.split("ID:")[1].split()[0], 16) for line in played] == src.id.tolist()


def test_logconvert_from_blf_writes_a_log_canfdi_reads(demo_log, tmp_path):
    blf, mcap = tmp_path / "demo.blf", tmp_path / "back.mcap"
    assert run("-m", "can.logconvert", demo_log, blf).returncode == 0
    res = run("-m", "can.logconvert", blf, mcap)
    assert res.returncode == 0, res.stderr
    with can.BLFReader(str(blf)) as reader:
        messages = list(reader)
    back = read_frames(mcap)
    assert back.size == len(messages) == read_frames(demo_log).size
    assert back.id.tolist() == [m.arbitration_id for m in messages]
    assert back.payloads() == [bytes(m.data) for m in messages]
    assert back.status.tolist() == [RX if m.is_rx else TX for m in messages]
    assert np.abs(back.t_ns - [m.timestamp * 1e9 for m in messages]).max() < 1000
    # canfdi's registry reads it as its own log: frames, a python-can Tx frame kept as heard
    assert FrameBlock.concat(list(frame_blocks(mcap))).size == back.size
    assert metadata_of(mcap) == {}


# ------------------------------------------------------------------------------------------
# python-can's own test logs, through canfdi's MCAP and back
# ------------------------------------------------------------------------------------------


def held(m: can.Message) -> tuple:
    """What a canfdi MCAP frame holds of a message. Not the channel, nor CAN FD's BRS and ESI
    bits; the DLC as the payload's length (a remote frame's: the length it requests)."""
    return (round(m.timestamp * 1e6), m.arbitration_id, m.is_extended_id, m.is_remote_frame,
            m.is_error_frame, m.is_fd, m.dlc if m.is_remote_frame else len(m.data),
            bytes(m.data), m.is_rx)


@pytest.mark.parametrize("log", PYTHON_CAN_LOGS, ids=lambda p: p.name)
def test_python_can_test_logs_convert_to_mcap_and_back(log, tmp_path):
    mcap = tmp_path / "log.mcap"
    res = run("-m", "can.logconvert", log, mcap)
    assert res.returncode == 0, res.stderr
    with can.LogReader(str(log)) as reader:
        original = [held(m) for m in reader]
    with can.LogReader(str(mcap)) as reader:
        assert [held(m) for m in reader] == original
    assert read_frames(mcap).size == len(original) > 0
    if log.suffix == ".blf":  # and back into the format it came in
        blf = tmp_path / "back.blf"
        assert run("-m", "can.logconvert", mcap, blf).returncode == 0
        with can.LogReader(str(blf)) as reader:
            assert [held(m) for m in reader] == original


# ------------------------------------------------------------------------------------------
# the writer, in this interpreter
# ------------------------------------------------------------------------------------------


def test_the_writer_records_directions_and_refuses_what_it_cannot(tmp_path):
    path = tmp_path / "w.mcap"
    with McapWriter(path) as writer:
        for k in range(3000):
            writer(can.Message(timestamp=1.0 + k * 1e-3, arbitration_id=k % 0x800,
                               data=bytes([k % 256]) * (k % 9), is_rx=k % 7 != 0))
        assert writer.file_size() > 0
    back = read_frames(path)
    assert back.size == 3000
    assert back.status.tolist() == [TX if k % 7 == 0 else RX for k in range(3000)]
    assert back.payloads() == [bytes([k % 256]) * (k % 9) for k in range(3000)]
    with pytest.raises(ValueError, match="append"):
        McapWriter(tmp_path / "a.mcap", append=True)
    with pytest.raises(TypeError, match="file name"), open(tmp_path / "f.mcap", "wb") as file:
        McapWriter(file)


def test_a_foreign_mcap_is_a_clear_error_not_zero_frames(tmp_path):
    """Issue 28: python-can's LogReader on an MCAP canfdi did not write (a robot's poses, by
    the mcap package's own writer) read as 0 frames; it now names the file's topics."""
    import json

    import can
    import pytest
    from mcap.writer import Writer

    path = tmp_path / "robot.mcap"
    with open(path, "wb") as f:
        writer = Writer(f)
        writer.start()
        schema = writer.register_schema("pose", "jsonschema", b'{"type": "object"}')
        channel = writer.register_channel("/robot/pose", "json", schema)
        for i in range(10):
            writer.add_message(channel, i, json.dumps({"x": i}).encode(), i)
        writer.finish()
    with pytest.raises(ValueError, match=r"did not write \(its topics: /robot/pose\)"):
        can.LogReader(str(path))

"""`canfdi export`: every raw frame of a log, read back by python-can and by the registry, for
each format the registry writes."""

import subprocess
import sys

import can
import numpy as np
import pytest

from canfdi.bus.frames import FLAG_ERROR, FLAG_EXTENDED, FLAG_REMOTE, FrameBlock
from canfdi.io.formats import formats
from canfdi.io.logs import frame_blocks
from canfdi.io.reader import read_frames
from canfdi.io.writer import McapRecorder
from tests.cli import canfdi_main as main
from tests.conftest import REPO

T0 = 1_795_000_000_000_000_000


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    """A monitor log with drive frames, the monitor's own, and every odd kind of frame."""
    path = tmp_path_factory.mktemp("export") / "run.mcap"
    rng = np.random.default_rng(0)
    n = 3000
    t = T0 + np.cumsum(rng.integers(50_000, 3_000_000, n))
    ids = rng.choice([0x104, 0x105, 0x106, 0x082, 0x300, 0x1ABCDEF], n)
    dlc = rng.integers(0, 9, n)
    data = rng.integers(0, 256, (n, 8), dtype=np.uint8)
    flags = np.where(ids > 0x7FF, FLAG_EXTENDED, 0)
    flags[rng.random(n) < 0.02] |= FLAG_REMOTE
    flags[rng.random(n) < 0.01] = FLAG_ERROR
    status = rng.choice(["ok", "crc", "dlc", "sent", "unknown_id"], n)
    with McapRecorder(path, block_frames=512) as rec:
        rec.write_frames(FrameBlock(t, ids, dlc, flags, data), status)
    return path


@pytest.mark.parametrize(("fmt", "resolution_s"),
                         [("blf", 1e-5), ("asc", 1e-6), ("log", 1e-6), ("csv", 1e-6)])
def test_export_round_trips_every_frame(log, tmp_path, fmt, resolution_s):
    out = tmp_path / f"frames.{fmt}"
    res = subprocess.run([sys.executable, "-m", "canfdi", "export", str(log), "--format", fmt,
                          "-o", str(out), "--no-progress"], capture_output=True, text=True,
                         timeout=120, cwd=REPO)
    assert res.returncode == 0, res.stderr
    src = read_frames(log)
    back = list(can.LogReader(str(out)))
    assert len(back) == src.size == 3000
    error = (src.flags & FLAG_ERROR) != 0
    ids = np.array([m.arbitration_id for m in back])
    if fmt == "csv":
        np.testing.assert_array_equal(ids, src.id)
    else:  # a bus error frame has no identifier in these formats
        np.testing.assert_array_equal(ids[~error], src.id[~error])
    times = np.array([m.timestamp for m in back])
    expected = src.t_ns / 1e9
    if fmt == "asc":  # ASC times count from its trigger block, whose date has 1 ms resolution
        times, expected = times - times[0], (src.t_ns - src.t_ns[0]) / 1e9
    np.testing.assert_allclose(times, expected, rtol=0, atol=resolution_s * 1.01)
    np.testing.assert_array_equal(np.array([m.is_extended_id for m in back])[~error],
                                  ((src.flags & FLAG_EXTENDED) != 0)[~error])
    np.testing.assert_array_equal([m.is_error_frame for m in back], error)
    remote = (src.flags & FLAG_REMOTE) != 0
    if fmt != "csv":  # python-can's CSV keeps the remote bit; its other readers too
        np.testing.assert_array_equal([m.is_remote_frame for m in back], remote)
    data_frames = ~remote & ~error
    for m, payload, keep in zip(back, src.payloads(), data_frames, strict=True):
        if keep:
            assert bytes(m.data) == payload
    if fmt in ("blf", "asc", "log"):  # the formats with a direction
        np.testing.assert_array_equal(np.array([m.is_rx for m in back])[~error],
                                      (src.status != "sent")[~error])


def test_export_of_a_missing_log_exits_2(tmp_path):
    res = subprocess.run([sys.executable, "-m", "canfdi", "export", str(tmp_path / "no.mcap"),
                          "--format", "blf"], capture_output=True, text=True, timeout=60,
                         cwd=REPO)
    assert res.returncode == 2 and "no.mcap" in res.stderr


WRITABLE = [f for f in formats() if f.writable]


@pytest.mark.parametrize("fmt", WRITABLE, ids=lambda f: f.name)
def test_export_writes_every_format_of_the_registry(log, tmp_path, capsys, fmt):
    if fmt.missing():
        pytest.skip(fmt.missing())
    out = tmp_path / f"frames{fmt.suffix}"
    assert main(["export", str(log), "--format", fmt.name, "-o", str(out), "--no-progress"]) == 0
    src = read_frames(log)
    held = np.ones(src.size, dtype=bool)
    for kind, flag in (("remote", FLAG_REMOTE), ("error", FLAG_ERROR)):
        if kind not in fmt.holds:
            held &= (src.flags & flag) == 0
    line = capsys.readouterr().err.strip()
    assert f"{held.sum():,} frames -> {out}" in line
    assert ("left out" in line) == (not held.all())
    back = FrameBlock.concat(list(frame_blocks(out, received=False)))
    src = src.select(held)
    assert back.size == src.size
    data = ((src.flags & (FLAG_REMOTE | FLAG_ERROR)) == 0).tolist()  # others carry no data
    assert [p for p, d in zip(back.payloads(), data, strict=True) if d] == \
        [p for p, d in zip(src.payloads(), data, strict=True) if d]
    if fmt.name != "mcap":  # python-can reads what it wrote
        with can.LogReader(str(out)) as reader:
            assert sum(1 for _ in reader) == held.sum()


def test_export_takes_the_format_from_the_output_name_and_any_log(log, tmp_path, capsys):
    asc = tmp_path / "a.asc.gz"
    assert main(["export", str(log), "-o", str(asc), "--no-progress"]) == 0
    blf = tmp_path / "a.blf"
    assert main(["export", str(asc), "-o", str(blf), "--no-progress"]) == 0  # not an MCAP
    assert main(["export", str(blf), "--format", "log", "--no-progress"]) == 0
    candump = tmp_path / "a.log"  # the default name: the input's, with the format's suffix
    src = read_frames(log)
    back = FrameBlock.concat(list(frame_blocks(candump)))
    assert back.size == src.size
    # through .asc, whose times count from its start, with microsecond resolution
    np.testing.assert_allclose(back.t_ns - back.t_ns[0], src.t_ns - src.t_ns[0], rtol=0,
                               atol=1500)
    capsys.readouterr()
    assert main(["export", str(log), "--no-progress"]) == 2
    assert "--format or -o" in capsys.readouterr().err
    assert main(["export", str(log), "-o", str(tmp_path / "x.blf.gz")]) == 2
    assert "cannot write .blf.gz" in capsys.readouterr().err


@pytest.mark.parametrize("suffix", [".asc", ".asc.gz"])
def test_export_asc_dates_the_measurement_start_and_keeps_absolute_times(log, tmp_path, suffix):
    import gzip

    from canfdi.io.pycan import ASC_VERSION, asc_date

    out = tmp_path / f"frames{suffix}"
    assert main(["export", str(log), "-o", str(out), "--no-progress"]) == 0
    src = read_frames(log)
    start = asc_date(round(src.t_ns[0] / 1000))
    opener = gzip.open if suffix.endswith(".gz") else open
    with opener(out, "rt") as file:
        head = [next(file).rstrip("\n") for _ in range(5)]
    assert head == [f"date {start}", "base hex  timestamps absolute", "internal events logged",
                    f"// version {ASC_VERSION}", f"Begin Triggerblock {start}"]
    with opener(out, "rt") as file, can.ASCReader(file, relative_timestamp=False) as reader:
        back = list(reader)
    assert len(back) == src.size
    times = np.array([round(m.timestamp * 1e9) for m in back])
    np.testing.assert_allclose(times, src.t_ns, rtol=0, atol=1000)  # to the microsecond

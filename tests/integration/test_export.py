"""`canfdi export`: every raw frame of an MCAP, read back by python-can, for each format."""

import subprocess
import sys

import can
import numpy as np
import pytest

from canfdi.bus.frames import FLAG_ERROR, FLAG_EXTENDED, FLAG_REMOTE, FrameBlock
from canfdi.io.reader import read_frames
from canfdi.io.writer import McapRecorder
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

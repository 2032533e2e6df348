"""recording.keep_days / keep_mib (canfdi.io.retention): which of a daemon's logs go."""

from __future__ import annotations

import os
from pathlib import Path

from canfdi.io.retention import LogFile, expired, prune_logs, run_log_files

MIB = 2**20


def _file(name: str, age_days: float, mib: float, now: float = 1e9) -> LogFile:
    return LogFile(Path(name), now - age_days * 86400, int(mib * MIB))


def test_the_oldest_go_until_the_rest_fits_and_the_open_segment_stays():
    files = [_file("a", 3, 40), _file("b", 2, 40), _file("c", 1, 40), _file("d", 0, 40)]
    gone = expired(files, 1e9, None, 100 * MIB, current=[Path("a")])
    assert [f.path.name for f in gone] == ["b", "c"]  # 160 MiB -> 80: a is being written
    both = expired(files, 1e9, 2.5, 100 * MIB)
    assert [f.path.name for f in both] == ["a", "b"]
    assert expired(files, 1e9, None, None) == []


def test_ties_in_time_are_broken_by_name():
    files = [_file("y", 1, 10), _file("x", 1, 10)]
    assert [f.path.name for f in expired(files, 1e9, None, 10 * MIB)] == ["x"]


def test_only_the_files_run_named_for_this_config_are_considered(tmp_path):
    names = ["m-20260101-000000.mcap", "m-20260101-000000-0001.mcap",
             "m-20260101-000000-12345.mcap", "m-2026.mcap", "mm-20260101-000000.mcap",
             "m-20260101-000000.mcap.bak", "x.mcap"]
    for name in names:
        (tmp_path / name).write_bytes(b"12")
    (tmp_path / "m-20260102-000000.mcap").mkdir()  # not a file
    found = sorted(f.path.name for f in run_log_files(tmp_path, "m"))
    assert found == sorted(names[:3])
    assert run_log_files(tmp_path / "missing", "m") == []
    for name in names:
        os.utime(tmp_path / name, (0, 0))
    removed = prune_logs(tmp_path, "m", 1e9, 1, None)
    assert sorted(f.path.name for f in removed) == sorted(names[:3])
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        [*names[3:], "m-20260102-000000.mcap"])

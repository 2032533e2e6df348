"""ASC as CANalyzer writes it (canfdi.io.pycan): the header dates the measurement start, to the
millisecond, in English whatever the locale, and python-can's ASCReader with absolute times
gives back every frame's time to the microsecond."""

from __future__ import annotations

import gzip
import os
import shutil
import subprocess
import sys
from datetime import datetime, timedelta
from pathlib import Path

import can
import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from canfdi.bus.frames import FLAG_EXTENDED, SENT, FrameBlock
from canfdi.io.pycan import ASC_VERSION, asc_date, write_blocks
from tests.conftest import REPO


def local_us(*args: int) -> int:
    """Microseconds since the epoch of a local date and time."""
    return round(datetime(*args).timestamp() * 1e6)


def block_at(t_us: list[int] | np.ndarray, status: list[str] | None = None) -> FrameBlock:
    t_us = np.asarray(t_us, dtype=np.int64)
    n = len(t_us)
    ids = np.where(np.arange(n) % 3 == 2, 0x18FF1234, 0x104 + np.arange(n) % 3)
    data = (np.arange(n * 8, dtype=np.int64).reshape(n, 8) % 256).astype(np.uint8)
    return FrameBlock(t_us * 1000, ids, np.full(n, 8), np.where(ids > 0x7FF, FLAG_EXTENDED, 0),
                      data, status=np.array(status or ["ok"] * n))


def read_absolute(path: Path, opener=open) -> list[can.Message]:
    with opener(path, "rt") as file, can.ASCReader(file, relative_timestamp=False) as reader:
        return list(reader)


def times_us(messages: list[can.Message]) -> list[int]:
    return [round(m.timestamp * 1e6) for m in messages]


# ------------------------------------------------------------------------------------------
# the date
# ------------------------------------------------------------------------------------------


@pytest.mark.parametrize(("when", "text"), [
    ((2026, 3, 7, 9, 5, 7, 11559), "Sat Mar 7 09:05:07.011 am 2026"),
    ((2026, 3, 7, 13, 21, 51, 11559), "Sat Mar 7 01:21:51.011 pm 2026"),
    ((2026, 11, 24, 0, 0, 0, 999999), "Tue Nov 24 12:00:00.999 am 2026"),  # midnight: 12 am
    ((2026, 11, 24, 12, 0, 0, 0), "Tue Nov 24 12:00:00.000 pm 2026"),  # noon: 12 pm
    ((2027, 12, 31, 23, 59, 59, 1000), "Fri Dec 31 11:59:59.001 pm 2027"),
])
def test_the_date_is_written_as_canalyzer_writes_it(when, text):
    assert asc_date(local_us(*when)) == text


def test_the_header_is_the_measurement_start_and_the_times_count_from_it(tmp_path):
    start = local_us(2026, 3, 7, 13, 21, 51, 11559)
    path = tmp_path / "run.asc"
    write_blocks(path, ".asc", [block_at([start, start + 1441, start + 2_000_000],
                                         ["ok", SENT, "ok"])])
    lines = path.read_text().splitlines()
    assert lines == [
        "date Sat Mar 7 01:21:51.011 pm 2026",
        "base hex  timestamps absolute",
        "internal events logged",
        f"// version {ASC_VERSION}",
        "Begin Triggerblock Sat Mar 7 01:21:51.011 pm 2026",
        " 0.000000 Start of measurement",
        " 0.000559 1  104             Rx   d 8 00 01 02 03 04 05 06 07",
        " 0.002000 1  105             Tx   d 8 08 09 0A 0B 0C 0D 0E 0F",
        " 2.000559 1  18FF1234x       Rx   d 8 10 11 12 13 14 15 16 17",
        "End TriggerBlock",
    ]


# ------------------------------------------------------------------------------------------
# absolute times read back exactly
# ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("when", [(2026, 3, 7, 9, 5, 7, 11559), (2026, 3, 7, 15, 5, 7, 11559),
                                  (2026, 11, 24, 0, 0, 0, 11559), (2026, 11, 24, 12, 0, 0, 0)],
                         ids=["morning", "afternoon", "midnight", "noon"])
def test_python_can_reads_every_absolute_time_back_to_the_microsecond(tmp_path, when):
    start = local_us(*when)
    t = start + np.array([0, 1, 999, 1000, 250_000, 3_600_000_001, 86_400_000_000])
    path = tmp_path / "run.asc"
    write_blocks(path, ".asc", [block_at(t)])
    back = read_absolute(path)
    assert times_us(back) == t.tolist()
    assert [m.arbitration_id for m in back] == block_at(t).id.tolist()


@settings(max_examples=60, deadline=None)
@given(start=st.integers(local_us(2000, 1, 1), local_us(2037, 12, 31)),
       steps=st.lists(st.integers(-3_000, 10_000_000), min_size=1, max_size=20))
def test_any_start_and_frames_read_back_exactly(tmp_path_factory, start, steps):
    # a local time of a daylight-saving change (said twice, or never) names no single instant
    second = start // 1_000_000
    assume(round(datetime.fromtimestamp(second).timestamp()) == second)
    assume(round((datetime.fromtimestamp(second) + timedelta(days=1)).timestamp())
           == second + 86_400)
    t = start + np.concatenate([[0], np.cumsum(steps)])  # some frames out of order
    path = tmp_path_factory.mktemp("asc") / "run.asc"
    write_blocks(path, ".asc", [block_at(t)])
    assert times_us(read_absolute(path)) == t.tolist()
    assert path.read_text().startswith(f"date {asc_date(start)}\n")


def test_a_frame_before_the_start_opens_a_new_trigger_block(tmp_path):
    start = local_us(2026, 5, 4, 10, 0, 0, 500_000)
    t = [start, start + 10, start - 2_500, start + 20]
    path = tmp_path / "run.asc"
    write_blocks(path, ".asc", [block_at(t)])
    text = path.read_text()
    assert text.count("Begin Triggerblock") == 2 and text.count("End TriggerBlock") == 2
    assert "Begin Triggerblock Mon May 4 10:00:00.497 am 2026" in text
    assert times_us(read_absolute(path)) == t


def test_gzip_asc_is_written_the_same_way(tmp_path):
    start = local_us(2026, 7, 1, 16, 30, 0, 11559)
    t = start + np.arange(0, 5_000_000, 123_457)
    plain, packed = tmp_path / "run.asc", tmp_path / "run.asc.gz"
    write_blocks(plain, ".asc", [block_at(t)])
    write_blocks(packed, ".asc", [block_at(t)], compressed=True)
    assert gzip.decompress(packed.read_bytes()).decode() == plain.read_text()
    assert times_us(read_absolute(packed, gzip.open)) == t.tolist()


def test_a_log_without_frames_still_has_its_header(tmp_path):
    path = tmp_path / "empty.asc"
    write_blocks(path, ".asc", [])
    lines = path.read_text().splitlines()
    assert lines[0].startswith("date ") and lines[4].startswith("Begin Triggerblock ")
    assert lines[-1] == "End TriggerBlock" and read_absolute(path) == []


# ------------------------------------------------------------------------------------------
# whatever the locale and the time zone
# ------------------------------------------------------------------------------------------

WRITE = """\
import locale, sys
from datetime import datetime
from pathlib import Path
import numpy as np
from canfdi.bus.frames import FrameBlock
from canfdi.io.pycan import write_blocks
if sys.argv[2] != "C":
    locale.setlocale(locale.LC_ALL, sys.argv[2])
start = round(datetime(2026, 10, 6, 14, 7, 9, 11559).timestamp() * 1e6)
t = (start + np.array([0, 1, 5_000_000])) * 1000
write_blocks(Path(sys.argv[1]), ".asc",
             [FrameBlock(t, [1, 2, 3], [1, 1, 1], [0, 0, 0], np.zeros((3, 8), np.uint8))])
print(datetime.now().strftime("%a %b %p"), start)
"""

READ = """\
import sys, can
with can.ASCReader(sys.argv[1], relative_timestamp=False) as reader:
    print(*[round(m.timestamp * 1e6) for m in reader])
"""


@pytest.fixture(scope="module")
def german(tmp_path_factory) -> dict[str, str]:
    """An environment whose de_DE.UTF-8 locale exists (compiled here when the system has
    none): weekday and month names in German, no am/pm."""
    if shutil.which("localedef") is None:
        pytest.skip("no localedef to make a German locale with")
    where = tmp_path_factory.mktemp("locales")
    res = subprocess.run(["localedef", "-i", "de_DE", "-f", "UTF-8", str(where / "de_DE.UTF-8")],
                         capture_output=True, text=True, timeout=60)
    if res.returncode not in (0, 1) or not (where / "de_DE.UTF-8").exists():
        pytest.skip(f"cannot make a German locale: {res.stderr.strip()[:200]}")
    return {**os.environ, "LOCPATH": str(where)}


@pytest.mark.parametrize("zone", ["UTC", "America/New_York", "Asia/Kolkata"])
def test_a_german_process_writes_english_dates_in_any_time_zone(tmp_path, german, zone):
    path = tmp_path / "run.asc"
    env = {**german, "TZ": zone}
    res = subprocess.run([sys.executable, "-c", WRITE, str(path), "de_DE.UTF-8"], env=env,
                         capture_output=True, text=True, timeout=60, cwd=REPO)
    assert res.returncode == 0, res.stderr
    *names, start = res.stdout.split()
    assert names[0] in ("Mo", "Di", "Mi", "Do", "Fr", "Sa", "So")  # the locale is German
    # the measurement start in the zone's local time, as CANalyzer writes it
    assert path.read_text().splitlines()[0] == "date Tue Oct 6 02:07:09.011 pm 2026"
    env = {k: v for k, v in env.items() if not k.startswith("LC_") and k != "LANG"}
    res = subprocess.run([sys.executable, "-c", READ, str(path)], env=env, capture_output=True,
                         text=True, timeout=60, cwd=REPO)
    assert res.returncode == 0, res.stderr
    start = int(start)
    assert [int(x) for x in res.stdout.split()] == [start, start + 1, start + 5_000_000]

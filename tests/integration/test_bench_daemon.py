"""`canfdi bench --daemon-frames`: the daemon soak's accounting, on a short run.

The RSS bound itself is the bench's figure (README), not asserted here: these check that the
soak feeds what it says, that its traffic stays valid across repeats, and that every rotated
segment is read back and accounted for.
"""

from __future__ import annotations

import json
import math

import pytest

from canfdi.config import load_config
from canfdi.io.reader import read_frames
from canfdi.io.segments import log_segments
from canfdi.tools.bench import loop_traffic, run_daemon_soak
from tests.cli import canfdi_main as main

CONFIG = "deploy/config/dc_motor.yaml"
FRAMES = 200_000
LOOP = 6400  # 64 s of the drive: a multiple of 256 (alive counter) and 800 (its reference)


@pytest.fixture(scope="module")
def config():
    return load_config(CONFIG)


@pytest.fixture(scope="module")
def soak(config, tmp_path_factory):
    workdir = tmp_path_factory.mktemp("soak")
    result = run_daemon_soak(config, FRAMES, 256 * 1024, workdir=workdir, warmup=40_000,
                             loop_samples=LOOP)
    return result, workdir


@pytest.mark.slow
def test_soak_feeds_and_records_every_frame(soak):
    r, workdir = soak
    assert r["daemon_frames"] == FRAMES
    assert r["daemon_loop_samples"] == LOOP
    # 3 frames a period: the run wraps round the stretch several times.
    assert r["daemon_loop_frames"] == 3 * LOOP
    assert r["daemon_segments"] > 10  # 256 KiB segments
    assert r["daemon_segments_verified"] == r["daemon_segments"]
    assert r["daemon_frames_in_segments"] == FRAMES
    assert r["daemon_messages_dropped"] == 0
    assert r["daemon_unreadable_segments"] == {}
    # Read back, then deleted: nothing is left in the log directory.
    assert list(workdir.iterdir()) == []


@pytest.mark.slow
def test_soak_traffic_stays_valid_across_repeats(soak):
    r, _ = soak
    stats = r["daemon_frame_stats"]
    assert stats["frames_received"] == FRAMES
    assert stats["frames_invalid"] == 0
    assert stats["samples_missing"] == 0
    assert stats["samples_broken"] <= 1  # the run may stop inside a period
    assert r["daemon_samples"] == math.ceil(FRAMES / 3)
    assert r["daemon_false_alarms"] == 0


@pytest.mark.slow
def test_soak_reports_rss_from_warmup_on(soak):
    r, _ = soak
    assert r["daemon_rss_warmup_frames"] == 40_000
    series = r["daemon_rss_series"]
    assert series[0][0] >= 40_000 and series[-1][0] == FRAMES
    assert [f for f, _ in series] == sorted(f for f, _ in series)
    assert r["daemon_rss_start_mib"] == pytest.approx(series[0][1], abs=1e-3)
    assert r["daemon_rss_end_mib"] == pytest.approx(series[-1][1], abs=1e-3)
    assert r["daemon_rss_max_mib"] >= max(m for _, m in series) - 1e-3
    assert r["daemon_rss_max_growth_mib"] == pytest.approx(
        r["daemon_rss_max_mib"] - r["daemon_rss_start_mib"])
    assert r["daemon_rss_end_growth_mib"] == pytest.approx(
        r["daemon_rss_end_mib"] - r["daemon_rss_start_mib"])
    assert r["daemon_fps"] > 0 and r["daemon_service_fps"] >= r["daemon_fps"]


def test_kept_segments_are_the_log_family(config, tmp_path):
    r = run_daemon_soak(config, 100_000, 256 * 1024, workdir=tmp_path, warmup=10_000,
                        keep_segments=True, loop_samples=LOOP)
    files = log_segments(tmp_path / f"{config.name}-soak.mcap")
    assert len(files) == r["daemon_segments"] > 1
    assert read_frames(files[0]).size == r["daemon_frames_in_segments"] == 100_000


def test_a_stretch_off_the_counter_period_shows_at_its_seams(config, tmp_path):
    # 6000 periods is no multiple of 256: the alive counters jump at every repeat, and the
    # monitor says so (the check the soak's 0 invalid frames rests on).
    r = run_daemon_soak(config, 100_000, 1 << 20, workdir=tmp_path, warmup=10_000,
                        loop_samples=6000)
    assert r["daemon_frame_stats"]["frames_invalid"] > 0


def test_loop_traffic_repeats_one_stretch():
    frames, period_ns = loop_traffic("dc_motor_nominal", LOOP, search=640)
    assert period_ns == LOOP * 10_000_000  # 100 Hz
    assert frames.size == 3 * LOOP
    span = int(frames.t_ns[-1] - frames.t_ns[0])
    assert 0 < span < period_ns


@pytest.mark.parametrize("args, message", [
    (["--daemon-frames", "10"], "--daemon-frames: at least 100000"),
    (["--daemon-frames", "100000", "--rotate-mib", "0"], "--rotate-mib: must be > 0"),
])
def test_bad_soak_options_exit_2(args, message, capsys):
    assert main(["bench", "--config", CONFIG, *args]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err


@pytest.mark.slow
def test_cli_soak_prints_json(capsys):
    assert main(["bench", "--config", CONFIG, "--daemon-frames", "100000", "--rotate-mib",
                 "0.5", "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    assert r["daemon_frames"] == r["daemon_frames_in_segments"] == 100_000
    assert r["daemon_rotate_mib"] == 0.5 and r["daemon_segments"] > 1
    assert r["daemon_log_dir"] is None  # a temporary directory, removed

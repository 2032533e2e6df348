"""Reliability (issue 7, in part): garbage on the bus, and bad configs on every verb."""

import subprocess
import sys

import numpy as np
import pytest
import yaml

from canfdi.bus.frames import FrameBlock
from canfdi.config import load_config
from canfdi.io.reader import read_frames
from canfdi.io.writer import McapRecorder
from canfdi.monitor import Monitor
from canfdi.tools.bench import make_traffic
from tests.conftest import REPO, feed_frame_log

CONFIG = REPO / "deploy" / "config" / "dc_motor.yaml"


def _fuzzed_stream(n_valid: int, n_garbage: int, seed: int = 0):
    """Valid drive traffic with drops, duplicates, swaps and counter jumps, mixed with random
    frames: random and our own IDs, any DLC including CAN FD lengths, random payloads."""
    rng = np.random.default_rng(seed)
    tr = make_traffic(n_valid)
    t, ids, dlc, P = (tr.t_ns.copy(), tr.id.astype(np.int64), tr.dlc.astype(np.int64),
                      tr.data.copy())
    keep = rng.random(len(ids)) > 0.02
    dup = np.flatnonzero(rng.random(len(ids)) < 0.02)
    order = np.concatenate([np.flatnonzero(keep), dup])
    order.sort(kind="stable")
    t, ids, dlc, P = t[order], ids[order], dlc[order], P[order]
    swap = np.flatnonzero(rng.random(len(ids) - 1) < 0.01)
    for a in swap:  # neighbours exchanged: reordering within and across periods
        for arr in (ids, dlc, P):
            arr[[a, a + 1]] = arr[[a + 1, a]]
    jump = rng.random(len(ids)) < 0.005
    P[jump, 1] = rng.integers(0, 256, jump.sum())  # counter jumps (the CRC now fails too)
    ours = np.array([0x080, 0x081, 0x082, 0x083, 0x104, 0x105, 0x106])
    g_ids = np.where(rng.random(n_garbage) < 0.5, rng.choice(ours, n_garbage),
                     rng.integers(0, 2048, n_garbage))
    g_dlc = rng.choice([0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64], n_garbage)
    g_flags = np.where(g_dlc > 8, 8, 0) | np.where(rng.random(n_garbage) < 0.05, 1, 0)
    g_P = rng.integers(0, 256, (n_garbage, 8), dtype=np.uint8)
    g_t = rng.integers(int(t.min()), int(t.max()), n_garbage)
    all_t = np.concatenate([t, g_t])
    mix = np.argsort(all_t, kind="stable")
    flags = np.concatenate([np.zeros(len(ids), dtype=np.int64), g_flags])[mix]
    return FrameBlock(all_t[mix], np.concatenate([ids, g_ids])[mix],
                      np.concatenate([dlc, g_dlc])[mix], flags, np.concatenate([P, g_P])[mix])


def test_fuzz_1e6_frames_no_exception_every_frame_logged_no_fault(tmp_path):
    frames = _fuzzed_stream(500_000, 500_000)
    monitor = Monitor(load_config(CONFIG))
    recorder = McapRecorder(tmp_path / "fuzz.mcap", metadata=monitor.metadata())
    monitor.sink = recorder
    for i in range(0, frames.size, 4096):
        monitor.on_frames(frames.slice(i, i + 4096))
    monitor.finish()
    recorder.close()
    stats = monitor.assembler.stats
    assert stats["frames_received"] == frames.size > 990_000
    assert stats["frames_valid"] + stats["frames_invalid"] == frames.size
    assert stats["invalid_by_reason"]["crc"] > 0 and stats["invalid_by_reason"]["fd"] > 0
    logged = read_frames(tmp_path / "fuzz.mcap")
    assert logged.size == frames.size  # every frame logged, valid or not
    np.testing.assert_array_equal(logged.id, frames.id)
    # Nothing is detected from garbage. A random frame passes the 8-bit CRC once in 256; with a
    # counter ahead of the pending one (half of them) it would open a sample of garbage values
    # (7 detections in this stream, each ending "unexplained"): a counter further ahead than
    # the time since the last frame allows is a "jump" unless the next frame confirms it.
    assert stats["invalid_by_reason"]["jump"] > 0
    assert monitor.events == []


def test_fuzz_stream_gives_the_same_statuses_frame_by_frame_and_in_blocks():
    frames = _fuzzed_stream(30_000, 30_000, seed=1)
    block = Monitor(load_config(CONFIG), diagnose=False)
    block.on_frames(frames)
    single = Monitor(load_config(CONFIG), diagnose=False)
    t, ids, dlc, P, flags = frames.t_ns, frames.id, frames.dlc, frames.data, frames.flags
    for i in range(frames.size):
        single.on_frame(int(t[i]), int(ids[i]), P[i, : min(dlc[i], 8)].tobytes(),
                        is_extended=bool(flags[i] & 1), is_fd=bool(flags[i] & 8))
    # A frame's DLC beyond its bytes only exists in the block form (FD lengths): compare the
    # counters that do not depend on it.
    for key in ("frames_received", "samples_complete"):
        assert block.assembler.stats[key] == single.assembler.stats[key]


def _bad(tmp_path, path: str, value) -> str:
    data = yaml.safe_load(CONFIG.read_text())
    node = data
    keys = path.split(".")
    for key in keys[:-1]:
        node = node[key]
    node[keys[-1]] = value
    out = tmp_path / "bad.yaml"
    out.write_text(yaml.safe_dump(data))
    return str(out)


@pytest.mark.parametrize(
    ("path", "value", "field"),
    [
        ("model.B", [[0.1, 0.2], [0.1, 0.2], [0.0, 0.0]], "signals.inputs"),
        ("model.C", [[1, 0], [0, 1]], "model.C"),
        ("signals.outputs", ["i_f", "i_a", "i_total", "omega_r"], "bus.map.i_total"),
        ("design.sensor_window", -2, "design.sensor_window"),
        ("detection.drift", -1.0, "detection.drift"),
        ("detection.false_alarm_interval", 1.0, "detection.false_alarm_interval"),
        ("identification.settle_rel_std", 5.0, "identification.settle_rel_std"),
        ("bus.dbc", "no_such_drive", "bus.dbc"),
        ("method", "kalman", "method"),
    ],
)
def test_bad_configs_exit_2_naming_the_field(tmp_path, path, value, field):
    bad = _bad(tmp_path, path, value)
    for verb in (["run", "--config", bad, "--no-record"],
                 ["replay", str(tmp_path / "bad.yaml"), "--config", bad],
                 ["demo", "--config", bad]):
        res = subprocess.run([sys.executable, "-m", "canfdi", *verb], capture_output=True,
                             text=True, timeout=120, cwd=REPO)
        assert res.returncode == 2, (verb, res.stderr)
        lines = res.stderr.strip().splitlines()
        assert len(lines) == 1 and field in lines[0], (verb, res.stderr)


def test_missing_config_file_exits_2(tmp_path):
    res = subprocess.run([sys.executable, "-m", "canfdi", "run", "--config",
                          str(tmp_path / "none.yaml")], capture_output=True, text=True,
                         timeout=60, cwd=REPO)
    assert res.returncode == 2 and "file not found" in res.stderr


def _diagnose_log(log) -> Monitor:
    return feed_frame_log(Monitor(load_config(CONFIG)), log)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_drops_and_jitter_give_the_same_diagnoses_and_no_false_alarm(seed):
    """dc_motor_consecutive with 5% of frames dropped at random and up to 1 ms of jitter per
    frame (frames of a period reorder): the three faults are diagnosed as on a clean bus, with
    estimates within tolerance, and nothing else is detected."""
    from canfdi.firmware_sim.emitter import Disturbance, frame_log
    from canfdi.firmware_sim.scenario import load_scenario

    scenario = load_scenario("dc_motor_consecutive")
    clean = _diagnose_log(frame_log(scenario))
    log = frame_log(scenario, Disturbance(drop=0.05, jitter=0.001, seed=seed))
    assert 0.04 < log.stats.frames_dropped / (3 * len(log.chunk)) < 0.06
    lossy = _diagnose_log(log)
    stats = lossy.assembler.stats
    assert stats["samples_broken"] > 0.1 * len(log.chunk)  # about 1 - 0.95^3 of the samples
    assert stats["frames_invalid"] == 0  # reordering within a period is not a defect
    # (The parity method's refinements aside: between diagnoses, with no detection, or a
    # re-detection of what an accepted estimate left, diagnosed as more of the same fault.)
    refining = {e.detected_sample for e in lossy.events if e.kind == "refined"}
    kinds = [e.kind for e in lossy.events if e.kind not in ("refined", "named")
             and not (e.kind == "detected" and e.sample in refining)]
    assert kinds == ["detected", "accepted"] * 3, kinds  # no false alarm, nothing unexplained
    ref = [e for e in clean.events if e.kind == "accepted"]
    got = [e for e in lossy.events if e.kind == "accepted"]
    assert [(e.target, e.index) for e in got] == [(e.target, e.index) for e in ref] == \
        [("actuator", 0), ("sensor", 0), ("sensor", 1)]
    truth = {"eta": 2.0, "lambda": 10.0}
    for e, r in zip(got, ref, strict=True):
        assert abs(e.onset_sample - r.onset_sample) <= 10
        for key, value in e.estimates.items():
            expected = truth.get(key, r.estimates[key])
            assert value == pytest.approx(expected, rel=0.03), (e.name, key)
        # Accepted before the next fault (1000 samples apart): diagnosis keeps up.
        assert e.accepted_sample - e.onset_sample < 1000

"""canfdi.bus.clock: the trigger and grid clocks (streaming equals block, values, ages, lost
triggers, duplicates) on a small vendor-style bus with no E2E."""

from __future__ import annotations

import dataclasses
import itertools

import cantools
import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from canfdi.bus.clock import LatestValueClock, make_clock
from canfdi.bus.dbc import BusMap
from canfdi.bus.frames import (
    FLAG_ERROR,
    FLAG_EXTENDED,
    FLAG_REMOTE,
    STATUS_NAMES,
    FrameBlock,
)
from canfdi.config import load_config
from canfdi.core.settings import BusConfig, ClockConfig, E2EConfig
from tests.conftest import REPO

DT_NS = 10_000_000
_DBC = """VERSION ""
NS_ :
BS_:
BU_: MASTER DRIVE
BO_ 128 SYNC: 0 MASTER
BO_ 513 COMMAND: 2 MASTER
 SG_ Target : 0|16@1- (0.01,0) [-327.68|327.67] "V" DRIVE
BO_ 385 FEEDBACK: 6 DRIVE
 SG_ Speed : 0|16@1- (0.01,0) [-327.68|327.67] "rad/s" MASTER
 SG_ Current : 16|16@1- (0.001,0) [-32.768|32.767] "A" MASTER
 SG_ Alive : 32|4@1+ (1,0) [0|15] "" MASTER
BO_ 641 FEEDBACK2: 4 DRIVE
 SG_ Field : 0|16@1- (0.001,0) [-32.768|32.767] "A" MASTER
 SG_ Total : 16|16@1- (0.001,0) [-32.768|32.767] "A" MASTER
BO_ 1793 HEARTBEAT: 1 DRIVE
 SG_ State : 0|8@1+ (1,0) [0|255] "" MASTER
"""
MAP = {"V": ("COMMAND", "Target"), "i_f": ("FEEDBACK2", "Field"),
       "i_a": ("FEEDBACK", "Current"), "i_f_plus_i_a": ("FEEDBACK2", "Total"),
       "omega_r": ("FEEDBACK", "Speed")}


def _bus_map(tmp_path, clock: ClockConfig) -> BusMap:
    from canfdi.core.settings import SignalRef

    (tmp_path / "drive.dbc").write_text(_DBC)
    base = load_config(REPO / "deploy" / "config" / "dc_motor.yaml")
    bus = BusConfig(dbc="drive.dbc", e2e=E2EConfig(default="none"), clock=clock,
                    map={k: SignalRef(*v) for k, v in MAP.items()})
    config = dataclasses.replace(base, path=tmp_path / "monitor.yaml", bus=bus)
    return BusMap.from_config(config)


def _traffic(n: int, seed: int = 0, lose: float = 0.0):
    """n periods of SYNC, COMMAND, FEEDBACK, FEEDBACK2 (heartbeat every 10), some frames
    lost; returns (FrameBlock, the values sent per period (n, 5) in model order)."""
    db = cantools.database.load_string(_DBC, database_format="dbc")
    rng = np.random.default_rng(seed)
    rows, truth = [], np.zeros((n, 5))
    for k in range(n):
        t = k * DT_NS
        v, i_f, i_a, omega = (rng.uniform(-50, 50), rng.uniform(0, 2), rng.uniform(0, 20),
                              rng.uniform(80, 120))
        truth[k] = [v, i_f, i_a, i_f + i_a, omega]
        frames = [(0, 128, b""),
                  (100_000, 513, db.get_message_by_name("COMMAND").encode({"Target": v})),
                  (300_000, 385, db.get_message_by_name("FEEDBACK").encode(
                      {"Speed": omega, "Current": i_a, "Alive": k % 16})),
                  (400_000, 641, db.get_message_by_name("FEEDBACK2").encode(
                      {"Field": i_f, "Total": i_f + i_a}))]
        if k % 10 == 0:
            frames.append((500_000, 1793, bytes([5])))
        for offset, fid, data in frames:
            if lose and rng.random() < lose:
                continue
            rows.append((t + offset, fid, data))
    data = np.zeros((len(rows), 8), dtype=np.uint8)
    for i, (_, _, payload) in enumerate(rows):
        data[i, : len(payload)] = np.frombuffer(payload, np.uint8)
    block = FrameBlock(np.array([r[0] for r in rows]), np.array([r[1] for r in rows]),
                       np.array([len(r[2]) for r in rows]), np.zeros(len(rows), np.uint8), data)
    return block, truth


def _stream(clock, block: FrameBlock):
    statuses, samples = [], []
    payloads = block.payloads()
    for i in range(block.size):
        f = int(block.flags[i])
        status, got = clock.push(int(block.t_ns[i]), int(block.id[i]), payloads[i],
                                 is_extended=bool(f & FLAG_EXTENDED),
                                 is_remote=bool(f & FLAG_REMOTE), is_error=bool(f & FLAG_ERROR))
        statuses.append(status)
        samples += got
    return statuses, samples


def _blocks(clock, block: FrameBlock, cuts):
    statuses, ks, us, zs, ts, gaps = [], [], [], [], [], []
    bounds = [0, *cuts, block.size]
    for a, b in itertools.pairwise(bounds):
        log = clock.push_batch(block.slice(a, b))
        statuses += [STATUS_NAMES[c] for c in log.statuses]
        ks += log.k.tolist()
        ts += log.timestamp_ns.tolist()
        gaps += log.gap.tolist()
        us.append(log.u)
        zs.append(log.z)
    return statuses, ks, ts, gaps, np.vstack(us), np.vstack(zs)


@pytest.mark.parametrize("clock", [ClockConfig("trigger", message="SYNC"),
                                   ClockConfig("trigger", message="FEEDBACK2"),
                                   ClockConfig("grid")])
def test_streaming_equals_blocks_cut_anywhere(tmp_path, clock):
    bus_map = _bus_map(tmp_path, clock)
    block, _ = _traffic(300, lose=0.05)
    statuses, samples = _stream(make_clock(bus_map, 0.01, clock), block)
    for cuts in ([], [1, 2, 3, 50, 51], list(range(7, block.size, 7))):
        b_stat, ks, ts, gaps, U, Z = _blocks(make_clock(bus_map, 0.01, clock), block, cuts)
        assert b_stat == statuses
        assert ks == [s.k for s in samples] and ts == [s.timestamp_ns for s in samples]
        assert gaps == [s.gap for s in samples]
        np.testing.assert_array_equal(U, np.array([s.u for s in samples]))
        np.testing.assert_array_equal(Z, np.array([s.z for s in samples]))


def test_a_sync_trigger_closes_the_previous_period_with_its_values(tmp_path):
    clock = make_clock(_bus_map(tmp_path, ClockConfig("trigger", message="SYNC")), 0.01,
                       ClockConfig("trigger", message="SYNC"))
    block, truth = _traffic(50)
    log = clock.push_batch(block)
    # SYNC k+1 closes period k: sample k holds period k's values (at the DBC resolution);
    # the first SYNC only starts the clock, so 50 periods make 49 samples, all whole.
    assert log.k.tolist() == list(range(49))
    np.testing.assert_allclose(np.hstack([log.u, log.z]), truth[:49], atol=0.006)
    assert log.stats["samples_complete"] == 49 and log.stats["samples_broken"] == 0


def test_a_lost_trigger_is_a_gap_and_an_old_value_is_missing(tmp_path):
    cfg = ClockConfig("trigger", message="SYNC", max_age=0.012)
    clock = make_clock(_bus_map(tmp_path, cfg), 0.01, cfg)
    block, _ = _traffic(20)
    sync = np.flatnonzero(block.id == 128)
    keep = np.ones(block.size, dtype=bool)
    keep[sync[5]] = False  # SYNC 5 lost: it would close period 4; the next is k = 5, gap 1
    feedback2 = np.flatnonzero(block.id == 641)
    keep[feedback2[8]] = False  # FEEDBACK2 of period 8 lost: its values are missing at SYNC 9
    log = clock.push_batch(block.select(keep))
    assert log.k.tolist() == [k for k in range(19) if k != 4]
    assert log.gap.tolist() == [0] * 4 + [1] + [0] * 13
    row = log.k.tolist().index(8)
    assert np.isnan(log.z[row, [0, 2]]).all() and not np.isnan(log.z[row, [1, 3]]).any()


def test_the_grid_samples_between_frames_and_holds_fresh_values_only(tmp_path):
    cfg = ClockConfig("grid")  # period dt, phase dt / 2
    clock = make_clock(_bus_map(tmp_path, cfg), 0.01, cfg)
    block, truth = _traffic(40)
    log = clock.push_batch(block)
    # Instants at t0 + 5 ms + k dt: every frame of period k is before instant k.
    assert log.k.tolist() == list(range(39))
    assert (np.diff(log.timestamp_ns) == DT_NS).all()
    np.testing.assert_allclose(np.hstack([log.u, log.z]), truth[:39], atol=0.006)
    # A silent drive: once max_age has passed, every value is missing.
    late = FrameBlock([int(block.t_ns[-1]) + 50 * DT_NS], [1793], [1], [0],
                      np.array([[5, 0, 0, 0, 0, 0, 0, 0]], np.uint8))
    log = clock.push_batch(late)
    assert len(log.k) > 45 and np.isnan(log.u[3:]).all() and np.isnan(log.z[3:]).all()


def test_a_repeated_alive_count_is_a_duplicate(tmp_path):
    from canfdi.core.settings import SignalRef

    (tmp_path / "drive.dbc").write_text(_DBC)
    base = load_config(REPO / "deploy" / "config" / "dc_motor.yaml")
    bus = BusConfig(dbc="drive.dbc", clock=ClockConfig("trigger", message="SYNC"),
                    map={k: SignalRef(*v) for k, v in MAP.items()},
                    e2e=E2EConfig(default="none", messages={"FEEDBACK": {
                        "profile": "counter", "signal": "Alive"}}))
    config = dataclasses.replace(base, path=tmp_path / "monitor.yaml", bus=bus)
    bus_map = BusMap.from_config(config)
    clock = LatestValueClock(bus_map, 0.01, "trigger")
    block, _ = _traffic(10)
    again = np.flatnonzero(block.id == 385)[3]
    doubled = FrameBlock.concat([block.slice(0, again + 1), block.slice(again, block.size)])
    log = clock.push_batch(doubled)
    assert [STATUS_NAMES[c] for c in log.statuses].count("duplicate") == 1
    streamed, _ = _stream(LatestValueClock(bus_map, 0.01, "trigger"), doubled)
    assert streamed == [STATUS_NAMES[c] for c in log.statuses]


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), lose=st.floats(0.0, 0.3))
def test_property_trigger_streaming_equals_one_block(tmp_path_factory, seed, lose):
    tmp = tmp_path_factory.mktemp("clock")
    cfg = ClockConfig("trigger", message="FEEDBACK")
    bus_map = _bus_map(tmp, cfg)
    block, _ = _traffic(40, seed=seed, lose=lose)
    statuses, samples = _stream(make_clock(bus_map, 0.01, cfg), block)
    b_stat, ks, _, _, U, Z = _blocks(make_clock(bus_map, 0.01, cfg), block, [])
    assert b_stat == statuses and ks == [s.k for s in samples]
    np.testing.assert_array_equal(U, np.array([s.u for s in samples]).reshape(-1, 1))
    np.testing.assert_array_equal(Z, np.array([s.z for s in samples]).reshape(len(samples), -1))


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), lose=st.floats(0.0, 0.3),
       jitter_ms=st.floats(0.0, 6.0), kind=st.sampled_from(["SYNC", "FEEDBACK2", "grid"]),
       cuts=st.lists(st.integers(1, 200), max_size=6))
# A stray stamped after the first valid frame but arriving before it closed the first grid
# instant in a block, not one frame at a time.
@example(seed=1372506, lose=0.25, jitter_ms=6.0, kind="grid", cuts=[])
def test_property_one_frame_at_a_time_equals_blocks_on_a_disordered_bus(
        tmp_path_factory, seed, lose, jitter_ms, kind, cuts):
    """push (the live, scalar path) and push_batch agree frame for frame on traffic with lost
    frames, arrival order off the timestamps' by up to a few ms, error frames, polls (RTR),
    29-bit and unknown IDs mixed in."""
    cfg = ClockConfig("grid") if kind == "grid" else ClockConfig("trigger", message=kind)
    bus_map = _bus_map(tmp_path_factory.mktemp("clock"), cfg)
    block, _ = _traffic(40, seed=seed, lose=lose)
    rng = np.random.default_rng(seed)
    m = 30
    strays = FrameBlock(rng.integers(0, 40 * DT_NS, m), rng.choice([385, 641, 0x7E0, 0x1ABCDE], m),
                        rng.integers(0, 9, m), rng.choice([0, FLAG_ERROR, FLAG_REMOTE,
                                                           FLAG_EXTENDED], m),
                        rng.integers(0, 256, (m, 8)).astype(np.uint8))
    both = FrameBlock.concat([block, strays])
    jitter = rng.uniform(-jitter_ms, jitter_ms, both.size) * 1e6
    both = both.select(np.argsort(both.t_ns + jitter, kind="stable"))
    statuses, samples = _stream(make_clock(bus_map, 0.01, cfg), both)
    b_stat, ks, ts, gaps, U, Z = _blocks(make_clock(bus_map, 0.01, cfg), both,
                                         sorted({c for c in cuts if c < both.size}))
    assert b_stat == statuses
    assert ks == [s.k for s in samples] and ts == [s.timestamp_ns for s in samples]
    assert gaps == [s.gap for s in samples]
    np.testing.assert_array_equal(U, np.array([s.u for s in samples]).reshape(len(ks), -1))
    np.testing.assert_array_equal(Z, np.array([s.z for s in samples]).reshape(len(ks), -1))


def _with_times(block: FrameBlock, t_ns: np.ndarray) -> FrameBlock:
    return FrameBlock(np.asarray(t_ns, dtype=np.int64), block.id, block.dlc, block.flags,
                      block.data)


_CLOCKS = [ClockConfig("trigger", message="SYNC"), ClockConfig("trigger", message="FEEDBACK2"),
           ClockConfig("grid")]
_OFFSETS = [3600, 86400, -3600, -1.7e9]  # an hour, a day, an hour back, back to 1970


@pytest.mark.parametrize("clock", _CLOCKS)
@pytest.mark.parametrize("off_s", _OFFSETS)
def test_one_frame_with_a_wild_timestamp_is_dropped(tmp_path, clock, off_s):
    """A frame stamped far from the drive's time (a merged log's stray copy) is a time_jump:
    the samples are those of the clean bus, in streaming and in blocks."""
    bus_map = _bus_map(tmp_path, clock)
    block, _ = _traffic(300)
    clean = _stream(make_clock(bus_map, 0.01, clock), block)[1]
    t = block.t_ns.copy()
    feedback2 = np.flatnonzero(block.id == 641)
    t[feedback2[150]] += round(off_s * 1e9)
    wild = _with_times(block, t)
    statuses, samples = _stream(make_clock(bus_map, 0.01, clock), wild)
    assert statuses.count("time_jump") == 1
    lost = [s.k for s in clean if s.k not in {x.k for x in samples}]
    assert len(samples) >= len(clean) - 1 and len(lost) <= 1
    assert max(s.k for s in samples) <= max(s.k for s in clean) + 1
    b_stat, ks, *_ = _blocks(make_clock(bus_map, 0.01, clock), wild, [7, 400, 401, 700])
    assert b_stat == statuses and ks == [s.k for s in samples]


@pytest.mark.parametrize("clock", _CLOCKS)
@pytest.mark.parametrize("off_s", _OFFSETS)
def test_a_step_of_the_clock_is_followed_with_a_bounded_pause(tmp_path, clock, off_s):
    """The wall clock steps (NTP, a gateway without a real-time clock) mid-run: a few frames
    go as time_jump, then the clock follows; the samples the step adds are at most the bound
    (64 periods), never the step's hundreds of thousands; the step is counted once."""
    bus_map = _bus_map(tmp_path, clock)
    block, _ = _traffic(300)
    t = block.t_ns.copy()
    t[t >= 150 * DT_NS] += round(off_s * 1e9)
    stepped = _with_times(block, t)
    c = make_clock(bus_map, 0.01, clock)
    statuses, samples = _stream(c, stepped)
    assert c.stats["clock_steps"] == 1
    assert 1 <= statuses.count("time_jump") <= 8
    assert 280 <= len(samples) and max(s.k for s in samples) <= 300 + 64 + 2
    b_stat, ks, ts, *_ = _blocks(make_clock(bus_map, 0.01, clock), stepped, [7, 400, 401, 700])
    assert b_stat == statuses and ks == [s.k for s in samples]
    assert ts == [s.timestamp_ns for s in samples]

"""SampleAssembler: the bus contract on clean, damaged and shuffled drive traffic.

Traffic comes from canfdi.firmware_sim (the dc_motor actuator scenario on motor_drive.dbc: DRIVE_CMD
0x104, DRIVE_CURRENTS 0x105, DRIVE_SPEED 0x106 every 10 ms). Every sample the assembler emits
must carry exactly the values the drive sent for that k; nothing else may get through. A
broken sample (some of its messages lost) carries NaN for exactly those messages' signals.
"""

from __future__ import annotations

import dataclasses
import functools
import itertools

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from canfdi import dbc as dbc_files
from canfdi.bus.assembler import SampleAssembler, assemble_batch
from canfdi.bus.e2e import protect
from canfdi.bus.frames import (
    FLAG_ERROR,
    FLAG_EXTENDED,
    FLAG_FD,
    FLAG_REMOTE,
    STATUS_NAMES,
    FrameBlock,
)
from canfdi.bus.timegate import CONFIRM_FRAMES
from tests.unit.bus.test_busmap import DT_NS, as_log, dc_motor_map, drive_traffic

DT = DT_NS / 1e9
CMD, CURRENTS, SPEED = 0x104, 0x105, 0x106
STATUS_FRAME = protect(0x082, bytes(8), 7)  # a valid FDI_STATUS frame of the monitor


def frames_of(n: int, k0: int = 0) -> list[tuple[int, int, bytes, int]]:
    """(timestamp_ns, frame_id, payload, flags) of clean drive traffic, samples k0 .. k0+n-1."""
    _, frames = drive_traffic(n, k0)
    return [(t, frame_id, data, 0) for t, frame_id, data, _ in frames]


def index_of(frames, frame_id: int, k: int) -> int:
    """Position of the frame of message ``frame_id`` and period k (counter k mod 256)."""
    t_lo, t_hi = k * DT_NS, (k + 1) * DT_NS
    for i, (t, fid, data, _) in enumerate(frames):
        if fid == frame_id and t_lo <= t < t_hi and data[1] == k % 256:
            return i
    raise LookupError(f"no frame 0x{frame_id:X} of k={k}")


@functools.cache
def expected_values(n: int, k0: int = 0) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """k -> (u, z) as cantools decodes the clean frames (the values the drive put on the bus)."""
    bus_map = dc_motor_map()
    database = dbc_files.load("motor_drive")
    _, frames = drive_traffic(n, k0)
    out: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    for _, frame_id, data, k in frames:
        u, z = out.setdefault(k, (np.full(bus_map.p, np.nan), np.full(bus_map.q, np.nan)))
        decoded = database.get_message_by_frame_id(frame_id).decode(data, decode_choices=False)
        slot = bus_map.slot_of[(frame_id, False)]
        for name, vector, j in bus_map.fields[slot]:
            (u if vector == "u" else z)[j] = decoded[name]
    return out


def push_all(assembler: SampleAssembler, frames) -> tuple[list[str], list]:
    statuses, samples = [], []
    for t, frame_id, data, flags in frames:
        status, done = assembler.push(
            t, frame_id, data, is_extended=bool(flags & FLAG_EXTENDED),
            is_remote=bool(flags & FLAG_REMOTE), is_error=bool(flags & FLAG_ERROR),
            is_fd=bool(flags & FLAG_FD))
        assert len(done) <= 2  # a broken sample closed, and/or this frame's completed
        statuses.append(status)
        samples.extend(done)
    return statuses, samples


def run(frames, flush: bool = True) -> tuple[list[str], list, dict]:
    assembler = SampleAssembler(dc_motor_map(), DT)
    statuses, samples = push_all(assembler, frames)
    if flush:
        samples += assembler.flush()
    return statuses, samples, assembler.stats


def lost_messages(sample) -> set[int]:
    """IDs of the drive messages whose signals are NaN in the sample (each all or none)."""
    bus_map = dc_motor_map()
    flat = np.concatenate([sample.u, sample.z])
    lost = set()
    for slot, fields in enumerate(bus_map.fields):
        nan = [np.isnan((sample.u if vector == "u" else sample.z)[j])
               for _, vector, j in fields]
        assert all(nan) or not any(nan), f"k={sample.k}: a message only partly missing"
        if all(nan):
            lost.add(bus_map.layouts[slot].frame_id)
    assert len(lost) < len(bus_map.layouts), f"k={sample.k}: delivered with nothing in it"
    assert np.isnan(flat).sum() == sum(
        len(bus_map.fields[bus_map.slot_of[(i, False)]]) for i in lost)
    return lost


def assert_values_are_the_drives(samples, n: int, k0: int = 0) -> None:
    """Every value is the drive's; NaN only for whole lost messages."""
    expected = expected_values(n, k0)
    for sample in samples:
        assert sample.k in expected, f"sample k={sample.k} was never sent"
        lost_messages(sample)
        u, z = expected[sample.k]
        np.testing.assert_array_equal(np.where(np.isnan(sample.u), u, sample.u), u,
                                      err_msg=f"u of k={sample.k}")
        np.testing.assert_array_equal(np.where(np.isnan(sample.z), z, sample.z), z,
                                      err_msg=f"z of k={sample.k}")


def assert_batch_equals_streaming(frames) -> None:
    """assemble_batch over the log == push frame by frame, then flush."""
    statuses, samples, stats = run(frames)
    t, ids, dlc, payloads = as_log(frames)
    flags = np.array([f[3] for f in frames], dtype=np.int64)
    log = assemble_batch(dc_motor_map(), DT, FrameBlock(t, ids, dlc, flags, payloads))
    assert [STATUS_NAMES[c] for c in log.statuses] == statuses
    assert log.stats == stats
    assert log.k.tolist() == [s.k for s in samples]
    assert log.timestamp_ns.tolist() == [s.timestamp_ns for s in samples]
    assert log.gap.tolist() == [s.gap for s in samples]
    bus_map = dc_motor_map()
    assert log.u.shape == (len(samples), bus_map.p)
    assert log.z.shape == (len(samples), bus_map.q)
    if samples:
        np.testing.assert_array_equal(log.u, np.array([s.u for s in samples]))
        np.testing.assert_array_equal(log.z, np.array([s.z for s in samples]))


# -- clean traffic ------------------------------------------------------------------------------


def test_clean_traffic_assembles_every_sample_to_the_dbc_resolution():
    n = 2000
    chunk, _ = drive_traffic(n)
    frames = frames_of(n)
    statuses, samples, stats = run(frames)
    assert set(statuses) == {"ok"}
    assert [s.k for s in samples] == list(range(n))
    assert all(s.gap == 0 for s in samples)
    # Each sample is completed by its period's last frame (DRIVE_SPEED, ID order).
    assert [s.timestamp_ns for s in samples] == [f[0] for f in frames[2::3]]
    bus_map = dc_motor_map()
    step = {sig.name: sig.scale for layout in bus_map.layouts for sig in layout.signals}
    u = np.array([s.u for s in samples])
    z = np.array([s.z for s in samples])
    u_step = np.array([step[name] for name in bus_map.input_names])
    z_step = np.array([step[name] for name in bus_map.output_names])
    assert np.all(np.abs(u - chunk.u_c) <= u_step / 2 * (1 + 1e-9))
    assert np.all(np.abs(z - chunk.z) <= z_step / 2 * (1 + 1e-9))
    assert_values_are_the_drives(samples, n)
    assert stats == {
        "frames_received": 3 * n, "frames_valid": 3 * n, "frames_invalid": 0,
        "invalid_by_reason": dict.fromkeys(
            ("unknown_id", "extended", "remote", "error_frame", "fd", "dlc", "crc",
             "duplicate", "stale", "jump", "time_jump", "implausible", "saturated"), 0),
        "samples_complete": n, "samples_broken": 0, "samples_missing": 0, "duplicates": 0,
        "clock_steps": 0,
    }


def test_samples_hold_copies_not_views_of_the_pending_buffer():
    _, samples, _ = run(frames_of(3))
    first = samples[0].u.copy(), samples[0].z.copy()
    assert not np.shares_memory(samples[0].z, samples[1].z)
    np.testing.assert_array_equal(samples[0].u, first[0])
    np.testing.assert_array_equal(samples[0].z, first[1])
    assert not np.array_equal(samples[0].z, samples[1].z)


def test_reordering_within_a_period_still_completes_every_sample():
    frames = frames_of(20)
    shuffled = []
    rng = np.random.default_rng(3)
    for k in range(20):
        period = frames[3 * k: 3 * k + 3]
        shuffled += [period[i] for i in rng.permutation(3)]
    statuses, samples, stats = run(shuffled)
    assert set(statuses) == {"ok"}
    assert [s.k for s in samples] == list(range(20))
    assert_values_are_the_drives(samples, 20)
    assert stats["samples_complete"] == 20


def test_counter_wraps_from_255_to_0():
    frames = frames_of(12, k0=250)
    assert [f[2][1] for f in frames[::3]] == [250, 251, 252, 253, 254, 255, 0, 1, 2, 3, 4, 5]
    statuses, samples, _ = run(frames)
    assert set(statuses) == {"ok"}
    # The first sample seen starts at its counter: here the true k.
    assert [s.k for s in samples] == list(range(250, 262))
    assert [s.gap for s in samples] == [0] * 12
    assert_values_are_the_drives(samples, 12, k0=250)


def test_first_sample_starts_at_its_counter():
    frames = frames_of(4, k0=300)
    _, samples, _ = run(frames)
    assert [s.k for s in samples] == [44, 45, 46, 47]
    expected = expected_values(4, k0=300)
    np.testing.assert_array_equal(samples[0].z, expected[300][1])


def test_invalid_dt_is_refused():
    with pytest.raises(ValueError, match="dt"):
        SampleAssembler(dc_motor_map(), 0.0)


# -- defects ------------------------------------------------------------------------------------


def test_dropped_frame_breaks_its_sample_which_is_delivered_without_its_signals():
    frames = frames_of(10)
    del frames[index_of(frames, CURRENTS, 5)]
    statuses, samples, stats = run(frames)
    assert set(statuses) == {"ok"}
    assert [s.k for s in samples] == list(range(10))
    assert [s.gap for s in samples] == [0] * 10
    assert [lost_messages(s) for s in samples] == [set()] * 5 + [{CURRENTS}] + [set()] * 4
    assert (stats["samples_complete"], stats["samples_broken"], stats["samples_missing"]) == \
        (9, 1, 0)
    assert_values_are_the_drives(samples, 10)
    # Sample 5 is delivered when the first frame of sample 6 shows it cannot complete, with the
    # arrival time of its own last frame.
    assembler = SampleAssembler(dc_motor_map(), DT)
    i6 = index_of(frames, CMD, 6)
    push_all(assembler, frames[:i6])
    status, done = assembler.push(*frames[i6][:3])
    assert status == "ok" and [s.k for s in done] == [5]
    assert done[0].timestamp_ns == frames[i6 - 1][0]


def test_whole_period_lost_counts_as_missing():
    frames = [f for f in frames_of(10) if not 3 * DT_NS <= f[0] < 5 * DT_NS]
    _, samples, stats = run(frames)
    assert [s.k for s in samples] == [0, 1, 2, 5, 6, 7, 8, 9]
    assert samples[3].gap == 2
    assert (stats["samples_broken"], stats["samples_missing"]) == (0, 2)


def test_duplicate_frames_are_counted_and_the_first_copy_wins():
    bus_map = dc_motor_map()
    frames = frames_of(10)
    i = index_of(frames, CMD, 3)
    t = frames[i][0]
    # A same-counter frame with another valid V: must not overwrite what was received first.
    forged, _ = bus_map.layouts[0].encode({"V": np.array([123.45])}, 1)
    frames.insert(i + 1, (t + 1, CMD, protect(CMD, forged[0].tobytes(), 3), 0))
    # The DRIVE_SPEED frame again after sample 3 completed.
    j = index_of(frames, SPEED, 3)
    frames.insert(j + 1, frames[j])
    statuses, samples, stats = run(frames)
    assert statuses.count("duplicate") == 2
    assert statuses[i + 1] == "duplicate" and statuses[j + 1] == "duplicate"
    assert [s.k for s in samples] == list(range(10))
    assert_values_are_the_drives(samples, 10)
    assert stats["duplicates"] == stats["invalid_by_reason"]["duplicate"] == 2
    assert stats["frames_invalid"] == 2
    assert stats["samples_complete"] == 10


def test_bad_crc_is_rejected_and_a_good_retransmission_completes_the_sample():
    frames = frames_of(10)
    i = index_of(frames, CURRENTS, 4)
    t, frame_id, data, _ = frames[i]
    bad = bytearray(data)
    bad[3] ^= 0x10  # one bit of i_f
    frames[i] = (t, frame_id, bytes(bad), 0)
    statuses, samples, stats = run(frames)
    assert statuses[i] == "crc"
    assert [s.k for s in samples] == list(range(10))
    assert lost_messages(samples[4]) == {CURRENTS} and samples[5].gap == 0
    assert stats["invalid_by_reason"]["crc"] == 1
    assert stats["samples_broken"] == 1
    assert_values_are_the_drives(samples, 10)
    # The same corruption followed by the intact frame: the sample is whole and correct.
    frames.insert(i + 1, (t + 1, frame_id, data, 0))
    statuses, samples, _ = run(frames)
    assert statuses[i: i + 2] == ["crc", "ok"]
    assert [s.k for s in samples] == list(range(10))
    assert_values_are_the_drives(samples, 10)


def test_corrupted_counter_is_caught_by_the_crc():
    frames = frames_of(6)
    i = index_of(frames, SPEED, 2)
    t, frame_id, data, _ = frames[i]
    # Counter 2 -> 3: the frame would join sample 3 if the CRC did not cover byte 1.
    frames[i] = (t, frame_id, data[:1] + bytes([3]) + data[2:], 0)
    statuses, samples, _ = run(frames)
    assert statuses[i] == "crc"
    assert [s.k for s in samples] == list(range(6))
    assert lost_messages(samples[2]) == {SPEED}
    assert_values_are_the_drives(samples, 6)


def test_wrong_dlc_is_rejected():
    frames = frames_of(6)
    i = index_of(frames, SPEED, 2)
    t, frame_id, data, _ = frames[i]
    frames[i] = (t, frame_id, data + b"\0", 0)  # 5 bytes for a DLC-4 message
    j = index_of(frames, CMD, 4)
    frames[j] = (frames[j][0], CMD, frames[j][2][:7], 0)
    statuses, samples, stats = run(frames)
    assert statuses[i] == statuses[j] == "dlc"
    assert [s.k for s in samples] == list(range(6))
    assert [lost_messages(s) for s in samples] == [set(), set(), {SPEED}, set(), {CMD}, set()]
    assert stats["invalid_by_reason"]["dlc"] == 2
    assert_values_are_the_drives(samples, 6)


def test_frames_outside_the_drive_contract_are_counted_by_reason():
    frames = frames_of(6)
    i = index_of(frames, CMD, 2)
    t, _, data, _ = frames[i]
    strangers = [
        (t + 1, 0x200, data, 0),  # unknown 11-bit ID
        (t + 2, CMD, data, FLAG_EXTENDED),  # a drive ID, but 29-bit
        (t + 3, 0x1ABCDEF, data, FLAG_EXTENDED),
        (t + 4, 0, b"", FLAG_ERROR),
        (t + 5, CURRENTS, b"", FLAG_REMOTE),  # a master polling a drive message: known
        (t + 6, 0x7E0, b"", FLAG_REMOTE),  # a request for an ID no message has
        (t + 7, CURRENTS, data + bytes(8), FLAG_FD),
    ]
    frames[i + 1: i + 1] = strangers
    statuses, samples, stats = run(frames)
    assert statuses[i + 1: i + 8] == ["unknown_id", "extended", "extended", "error_frame",
                                      "unused", "remote", "fd"]
    assert [s.k for s in samples] == list(range(6))
    assert_values_are_the_drives(samples, 6)
    reasons = stats["invalid_by_reason"]
    assert (reasons["unknown_id"], reasons["extended"], reasons["error_frame"],
            reasons["remote"], reasons["fd"]) == (1, 2, 1, 1, 1)
    assert stats["frames_invalid"] == 6
    assert stats["frames_valid"] == 19  # 18 drive frames + the poll of a known message


def test_an_extended_frame_cannot_stand_in_for_a_drive_frame():
    frames = frames_of(4)
    i = index_of(frames, SPEED, 1)
    frames[i] = (*frames[i][:3], FLAG_EXTENDED)
    statuses, samples, _ = run(frames)
    assert statuses[i] == "extended"
    assert [s.k for s in samples] == [0, 1, 2, 3]
    assert lost_messages(samples[1]) == {SPEED}


def test_monitor_frames_are_valid_and_not_part_of_samples():
    frames = frames_of(6)
    i = index_of(frames, CURRENTS, 3)
    frames.insert(i, (frames[i][0], 0x082, STATUS_FRAME, 0))
    bad_status = bytes([STATUS_FRAME[0] ^ 1]) + STATUS_FRAME[1:]
    frames.insert(i, (frames[i][0], 0x082, bad_status, 0))
    statuses, samples, stats = run(frames)
    assert statuses[i: i + 2] == ["crc", "monitor"]
    assert [s.k for s in samples] == list(range(6))
    assert stats["frames_valid"] == 19
    assert stats["frames_invalid"] == 1
    assert_values_are_the_drives(samples, 6)


def test_late_frame_of_an_older_period_is_stale():
    frames = frames_of(8)
    # The last frame of period 3 arrives after the first of period 4.
    i = index_of(frames, SPEED, 3)
    frames[i], frames[i + 1] = frames[i + 1], frames[i]
    # And a replay of period 1's DRIVE_CMD arrives after period 6.
    frames.insert(index_of(frames, SPEED, 6) + 1, frames[index_of(frames, CMD, 1)])
    statuses, samples, stats = run(frames)
    assert statuses.count("stale") == 2
    assert [s.k for s in samples] == list(range(8))
    assert lost_messages(samples[3]) == {SPEED} and samples[4].gap == 0
    assert stats["samples_broken"] == 1
    assert_values_are_the_drives(samples, 8)


def test_counter_step_over_128_without_elapsed_time_is_stale():
    frames = frames_of(1)
    # Every frame at the same instant: only the counter can order them.
    assembler = SampleAssembler(dc_motor_map(), DT)
    push_all(assembler, [(0, *f[1:]) for f in frames])
    base = frames[0][2]
    assert assembler.push(0, CMD, protect(CMD, base, 129))[0] == "stale"
    # 128 ahead with no time elapsed: a jump, until a second frame confirms the new count.
    assert assembler.push(0, CMD, protect(CMD, base, 128))[0] == "jump"
    assert assembler.push(0, CURRENTS, protect(CURRENTS, frames[1][2], 128))[0] == "ok"
    stats = assembler.stats
    assert stats["samples_missing"] == 127
    assert stats["invalid_by_reason"]["stale"] == 1
    assert stats["invalid_by_reason"]["jump"] == 1


def test_a_counter_ahead_of_the_clock_is_garbage_unless_the_next_frame_confirms_it():
    """A random frame passing the 8-bit CRC with a counter d ahead (d up to 128) would open a
    sample of garbage and make the drive's next d samples stale. One period after sample 4,
    a frame claiming sample 40 is a jump; the drive's sample 5 then goes on normally. A drive
    restarted with a new count is followed after one lost frame."""
    frames = frames_of(10)
    i = index_of(frames, CMD, 5)
    t = frames[i][0]
    garbage = (t - 1000, CURRENTS, protect(CURRENTS, frames[1][2], 40), 0)
    frames.insert(i, garbage)
    statuses, samples, stats = run(frames)
    assert statuses[i] == "jump" and statuses.count("jump") == 1
    assert [s.k for s in samples] == list(range(10))
    assert stats["samples_complete"] == 10 and stats["samples_missing"] == 0
    assert_values_are_the_drives(samples, 10)
    # A restart: from period 10 on the drive counts from 100 (90 ahead of the clock).
    later = [(t_, fid, protect(fid, data, (data[1] + 90) % 256), f)
             for t_, fid, data, f in frames_of(5, k0=10)]
    statuses, samples, _ = run(frames + later)
    tail = statuses[len(frames):]
    assert tail[0] == "jump" and set(tail[1:]) == {"ok"}
    assert [s.k for s in samples][-5:] == [100, 101, 102, 103, 104]
    assert lost_messages(samples[-5]) == {CMD}  # its first frame was the unconfirmed jump


@pytest.mark.parametrize("lost", [129, 200, 255])
def test_long_outage_is_unwrapped_by_the_timestamps(lost):
    # Beyond 128 periods the counter alone would call the frames stale: the elapsed time
    # (within the time gate's bound of 256 periods) says how far it went.
    n, start = lost + 300, 200
    frames = [f for f in frames_of(n) if not start * DT_NS <= f[0] < (start + lost) * DT_NS]
    statuses, samples, stats = run(frames)
    assert set(statuses) == {"ok"}
    assert [s.k for s in samples] == [*range(start), *range(start + lost, n)]
    assert samples[start].gap == lost
    assert stats["samples_missing"] == lost
    assert_values_are_the_drives(samples, n)


@pytest.mark.parametrize("step_s", [3600, 86400, -3600, -1.7e9])
def test_a_step_of_the_clock_is_followed_not_counted(step_s):
    # The timestamps step by an hour, a day, an hour back, back to 1970 (NTP, a gateway
    # without a real-time clock): beyond the bound, confirmed by the frames after it. Eight
    # frames go as time_jump, then the clock follows: a pause of at most the bound (256
    # periods) plus the counter's reach, never the step's 360,000 periods.
    n, start = 600, 200
    step = round(step_s * 1e9)
    frames = [(t + (step if t >= start * DT_NS else 0), *rest) for t, *rest in frames_of(n)]
    statuses, samples, stats = run(frames)
    assert statuses.count("time_jump") == CONFIRM_FRAMES - 1
    assert stats["clock_steps"] == 1
    assert stats["samples_missing"] <= 256 + 256
    assert len(samples) >= n - 5 and max(s.gap for s in samples) <= 512
    assert_batch_equals_streaming(frames)


@pytest.mark.parametrize("off_s", [3600, 86400, -3600, -1.7e9])
def test_one_frame_with_a_wild_timestamp_is_dropped(off_s):
    # A copy of a valid frame stamped an hour ahead (a merged log), a day ahead, back, 1970:
    # dropped as time_jump, nothing else changes.
    frames = frames_of(400)
    wild = (frames[300][0] + round(off_s * 1e9), *frames[300][1:])
    statuses, samples, stats = run([*frames[:301], wild, *frames[301:]])
    assert statuses[301] == "time_jump" and statuses.count("time_jump") == 1
    assert [s.k for s in samples] == list(range(400))
    assert stats["samples_missing"] == 0 and stats["clock_steps"] == 0
    assert_batch_equals_streaming([*frames[:301], wild, *frames[301:]])


def test_flush_breaks_the_pending_sample_and_delivers_it():
    frames = frames_of(3)[:-1]
    _, samples, stats = run(frames, flush=False)
    assert stats["samples_broken"] == 0
    assert [s.k for s in samples] == [0, 1]
    assembler = SampleAssembler(dc_motor_map(), DT)
    push_all(assembler, frames)
    (last,) = assembler.flush()
    assert last.k == 2 and lost_messages(last) == {SPEED}
    assert assembler.flush() == []
    assert assembler.stats["samples_broken"] == 1
    # The missing frame after the end of stream: that sample was given up.
    last = frames_of(3)[-1]
    assert assembler.push(last[0], last[1], last[2]) == ("stale", [])


# -- batch replay -------------------------------------------------------------------------------


def _every_defect() -> list[tuple[int, int, bytes, int]]:
    frames = frames_of(1500, k0=100)
    # An outage of 240 periods: beyond the counter's half range, within the time gate's bound.
    frames = [f for f in frames if not 300 * DT_NS <= f[0] < 540 * DT_NS]
    rng = np.random.default_rng(11)
    out = []
    for t, frame_id, data, flags in frames:
        roll = rng.random()
        if roll < 0.03:
            continue
        if roll < 0.06:
            out += [(t, frame_id, data, flags)] * 2
            continue
        if roll < 0.09:
            bad = bytearray(data)
            bad[int(rng.integers(len(data)))] ^= int(rng.integers(1, 256))
            out.append((t, frame_id, bytes(bad), flags))
            continue
        if roll < 0.11:
            out.append((t, frame_id, data[:-1], flags))
            continue
        if roll < 0.13:
            out.append((t, 0x300, data, flags))
            continue
        if roll < 0.14:
            out.append((t, frame_id, data, FLAG_EXTENDED | FLAG_ERROR))
        elif roll < 0.16:
            out.append((t, 0x082, STATUS_FRAME, 0))
        out.append((t, frame_id, data, flags))
    # Reorder some neighbours, within and across periods.
    for i in rng.choice(len(out) - 1, size=len(out) // 30, replace=False):
        out[i], out[i + 1] = out[i + 1], out[i]
    return out


def test_batch_equals_streaming_on_every_kind_of_defect():
    frames = _every_defect()
    statuses, samples, stats = run(frames)
    # The stream really exercises every path.
    assert {"ok", "monitor", "unknown_id", "error_frame", "dlc", "crc", "duplicate",
            "stale"} <= set(statuses)
    assert stats["samples_missing"] >= 240 and stats["samples_broken"] > 0
    assert max(s.gap for s in samples) >= 240
    assert_values_are_the_drives(samples, 1500, k0=100)
    assert_batch_equals_streaming(frames)


def test_batch_on_clean_traffic_and_in_chunks():
    frames = frames_of(300, k0=200)
    assert_batch_equals_streaming(frames)
    block = FrameBlock(*as_log(frames)[:3], np.zeros(len(frames), dtype=np.uint8),
                       as_log(frames)[3])
    whole = assemble_batch(dc_motor_map(), DT, block)
    assert whole.k.tolist() == list(range(200, 500))
    # Chunks cut anywhere (even inside a period) carry the state over.
    assembler = SampleAssembler(dc_motor_map(), DT)
    parts = [assembler.push_batch(block.slice(a, b))
             for a, b in ((0, 100), (100, 101), (101, 101), (101, 900))]
    assembler.flush()
    assert np.concatenate([p.k for p in parts]).tolist() == whole.k.tolist()
    np.testing.assert_array_equal(np.concatenate([p.z for p in parts]), whole.z)
    assert np.concatenate([p.statuses for p in parts]).tolist() == whole.statuses.tolist()
    assert assembler.stats == whole.stats


def test_a_block_of_mismatched_arrays_is_refused_naming_the_array():
    t, ids, dlc, payloads = as_log(frames_of(2))
    flags = np.zeros(len(t), dtype=np.uint8)
    with pytest.raises(ValueError, match=r"id: expected shape \(5,\), got \(6,\)"):
        FrameBlock(t[:-1], ids, dlc, flags[:-1], payloads[:-1])
    with pytest.raises(ValueError, match="flags: expected integers"):
        FrameBlock(t, ids, dlc, np.zeros(len(t)), payloads)
    with pytest.raises(ValueError, match=r"data: expected shape \(6, 8\), got \(6, 7\)"):
        FrameBlock(t, ids, dlc, flags, payloads[:, :7])


# -- random damage (hypothesis) -----------------------------------------------------------------

BASE_N, BASE_K0 = 30, 240  # wraps the counter at k = 256

_POSITION = st.integers(0, 10_000)
_mutation = st.one_of(
    st.tuples(st.just("drop"), _POSITION),
    st.tuples(st.just("duplicate"), _POSITION, st.integers(0, 8)),
    st.tuples(st.just("corrupt"), _POSITION, st.integers(0, 7), st.integers(1, 255)),
    st.tuples(st.just("resize"), _POSITION, st.sampled_from([-2, -1, 1])),
    st.tuples(st.just("swap"), _POSITION),
    st.tuples(st.just("move"), _POSITION, st.integers(-12, 12)),
    st.tuples(st.just("retarget"), _POSITION,
              st.sampled_from([CMD, CURRENTS, SPEED, 0x080, 0x103, 0x200])),
    st.tuples(st.just("flag"), _POSITION,
              st.sampled_from([FLAG_EXTENDED, FLAG_REMOTE, FLAG_ERROR, FLAG_FD])),
    st.tuples(st.just("monitor"), _POSITION),
)


def _mutate(frames, mutations):
    """Apply mutations in turn; a frame whose bytes or ID were changed once is not changed again.

    An 8-bit CRC catches every error burst of up to 8 bits (one byte) and every ID change within
    the low byte, but not every combination of them; stacking damage on one frame would test
    the CRC's limits, not the assembler.
    """
    stream = [(*f, False) for f in frames]  # (t, id, data, flags, tainted)
    for op, position, *args in mutations:
        if not stream:
            break
        i = position % len(stream)
        t, frame_id, data, flags, tainted = stream[i]
        if op == "drop":
            del stream[i]
        elif op == "duplicate":
            stream.insert(min(i + 1 + args[0], len(stream)), stream[i])
        elif op == "swap" and i + 1 < len(stream):
            stream[i], stream[i + 1] = stream[i + 1], stream[i]
        elif op == "move":
            frame = stream.pop(i)
            stream.insert(min(max(i + args[0], 0), len(stream)), frame)
        elif op == "flag":
            stream[i] = (t, frame_id, data, flags | args[0], tainted)
        elif op == "monitor":
            stream.insert(i, (t, 0x082, STATUS_FRAME, 0, False))
        elif tainted:
            continue
        elif op == "corrupt":
            bad = bytearray(data)
            bad[args[0] % len(bad)] ^= args[1]
            stream[i] = (t, frame_id, bytes(bad), flags, True)
        elif op == "resize":
            resized = data[: len(data) + args[0]] if args[0] < 0 else data + bytes(args[0])
            stream[i] = (t, frame_id, resized, flags, True)
        elif op == "retarget" and args[0] != frame_id:
            stream[i] = (t, args[0], data, flags, True)
    return [f[:4] for f in stream]


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(_mutation, max_size=40))
def test_random_damage_never_lets_bad_data_through(mutations):
    frames = _mutate(frames_of(BASE_N, BASE_K0), mutations)
    statuses, samples, stats = run(frames)
    assert len(statuses) == len(frames)
    assert set(statuses) <= set(STATUS_NAMES)
    assert stats["frames_received"] == len(frames)
    assert stats["frames_valid"] + stats["frames_invalid"] == len(frames)
    assert sum(stats["invalid_by_reason"].values()) == stats["frames_invalid"]
    assert stats["samples_complete"] + stats["samples_broken"] == len(samples)
    ks = [s.k for s in samples]
    assert ks == sorted(set(ks))
    assert [s.gap for s in samples[1:]] == [b - a - 1 for a, b in itertools.pairwise(ks)]
    if samples:
        # k starts at the first counter seen (240 unless damage moved a later frame first):
        # shift to the true k, which the 30 distinct counters of the base stream determine.
        first_true = next(k for k in range(BASE_K0, BASE_K0 + BASE_N) if k % 256 == ks[0] % 256)
        shifted = [dataclasses.replace(s, k=s.k - ks[0] + first_true) for s in samples]
        assert_values_are_the_drives(shifted, BASE_N, BASE_K0)
    assert_batch_equals_streaming(frames)

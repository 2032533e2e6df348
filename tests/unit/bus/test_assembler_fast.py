"""SampleAssembler.push_batch's fast path: numpy on regular periods, identical to `push`.

push_batch assembles whole runs of regular periods (every used drive message once, in slot
order, one counter per period, the next counter in the next period, no long pause) with numpy
and sends every other frame through the state machine. Whatever the traffic and however it is
cut into batches, the result must be the one of pushing the frames one by one: the samples,
each frame's status, the stats and the state the next frame meets.
"""

from __future__ import annotations

import itertools
import time

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

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
from tests.unit.bus.test_assembler import (
    DT,
    STATUS_FRAME,
    _mutate,
    _mutation,
    assert_values_are_the_drives,
    frames_of,
    push_all,
)
from tests.unit.bus.test_busmap import DT_NS, as_log, dc_motor_map

# 80 wraps of the 8-bit counter; a multiple of 256 so that copies of the log can be chained.
N_CLEAN = 20_480
# Everything the state machine keeps between frames.
_STATE = ("_buffer", "_seen", "_open", "_k", "_t_ref", "_last_complete", "_last_delivered",
          "_last_gap", "_partial", "_jump", "_counts", "_complete", "_broken", "_missing")


def log_of(frames) -> FrameBlock:
    """The FrameBlock of (t, id, data, flags) frames."""
    t, ids, dlc, payloads = as_log(frames)
    return FrameBlock(t, ids, dlc, np.array([f[3] for f in frames], dtype=np.int64), payloads)


def state_of(assembler: SampleAssembler) -> dict:
    state = {name: getattr(assembler, name) for name in _STATE}
    # Python ints, not numpy scalars that would wrap or change the arithmetic of _place.
    assert all(type(state[name]) is int for name in ("_seen", "_k", "_t_ref", "_last_complete",
                                                     "_last_delivered", "_last_gap"))
    return state


def count_machine_frames(assembler: SampleAssembler) -> list[int]:
    """Count the frames that go through the state machine (`_place`) from now on."""
    calls = [0]
    place = assembler._place

    def counted(slot: int, counter: int, t: int) -> int:
        calls[0] += 1
        return place(slot, counter, t)

    assembler._place = counted  # type: ignore[method-assign]
    return calls


def push_batches(assembler: SampleAssembler, frames, cuts=()) -> dict[str, np.ndarray]:
    """push_batch over ``frames`` cut at the sorted positions ``cuts``, results concatenated."""
    arrays = log_of(frames)
    bounds = [0, *cuts, len(frames)]
    logs = [assembler.push_batch(arrays.slice(lo, hi))
            for lo, hi in itertools.pairwise(bounds)]
    return {name: np.concatenate([getattr(log, name) for log in logs])
            for name in ("k", "timestamp_ns", "u", "z", "gap", "statuses")}


def assert_same(batched: dict[str, np.ndarray], statuses: list[str], samples: list) -> None:
    assert [STATUS_NAMES[c] for c in batched["statuses"]] == statuses
    assert batched["k"].tolist() == [s.k for s in samples]
    assert batched["timestamp_ns"].tolist() == [s.timestamp_ns for s in samples]
    assert batched["gap"].tolist() == [s.gap for s in samples]
    bus_map = dc_motor_map()
    assert batched["u"].shape == (len(samples), bus_map.p)
    assert batched["z"].shape == (len(samples), bus_map.q)
    assert batched["k"].dtype == batched["timestamp_ns"].dtype == batched["gap"].dtype == np.int64
    if samples:
        np.testing.assert_array_equal(batched["u"], np.array([s.u for s in samples]))
        np.testing.assert_array_equal(batched["z"], np.array([s.z for s in samples]))


def assert_batch_equals_push(frames, cuts=(), then=()
                             ) -> tuple[SampleAssembler, list[str], list]:
    """push_batch (in chunks) == push frame by frame, also for the frames ``then`` after.

    Returns the batch assembler, and the statuses and samples of the reference (all frames).
    """
    reference = SampleAssembler(dc_motor_map(), DT)
    statuses, samples = push_all(reference, frames)
    assembler = SampleAssembler(dc_motor_map(), DT)
    assert_same(push_batches(assembler, frames, cuts), statuses, samples)
    assert assembler.stats == reference.stats
    assert state_of(assembler) == state_of(reference)
    # The state carried over: the next frames meet the same machine.
    later_statuses, later_samples = push_all(reference, then)
    assert_same(push_batches(assembler, then), later_statuses, later_samples)
    assert assembler.stats == reference.stats
    assert state_of(assembler) == state_of(reference)
    last = reference.flush()
    assert_same(_as_batched(assembler.flush()), [], last)
    assert assembler.stats == reference.stats
    return assembler, statuses + later_statuses, samples + later_samples


def _as_batched(samples: list) -> dict[str, np.ndarray]:
    bus_map = dc_motor_map()
    return {"k": np.array([s.k for s in samples], dtype=np.int64),
            "timestamp_ns": np.array([s.timestamp_ns for s in samples], dtype=np.int64),
            "gap": np.array([s.gap for s in samples], dtype=np.int64),
            "u": np.array([s.u for s in samples]).reshape(len(samples), bus_map.p),
            "z": np.array([s.z for s in samples]).reshape(len(samples), bus_map.q),
            "statuses": np.zeros(0, dtype=np.int8)}


def shifted(frames, by_ns: int):
    return [(t + by_ns, *rest) for t, *rest in frames]


# -- clean traffic ------------------------------------------------------------------------------


def test_clean_traffic_is_assembled_by_the_fast_path_exactly_as_by_push():
    frames = frames_of(N_CLEAN)
    # After the log: a pause, a period with its frames in reverse order, then regular again.
    later = shifted(frames_of(300), N_CLEAN * DT_NS)
    later[3:6] = later[3:6][::-1]
    assembler = SampleAssembler(dc_motor_map(), DT)
    machine = count_machine_frames(assembler)
    arrays = log_of(frames)
    log = assembler.push_batch(arrays)
    # Only the first period goes through the state machine: nothing is pending before it.
    assert machine[0] == 3
    assert log.k.tolist() == list(range(N_CLEAN))
    assert_batch_equals_push(frames, then=later)
    whole = assemble_batch(dc_motor_map(), DT, arrays)
    np.testing.assert_array_equal(whole.z, log.z)
    assert whole.stats["samples_complete"] == N_CLEAN


def test_chunk_boundaries_anywhere_carry_the_state_over():
    frames = frames_of(3000, k0=100)
    rng = np.random.default_rng(5)
    cuts = sorted({0, 1, 2, 3, 4, 5, 299, 300, 301, 302, *rng.integers(0, len(frames), 40)})
    assembler, _, _ = assert_batch_equals_push(frames, cuts=cuts, then=frames_of(10, k0=3100))
    # Clean traffic cut inside periods: the machine only finishes the periods cut in two.
    machine = count_machine_frames(assembler)
    push_batches(assembler, shifted(frames_of(3000, k0=100), 3010 * DT_NS), cuts=cuts)
    assert machine[0] <= 3 * (len(cuts) + 1)


def test_first_frames_after_a_completed_log_continue_the_fast_path():
    frames = frames_of(600)
    assembler = SampleAssembler(dc_motor_map(), DT)
    assembler.push_batch(log_of(frames[:900]))
    machine = count_machine_frames(assembler)
    log = assembler.push_batch(log_of(frames[900:]))
    assert machine[0] == 0
    assert log.k.tolist() == list(range(300, 600))
    assert log.gap.tolist() == [0] * 300


def test_monitor_frames_between_drive_frames_do_not_interrupt_a_run():
    frames = frames_of(400)
    mixed = []
    for i, frame in enumerate(frames):
        mixed.append(frame)
        if i % 5 == 0:
            mixed.append((frame[0] + 1, 0x082, STATUS_FRAME, 0))
    assembler = SampleAssembler(dc_motor_map(), DT)
    machine = count_machine_frames(assembler)
    assembler.push_batch(log_of(mixed))
    assert machine[0] == 3
    assert_batch_equals_push(mixed)


def test_throughput_of_assemble_batch_on_clean_traffic():
    # 3 x 10^5 frames: copies of the log, chained (the counter continues across them).
    base = log_of(frames_of(N_CLEAN))
    copies = 5
    block = FrameBlock.concat([
        FrameBlock(base.t_ns + c * N_CLEAN * DT_NS, base.id, base.dlc, base.flags, base.data)
        for c in range(copies)])
    bus_map = dc_motor_map()

    def best_of(repeats: int) -> tuple[float, object]:
        best, log = np.inf, None
        for _ in range(repeats):
            start = time.perf_counter()
            log = assemble_batch(bus_map, DT, block)
            best = min(best, time.perf_counter() - start)
        return best, log

    fast, log = best_of(5)
    assert log.k.tolist() == list(range(copies * N_CLEAN))
    with pytest.MonkeyPatch.context() as patch:
        # No regular runs found: every drive frame through the state machine, as before.
        empty = np.zeros(0, dtype=np.intp)
        patch.setattr(SampleAssembler, "_regular_runs", lambda self, *a: (empty, empty))
        slow, machine_log = best_of(1)
    np.testing.assert_array_equal(machine_log.z, log.z)
    n = block.size
    print(f"\nassemble_batch on {n} clean frames: fast path {n / fast:,.0f} frames/s "
          f"({n / 3 / fast:,.0f} samples/s); state machine only {n / slow:,.0f} frames/s "
          f"(x{slow / fast:.1f})")


# -- defects ------------------------------------------------------------------------------------


def _defect(out: list, frame: tuple[int, int, bytes, int], roll: float,
            rng: np.random.Generator) -> bool:
    """Append the defect ``roll`` picks for ``frame`` to ``out``; True when the frame itself
    is not to follow (dropped, doubled or replaced)."""
    t, frame_id, data, flags = frame
    if roll < 0.1:
        return True  # dropped
    if roll < 0.2:
        out += [(t, frame_id, data, flags)] * 2
        return True
    if roll < 0.3:
        bad = bytearray(data)
        bad[int(rng.integers(len(data)))] ^= int(rng.integers(1, 256))
        out.append((t, frame_id, bytes(bad), flags))
        return True
    if roll < 0.4:
        out.append((t, frame_id, data[:-1] if rng.random() < 0.5 else data + b"\0",
                    flags))
        return True
    if roll < 0.5:
        out.append((t, frame_id, data, FLAG_EXTENDED))
    elif roll < 0.6:
        out.append((t, 0x300, data, 0))
    elif roll < 0.7:
        out.append((t, 0x082, STATUS_FRAME, 0))
    elif roll < 0.8 and out:
        # A late copy of an older frame (stale, or a duplicate of the pending sample).
        old = out[-int(rng.integers(1, min(len(out), 40) + 1))]
        out.append((t, *old[1:]))
    elif roll < 0.9:
        # Another valid counter: a period ahead, or one behind.
        counter = data[1] + int(rng.choice([-1, 1, 2, 130]))
        out.append((t, frame_id, protect(frame_id, data, counter & 0xFF), flags))
    elif roll < 1.0:
        out.append((t, 0, b"", FLAG_ERROR))
    return False


def _sprinkled(n: int, k0: int, seed: int, rate: float) -> list[tuple[int, int, bytes, int]]:
    """Clean traffic with outages, pauses of the clock and frame defects at random places."""
    frames = frames_of(n, k0)
    periods = [frames[i: i + 3] for i in range(0, len(frames), 3)]
    rng = np.random.default_rng(seed)
    # Outages: lost periods (the counter jumps; 600 needs the timestamps to unwrap it).
    lost = set()
    for length in (1, 2, 127, 128, 129, 255, 256, 257, 600):
        start = int(rng.integers(10, len(periods) - length - 10))
        lost.update(range(start, start + length))
    # Pauses: the clock jumps, the counter does not (around the 128-period unwrap limit), or
    # steps back a little; at a period's start or inside it.
    shift = np.zeros(len(frames), dtype=np.int64)
    for pause in (3, 126, 126.9, 127, 127.5, 128, 128.5, 129, 200, 256.5, -2.5):
        shift[int(rng.integers(len(frames))):] += int(pause * DT_NS)
    out = []
    for p, period in enumerate(periods):
        if p in lost:
            continue
        if rng.random() < rate:
            period = [period[i] for i in rng.permutation(3)]
        for t, frame_id, data, flags in period:
            t += int(shift[3 * p])
            roll = rng.random() / rate if rate else 1.0
            if _defect(out, (t, frame_id, data, flags), roll, rng):
                continue
            out.append((t, frame_id, data, flags))
    return out


@pytest.mark.parametrize("rate", [0.002, 0.02, 0.2])
def test_defects_sprinkled_over_long_traffic(rate):
    frames = _sprinkled(N_CLEAN, 0, seed=int(rate * 1000), rate=rate)
    rng = np.random.default_rng(17)
    cuts = sorted(set(rng.integers(0, len(frames), 25).tolist()))
    then = shifted(frames_of(50, k0=N_CLEAN), 240 * DT_NS)  # an outage within the bound
    assembler, statuses, samples = assert_batch_equals_push(frames, then=then)
    assert {"ok", "monitor", "unknown_id", "extended", "error_frame", "dlc", "crc",
            "duplicate", "stale"} <= set(statuses)
    stats = assembler.stats
    assert stats["samples_missing"] > 200 and stats["samples_broken"] > 0
    assert max(s.gap for s in samples) >= 200
    assert_batch_equals_push(frames, cuts=cuts, then=then)
    # The fast path still carries the regular stretches between the defects.
    fresh = SampleAssembler(dc_motor_map(), DT)
    machine = count_machine_frames(fresh)
    fresh.push_batch(log_of(frames))
    print(f"\nrate {rate}: {machine[0] / len(frames):.1%} of the frames through the machine")
    if rate <= 0.02:
        assert machine[0] < 0.25 * len(frames)


@pytest.mark.parametrize("pause", [-3.0, 126.0, 126.99, 127.0, 127.5, 128.0, 128.5, 129.0, 200.0,
                                   255.5, 256.0, 257.0, 1000.0])
@pytest.mark.parametrize("where", [0, 1, 2])
def test_clock_jumps_without_counter_jumps(pause, where):
    # The drive stops sending and resumes with the next counter: after more than ~128 periods
    # the unwrap rule reads the elapsed time as wraps of the counter.
    frames = frames_of(600)
    at = 3 * 300 + where
    frames[at:] = shifted(frames[at:], int(pause * DT_NS))
    _, _, samples = assert_batch_equals_push(frames, cuts=[at - 1, at + 7])
    ks = [s.k for s in samples]
    if pause >= 129:
        assert ks[-1] > 599
    if pause < 127:
        assert ks == list(range(600))


def test_timestamps_whose_difference_overflows_int64():
    frames = frames_of(40)
    huge = 2**62 + 2**61
    frames = shifted(frames[:60], -huge) + shifted(frames[60:], huge)
    assert_batch_equals_push(frames)
    # Unsigned times (within int64) are taken as they are.
    b = log_of(frames_of(200))
    signed = assemble_batch(dc_motor_map(), DT, b)
    unsigned = assemble_batch(dc_motor_map(), DT, FrameBlock(b.t_ns.astype(np.uint64), b.id,
                                                             b.dlc, b.flags, b.data))
    assert unsigned.k.tolist() == signed.k.tolist()
    assert unsigned.timestamp_ns.tolist() == signed.timestamp_ns.tolist()
    assert unsigned.timestamp_ns.dtype == np.int64


def test_flush_between_batches_is_respected():
    frames = frames_of(90)
    reference = SampleAssembler(dc_motor_map(), DT)
    statuses, samples = push_all(reference, frames[:100])
    reference.flush()
    later_statuses, later_samples = push_all(reference, frames[100:])
    assembler = SampleAssembler(dc_motor_map(), DT)
    assert_same(push_batches(assembler, frames[:100]), statuses, samples)
    assembler.flush()
    assert_same(push_batches(assembler, frames[100:]), later_statuses, later_samples)
    assert state_of(assembler) == state_of(reference)
    assert assembler.stats == reference.stats


# -- random damage (hypothesis) -----------------------------------------------------------------

HYP_N, HYP_K0, HYP_TAIL = 60, 220, 20  # wraps the counter at k = 256

_pause = st.tuples(st.integers(0, 10_000), st.sampled_from([-1.0, 0.5, 126.5, 127.5, 128.5,
                                                            129.0, 300.0]))


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(_mutation, max_size=40), st.lists(_pause, max_size=2),
       st.lists(st.integers(0, 10_000), max_size=6))
def test_random_damage_batch_equals_push(mutations, pauses, cuts):
    base = frames_of(HYP_N + HYP_TAIL, HYP_K0)
    frames = _mutate(base[: 3 * HYP_N], mutations)
    for position, periods in pauses:
        if frames:
            at = position % len(frames)
            frames[at:] = shifted(frames[at:], int(periods * DT_NS))
    cuts = sorted({c % (len(frames) + 1) for c in cuts})
    # Clean periods after the damage, whose time continues from the last frame.
    last = max((f[0] for f in frames), default=0)
    tail = base[3 * HYP_N:]
    then = shifted(tail, max(0, last - tail[0][0] + DT_NS))
    _, _, samples = assert_batch_equals_push(frames, cuts=cuts, then=then)
    ks = [s.k for s in samples]
    assert ks == sorted(set(ks))


def test_random_damage_examples_reach_the_fast_path():
    # Not vacuous: on lightly damaged traffic most frames skip the machine.
    frames = _mutate(frames_of(HYP_N, HYP_K0), [("drop", 40), ("swap", 100)])
    assembler = SampleAssembler(dc_motor_map(), DT)
    machine = count_machine_frames(assembler)
    assembler.push_batch(log_of(frames))
    assert machine[0] < len(frames) // 2
    _, _, samples = assert_batch_equals_push(frames)
    assert_values_are_the_drives(samples, HYP_N, HYP_K0)


def test_all_flags_and_strangers_only():
    frames = [(i * 1000, 0x104, bytes(8), flag)
              for i, flag in enumerate([FLAG_ERROR, FLAG_REMOTE, FLAG_FD, FLAG_EXTENDED, 0])]
    log = assemble_batch(dc_motor_map(), DT, log_of(frames))
    assert log.k.size == 0 and log.u.shape == (0, 1) and log.z.shape == (0, 4)
    assert_batch_equals_push(frames)

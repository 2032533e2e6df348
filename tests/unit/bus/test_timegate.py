"""canfdi.bus.timegate: a drive's time, checked (stray frames dropped, clock steps followed),
the same frame by frame and by the block on every cut."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from canfdi.bus.timegate import TimeGate

BOUND = 100


def _stream(t: np.ndarray, rows: np.ndarray, confirm: int = 4):
    gate = TimeGate(BOUND, confirm)
    return gate, [gate.step(int(x)) for x in t[rows]]


def _blocks(t: np.ndarray, rows: np.ndarray, cuts: list[int], confirm: int = 4):
    gate, out = TimeGate(BOUND, confirm), []
    bounds = [0, *cuts, len(t)]
    for lo, hi in itertools.pairwise(bounds):
        sel = rows[(rows >= lo) & (rows < hi)] - lo
        times, dropped = gate.apply(t[lo:hi], sel)
        got: list[int | None] = [int(times[r]) for r in sel]
        for d in dropped:
            got[d] = None
        out += got
    return gate, out


def test_jitter_and_outages_within_the_bound_pass_unchanged():
    t = np.array([0, 10, 5, 90, 185, 170, 270], dtype=np.int64)
    gate, out = _stream(t, np.arange(len(t)))
    assert out == t.tolist() and gate.jumps == 0 and gate.steps == []


def test_a_stray_frame_ahead_or_behind_is_dropped():
    t = np.array([0, 10, 10**12, 20, -(10**12), 30], dtype=np.int64)
    gate, out = _stream(t, np.arange(len(t)))
    assert out == [0, 10, None, 20, None, 30] and gate.jumps == 2 and gate.steps == []


def test_a_confirmed_step_lands_a_bound_after_the_drive_time():
    step = 86_400 * 10**9
    t = np.array([0, 10, 20, *(step + 30 + 10 * np.arange(6))], dtype=np.int64)
    gate, out = _stream(t, np.arange(len(t)), confirm=4)
    # Three frames dropped, the fourth confirms the step and lands at 20 + BOUND.
    assert out[:6] == [0, 10, 20, None, None, None]
    assert out[6:] == [20 + BOUND, 30 + BOUND, 40 + BOUND]
    # The step is said as the first frame after it saw it: 10 ns after the drive's time.
    assert gate.steps == [(step + 30, step + 10)]


def test_scattered_stray_frames_never_confirm_a_step():
    # Strays far apart from each other (a random log's times) are each their own chain.
    t = np.array([0, 10**12, 2 * 10**12, 3 * 10**12, 4 * 10**12, 10], dtype=np.int64)
    gate, out = _stream(t, np.arange(len(t)))
    assert out == [0, None, None, None, None, 10] and gate.steps == []


@pytest.mark.parametrize("seed", range(40))
def test_blocks_cut_anywhere_equal_frame_by_frame(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 3000))
    t = np.cumsum(rng.integers(0, 20, n)).astype(np.int64) + 10**18
    for _ in range(int(rng.integers(0, 6))):
        i, kind = int(rng.integers(0, n)), int(rng.integers(0, 4))
        if kind == 0:
            t[i] += int(rng.choice([3600, -3600, 86400])) * 10**9
        elif kind == 1:
            t[i:] += int(rng.choice([1, -1])) * int(rng.integers(1, 10**6))
        elif kind == 2:
            t[i] = 0
        else:
            t[i] = np.iinfo(np.int64).max - int(rng.integers(0, 100))
    rows = np.flatnonzero(rng.random(n) < 0.8)
    a, stream = _stream(t, rows)
    cuts = sorted({int(c) for c in rng.integers(0, n, 3)})
    b, blocks = _blocks(t, rows, cuts)
    assert blocks == stream
    assert (a.jumps, a.steps, a.offset, a.ref) == (b.jumps, b.steps, b.offset, b.ref)


def test_work_is_bounded_by_frames_on_a_log_of_random_times():
    # 10^5 frames at random times over 50 years: each is a jump, none a sample time; the
    # block form takes them one by one without a pass over the rest each time.
    rng = np.random.default_rng(1)
    t = rng.integers(0, 50 * 365 * 86400 * 10**9, 100_000)
    gate = TimeGate(BOUND)
    _, dropped = gate.apply(t, np.arange(len(t)))
    assert len(dropped) >= 99_990 and gate.steps == []

"""The C core's time gate (canfdi/_c/gate.c) against the numpy reference
(TimeGate.apply_reference): the same corrected times, drops, clock steps and gate state, block
after block, on traffic with stray frames, clock steps both ways, times at int64's ends (where
the C hands the rest of the block to the reference) and random times."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from canfdi.bus.timegate import TimeGate
from canfdi.core import kernel

pytestmark = [pytest.mark.c,
              pytest.mark.skipif("c" not in kernel.available(),
                                 reason="canfdi._ckernel is not built here")]
I64 = np.iinfo(np.int64)


def _state(gate: TimeGate) -> tuple:
    return gate.ref, gate.offset, gate.chain, gate.jumps, gate.steps


def _same_over_blocks(t: np.ndarray, rows: np.ndarray, cuts: list[int], bound: int,
                      confirm: int) -> TimeGate:
    ref, c = TimeGate(bound, confirm), TimeGate(bound, confirm)
    kernel.get("c").install(gate=c)
    for lo, hi in itertools.pairwise([0, *cuts, len(t)]):
        sel = rows[(rows >= lo) & (rows < hi)] - lo
        want = ref.apply(t[lo:hi], sel)
        got = c.apply(t[lo:hi], sel)
        np.testing.assert_array_equal(got[0], want[0])
        np.testing.assert_array_equal(got[1], want[1])
        assert got[1].dtype == want[1].dtype and got[0].dtype == want[0].dtype
        assert _state(c) == _state(ref)
    return c


def _traffic(rng: np.random.Generator, n: int) -> np.ndarray:
    t = np.cumsum(rng.integers(0, 20, n)).astype(np.int64) + 10**18
    for _ in range(int(rng.integers(0, 8))):
        i, kind = int(rng.integers(0, n)), int(rng.integers(0, 5))
        if kind == 0 and abs(int(t[i])) < 1 << 62:
            t[i] += int(rng.choice([3600, -3600, 86400])) * 10**9
        elif kind == 1 and np.abs(t[i:]).max(initial=0) < 1 << 62:
            t[i:] += int(rng.choice([1, -1])) * int(rng.integers(1, 10**6))
        elif kind == 2:
            t[i] = 0
        elif kind == 3:
            t[i] = I64.max - int(rng.integers(0, 100))
        else:
            t[i:i + 20] = I64.min + int(rng.integers(0, 100))
    return t


@pytest.mark.parametrize("seed", range(60))
def test_c_gate_is_the_reference_block_after_block(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 3000))
    t = _traffic(rng, n)
    rows = np.flatnonzero(rng.random(n) < 0.8)
    cuts = sorted({int(c) for c in rng.integers(0, n, 3)})
    _same_over_blocks(t, rows, cuts, 100, int(rng.integers(1, 6)))


def test_steps_are_followed_alike_and_the_chain_carries_over_a_cut():
    t = np.concatenate([np.arange(0, 1000, 10), 10**12 + np.arange(0, 300, 10)]).astype(np.int64)
    rows = np.arange(len(t))
    for cut in (101, 103, 104, 105, 110):  # inside the confirming chain and after it
        gate = _same_over_blocks(t, rows, [cut], 100, 4)
        assert gate.steps and gate.jumps == 3


def test_times_near_int64s_ends_are_finished_by_the_reference():
    t = np.array([0, 10, I64.max, I64.max - 5, I64.max - 3, I64.max - 1, 20, I64.min,
                  I64.min + 1, I64.min + 2, I64.min + 3, I64.min + 4, 30], dtype=np.int64)
    _same_over_blocks(t, np.arange(len(t)), [], 100, 3)
    _same_over_blocks(t, np.arange(len(t)), [3, 8], 100, 3)


def test_random_times_over_fifty_years():
    rng = np.random.default_rng(1)
    t = rng.integers(0, 50 * 365 * 86400 * 10**9, 20_000)
    gate = _same_over_blocks(t, np.arange(len(t)), [5000], 10**6, 8)
    assert gate.jumps >= 19_990


@settings(max_examples=200, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow])
@given(steps=st.lists(st.integers(-10**6, 10**6), min_size=1, max_size=200),
       start=st.integers(-(1 << 62), 1 << 62), bound=st.integers(1, 10**5),
       confirm=st.integers(1, 6), cut=st.integers(0, 200))
def test_fuzz_c_gate_is_the_reference(steps, start, bound, confirm, cut):
    t = np.clip(start + np.cumsum(np.array(steps, dtype=object)), I64.min, I64.max)
    t = t.astype(np.int64)
    rows = np.arange(len(t))
    _same_over_blocks(t, rows, [min(cut, len(t))], bound, confirm)

"""The C core's sample clocks (canfdi/_c/latest.c: the trigger and grid clocks' samples;
canfdi/_c/counter.c: the counter clock's state machine) against the numpy reference: every
shipped bus's clock gives the same samples, statuses and counters on either kernel, clean and
hostile, cut anywhere; and the latest-value function alone on random blocks."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from canfdi.configs import CONFIG_DIR

from canfdi.bus.clock import latest_values
from canfdi.bus.frames import FrameBlock
from canfdi.config import load_config
from canfdi.core import kernel
from canfdi.monitor import Monitor
from tests.unit.core.test_kernel_decode import _hostile, _same_values

pytestmark = [pytest.mark.c,
              pytest.mark.skipif("c" not in kernel.available(),
                                 reason="canfdi._ckernel is not built here")]


def _cut(block: FrameBlock, lo: int, hi: int) -> FrameBlock:
    long = {r - lo: d for r, d in block.long.items() if lo <= r < hi}
    return FrameBlock(block.t_ns[lo:hi], block.id[lo:hi], block.dlc[lo:hi],
                      block.flags[lo:hi], block.data[lo:hi], long=long)


@pytest.mark.parametrize("name", ["dc_motor_cia402", "dc_motor_float",
                                  "dc_motor_two_drives_cia402", "dc_motor", "vtol",
                                  "winding_machine"])
@pytest.mark.parametrize("hostile", [False, True])
def test_every_clock_samples_alike_on_either_kernel(name, hostile):
    from canfdi.tools.bench import bench_scenarios, make_traffic

    config = load_config(CONFIG_DIR / f"{name}.yaml")
    _, faulty = bench_scenarios(config)
    traffic = make_traffic(8000, faulty)
    rng = np.random.default_rng(5)
    ref = Monitor(config, diagnose=False, kernel=kernel.get("python"))
    c = Monitor(config, diagnose=False, kernel=kernel.get("c"))
    if hostile:
        traffic = _hostile(traffic, rng, sorted({k[0] for d in ref.drives
                                                 for k in d.bus_map.keys}))
    cuts = [0, *sorted(rng.integers(1, traffic.size, 6).tolist()), traffic.size]
    samples = 0
    for lo, hi in itertools.pairwise(cuts):
        part = _cut(traffic, lo, hi)
        for a, b in zip(ref.drives, c.drives, strict=True):
            want, got = a.clock.push_batch(part), b.clock.push_batch(part)
            for field in ("k", "timestamp_ns", "gap", "statuses"):
                np.testing.assert_array_equal(getattr(got, field), getattr(want, field))
            _same_values(got.u, want.u)
            _same_values(got.z, want.z)
            assert got.stats == want.stats
            samples += len(want.k)
    assert samples > 1000


def test_the_counter_machine_hands_times_near_int64s_ends_to_python():
    """Times that cross 2^62 ns (year 2116) in a stretch of damaged traffic: the compiled
    machine stops there and the Python machine takes the rest from its state, with the same
    answers."""
    from canfdi.tools.bench import make_traffic

    config = load_config(CONFIG_DIR / "dc_motor.yaml")
    traffic = make_traffic(3000, "dc_motor_nominal")
    rng = np.random.default_rng(9)
    ref = Monitor(config, diagnose=False, kernel=kernel.get("python"))
    c = Monitor(config, diagnose=False, kernel=kernel.get("c"))
    block = _hostile(traffic, rng, [0x104, 0x105, 0x106])
    t = block.t_ns - int(block.t_ns[1500]) + (1 << 62)  # 2^62 ns at the 1500th frame
    block = FrameBlock(t, block.id, block.dlc, block.flags, block.data, long=block.long)
    for lo, hi in ((0, 1400), (1400, 3000)):
        want = ref.drives[0].clock.push_batch(_cut(block, lo, hi))
        got = c.drives[0].clock.push_batch(_cut(block, lo, hi))
        for field in ("k", "timestamp_ns", "gap", "statuses"):
            np.testing.assert_array_equal(getattr(got, field), getattr(want, field))
        _same_values(got.z, want.z)
        assert got.stats == want.stats


def test_the_function_alone_on_random_blocks():
    rng = np.random.default_rng(2)
    for _ in range(200):
        n, slots, cols, width = (int(rng.integers(0, 60)), int(rng.integers(1, 4)),
                                 int(rng.integers(1, 4)), int(rng.integers(1, 9)))
        dest = np.full((slots, cols), -1, dtype=np.int64)
        free = list(rng.permutation(width))
        for s in range(slots):
            for col in range(int(rng.integers(0, cols + 1))):
                if free:
                    dest[s, col] = free.pop()
        slot = rng.integers(0, slots, n).astype(np.int16)
        ok = np.flatnonzero(rng.random(n) < 0.7)
        t = np.cumsum(rng.integers(0, 50, n)).astype(np.int64)
        t[rng.random(n) < 0.05] = np.iinfo(np.int64).max  # wild times: numpy's int64 wrap
        values = rng.standard_normal((n, cols))
        values[rng.random(values.shape) < 0.1] = np.nan
        s = int(rng.integers(0, 20))
        upto = np.sort(rng.integers(-1, max(n, 1), s))
        instants = np.sort(rng.integers(0, 2000, s)).astype(np.int64)
        value0 = rng.standard_normal(width)
        time0 = rng.integers(-100, 100, width).astype(np.int64)
        args = (ok, slot, values, t, instants, upto, dest, float(rng.integers(1, 300)))
        v1, t1, v2, t2 = value0.copy(), time0.copy(), value0.copy(), time0.copy()
        want = latest_values(*args, v1, t1)
        got = kernel.get("c").latest_values(*args, v2, t2)
        _same_values(got, want)
        _same_values(v2, v1)
        np.testing.assert_array_equal(t2, t1)


def test_rows_out_of_order_are_an_error_not_a_read_outside():
    args = (np.array([3, 1]), np.zeros(4, np.int16), np.zeros((4, 1)), np.zeros(4, np.int64),
            np.zeros(1, np.int64), np.zeros(1, np.int64), np.zeros((1, 1), np.int64), 1.0,
            np.zeros(1), np.zeros(1, np.int64))
    with pytest.raises(ValueError, match="status"):
        kernel.get("c").latest_values(*args)
    bad = list(args)
    bad[0] = np.array([9])  # a row past the block
    with pytest.raises(ValueError, match="status"):
        kernel.get("c").latest_values(*bad)
    bad = list(args)
    bad[0], bad[5] = np.array([1]), np.array([5, 2])  # upto decreasing
    bad[4] = np.zeros(2, np.int64)
    with pytest.raises(ValueError, match="status"):
        kernel.get("c").latest_values(*bad)

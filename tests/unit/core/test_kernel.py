"""canfdi.core.kernel: the C kernel against the numpy reference, function by function (the
whole diagnosers on both kernels: tests/methods/test_conformance.py)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from canfdi.core import kernel
from canfdi.core.detect import ChangePointDetector, change_point_block
from canfdi.core.residuals import fir_rows


def test_a_kernel_is_named_and_an_unknown_or_unbuilt_one_says_so():
    assert kernel.get("python").name == "python"
    with pytest.raises(kernel.KernelError, match="expected one of c, python, got 'gpu'"):
        kernel.get("gpu")
    assert kernel.resolve("python").name == "python"
    assert kernel.resolve(None, env={"CANFDI_KERNEL": "python"}).name == "python"
    default = kernel.resolve(None, env={}).name
    assert default == ("c" if "c" in kernel.available() else "python")


def _bank_case(rng, S, width, m, rows, lost):
    blocks = rng.standard_normal((S + 1, width, m))
    blocks[rng.random(blocks.shape) < 0.3] = 0.0  # entries a residual does not read
    uses = (blocks != 0).astype(float)
    x = rng.standard_normal((rows, width)) * 10.0 ** rng.integers(-3, 3, width)
    x[rng.random(x.shape) < lost] = np.nan
    return x, blocks, uses


@pytest.mark.c
@pytest.mark.parametrize(("S", "width", "m", "rows", "lost"),
                         [(0, 1, 1, 1, 0.0), (4, 6, 5, 300, 0.0), (8, 9, 12, 1000, 0.02),
                          (3, 2, 3, 50, 0.5), (10, 4, 2, 11, 1.0),
                          # windows too wide to stage on the stack: the strided path
                          (30, 12, 3, 203, 0.0), (30, 12, 3, 203, 0.01)])
def test_c_residuals_are_numpys_to_rounding_and_missing_alike(S, width, m, rows, lost):
    rng = np.random.default_rng(S * 100 + width)
    x, blocks, uses = _bank_case(rng, S, width, m, rows, lost)
    ref = fir_rows(x, blocks, uses)
    got = kernel.get("c").fir_rows(x, blocks, uses)
    assert got.shape == ref.shape == (rows - S, m)
    np.testing.assert_array_equal(np.isnan(got), np.isnan(ref))
    scale = np.nanmax(np.abs(ref), initial=1.0)
    np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-12 * scale)


@pytest.mark.c
def test_c_residuals_refuse_sizes_that_do_not_fit():
    rng = np.random.default_rng(1)
    x, blocks, uses = _bank_case(rng, 4, 3, 2, 20, 0.0)
    with pytest.raises(ValueError, match="x: expected shape"):
        kernel.get("c").fir_rows(x[:, :2], blocks, uses)
    with pytest.raises(ValueError, match="sizes do not fit"):
        kernel.get("c").fir_rows(x[:4], blocks, uses)  # rows <= S


def _detector_case(rng, n, c, lost, jump_at):
    x = rng.standard_normal((n, c))
    x[rng.random(x.shape) < lost] = np.nan
    if jump_at is not None:
        x[jump_at:, rng.integers(c)] += rng.choice([-2.5, 2.5])
    delta = rng.uniform(0.1, 0.8, c)
    h = rng.uniform(5.0, 40.0, c)
    state = rng.uniform(0.0, 3.0, (c, 2)) * (rng.random((c, 2)) < 0.5)
    last_zero = rng.integers(-5, 5, (c, 2))
    return np.arange(1000, 1000 + n), x, delta, h, state, last_zero


@pytest.mark.c
@pytest.mark.parametrize(("n", "c", "lost", "jump_at"),
                         [(0, 1, 0.0, None), (1, 3, 0.0, None), (500, 4, 0.05, 300),
                          (9000, 3, 0.01, None), (9000, 2, 0.0, 8500), (200, 6, 1.0, None),
                          (60, 5, 0.2, 0)])
def test_c_page_hinkley_is_numpys_bit_for_bit(n, c, lost, jump_at):
    """The same closed form op for op (over 4,096-row segments, as numpy restarts its sums):
    statistics, alarm row, signs, state and change dating equal exactly."""
    rng = np.random.default_rng(n + c)
    args = _detector_case(rng, n, c, lost, jump_at)
    ref = change_point_block(*args)
    got = kernel.get("c").change_point_block(*args)
    assert got.done == ref.done
    for name in ("g_up", "g_down", "alarm", "state", "last_zero"):
        np.testing.assert_array_equal(getattr(got, name), getattr(ref, name), err_msg=name)
    if jump_at is not None and n > 1000:
        assert ref.done < n  # the case has an alarm


@pytest.mark.c
def test_a_detector_on_either_kernel_runs_the_same_blocks():
    """ChangePointDetector with projections, block after block to each alarm and on: the
    same rows done, alarms, statistics and change points on both kernels."""
    rng = np.random.default_rng(8)
    rn = rng.standard_normal((3000, 3))
    rn[rng.random(rn.shape) < 0.05] = np.nan
    for start in (700, 1500, 2400):
        rn[start:start + 200] += np.array([0.9, 0.9, 0.0])
    proj = np.array([[1.0, 1.0], [1.0, 1.0], [0.0, 0.0]]) / np.sqrt(2.0)
    dets = []
    for name in ("python", "c"):
        det = ChangePointDetector(3, 0.5, np.full(3, 30.0), projection=proj,
                                  drifts=[0.25, 0.5], h_projected=[12.0, 10.0])
        kernel.get(name).install(detectors=(det,))
        dets.append(det)
    k = np.arange(3000)
    i, seen = 0, []
    while i < len(k):
        blocks = [det.update_block(k[i:], rn[i:]) for det in dets]
        assert blocks[0].done == blocks[1].done
        np.testing.assert_array_equal(blocks[0].alarm, blocks[1].alarm)
        np.testing.assert_array_equal(dets[0].statistics, dets[1].statistics)
        i += blocks[0].done
        if i < len(k):
            alarm = dets[0].update(int(k[i]), rn[i])
            np.testing.assert_array_equal(alarm, dets[1].update(int(k[i]), rn[i]))
            assert dets[0].change_point(alarm) == dets[1].change_point(alarm)
            seen.append(i)
            for det in dets:
                det.reset(int(k[i]))
            i += 1
    assert len(seen) >= 3


# -- differential fuzz: random shapes, values and lost entries through both kernels -----------

FUZZ = settings(max_examples=300, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
REALS = st.floats(min_value=-1e6, max_value=1e6, allow_nan=False, width=64)


@st.composite
def bank_cases(draw):
    S = draw(st.integers(0, 12))
    width, m = draw(st.integers(1, 10)), draw(st.integers(1, 12))
    rows = draw(st.integers(S + 1, S + 60))
    blocks = draw(hnp.arrays(np.float64, (S + 1, width, m), elements=REALS))
    blocks[draw(hnp.arrays(bool, blocks.shape))] = 0.0
    x = draw(hnp.arrays(np.float64, (rows, width), elements=REALS))
    x[draw(hnp.arrays(bool, x.shape)) & draw(hnp.arrays(bool, x.shape))] = np.nan
    return x, blocks, (blocks != 0).astype(float)


@pytest.mark.c
@FUZZ
@given(bank_cases())
def test_fuzz_c_residuals_equal_numpys(case):
    x, blocks, uses = case
    ref = fir_rows(x, blocks, uses)
    got = kernel.get("c").fir_rows(x, blocks, uses)
    np.testing.assert_array_equal(np.isnan(got), np.isnan(ref))
    # To rounding of the terms summed: each output's bound is its sum of |terms|.
    terms = fir_rows(np.abs(np.nan_to_num(x)), np.abs(blocks), uses)
    present = ~np.isnan(ref)
    assert np.all(np.abs(got - ref)[present] <= 1e-12 * terms[present] + 1e-300)


@st.composite
def detector_cases(draw):
    n, c = draw(st.integers(0, 300)), draw(st.integers(1, 8))
    x = draw(hnp.arrays(np.float64, (n, c), elements=st.floats(-20, 20, allow_nan=False)))
    x[draw(hnp.arrays(bool, x.shape))] = np.nan
    delta = draw(hnp.arrays(np.float64, c, elements=st.floats(0.0, 2.0)))
    h = draw(hnp.arrays(np.float64, c, elements=st.floats(0.01, 200.0)))
    state = draw(hnp.arrays(np.float64, (c, 2), elements=st.floats(0.0, 50.0)))
    last_zero = draw(hnp.arrays(np.int64, (c, 2), elements=st.integers(-10, 10)))
    start = draw(st.integers(-(1 << 40), 1 << 40))
    return np.arange(start, start + n, dtype=np.int64), x, delta, h, state, last_zero


@pytest.mark.c
@FUZZ
@given(detector_cases())
def test_fuzz_c_page_hinkley_is_numpys_bit_for_bit(case):
    ref = change_point_block(*case)
    got = kernel.get("c").change_point_block(*case)
    assert got.done == ref.done
    for name in ("g_up", "g_down", "alarm", "state", "last_zero"):
        np.testing.assert_array_equal(getattr(got, name), getattr(ref, name), err_msg=name)

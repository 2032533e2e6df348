"""Tests of canfdi.core.detect and canfdi.core.calibrate: the Page-Hinkley test and its design."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from scipy import signal

from canfdi.core.calibrate import (
    SIEGMUND_OVERSHOOT,
    arl_one_sided,
    arl_two_sided,
    calibrate_threshold,
    false_alarm_interval,
    threshold_for_false_alarm_interval,
    threshold_for_long_run_variance,
)
from canfdi.core.detect import ChangePointDetector, onset_candidates, page_hinkley_batch

# --------------------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------------------


def run_steps(x, delta, h, *, mu0=0.0, sigma=1.0, state=None, restart=False):
    """Reference: the recursion written out, sample by sample and residual by residual, as
    Basseville and Nikiforov state it (a NaN residual is missing: its statistics hold)."""
    n, m = x.shape
    delta, h, mu0, sigma = (np.broadcast_to(np.asarray(v, dtype=float), (m,))
                            for v in (delta, h, mu0, sigma))
    st_ = np.zeros((m, 2)) if state is None else np.array(state, dtype=float)
    g_up = np.empty((n, m))
    g_down = np.empty((n, m))
    alarms = np.zeros((n, m), dtype=np.int8)
    for k in range(n):
        for i in range(m):
            u = (x[k, i] - mu0[i]) / sigma[i]
            if not np.isnan(u):
                st_[i, 0] = max(0.0, st_[i, 0] + (u - delta[i]))
                st_[i, 1] = max(0.0, st_[i, 1] + (-u - delta[i]))
            g_up[k, i], g_down[k, i] = st_[i]
            if max(st_[i]) >= h[i]:
                alarms[k, i] = 1 if st_[i, 0] >= st_[i, 1] else -1
                if restart:
                    st_[i] = 0.0
    return g_up, g_down, alarms, st_


def assert_same_run(result, g_up, g_down, alarms, state):
    np.testing.assert_array_equal(result.alarms, alarms)
    assert result.alarms.dtype == np.int8
    # Once a statistic has climbed to G, both summation orders carry rounding of order
    # eps * G into it, even after it falls back: the tolerance scales with the largest G.
    atol = 1e-12 * max(1.0, float(np.max(g_up, initial=0)), float(np.max(g_down, initial=0)))
    np.testing.assert_allclose(result.g_up, g_up, rtol=1e-12, atol=atol)
    np.testing.assert_allclose(result.g_down, g_down, rtol=1e-12, atol=atol)
    np.testing.assert_allclose(result.state, state, rtol=1e-12, atol=atol)


def record_with_changes(seed, n=10_000, m=3):
    """Gaussian residuals with up and down steps, so that both directions alarm."""
    gen = np.random.default_rng(seed)
    x = gen.standard_normal((n, m))
    x[n // 4 : n // 2, 0] += 1.5
    x[n // 3 :, 1] -= 1.0
    x[::997, 2] += 6.0
    return x


def first_alarm_times(gen, runs, mean, delta, h, block):
    """Run length (alarm sample counted) of `runs` independent two-sided tests.

    The runs are the columns of one page_hinkley_batch call; the record is extended block
    by block, carrying the state, only for the runs that have not alarmed yet.
    """
    run_length = np.zeros(runs, dtype=np.int64)
    state = np.zeros((runs, 2))
    todo = np.arange(runs)
    offset = 0
    while todo.size:
        x = gen.normal(mean, 1.0, size=(block, todo.size))
        res = page_hinkley_batch(x, delta, h, state=state[todo])
        hit = res.alarms != 0
        found = hit.any(axis=0)
        run_length[todo[found]] = offset + hit.argmax(axis=0)[found] + 1
        state[todo] = res.state
        todo = todo[~found]
        offset += block
    return run_length


def ar1(gen, n, phi):
    """Stationary AR(1) Gaussian noise of unit variance, shape (n,)."""
    w = gen.standard_normal(n)
    zi = [phi * gen.standard_normal()]
    y, _ = signal.lfilter([np.sqrt(1.0 - phi**2)], [1.0, -phi], w, zi=zi)
    return y


# --------------------------------------------------------------------------------------
# Page-Hinkley: batch against the recursion, chunks, streaming
# --------------------------------------------------------------------------------------


def test_page_hinkley_hand_computed_with_initial_state():
    # g+: 3 - 1.5 = 1.5, 1.5 - 1.5 = 0, 0 + 1.5 = 1.5
    # g-: 0 + 0.5 = 0.5, 0.5 + 0.5 = 1.0, max(0, 1 - 2.5) = 0
    x = np.array([[-1.0], [-1.0], [2.0]])
    res = page_hinkley_batch(x, delta=0.5, h=1.5, state=[[3.0, 0.0]])
    np.testing.assert_array_equal(res.g_up[:, 0], [1.5, 0.0, 1.5])
    np.testing.assert_array_equal(res.g_down[:, 0], [0.5, 1.0, 0.0])
    # inclusive threshold: g+ == h alarms
    np.testing.assert_array_equal(res.alarms[:, 0], [1, 0, 1])
    np.testing.assert_array_equal(res.state, [[1.5, 0.0]])


def test_page_hinkley_initial_state_shifts_start():
    # g_k = max(g0 + S_k, S_k - min_{0<=j<=k} S_j): the initial value survives only until
    # the statistic first hits zero.
    gen = np.random.default_rng(3)
    x = gen.normal(-0.2, 1.0, size=(200, 1))
    g0 = 4.0
    res = page_hinkley_batch(x, delta=0.3, h=100.0, state=[[g0, 0.0]])
    s = np.concatenate([[0.0], np.cumsum(x[:, 0] - 0.3)])
    expected = np.maximum(g0 + s[1:], s[1:] - np.minimum.accumulate(s)[1:])
    np.testing.assert_allclose(res.g_up[:, 0], expected, rtol=1e-12, atol=1e-12)
    assert expected[0] > 0 and np.any(expected == 0)


@pytest.mark.parametrize("restart", [False, True])
def test_page_hinkley_batch_equals_steps(restart):
    x = record_with_changes(11)
    delta = np.array([0.5, 0.25, 0.5])
    h = np.array([5.0, 8.0, 4.0])
    mu0 = np.array([0.0, 0.1, -0.1])
    sigma = np.array([1.0, 1.2, 0.9])
    ref = run_steps(x, delta, h, mu0=mu0, sigma=sigma, restart=restart)
    res = page_hinkley_batch(x, delta, h, mu0=mu0, sigma=sigma, restart_on_alarm=restart)
    assert_same_run(res, *ref)
    n_alarms = np.count_nonzero(res.alarms, axis=0)
    assert np.all(n_alarms > 0)
    assert np.any(res.alarms == 1) and np.any(res.alarms == -1)
    if restart:
        # every alarm is one sample; without restart a persistent change stays in alarm
        assert not np.any((res.alarms[1:] != 0) & (res.alarms[:-1] != 0))
    else:
        assert np.any((res.alarms[1:] != 0) & (res.alarms[:-1] != 0))


@pytest.mark.parametrize("restart", [False, True])
def test_missing_residuals_hold_their_statistics_in_both_forms(restart):
    x = record_with_changes(13)
    rng = np.random.default_rng(3)
    gappy = np.where(rng.random(x.shape) < 0.2, np.nan, x)
    delta, h = np.array([0.5, 0.25, 0.5]), np.array([5.0, 8.0, 4.0])
    ref = run_steps(gappy, delta, h, restart=restart)
    res = page_hinkley_batch(gappy, delta, h, restart_on_alarm=restart)
    assert_same_run(res, *ref)
    # A missing value adds nothing: the statistics after it are those before it.
    rows, cols = np.nonzero(np.isnan(gappy[1:]))
    rows += 1
    held = res.alarms[rows - 1, cols] == 0  # (after an alarm a restart may zero them)
    np.testing.assert_array_equal(res.g_up[rows, cols][held], res.g_up[rows - 1, cols][held])
    np.testing.assert_array_equal(res.g_down[rows, cols][held],
                                  res.g_down[rows - 1, cols][held])
    # And the run equals one over the record with the missing samples left out, per residual.
    if not restart:
        for c in range(x.shape[1]):
            keep = ~np.isnan(gappy[:, c])
            alone = page_hinkley_batch(gappy[keep, c:c + 1], delta[c], h[c])
            np.testing.assert_allclose(res.g_up[keep, c], alone.g_up[:, 0], atol=1e-9)


@pytest.mark.parametrize("restart", [False, True])
def test_page_hinkley_chunked_equals_single_call(restart):
    x = record_with_changes(12)
    delta, h = 0.5, 5.0
    single = page_hinkley_batch(x, delta, h, restart_on_alarm=restart)
    state = None
    parts = []
    for chunk in np.split(x, [1234, 1235]):  # uneven, including a one-sample chunk
        res = page_hinkley_batch(x=chunk, delta=delta, h=h, state=state, restart_on_alarm=restart)
        parts.append(res)
        state = res.state
    np.testing.assert_array_equal(np.concatenate([p.alarms for p in parts]), single.alarms)
    atol = 1e-12 * max(single.g_up.max(), single.g_down.max())
    for field in ("g_up", "g_down"):
        joined = np.concatenate([getattr(p, field) for p in parts])
        np.testing.assert_allclose(joined, getattr(single, field), rtol=1e-12, atol=atol)
    np.testing.assert_allclose(state, single.state, rtol=1e-12, atol=atol)


def test_restart_state_is_zero_after_alarm_on_last_sample():
    x = np.array([[0.0], [10.0]])
    res = page_hinkley_batch(x, 0.5, 5.0, restart_on_alarm=True)
    np.testing.assert_array_equal(res.alarms[:, 0], [0, 1])
    np.testing.assert_array_equal(res.state, [[0.0, 0.0]])
    res = page_hinkley_batch(x, 0.5, 5.0)
    np.testing.assert_array_equal(res.state, [[9.5, 0.0]])


finite = {"allow_nan": False, "allow_infinity": False}


@st.composite
def page_hinkley_cases(draw):
    n = draw(st.integers(1, 40))
    m = draw(st.integers(1, 3))
    x = draw(hnp.arrays(np.float64, (n, m), elements=st.floats(-6, 6, **finite)))
    delta = draw(hnp.arrays(np.float64, (m,), elements=st.floats(0, 2, **finite)))
    h = draw(hnp.arrays(np.float64, (m,), elements=st.floats(0.05, 10, **finite)))
    state = draw(hnp.arrays(np.float64, (m, 2), elements=st.floats(0, 12, **finite)))
    cuts = sorted(draw(st.lists(st.integers(0, n), min_size=2, max_size=2)))
    return x, delta, h, state, cuts


@settings(max_examples=300, deadline=None)
@given(case=page_hinkley_cases(), restart=st.booleans())
def test_page_hinkley_batch_equals_steps_property(case, restart):
    x, delta, h, state, cuts = case
    ref = run_steps(x, delta, h, state=state, restart=restart)
    res = page_hinkley_batch(x, delta, h, state=state, restart_on_alarm=restart)
    # A statistic within rounding of h may fall either side of it depending on the order
    # of the additions (sequential vs cumulative sum); that tie is not a defect.
    g_ref = np.stack(ref[:2])
    g_res = np.stack([res.g_up, res.g_down])
    assume(not np.any((np.abs(g_ref - h) < 1e-9) & (g_ref != g_res)))
    assert_same_run(res, *ref)
    chunk_state = state
    alarms = []
    for chunk in np.split(x, cuts):
        part = page_hinkley_batch(chunk, delta, h, state=chunk_state, restart_on_alarm=restart)
        alarms.append(part.alarms)
        chunk_state = part.state
    np.testing.assert_array_equal(np.concatenate(alarms), ref[2])
    np.testing.assert_allclose(chunk_state, ref[3], rtol=1e-12, atol=1e-12)


def test_streaming_detector_matches_batch_and_keeps_running_after_an_alarm():
    """ChangePointDetector.update, sample by sample, gives page_hinkley_batch's alarms and
    statistics; nothing resets on an alarm (a persistent change stays in alarm) until reset."""
    x = record_with_changes(13, n=3000)
    h = np.array([5.0, 5.0, 5.0])
    det = ChangePointDetector(3, 0.5, h)
    alarms = np.array([det.update(k, row) for k, row in enumerate(x)])
    res = page_hinkley_batch(x, 0.5, h)
    np.testing.assert_array_equal(alarms, res.alarms)
    np.testing.assert_allclose(det.statistics, res.state.max(axis=1), rtol=1e-12, atol=1e-12)
    # no self-reset: residual 1 is still in alarm at the end of its persistent step
    assert alarms[-1, 1] == -1 and det.statistics[1] > 5.0
    det.reset()
    np.testing.assert_array_equal(det.statistics, np.zeros(3))


def test_known_mean_is_used_not_estimated():
    # A constant offset equal to mu0 never alarms; the same offset with mu0 = 0 alarms up,
    # and keeps alarming (a running-mean test would absorb it).
    x = np.full((500, 1), 3.0)
    assert not np.any(page_hinkley_batch(x, 0.5, 4.0, mu0=3.0).alarms)
    alarms = page_hinkley_batch(x, 0.5, 4.0).alarms[:, 0]
    assert alarms[1] == 1 and np.all(alarms[1:] == 1)


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"delta": -0.1}, "delta"),
        ({"h": 0.0}, "h"),
        ({"sigma": 0.0}, "sigma"),
        ({"mu0": float("nan")}, "mu0"),
        ({"state": np.zeros((3, 2))}, "state"),
        ({"state": -np.ones((2, 2))}, "state"),
        ({"x": np.zeros(5)}, "x"),
        ({"x": np.full((5, 2), np.inf)}, "x"),
        ({"h": [1.0, 2.0, 3.0]}, "h"),
    ],
)
def test_page_hinkley_rejects_bad_arguments(kwargs, name):
    args = {"x": np.zeros((5, 2)), "delta": 0.5, "h": 4.0} | kwargs
    with pytest.raises(ValueError, match=name):
        page_hinkley_batch(**args)


def test_streaming_detector_rejects_an_infinite_residual():
    det = ChangePointDetector(2, 0.5, [4.0, 4.0])
    with pytest.raises(ValueError, match="x"):
        det.update(0, np.array([np.inf, 0.0]))


# --------------------------------------------------------------------------------------
# Siegmund's approximation against Monte Carlo
# --------------------------------------------------------------------------------------


def test_siegmund_arl0_false_alarm_interval_monte_carlo():
    """Siegmund's ARL approximation: two-sided false-alarm interval within 10%.

    delta = 0.5, h = 4 gives about 170 samples; 4000 runs make the Monte Carlo standard
    error about 1.6%, and Siegmund is accurate to ~1% here (measured 167.9 vs 169.0).
    """
    predicted = false_alarm_interval(0.5, 4.0)
    assert 160 < predicted < 180
    run_length = first_alarm_times(np.random.default_rng(1985), 4000, 0.0, 0.5, 4.0, 1000)
    assert run_length.min() >= 1
    assert run_length.mean() == pytest.approx(predicted, rel=0.10)


def test_siegmund_mean_detection_delay_monte_carlo():
    """Siegmund's ARL approximation: worst-case mean delay for a 1.5 sigma step within 10%.

    The statistics are zero when the change occurs (worst case); delta = 0.5, h = 4 gives
    4.67 samples (measured 4.75 over 20000 runs).
    """
    predicted = arl_one_sided(1.5 - 0.5, 4.0)  # the statistic drifts by |change| - delta
    run_length = first_alarm_times(np.random.default_rng(1993), 20_000, 1.5, 0.5, 4.0, 100)
    assert run_length.mean() == pytest.approx(predicted, rel=0.10)


def test_arl_formula_values_and_small_mu_limit():
    b = 4.0 + SIEGMUND_OVERSHOOT
    assert arl_one_sided(0.0, 4.0) == pytest.approx(b**2, rel=1e-15)
    mu = -0.5
    closed = (np.exp(-2 * mu * b) + 2 * mu * b - 1) / (2 * mu**2)
    assert arl_one_sided(mu, 4.0) == pytest.approx(closed, rel=1e-14)
    # continuous across the switch between the series and the closed form
    t_switch = 0.1 / (2 * b)
    for sign in (1.0, -1.0):
        below = arl_one_sided(sign * t_switch * (1 - 1e-9), 4.0)
        above = arl_one_sided(sign * t_switch * (1 + 1e-9), 4.0)
        assert below == pytest.approx(above, rel=1e-9)
    tiny = np.array([-1e-9, 1e-12, 1e-9])
    np.testing.assert_allclose(arl_one_sided(tiny, 4.0), b**2, rtol=1e-7)
    # monotone: a larger mean reaches the threshold sooner
    mus = np.linspace(-1.0, 2.0, 301)
    assert np.all(np.diff(arl_one_sided(mus, 4.0)) < 0)
    with np.errstate(all="raise"):
        assert arl_one_sided(-200.0, 4.0) == np.inf
    assert false_alarm_interval(0.5, 4.0) == pytest.approx(arl_one_sided(-0.5, 4.0) / 2)
    assert arl_two_sided(100.0, np.inf) == 100.0
    assert arl_two_sided(100.0, 300.0) == pytest.approx(75.0)
    with pytest.raises(ValueError, match="arl_down"):
        arl_two_sided(1.0, 0.0)
    with pytest.raises(ValueError, match="h"):
        arl_one_sided(0.0, -1.0)
    with pytest.raises(ValueError, match="delta"):
        false_alarm_interval(-0.5, 4.0)


@pytest.mark.parametrize("delta", [0.0, 0.25, 0.5, 1.0])
@pytest.mark.parametrize("arl0", [20.0, 1e3, 1e6])
def test_threshold_for_false_alarm_interval_roundtrip(delta, arl0):
    h = threshold_for_false_alarm_interval(delta, arl0)
    assert h > 0
    assert false_alarm_interval(delta, h) == pytest.approx(arl0, rel=1e-9)


def test_threshold_for_false_alarm_interval_rejects_unreachable_target():
    with pytest.raises(ValueError, match="arl0"):
        threshold_for_false_alarm_interval(0.5, 1.0)
    with pytest.raises(ValueError, match="delta"):
        threshold_for_false_alarm_interval(-0.5, 100.0)


# --------------------------------------------------------------------------------------
# empirical calibration
# --------------------------------------------------------------------------------------


def test_calibrate_threshold_on_correlated_noise():
    gen = np.random.default_rng(806)
    n, target, delta, phi = 200_000, 500.0, 0.5, 0.8

    def record():
        return np.column_stack([ar1(gen, n, phi), gen.standard_normal(n)])

    h = calibrate_threshold(record(), delta, target)
    h_white = threshold_for_false_alarm_interval(delta, target)
    # AR(1) partial sums have long-run variance (1 + phi) / (1 - phi) = 9 times that of
    # white noise: the white-noise design is far too low for them.
    assert h[0] > 2.0 * h_white
    # for a white residual the empirical and Siegmund designs agree
    assert h[1] == pytest.approx(h_white, rel=0.10)
    alarms = page_hinkley_batch(record(), delta, h, restart_on_alarm=True).alarms
    arl0 = n / np.count_nonzero(alarms, axis=0)
    assert np.all(arl0 > target / 2) and np.all(arl0 < 2 * target)
    # the white-noise threshold on the correlated residual misses the target badly
    n_white = np.count_nonzero(page_hinkley_batch(record()[:, :1], delta, h_white,
                                                  restart_on_alarm=True).alarms)
    assert n / n_white < target / 2


def test_calibrate_threshold_rejects_bad_arguments():
    with pytest.raises(ValueError, match="target_arl0"):
        calibrate_threshold(np.zeros((10, 1)), 0.5, 0.0)
    with pytest.raises(ValueError, match="x_fault_free"):
        calibrate_threshold(np.zeros(10), 0.5, 100.0)
    with pytest.raises(ValueError, match="tol"):
        calibrate_threshold(np.zeros((10, 1)), 0.5, 100.0, tol=0.0)


def change_points(det, width):
    """(width, 2) the change point each column's up and down statistic would date an alarm
    to: the detector's dating, read through change_point one statistic at a time."""
    return np.array([[det.change_point(np.eye(width, dtype=np.int8)[c] * sign)
                      for sign in (1, -1)] for c in range(width)])


def assert_same_detector(block, stream, width, k_next, rows):
    """Same statistics and change points now, and the same alarms on the rows that follow."""
    np.testing.assert_allclose(block.statistics, stream.statistics, rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(change_points(block, width), change_points(stream, width))
    for i, row in enumerate(rows):
        np.testing.assert_array_equal(block.update(k_next + i, row),
                                      stream.update(k_next + i, row))


def test_change_point_detector_block_form_leaves_the_streaming_state():
    """update_block() stops before the first alarm row with the state and change points that
    update() reaches on the same rows; the change point dates the alarm; reset(k) dates later
    changes from k."""
    rng = np.random.default_rng(5)
    rn = rng.standard_normal((400, 3))
    rn[rng.random(rn.shape) < 0.1] = np.nan
    rn[300:, 1] += 3.0  # a change at sample 300 on residual 1
    k = np.arange(1000, 1400)
    h = np.array([40.0, 8.0, 40.0])
    block, stream = ChangePointDetector(3, 0.5, h), ChangePointDetector(3, 0.5, h)
    blk = block.update_block(k, rn)
    done = blk.done
    assert 300 < done < 320 and blk.alarm.any() and len(blk.g_up) == done + 1
    for r in range(done):
        assert not stream.update(int(k[r]), rn[r]).any()
    np.testing.assert_array_equal(change_points(block, 3), change_points(stream, 3))
    alarm = block.update(int(k[done]), rn[done])
    np.testing.assert_array_equal(alarm, blk.alarm)
    np.testing.assert_array_equal(stream.update(int(k[done]), rn[done]), alarm)
    assert alarm[1] == 1 and abs(stream.change_point(alarm) - 1300) <= 5
    assert block.change_point(alarm) == stream.change_point(alarm)
    assert_same_detector(block, stream, 3, int(k[done]) + 1, rn[done + 1:])
    stream.reset(1400)
    assert (stream.statistics == 0).all() and (change_points(stream, 3) == 1401).all()
    alarm = stream.update(1401, np.array([0.0, 100.0, 0.0]))
    assert alarm.tolist() == [0, 1, 0] and stream.change_point(alarm) == 1401


def test_onset_candidates():
    assert onset_candidates(100, 110, 0, 3, 16) == list(range(97, 111))
    assert onset_candidates(100, 110, 0, 3, 5) == list(range(106, 111))
    assert onset_candidates(100, 110, 99, 3, 16) == list(range(99, 111))
    assert onset_candidates(100, 110, 200, 3, 16) == [110]


def test_threshold_for_long_run_variance():
    """White residuals (L <= 1) get Siegmund's threshold; a 5-sample moving sum (L = 5, the DC
    motor's s:omega_r) gets sqrt(5) h(0.5 / sqrt(5)): 69.9 at 1e7 samples."""
    white = threshold_for_false_alarm_interval(0.5, 1e7)
    h = threshold_for_long_run_variance(0.5, 1e7, [0.3, 1.0, 5.0])
    assert h[0] == h[1] == white
    assert h[2] == pytest.approx(69.94, abs=0.01) and h[2] > white


def test_change_point_detector_with_projections_block_and_stream_agree():
    """Projected columns (rn @ projection, their own drifts and thresholds) run beside the
    residuals: block and stream leave the same state and date the change alike; a row with
    a missing residual leaves the projections' statistics as they were; setting the
    residuals' thresholds leaves the projections'."""
    rng = np.random.default_rng(8)
    rn = rng.standard_normal((600, 3))
    rn[rng.random(rn.shape) < 0.05] = np.nan
    rn[400:] += np.array([0.6, 0.6, 0.0])  # small on each residual, larger on their sum
    k = np.arange(2000, 2600)
    proj = np.array([[1.0, 1.0], [1.0, 1.0], [0.0, 0.0]]) / np.sqrt(2.0)
    args = (3, 0.5, np.full(3, 40.0))
    kw = {"projection": proj, "drifts": [0.25, 0.5], "h_projected": [12.0, 10.0]}
    block, stream = ChangePointDetector(*args, **kw), ChangePointDetector(*args, **kw)
    blk = block.update_block(k, rn)
    done = blk.done
    assert blk.g_up.shape == (done + 1, 5) and 400 < done < 600
    assert not blk.alarm[:3].any() and blk.alarm[3:].any()  # the sum saw it
    for r in range(done):
        stream.update(int(k[r]), rn[r])
    np.testing.assert_array_equal(change_points(block, 5), change_points(stream, 5))
    np.testing.assert_allclose(block.statistics, stream.statistics, rtol=1e-12, atol=1e-12)
    alarm = stream.update(int(k[done]), rn[done])
    np.testing.assert_array_equal(block.update(int(k[done]), rn[done]), alarm)
    assert abs(stream.change_point(alarm) - 2400) <= 40
    # A missing residual makes the projections missing: stream skips a row that block never
    # sees (one that would swing the sums far down), and their projections' alarms and datings
    # stay alike.
    stream.update(int(k[done]) + 1, np.array([np.nan, -100.0, -100.0]))
    np.testing.assert_array_equal(change_points(block, 5)[3:], change_points(stream, 5)[3:])
    # Lower residual thresholds raise residual alarms, not projection ones.
    stream.h = np.full(3, 7.0)
    np.testing.assert_array_equal(stream.h, [7.0, 7.0, 7.0])
    for i, row in enumerate(rn[done + 1:]):
        kk = int(k[done]) + 2 + i
        np.testing.assert_array_equal(block.update(kk, row)[3:], stream.update(kk, row)[3:])
    assert stream.statistics.shape == (3,)

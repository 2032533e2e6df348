"""The signature CUSUMs beside Page-Hinkley (canfdi.methods.parity.signatures): their
projections, their calibrated false-alarm rate and what they buy on a small fault."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from canfdi.config import load_config
from canfdi.core.design import design_bank
from canfdi.core.detect import page_hinkley_batch
from canfdi.core.residuals import ResidualBank
from canfdi.firmware_sim.scenario import parse_scenario
from canfdi.firmware_sim.simulate import simulate
from canfdi.methods import build_diagnoser
from canfdi.methods.parity.signatures import DRIFTS, signature_columns
from canfdi.methods.parity.thresholds import (
    calibrate_thresholds,
    instant_covariance,
    long_run_covariance,
)
from tests.conftest import REPO

CONFIG = load_config(REPO / "deploy" / "config" / "dc_motor.yaml")
MEAS = np.full(4, 0.01)


def _bank():
    design = design_bank(CONFIG.model, CONFIG.inputs, CONFIG.outputs, CONFIG.design)
    return design, ResidualBank(design)


def _fault_free(bank, n, seed):
    rng = np.random.default_rng(seed)
    x = np.zeros((n + bank.S, bank.q + bank.p))
    x[:, : bank.q] = rng.standard_normal((len(x), bank.q)) * MEAS
    return bank.batch(x) / bank.sigma


def test_one_column_per_signature_and_drift_with_unit_variance():
    """Proportional signatures share a projection (i_a and i_f + i_a cannot be told apart);
    omega_r, which no residual sees, has none; each projection of fault-free residuals has
    unit variance, its long-run variance what the exact formula says, and a positive fault
    moves it up."""
    design, bank = _bank()
    sig = signature_columns(bank, MEAS, design.input_names, design.output_names)
    assert sig is not None and sig.rungs == len(DRIFTS)
    assert list(dict.fromkeys(sig.names)) == ["cusum:V", "cusum:i_f", "cusum:i_a/i_f_plus_i_a"]
    assert sig.count == 3 * len(DRIFTS)
    np.testing.assert_array_equal(sig.drifts[: len(DRIFTS)], DRIFTS)
    w = sig.projection[:, :: len(DRIFTS)]  # one column per signature
    np.testing.assert_allclose(np.diag(w.T @ instant_covariance(bank, MEAS) @ w), 1.0,
                               rtol=1e-9)  # weights rounded to 1e-12
    s = _fault_free(bank, 400_000, 1) @ w
    np.testing.assert_allclose(s.var(axis=0), 1.0, rtol=0.02)
    # Its long-run variance (the sum of its autocovariances, which stop at lag S) is what
    # the exact formula says.
    lags = [float(np.mean((s[: len(s) - t] - s.mean(0)) * (s[t:] - s.mean(0)), axis=0)[c])
            for c in range(3) for t in range(bank.S + 1)]
    gamma = np.array(lags).reshape(3, bank.S + 1)
    np.testing.assert_allclose(gamma[:, 0] + 2.0 * gamma[:, 1:].sum(axis=1),
                               np.diag(w.T @ long_run_covariance(bank, MEAS) @ w), rtol=0.03)
    for col, j in zip(range(3), (None, 0, 1), strict=True):
        mu = (bank.Gu[0] if j is None else bank.Gz[j]).sum(axis=-1) / bank.sigma
        assert mu @ w[:, col] > 0.0
    # Each names the residuals its fault moves.
    assert sig.residuals[len(DRIFTS)] == tuple(int(i) for i in np.flatnonzero(
        bank.Gz[0].sum(axis=-1)))


def test_no_drift_no_columns():
    design, bank = _bank()
    assert signature_columns(bank, MEAS, design.input_names, design.output_names, ()) is None


def test_calibrated_thresholds_hold_the_false_alarm_interval():
    """Calibrated for an interval of 5,000 samples per residual (20,000 per signature rung),
    the columns alarm on a fresh fault-free record about as often: 25 alarms expected per
    rung in 500,000 samples. A threshold is the smallest that meets its count on one record
    of 100,000 samples (20 alarms), so it is chosen on that record's noise and runs low on
    another: up to 2.5 times the count is allowed here (at the configured 10^9, the
    extrapolation and Siegmund's bound on the long-run variance take over: `canfdi soak`)."""
    design, bank = _bank()
    sig = signature_columns(bank, MEAS, design.input_names, design.output_names)
    interval = 5_000.0
    h = calibrate_thresholds(bank, MEAS, None, design.model, 0.5, interval, signatures=sig)
    assert h.shape == (bank.m + sig.count,) and np.all(h > 0)
    plain = calibrate_thresholds(bank, MEAS, None, design.model, 0.5, interval)
    np.testing.assert_array_equal(h[: bank.m], plain)  # the residuals' are unchanged
    s = _fault_free(bank, 500_000, 7) @ sig.projection
    ph = page_hinkley_batch(s, sig.drifts, h[bank.m:], restart_on_alarm=True)
    counts = (ph.alarms != 0).sum(axis=0)
    assert counts.max() <= 62, counts
    # ... and not absurdly rarely either (the thresholds are not just large): the ladder of
    # a signature alarms at least a few times.
    per_signature = counts.reshape(3, len(DRIFTS)).sum(axis=1)
    assert per_signature.min() >= 5, counts


def _with_signatures(on: bool):
    det = dataclasses.replace(CONFIG.detection, signatures=on)
    return dataclasses.replace(CONFIG, detection=det, method_options=None)


@pytest.mark.parametrize("seed", range(4))
def test_a_small_sensor_bias_is_detected_sooner_and_diagnosed_the_same(seed):
    """An i_f bias of fault-to-noise 1.2 (0.0093 on a 0.01 noise): the signature CUSUMs detect
    it sooner than Page-Hinkley on the residuals alone, and both diagnose it: the channel, the
    onset (within 10 samples: the diagnosis starts at the change point, not at the alarm), the
    size within 3 of the standard deviations the event states (acceptance asks for 0.2 noise
    units, 17 % of this fault: the tracker refines it later)."""
    run = simulate(parse_scenario({
        "plant": "dc_motor", "duration": 60.0, "seed": seed, "noise": {"measurement": 0.01},
        "faults": [{"target": "sensor", "index": 0, "onset": 5.0, "bias": 0.0093}]}))
    found = {}
    for on in (False, True):
        dg = build_diagnoser(_with_signatures(on))
        res = dg.update_block(run.k, (run.t * 1e9).astype(np.int64), run.u_c, run.z)
        events = [e for e in res.events if e.kind != "named"]
        kinds = [e.kind for e in events]
        assert kinds[:2] == ["detected", "accepted"], (on, kinds)
        acc = events[1]
        assert (acc.target, acc.name) == ("sensor", "i_f")
        assert abs(acc.onset_sample - 500) <= 10
        sd = acc.variances["bias"] ** 0.5
        # Settled at 0.2 noise units (17 % of this fault) by the long-run sandwich; the
        # deviation reported counts the transient's correlation lag by lag, a little more.
        assert abs(acc.estimates["bias"] - 0.0093) <= 3.0 * sd <= 0.25 * 0.0093 * 3.0
        found[on] = res.events[0].sample - 500
    assert found[True] < found[False], found


def test_the_conformance_run_with_signatures_block_equals_stream_and_reset_restores():
    """The conformance suite's parity example (a sensor bias, an actuator bias, lost samples
    and values) with the signature CUSUMs on: the block path gives the streaming path's
    events, residuals and statistics, chunk by chunk; reset() restores the first run; both
    faults are diagnosed."""
    from tests.methods.conftest import make_example
    from tests.methods.test_conformance import _blocks, _same, _same_events, _stream

    example = make_example("parity")
    config = dataclasses.replace(
        example.config, method_options=None,
        detection=dataclasses.replace(example.config.detection, signatures=True))
    example = dataclasses.replace(example, config=config)
    events, rows, stats = _stream(build_diagnoser(config), example)
    n = len(example.k)
    for cuts in ([], [1, 8, 9, 100, 101, n // 2], list(range(37, n, 37))):
        b_events, b_rows, b_stats = _blocks(build_diagnoser(config), example, cuts)
        _same_events(b_events, events, f"chunks cut at {cuts[:6]}...")
        _same(b_rows, rows, "residuals")
        _same(b_stats, stats, "statistics")
    accepted = [(e.target, e.index) for e in events if e.kind == "accepted"]
    assert accepted[:2] == [("sensor", 0), ("actuator", 0)], accepted
    dg = build_diagnoser(config)
    first = _blocks(dg, example, [n // 3])
    dg.reset()
    again = _blocks(dg, example, [n // 3])
    assert again[0] == first[0]
    np.testing.assert_array_equal(again[2], first[2])

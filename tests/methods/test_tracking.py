"""The accepted faults' tracker (canfdi.methods.parity.tracking) holds samples absorbed one at a
time and sums them together: the daemon's per-frame path absorbs every monitored sample alone.
Held or not, the checkpoints see the same sums (to rounding), the hold stays bounded, and a
copy (the noise watchdog's undo) runs apart from the original."""

from __future__ import annotations

import copy

import numpy as np

from canfdi.core.design import design_bank
from canfdi.core.model import StateSpace
from canfdi.core.residuals import ResidualBank
from canfdi.methods.parity.hypotheses import Hypothesis, row_regressors
from canfdi.methods.parity.tracking import PENDING, AcceptedFaultTracker, Tracked


def _setup(n: int, seed: int = 3):
    model = StateSpace(A=[[0.9, 0.1], [0.0, 0.8]], B=[[1.0], [0.5]],
                       C=[[1.0, 0.0], [0.0, 1.0], [1.0, 1.0]], dt=0.01)
    bank = ResidualBank(design_bank(model, ["u"], ["y0", "y1", "y2"]))
    hyps = [Hypothesis("sensor", 1, "y1"), Hypothesis("actuator", 0, "u")]
    tracked = [Tracked(hyps[0], 40, np.array([[1e-3]])),
               Tracked(hyps[1], 10, np.array([[1e-3, 0.0], [0.0, 1e-3]]))]
    rng = np.random.default_rng(seed)
    k = np.arange(100, 100 + n)
    windows = rng.standard_normal((n, bank.S + 1, 1))
    phi = row_regressors(bank, hyps, [40, 10], k, windows)
    rn = phi @ np.array([0.3, 0.02, -0.5]) + rng.standard_normal((n, bank.m))
    rn[rng.random(rn.shape) < 0.05] = np.nan  # residuals missing here and there
    return bank, tracked, k, windows, rn


def _corrections(tracker: AcceptedFaultTracker) -> list[tuple[str, np.ndarray, np.ndarray]]:
    return [(c.tracked.hypothesis.label, c.delta, c.variances) for c in tracker.correction()]


def _same_corrections(got: list, want: list, variances: bool = True) -> None:
    """The same channels corrected (some), by the same amounts (and variances) to 1e-12."""
    assert got and [g[0] for g in got] == [w[0] for w in want]
    for (_, delta, var), (_, delta_w, var_w) in zip(got, want, strict=True):
        np.testing.assert_allclose(delta, delta_w, rtol=1e-12)
        if variances:
            np.testing.assert_allclose(var, var_w, rtol=1e-12)


def test_samples_absorbed_one_at_a_time_give_the_checkpoint_a_block_gives():
    n = 3 * PENDING + 17  # past several holds, ending part way into one
    bank, tracked, k, windows, rn = _setup(n)
    alone, together = AcceptedFaultTracker(bank), AcceptedFaultTracker(bank)
    alone.restart(tracked)
    together.restart(tracked)
    for i in range(n):
        alone.absorb(k[i:i + 1], windows[i:i + 1], rn[i:i + 1])
        assert alone._pending_n < PENDING  # the hold never grows past its bound
    together.absorb(k, windows, rn)
    assert alone.due and together.due
    assert alone.samples_to_check() == together.samples_to_check() == 0
    _same_corrections(_corrections(alone), _corrections(together))


def test_the_noise_each_sample_was_normalised_by_is_kept_while_held():
    # The noise watchdog may widen the bank's noise between samples: a held sample's
    # regressors are normalised by the noise of its own time, as summing at once would.
    n = 100
    bank, tracked, k, windows, rn = _setup(n)
    held, eager = AcceptedFaultTracker(bank), AcceptedFaultTracker(bank)
    held.restart(tracked)
    eager.restart(tracked)
    sigma0 = bank.sigma
    for i in range(n):
        bank.sigma = sigma0 * (1.0 + (i >= n // 2))  # replaced, never written to
        held.absorb(k[i:i + 1], windows[i:i + 1], rn[i:i + 1])
        eager.absorb(k[i:i + 1], windows[i:i + 1], rn[i:i + 1])
        eager._sum_pending()
    bank.sigma = sigma0
    _same_corrections(_corrections(held), _corrections(eager))


def test_a_copy_holding_samples_runs_apart():
    n = 80
    bank, tracked, k, windows, rn = _setup(n)
    tracker = AcceptedFaultTracker(bank)
    tracker.restart(tracked)
    tracker.absorb(k[:40], windows[:40], rn[:40])  # held: below PENDING
    twin = copy.deepcopy(tracker)
    assert twin._pending is not tracker._pending
    twin.absorb(k[40:], windows[40:], rn[40:] + 5.0)  # the copy sees other data
    tracker.absorb(k[40:], windows[40:], rn[40:])
    fresh = AcceptedFaultTracker(bank)
    fresh.restart(tracked)
    fresh.absorb(k, windows, rn)
    got, other = _corrections(tracker), _corrections(twin)
    _same_corrections(got, _corrections(fresh), variances=False)
    assert not [o for o in other if any(np.allclose(o[1], g[1]) for g in got)]


def test_a_restart_drops_what_was_held():
    bank, tracked, k, windows, rn = _setup(100)
    tracker, fresh = AcceptedFaultTracker(bank), AcceptedFaultTracker(bank)
    tracker.restart(tracked)
    tracker.absorb(k[:30], windows[:30], rn[:30] + 100.0)  # held, then dropped
    tracker.restart(tracked)
    assert tracker._pending_n == 0
    fresh.restart(tracked)
    for t in (tracker, fresh):
        t.absorb(k[30:], windows[30:], rn[30:])
    _same_corrections(_corrections(tracker), _corrections(fresh), variances=False)

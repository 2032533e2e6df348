"""The noise watchdog (canfdi.core.watchdog): a doubled or halved noise is a mismatch within
its window, a change of mean is not, it comes back, and the same verdicts whatever blocks the
samples arrive in; wrapped around a diagnoser (canfdi.core.watched), it checks the configured
noise first, says its verdicts as events and its state, the same whatever the chunks."""

from __future__ import annotations

import numpy as np
import pytest

from canfdi.core.records import FaultEvent, Sample
from canfdi.core.watchdog import NoiseWatchdog, monitoring_rows
from canfdi.core.watched import NoiseWatched

BLOCK, BLOCKS = 100, 2


def _noise(n: int, m: int = 3, seed: int = 1) -> np.ndarray:
    return np.random.default_rng(seed).standard_normal((n, m))


def _changes(rn: np.ndarray, cuts: int = 1) -> list:
    wd = NoiseWatchdog(rn.shape[1], 1.5, BLOCK, BLOCKS)
    k = np.arange(len(rn))
    out = []
    for part in np.array_split(np.arange(len(rn)), cuts):
        out += wd.update(k[part], rn[part])
    return out


def test_a_doubled_noise_is_flagged_within_the_window_a_halved_one_too():
    rn = _noise(4000)
    rn[1000:, 1] *= 2.0
    rn[2000:, 2] *= 0.5
    changes = _changes(rn)
    up = next(c for c in changes if c.entered[1])
    down = next(c for c in changes if c.entered[2])
    assert 1000 < up.k <= 1000 + BLOCK * BLOCKS
    assert 2000 < down.k <= 2000 + BLOCK * BLOCKS
    assert up.ratio[1] == pytest.approx(2.0, rel=0.2)
    assert down.ratio[2] == pytest.approx(0.5, rel=0.2)
    assert not any(c.entered[0] for c in changes)


def test_a_change_of_mean_is_no_mismatch():
    rn = _noise(5000)
    rn[1234:, :] += 25.0  # a fault's step, far beyond the noise, in every residual
    rn[3050:3100, 0] += np.linspace(0.0, 10.0, 50)  # and a short ramp
    assert _changes(rn) == []


def test_it_comes_back_when_the_noise_does():
    rn = _noise(5000)
    rn[1000:2500] *= 3.0
    changes = _changes(rn)
    assert [bool(c.entered.any()) for c in changes] == [True, False]
    assert 2500 < changes[-1].k <= 2500 + BLOCK * BLOCKS and changes[-1].left.all()


def test_the_verdicts_do_not_depend_on_the_chunks():
    rn = _noise(3000)
    rn[700:, 0] *= 2.5
    rn[100:130] = np.nan  # lost residuals
    one = _changes(rn)
    for cuts in (7, 300, 3000):
        other = _changes(rn, cuts)
        assert [(c.k, c.entered.tolist(), c.left.tolist()) for c in other] == \
            [(c.k, c.entered.tolist(), c.left.tolist()) for c in one]


def test_the_rows_of_a_diagnosis_are_held_back():
    k = np.arange(10, 20)
    events = [FaultEvent("detected", 12, 0), FaultEvent("unexplained", 15, 0),
              FaultEvent("detected", 18, 0)]
    assert monitoring_rows(k, events, False).tolist() == [
        True, True, False, False, False, False, True, True, False, False]
    assert monitoring_rows(k, [FaultEvent("accepted", 11, 0)], True).tolist() == [
        False, False] + [True] * 8


def test_noise_held_back_during_a_diagnosis_counts_when_it_found_no_fault():
    wd = NoiseWatchdog(1, 1.5, BLOCK, BLOCKS)
    rn = _noise(1000, 1) * 2.0
    k = np.arange(1000)
    wd.update(k[:50], rn[:50])
    for held in (100, 200, 300):  # a diagnosis holds samples 50..349 back; blocks still end
        assert wd.due(held) and wd.close(held) is None
    wd.add_late(k[50:350], rn[50:350])  # it found nothing: they were noise
    assert not wd.mismatch.any()  # the verdict waits for the next block's end
    change = wd.update(k[350:450], rn[350:450])
    assert change and change[0].entered[0] and change[0].k == 400


def test_a_window_held_back_keeps_the_noise_found():
    """A residual in mismatch whose blocks a diagnosis then holds back (no verdict, no ratio)
    is still detected against the noise found before, not an unknown (NaN) one."""
    wd = NoiseWatchdog(1, 1.5, BLOCK, BLOCKS)
    rn = _noise(501, 1) * 2.0
    rn[300:] = np.nan  # held back from sample 300 on
    k = np.arange(501)
    wd.update(k[:301], rn[:301])
    assert wd.mismatch[0] and wd.scale[0] == pytest.approx(2.0, rel=0.2)
    found = wd.scale.copy()
    for held in (400, 500):  # its blocks end empty
        assert wd.close(held) is None
    assert np.isnan(wd.ratio[0]) and wd.mismatch[0]
    np.testing.assert_array_equal(wd.scale, found)
    batch = NoiseWatchdog(1, 1.5, BLOCK, BLOCKS)  # the batch form keeps it too
    batch.update(k, rn)
    assert np.isnan(batch.ratio[0]) and batch.mismatch[0]
    np.testing.assert_array_equal(batch.scale, found)


def test_bad_settings_are_refused():
    with pytest.raises(ValueError, match="factor"):
        NoiseWatchdog(2, factor=1.0)
    with pytest.raises(ValueError, match="block"):
        NoiseWatchdog(2, block=1)


def _state(wd: NoiseWatchdog) -> tuple:
    return (wd._open, wd._open_variance(), list(wd._variances), wd.ratio, wd.known, wd.mismatch)


def _same_state(a: tuple, b: tuple) -> bool:
    """Two watchdog states alike to the bit: the same open block, variances and verdicts."""
    return a[0] == b[0] and len(a[2]) == len(b[2]) and all(
        np.array_equal(x, y, equal_nan=True)
        for x, y in zip([a[1], *a[2], *a[3:]], [b[1], *b[2], *b[3:]], strict=True))


@pytest.mark.parametrize("m", [1, 4])
def test_the_batch_update_leaves_the_bits_of_one_sample_at_a_time(m):
    rng = np.random.default_rng(m)
    # Gaps (partial blocks, whole blocks missing), lost values, noise that leaves and returns.
    k = np.cumsum(rng.choice([1] * 60 + [2, 150], size=6000))
    rn = rng.standard_normal((len(k), m))
    rn[1500:3500] *= 3.0
    rn[rng.random(rn.shape) < 0.03] = np.nan
    whole, single = NoiseWatchdog(m, 1.5, BLOCK, 3), NoiseWatchdog(m, 1.5, BLOCK, 3)
    got = whole.update(k, rn)
    want = []
    for i in range(len(k)):
        want += single.update(k[i:i + 1], rn[i:i + 1])
    # The same verdicts and ratios to the bit (a block is summed at its close, in the order of
    # its samples, however they came): a diagnoser widened by them diagnoses the same.
    assert [(c.k, c.entered.tolist(), c.left.tolist()) for c in got] == \
        [(c.k, c.entered.tolist(), c.left.tolist()) for c in want]
    for a, b in zip(got, want, strict=True):
        np.testing.assert_array_equal(a.ratio, b.ratio)
    assert len(got) >= 2 and _same_state(_state(whole), _state(single))


def test_the_batch_update_can_stop_at_the_first_change():
    rn = _noise(3000)
    rn[1000:, 1] *= 3.0
    k = np.arange(3000)
    wd, ref = NoiseWatchdog(3, 1.5, BLOCK, BLOCKS), NoiseWatchdog(3, 1.5, BLOCK, BLOCKS)
    (change,) = wd.update(k, rn, stop_on_change=True)
    first = ref.update(k[:change.k], rn[:change.k])  # up to the sample whose block end moved
    assert not first and ref.due(change.k)
    assert ref.close(change.k).k == change.k and _same_state(_state(wd), _state(ref))


# -- the watchdog as a wrapping diagnoser (canfdi.core.watched) --------------------------------


class _Echo:
    """A diagnoser whose residuals are the measurements (normalised by noise_scale), never
    alarming: what the watchdog alone makes of a drive's noise."""

    def __init__(self, m: int) -> None:
        self.residual_names = [f"r{i}" for i in range(m)]
        self.thresholds = np.full(m, 5.0)
        self.reset()

    def reset(self) -> None:
        m = len(self.residual_names)
        self.mode, self.compensation, self.events = "monitor", [], []
        self.last_residuals = self.last_normalized = None
        self.statistics = np.zeros(m)
        self.noise_scale = np.ones(m)

    def update(self, sample):
        self.last_residuals = np.asarray(sample.z, dtype=float)
        self.last_normalized = self.last_residuals / self.noise_scale
        return []

    def update_block(self, k, t_ns, U, Z, gap=None):
        from canfdi.core.records import BlockResult

        if len(k):
            self.update(Sample(int(k[-1]), int(t_ns[-1]), U[-1], Z[-1]))
        return BlockResult([], Z.copy(), Z / self.noise_scale, np.zeros_like(Z))


def _watched(m: int = 3) -> NoiseWatched:
    return NoiseWatched(_Echo(m), 1.5, BLOCK, BLOCKS, longest_diagnosis=300)


def _feed_watched(watched: NoiseWatched, rn: np.ndarray, chunk: int) -> tuple[list, list]:
    """(events, state after each chunk, repeated for each of its samples) of samples 0..
    with measurements rn, fed ``chunk`` at a time (1: `update`)."""
    k = np.arange(len(rn))
    events, states = [], []
    for a in range(0, len(rn), chunk):
        b = min(a + chunk, len(rn))
        if chunk == 1:
            events += watched.update(Sample(int(k[a]), int(k[a]) * 10, np.zeros(1), rn[a]))
        else:
            events += watched.update_block(k[a:b], k[a:b] * 10, np.zeros((b - a, 1)),
                                           rn[a:b]).events
        states += [watched.state] * (b - a)
    return events, states


def test_wrapped_the_watchdog_checks_then_says_the_noise_and_widens_detection():
    rn = _noise(1500)
    rn[:, 1] *= 2.5  # noisier than configured from the start
    rn[:, 2] *= 0.3  # quieter
    rn[800:, 2] /= 0.3  # and back
    events, states = _feed_watched(_watched(), rn, 1)
    armed = BLOCK * BLOCKS
    assert set(states[:armed - 1]) == {"checking"} and states[armed] == "mismatch"
    kinds = [(e.kind, e.sample, e.residuals) for e in events]
    assert kinds[:2] == [("mismatch", armed, ("r1",)), ("quiet", armed, ("r2",))]
    assert ("matched", 1000, ("r2",)) in kinds
    assert events[0].estimates["r1"] == pytest.approx(2.5, rel=0.2)


def test_wrapped_the_same_events_rows_and_states_whatever_the_chunks():
    rn = _noise(2000)
    rn[700:1400, 0] *= 3.0
    rn[100:130] = np.nan
    want = _feed_watched(_watched(), rn, 1)
    for chunk in (7, 250, 333, 2000):
        got = _feed_watched(_watched(), rn, chunk)
        assert [(e.kind, e.sample, e.residuals) for e in got[0]] == \
            [(e.kind, e.sample, e.residuals) for e in want[0]]
        ends = [*range(chunk - 1, len(rn), chunk), len(rn) - 1]
        assert [got[1][i] for i in ends] == [want[1][i] for i in ends]


def test_wrapped_quiet_says_quiet_and_reset_checks_again():
    watched = _watched(2)
    rn = _noise(1000, 2) * 0.3
    events, states = _feed_watched(watched, rn, 100)
    assert states[-1] == "quiet" and [e.kind for e in events] == ["quiet"]
    np.testing.assert_array_equal(watched.noise_scale, [1.0, 1.0])  # never tightened
    assert watched.events == events
    watched.reset()
    assert watched.state == "checking" and watched.events == []
    assert _feed_watched(watched, rn, 1000)[0] == events

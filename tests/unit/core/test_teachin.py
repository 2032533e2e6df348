"""Teach-in as a stand-in diagnoser (canfdi.core.teachin): the first samples are recorded, not
diagnosed ("teaching"); then the diagnoser learned takes over (the configured one when
learning failed), the learned values said once, the same one sample at a time or in blocks."""

from __future__ import annotations

import numpy as np
import pytest

from canfdi.core.records import BlockResult, Sample
from canfdi.core.supervision import Supervision
from canfdi.core.teachin import TeachIn


class _Scaled:
    """A diagnoser whose residuals are the measurements over ``gain`` (what it was built
    on), alarming never."""

    def __init__(self, gain: float) -> None:
        self.gain = gain
        self.residual_names, self.thresholds = ["r"], np.array([gain])
        self.reset()

    def reset(self) -> None:
        self.mode, self.compensation, self.events = "monitor", [], []
        self.last_residuals = self.last_normalized = None
        self.statistics, self.noise_scale = np.zeros(1), np.ones(1)

    def update(self, sample):
        self.last_residuals = np.asarray(sample.z, dtype=float) / self.gain
        self.last_normalized = self.last_residuals
        return []

    def update_block(self, k, t_ns, U, Z, gap=None):
        R = Z / self.gain
        if len(k):
            self.last_residuals = self.last_normalized = R[-1]
        return BlockResult([], R, R.copy(), np.zeros_like(R))


class _Teacher:
    samples = 50

    def __init__(self, fail: bool = False) -> None:
        self.fail, self.seen = fail, []

    def learn(self, k, U, Z):
        self.seen.append(k.copy())
        if self.fail:
            raise ValueError("a fault in the samples")
        std = float(np.std(Z))
        return _Scaled(std), {"status": "learned", "samples": str(len(k)),
                              "noise_json": f'[{{"sensor": "z", "std": {std}}}]'}


def _feed(teach: TeachIn, Z: np.ndarray, chunk: int) -> tuple[list, np.ndarray, list]:
    """(events, residual rows (NaN: none), state after each chunk) of samples 0.., ``chunk``
    at a time (1: `update`)."""
    events, rows, states = [], [], []
    k = np.arange(len(Z))
    for a in range(0, len(Z), chunk):
        b = min(a + chunk, len(Z))
        if chunk == 1:
            events += teach.update(Sample(a, a * 10, np.zeros(1), Z[a]))
            r = teach.last_residuals
            rows.append(np.full(1, np.nan) if r is None else r)
        else:
            result = teach.update_block(k[a:b], k[a:b] * 10, np.zeros((b - a, 1)), Z[a:b])
            events += result.events
            rows += list(result.residuals)
        states.append(teach.state)
    return events, np.array(rows), states


def test_it_teaches_then_hands_over_to_the_diagnoser_learned():
    Z = np.random.default_rng(1).standard_normal((120, 1)) * 4.0
    said = []
    teacher = _Teacher()
    teach = TeachIn(_Scaled(1.0), teacher, then=Supervision, on_learned=said.append)
    assert teach.state == "teaching" and teach.thresholds.tolist() == [1.0]
    events, rows, _ = _feed(teach, Z, 30)
    np.testing.assert_array_equal(teacher.seen[0], np.arange(50))
    assert [(e.kind, e.sample, e.timestamp_ns) for e in events] == [("taught", 49, 490)]
    assert events[0].estimates["z"] == pytest.approx(float(np.std(Z[:50])))
    assert len(said) == 1 and said[0]["status"] == "learned"
    assert np.isnan(rows[:50]).all()
    np.testing.assert_allclose(rows[50:], Z[50:] / np.std(Z[:50]))
    assert teach.state == "monitoring" and teach.diagnoser.gain == pytest.approx(np.std(Z[:50]))
    assert teach.events == events


def test_a_failed_teach_in_is_said_and_the_configured_diagnoser_runs():
    Z = np.ones((80, 1))
    said = []
    configured = _Scaled(2.0)
    teach = TeachIn(configured, _Teacher(fail=True), then=Supervision, on_learned=said.append)
    events, rows, _ = _feed(teach, Z, 1)
    assert [e.kind for e in events] == ["teach_failed"]
    assert events[0].candidates == ({"reason": "a fault in the samples"},)
    assert said[0]["status"] == "failed" and said[0]["samples"] == "50"
    assert teach.diagnoser is configured and np.allclose(rows[50:], 0.5)


def test_one_sample_at_a_time_or_in_blocks_the_same_and_reset_teaches_again():
    Z = np.random.default_rng(2).standard_normal((200, 1))
    teach = TeachIn(_Scaled(1.0), _Teacher(), then=Supervision)
    want = _feed(teach, Z, 1)
    for chunk in (7, 50, 51, 200):
        got = _feed(TeachIn(_Scaled(1.0), _Teacher(), then=Supervision), Z, chunk)
        assert got[0] == want[0]
        np.testing.assert_allclose(got[1], want[1])
    teach.reset()
    assert teach.state == "teaching" and teach.events == []
    again = _feed(teach, Z, 1)
    assert again[0] == want[0]

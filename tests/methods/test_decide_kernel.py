"""A diagnosis' decision on the C kernel (cfdi_decide) against the numpy reference
(canfdi.methods.parity.decide.decide_reference): random fits spread so that every action,
both settling outcomes, twins of equal cost, leftovers and NaN costs occur; bad tables refused.
(The conformance suite runs whole diagnoses on both kernels.)"""

from __future__ import annotations

from collections import Counter
from types import SimpleNamespace

import numpy as np
import pytest

from canfdi.core import kernel
from canfdi.core.identify import RlsSolution
from canfdi.methods.parity.decide import (
    ACCEPT,
    ACCEPT_NEAR,
    NAME,
    UNEXPLAINED,
    WAIT,
    Decision,
    HypothesisTable,
    decide_reference,
)
from canfdi.methods.parity.hypotheses import Hypothesis

pytestmark = pytest.mark.skipif("c" not in kernel.available(), reason="no C kernel built here")


def _hypotheses(rng, p: int, q: int) -> tuple[list[Hypothesis], dict]:
    hyps = [Hypothesis("actuator", j, f"u{j}") for j in range(p)]
    hyps += [Hypothesis("sensor", j, f"y{j}") for j in range(q)]
    hyps += [Hypothesis("actuator_bias", j, f"u{j}") for j in range(p)]
    if q > 2:
        hyps.append(Hypothesis("sensors", 0, "joint", members=(0, 1, 2)))
    singles = [h for h in hyps if h.target != "sensors"]
    twins = {h: set() for h in hyps}
    for _ in range(int(rng.integers(0, 3))):  # symmetric, as proportional() makes them
        a, b = rng.choice(len(singles), size=2, replace=False)
        twins[singles[a]].add(singles[b])
        twins[singles[b]].add(singles[a])
    return hyps, twins


def _case(seed: int):
    rng = np.random.default_rng(seed)
    p, q = int(rng.integers(1, 3)), int(rng.integers(1, 5))
    hyps, twins = _hypotheses(rng, p, q)
    H, d, K = len(hyps), max(h.n_params for h in hyps), int(rng.integers(1, 7))
    n_eq = int(rng.integers(20, 2000))
    settings = SimpleNamespace(
        max_samples=int(rng.integers(10, 60)), isolation_margin=float(rng.choice([5.0, 50.0])),
        settle_rel_std=float(rng.choice([0.005, 0.05])),
        settle_noise=float(rng.choice([0.0, 0.2, 2.0])), max_fit_variance=2.25)
    # Costs about the noise's (n_eq), the best a margin ahead or not; the fits' spread from
    # known to unknown; the no-fault cost from far above to barely above.
    cost = n_eq * np.exp(rng.normal(0.0, 0.3, (H, 1)) + rng.normal(0.0, 0.02, (H, K)))
    cost[rng.integers(H)] *= float(rng.choice([0.1, 0.5, 0.95]))
    if rng.random() < 0.2:  # exact ties of twins (the same fit), named by config order
        a, b = rng.choice(H, size=2, replace=False)
        if hyps[a].n_params == hyps[b].n_params and hyps[a].target != "sensors" \
                and hyps[b].target != "sensors":
            twins[hyps[a]].add(hyps[b])
            twins[hyps[b]].add(hyps[a])
            cost[b] = cost[a]
    if rng.random() < 0.05:
        cost[rng.integers(H), rng.integers(K)] = np.nan
    rr = cost + n_eq * np.exp(rng.uniform(-6.0, 3.0, (H, K)))
    A = rng.standard_normal((H, K, d, d)) * np.exp(rng.uniform(-12.0, 0.0, (H, K, 1, 1)))
    P = A @ np.swapaxes(A, -1, -2) + 1e-14 * np.eye(d)
    B = rng.standard_normal((H, K, d, d))
    meat = B @ np.swapaxes(B, -1, -2) * float(rng.choice([1.0, 1e3]))
    theta = rng.standard_normal((H, K, d)) * np.exp(rng.uniform(-8.0, 1.0, (H, K, 1)))
    if rng.random() < 0.3:  # a scale near 0 for the bias-only fits' full ones
        theta[:p, :, 0] *= 1e-6
    elif rng.random() < 0.4:  # a pure scale: its size is what it puts on the mean command
        theta[:p, :, 1] *= 1e-6
        cost[rng.integers(p)] *= 0.1
    fit = RlsSolution(theta=theta, P=P, cost=cost, dof=max(n_eq - d, 1))
    u_abs = rng.uniform(0.0, 50.0, p) * (rng.random(p) < 0.9)
    n_u = rng.integers(0, 40, p).astype(float)
    units = np.exp(rng.uniform(-8.0, 0.0, (H, d)))
    units[rng.random((H, d)) < 0.1] = np.inf
    leftover = np.where(rng.random(H) < 0.3, rng.integers(0, K, H), -1).astype(np.int32)
    since = int(rng.integers(settings.max_samples - 5, settings.max_samples + 2))
    table = HypothesisTable.of(hyps, twins, settings.isolation_margin)
    return (table, settings, fit, rr, n_eq, meat, u_abs, n_u, units, leftover, since,
            bool(rng.random() < 0.3))


def _same(got: Decision, want: Decision) -> None:
    for name in ("action", "best", "kb", "size_known", "form_known"):
        assert getattr(got, name) == getattr(want, name), name
    np.testing.assert_allclose(got.scale, want.scale, rtol=1e-13)
    for name in ("best_onset", "order", "near"):
        np.testing.assert_array_equal(getattr(got, name), getattr(want, name), err_msg=name)
    np.testing.assert_array_equal(got.cost_h, want.cost_h)


def test_the_c_decisions_are_numpys():
    seen = Counter()
    with np.errstate(invalid="ignore"):
        for seed in range(3000):
            case = _case(seed)
            want = decide_reference(*case)
            got = Decision(*kernel.get("c").decide(*case))
            _same(got, want)
            seen[want.action] += 1
            seen["size", want.size_known] += 1
            seen["form", want.form_known] += 1
            seen["near", bool(want.near.any())] += 1
    # The cases reach every rule (else the comparison proves less than it says).
    for key in (WAIT, ACCEPT, NAME, ACCEPT_NEAR, UNEXPLAINED, ("size", True), ("size", False),
                ("form", True), ("form", False), ("near", True)):
        assert seen[key] >= 10, (key, seen)


def test_twins_of_equal_cost_are_named_by_config_order():
    hyps = [Hypothesis("sensor", 1, "y1"), Hypothesis("sensor", 0, "y0"),
            Hypothesis("actuator_bias", 0, "u0")]
    twins = {hyps[0]: {hyps[1], hyps[2]}, hyps[1]: {hyps[0], hyps[2]},
             hyps[2]: {hyps[0], hyps[1]}}
    table = HypothesisTable.of(hyps, twins, 50.0)
    cost = np.array([[100.0], [100.0], [100.0 + 1e-9]])
    fit = RlsSolution(theta=np.full((3, 1, 1), 0.5), P=np.full((3, 1, 1, 1), 1e-6), cost=cost,
                      dof=99)
    settings = SimpleNamespace(max_samples=2000, isolation_margin=50.0, settle_rel_std=0.005,
                               settle_noise=0.2, max_fit_variance=2.25)
    case = (table, settings, fit, cost + 1e4, 101, np.ones((3, 1, 1, 1)), np.zeros(1),
            np.zeros(1), np.ones((3, 1)), np.full(3, -1, dtype=np.int32), 20, False)
    for decision in (decide_reference(*case), Decision(*kernel.get("c").decide(*case))):
        assert decision.best == 2  # the actuator's bias: inputs name a group before outputs
        assert decision.action == ACCEPT


@pytest.mark.parametrize("broken", ["kind", "index", "n_params", "full", "leftover"])
def test_bad_tables_are_refused(broken):
    case = list(_case(7))
    table = case[0]
    H, K = len(table.kind), case[2].theta.shape[1]
    if broken == "leftover":
        case[9] = np.full(H, K, dtype=np.int32)
    else:
        value = {"kind": 4, "index": 99, "n_params": 0, "full": H}[broken]
        column = getattr(table, broken).copy()
        column[0] = value
        case[0] = HypothesisTable(**{**table.__dict__, broken: column})
    with pytest.raises(ValueError, match="decide: status -2"):
        kernel.get("c").decide(*case)

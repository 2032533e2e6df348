"""Consecutive faults stay apart (issue 41): every ordered pair of fault kinds (look-alike then
look-alike, the same sensor twice, actuator then sensor, sensor then actuator), random sizes
and onsets, diagnosed one after the other with the first compensated. Each fault's estimate is
its own size, within its own confidence (the standard deviation its event gives), whatever was
accepted before on the same channel or on its look-alike; and nothing else is raised.

On the DC motor with the parity method (i_a and i_f_plus_i_a are look-alikes: their bias
signatures over the window are proportional, so the monitor names them together); the other
methods on their example plants, for the pairs those have. Scored by `canfdi evaluate`'s own
matching (canfdi.tools.evaluate.match_run), so the figures it reports are the ones checked here;
and each fault is a decision of its own ("accepted"), never a refinement of the one before."""

from __future__ import annotations

import numpy as np
import pytest

from canfdi.bus.dbc import BusMap
from canfdi.config import parse_config
from canfdi.firmware_sim.scenario import parse_scenario
from canfdi.firmware_sim.simulate import simulate
from canfdi.methods import build_diagnoser
from canfdi.tools.evaluate import InjectedFault, RunSpec, match_run, setup_from_config
from tests.methods.conftest import _plant_of, example_document

# (method, pair name, first channel, second channel): channels as (target, output/input name).
PAIRS = [
    ("parity", "look-alike then look-alike", ("sensor", "i_f_plus_i_a"), ("sensor", "i_a")),
    ("parity", "look-alike then look-alike", ("sensor", "i_a"), ("sensor", "i_f_plus_i_a")),
    ("parity", "the same sensor twice", ("sensor", "i_a"), ("sensor", "i_a")),
    ("parity", "the same sensor twice", ("sensor", "i_f"), ("sensor", "i_f")),
    ("parity", "the same actuator twice", ("actuator", "V"), ("actuator", "V")),
    ("parity", "actuator then sensor", ("actuator", "V"), ("sensor", "i_a")),
    ("parity", "actuator then look-alike", ("actuator", "V"), ("sensor", "i_f_plus_i_a")),
    ("parity", "sensor then actuator", ("sensor", "i_f_plus_i_a"), ("actuator", "V")),
    ("parity", "sensor then actuator", ("sensor", "i_f"), ("actuator", "V")),
    ("output_error", "the same sensor twice", ("sensor", 0), ("sensor", 0)),
    ("output_error", "actuator then sensor", ("actuator", 0), ("sensor", 1)),
    ("output_error", "sensor then actuator", ("sensor", 0), ("actuator", 0)),
    ("uio", "the same sensor twice", ("sensor", 0), ("sensor", 0)),
    ("uio", "actuator then sensor", ("actuator", 0), ("sensor", 0)),
    ("uio", "sensor then actuator", ("sensor", 0), ("actuator", 0)),
]
FNR = (5.0, 30.0)  # fault-to-noise ratios drawn log-uniformly: each pair well detectable
TOLERANCE_STD = 4.0  # a fault's estimate within this many of its standard deviations


def _channel(setup, target: str, which):
    pool = [c for c in setup.detectable if c.target == target]
    if isinstance(which, int):
        return pool[which]
    return next(c for c in pool if c.name == which)


def _spec(setup, case: int, first, second) -> RunSpec:
    rng = np.random.default_rng([41, case])
    faults, k = [], int(rng.integers(setup.lead[0], setup.lead[1] + 1))
    for target, which in (first, second):
        c = _channel(setup, target, which)
        fnr = float(np.exp(rng.uniform(*np.log(FNR))))
        size = (1.0 if rng.random() < 0.5 else -1.0) * fnr / c.gap
        if target == "sensor":
            kind, params = "sensor_bias", {"bias": size}
        else:
            kind, params = "actuator_bias", {"eta": 1.0, "lambda": size}
        faults.append(InjectedFault(c.target, c.index, c.name, kind, k, params, fnr))
        k += setup.spacing + int(rng.integers(0, setup.spacing // 10 + 1))
    return RunSpec(run=case, seed=int(rng.integers(0, 2**31 - 1)), samples=k, noise_scale=1.0,
                   faults=tuple(faults))


@pytest.mark.parametrize("case", range(len(PAIRS)),
                         ids=[f"{m}: {n}: {a[1]} then {b[1]}" for m, n, a, b in PAIRS])
def test_each_of_two_consecutive_faults_is_estimated_at_its_own_size(case):
    method, _, first, second = PAIRS[case]
    path, document = example_document(method)
    config = parse_config(document, path)
    setup = setup_from_config(config, _plant_of(config))
    spec = _spec(setup, case, first, second)
    names = {"actuator": list(config.inputs), "sensor": list(config.outputs)}
    run = simulate(parse_scenario(spec.scenario_dict(setup.plant, setup.dt,
                                                     setup.measurement_std)))
    U, Z = BusMap.from_config(config).quantize(run.u_c, run.z)
    events = build_diagnoser(config).update_block(
        run.k, run.k * round(setup.dt * 1e9), U, Z).events
    decisions = [e for e in events if e.kind in ("accepted", "refined", "unexplained")
                 and e.detected_sample is not None]
    assert {e.kind for e in decisions} == {"accepted"}, events
    assert len({e.detected_sample for e in decisions}) == 2, events
    outcome = match_run(spec.faults, events, len(run.k), 0, setup.twins, names)
    assert not outcome.false_alarms, outcome
    for o in outcome.faults:
        truth = o.fault.params
        assert o.decision == "accepted" and o.isolation in ("exact", "candidate"), o
        judged = [key for key in o.errors]
        assert judged, o
        for key in judged:
            std = o.estimate_std[key]
            assert abs(o.estimate[key] - truth[key]) <= TOLERANCE_STD * std, (key, o)
            # And the confidence itself says something: a tenth of the fault's size at most.
            assert std <= 0.1 * abs(truth[key]), (key, o)

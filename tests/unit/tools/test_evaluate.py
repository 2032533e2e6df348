"""canfdi.tools.evaluate: matching events to injected faults and the metrics, against hand
counts."""

import itertools

import numpy as np
import pytest

from canfdi.core.records import FaultEvent
from canfdi.tools.evaluate import (
    Channel,
    EvaluationSetup,
    InjectedFault,
    aggregate,
    cusum_bound,
    match_run,
    plan_runs,
    relative_errors,
)

DT = 0.01
NAMES = {"actuator": ["V"], "sensor": ["i_f", "i_a", "i_f_plus_i_a", "omega_r"]}
TWINS = {"s:i_a": frozenset({"s:i_f_plus_i_a"}), "s:i_f_plus_i_a": frozenset({"s:i_a"})}


def det(k):
    return FaultEvent(kind="detected", sample=k, timestamp_ns=k, detected_sample=k,
                      onset_sample=k)


def acc(k, k_d, target, index, estimates, candidates=()):
    names = NAMES[target]
    return FaultEvent(kind="accepted", sample=k, timestamp_ns=k, target=target, index=index,
                      name=names[index], estimates=estimates, onset_sample=k_d,
                      detected_sample=k_d, accepted_sample=k, candidates=candidates)


def unexp(k, k_d):
    return FaultEvent(kind="unexplained", sample=k, timestamp_ns=k, detected_sample=k_d)


def fault(target, index, kind, onset, fnr, **params):
    return InjectedFault(target, index, NAMES[target][index], kind, onset, params, fnr)


# Four runs, counted by hand:
# A: i_f +0.5 at 1000, detected 1002, accepted 1202 as i_f with 0.55: delay 2, exact, error 0.1;
#    fault-free (1000 - 8) + (4000 - 1202) = 3790.
# B: V lambda 2 at 500, never detected (missed); i_a -1 at 3500, detected 3510, accepted 3710 as
#    i_f_plus_i_a +1.2 with i_a -1.2 among the candidates: delay 10, candidate, error 0.2; a
#    detection at 5000 after that acceptance: false alarm; fault-free (500 - 8) + (6500 - 3710)
#    = 3282.
# C: a detection at 300 (ends unexplained at 800): false alarm before the fault; V eta 2 at
#    1000, detected 1020, accepted 1220 as i_f: delay 20, wrong; fault-free 992 + 2780 = 3772.
# D: no fault, a detection at 1500: false alarm; fault-free 3000 - 8 = 2992.
RUN_A = ([fault("sensor", 0, "sensor_bias", 1000, 30.0, bias=0.5)],
         [det(1002), acc(1202, 1002, "sensor", 0, {"bias": 0.55})], 4000)
CANDIDATES = ({"target": "sensor", "index": 2, "name": "i_f_plus_i_a", "estimates": {"bias": 1.2}},
              {"target": "sensor", "index": 1, "name": "i_a", "estimates": {"bias": -1.2}})
RUN_B = ([fault("actuator", 0, "actuator_bias", 500, 0.7, eta=1.0, **{"lambda": 2.0}),
          fault("sensor", 1, "sensor_bias", 3500, 3.0, bias=-1.0)],
         [det(3510), acc(3710, 3510, "sensor", 2, {"bias": 1.2}, CANDIDATES), det(5000)], 6500)
RUN_C = ([fault("actuator", 0, "actuator_scale", 1000, 1.5, eta=2.0, **{"lambda": 0.0})],
         [det(300), unexp(800, 300), det(1020), acc(1220, 1020, "sensor", 0, {"bias": 0.3})],
         4000)
RUN_D = ([], [det(1500)], 3000)


def _runs():
    return [match_run(f, e, n, first_monitored=8, twins=TWINS, names=NAMES, run=i)
            for i, (f, e, n) in enumerate((RUN_A, RUN_B, RUN_C, RUN_D))]


def test_matching_by_hand():
    a, b, c, d = _runs()
    (fa,) = a.faults
    assert (fa.detected_sample, fa.delay, fa.decision, fa.isolation) == (1002, 2, "accepted",
                                                                         "exact")
    assert fa.diagnosed == "s:i_f" and fa.accepted_sample == 1202
    assert fa.errors == pytest.approx({"bias": 0.1}) and fa.error == pytest.approx(0.1)
    assert a.false_alarms == () and a.fault_free_samples == 3790

    missed, twin = b.faults
    assert not missed.detected and missed.delay is None and missed.decision == "none"
    assert missed.diagnosed == "none" and missed.isolation is None and missed.errors == {}
    assert (twin.delay, twin.isolation, twin.diagnosed) == (10, "candidate", "s:i_f_plus_i_a")
    assert twin.correct and twin.estimate == {"bias": -1.2}
    assert twin.errors == pytest.approx({"bias": 0.2})
    assert b.false_alarms == ({"sample": 5000, "context": "after_accepted"},)
    assert b.fault_free_samples == 3282

    (fc,) = c.faults
    assert (fc.delay, fc.isolation, fc.diagnosed, fc.correct) == (20, "wrong", "s:i_f", False)
    assert fc.errors == {} and fc.error is None
    assert c.false_alarms == ({"sample": 300, "context": "before_fault"},)
    assert c.fault_free_samples == 3772

    assert d.faults == () and d.fault_free_samples == 2992
    assert d.false_alarms == ({"sample": 1500, "context": "before_fault"},)


def test_metrics_by_hand():
    m = aggregate(_runs(), DT)
    assert (m["runs"], m["runs_fault_free"], m["faults"]) == (4, 1, 4)
    assert (m["detected"], m["missed"], m["detection_rate"]) == (3, 1, 0.75)
    assert m["delay_mean_samples"] == pytest.approx(32 / 3)
    assert m["delay_median_samples"] == 10
    assert m["delay_p95_samples"] == pytest.approx(19.0)  # 10 + 0.9 (20 - 10), linear
    assert m["delay_max_samples"] == 20
    assert (m["accepted"], m["unexplained"], m["undecided"]) == (3, 0, 0)
    assert m["isolation"] == {"exact": 1, "candidate": 1, "design_twin": 0, "wrong": 1}
    assert m["isolation_accuracy"] == pytest.approx(2 / 3)
    assert m["isolation_accuracy_exact"] == pytest.approx(1 / 3)
    assert m["isolated_correctly_of_all"] == pytest.approx(0.5)
    assert m["estimate_errors"] == 2
    assert m["estimate_error_median"] == pytest.approx(0.15)
    assert m["estimate_error_p95"] == pytest.approx(0.195)
    assert m["false_alarms"] == 3
    assert (m["false_alarms_before_fault"], m["false_alarms_after_accepted"]) == (2, 1)
    free = 3790 + 3282 + 3772 + 2992
    assert m["fault_free_samples"] == free
    assert m["fault_free_hours"] == pytest.approx(free * DT / 3600)
    assert m["false_alarms_per_hour"] == pytest.approx(3 / (free * DT / 3600))
    assert m["samples"] == 4000 + 6500 + 4000 + 3000
    cols = ["a:V", "s:i_a", "s:i_f", "s:i_f_plus_i_a", "unexplained", "none"]
    zero = dict.fromkeys(cols, 0)
    assert m["confusion"] == {
        "a:V": {**zero, "s:i_f": 1, "none": 1},
        "s:i_a": {**zero, "s:i_f_plus_i_a": 1},
        "s:i_f": {**zero, "s:i_f": 1},
    }
    assert list(m["confusion"]["a:V"]) == cols
    bins = {(b["fnr_lo"], b["fnr_hi"]): b for b in m["by_fnr"]}
    assert bins[(0.5, 1.0)]["faults"] == 1 and bins[(0.5, 1.0)]["detection_rate"] == 0.0
    assert bins[(1.0, 2.0)]["isolation_accuracy"] == 0.0
    assert bins[(1.0, 2.0)]["delay_mean_samples"] == 20
    assert bins[(2.0, 5.0)]["isolation_accuracy"] == 1.0
    assert bins[(20.0, 50.0)]["delay_mean_samples"] == 2
    assert bins[(5.0, 10.0)]["faults"] == 0 and bins[(5.0, 10.0)]["detection_rate"] is None
    assert m["by_kind"]["sensor_bias"]["faults"] == 2
    assert m["by_kind"]["actuator_scale"]["isolation"]["wrong"] == 1
    assert m["by_channel"]["a:V"]["missed"] == 1
    assert m["estimate_error_by_parameter"]["bias"]["median"] == pytest.approx(0.15)


def test_acceptance_and_diagnosis_delays_and_the_cusum_bound_by_hand():
    # A, B, C accepted 200 samples after their detections (delays 2, 10, 20 after onset).
    m = aggregate(_runs(), DT, false_alarm_interval=1e6)
    assert m["acceptance_delay_median_samples"] == 200
    assert m["acceptance_delay_p95_samples"] == 200
    assert m["diagnosis_delay_median_samples"] == 210
    assert m["diagnosis_delay_p95_samples"] == pytest.approx(219.0)  # 210 + 0.9 (220 - 210)
    # ln(1e6) / (fnr^2 / 2): FNR 30, 3 and 1.5 give 0.0307, 3.07 and 12.28 samples.
    assert cusum_bound(3.0, 1e6) == pytest.approx(np.log(1e6) / 4.5)
    ratios = sorted([2 / cusum_bound(30.0, 1e6), 10 / cusum_bound(3.0, 1e6),
                     20 / cusum_bound(1.5, 1e6)])
    assert m["delay_over_bound_median"] == pytest.approx(ratios[1])
    assert m["cusum_bound_median_samples"] == pytest.approx(cusum_bound(3.0, 1e6))
    bins = {(b["fnr_lo"], b["fnr_hi"]): b for b in m["by_fnr"]}
    assert bins[(1.0, 2.0)]["delay_over_bound_median"] == pytest.approx(ratios[0])
    assert bins[(0.5, 1.0)]["delay_over_bound_median"] is None  # its fault was missed
    a, *_ = _runs()
    assert a.faults[0].as_dict()["acceptance_delay"] == 200
    assert a.faults[0].as_dict()["diagnosis_delay"] == 202
    # Without the interval there is no bound to compare with.
    assert aggregate(_runs(), DT)["delay_over_bound_median"] is None
    assert aggregate(_runs(), DT)["delay_over_bank_bound_median"] is None
    assert np.isnan(cusum_bound(0.0, 1e6))


def test_the_bank_bound_is_the_cusum_bound_at_the_fnr_the_bank_sees():
    # RUN_A's fault (detected 2 samples after its onset) at FNR 3, of which the bank sees 0.3
    # of the energy: FNR 3 sqrt(0.3), a bound of ln(1e6) / (0.3 * 9 / 2) = 10.2 samples.
    import dataclasses

    faults, events, n = RUN_A
    seen = [dataclasses.replace(faults[0], fnr=3.0, bank_fnr=3.0 * np.sqrt(0.3))]
    m = aggregate([match_run(seen, events, n, first_monitored=8, twins=TWINS, names=NAMES)],
                  DT, false_alarm_interval=1e6)
    assert m["bank_bound_median_samples"] == pytest.approx(np.log(1e6) / (0.3 * 9 / 2))
    assert m["delay_over_bank_bound_median"] == pytest.approx(2 / cusum_bound(3 * 0.3 ** 0.5,
                                                                              1e6))
    assert m["delay_over_bank_bound_median"] == pytest.approx(0.3 * m["delay_over_bound_median"])
    assert seen[0].as_dict()["bank_fnr"] == pytest.approx(3.0 * np.sqrt(0.3))
    # A bound under one sample counts as one: the faulty sample itself.
    louder = [dataclasses.replace(faults[0], bank_fnr=1000.0)]
    m = aggregate([match_run(louder, events, n, first_monitored=8, twins=TWINS, names=NAMES)],
                  DT, false_alarm_interval=1e6)
    assert m["bank_bound_median_samples"] == 1.0 and m["delay_over_bank_bound_median"] == 2.0


def test_acceptance_over_the_excitation_bound_by_hand():
    # RUN_A's fault (onset 1000, accepted 1202): had least squares that knew it settled at
    # 1045, the diagnosis took 202 / 45 of what the data allowed.
    faults, events, n = RUN_A
    run = match_run(faults, events, n, first_monitored=8, twins=TWINS, names=NAMES,
                    excitation={1000: 1045})
    (f,) = run.faults
    assert f.excitation_sample == 1045
    assert f.acceptance_over_excitation == pytest.approx(202 / 45)
    assert f.as_dict()["acceptance_over_excitation"] == pytest.approx(202 / 45)
    m = aggregate([run], DT)
    assert m["acceptance_over_excitation_median"] == pytest.approx(202 / 45)
    # Without a bound (another method, or none within max_samples) there is no ratio.
    assert aggregate(_runs(), DT)["acceptance_over_excitation_median"] is None


def refined(k, target, index, estimates):
    return FaultEvent(kind="refined", sample=k, timestamp_ns=k, target=target, index=index,
                      name=NAMES[target][index], estimates=estimates, accepted_sample=k)


def test_the_final_estimate_follows_the_refinements_of_the_accepted_channel():
    # A's i_f refined from 0.55 to 0.51 (error 0.1 -> 0.02); a refinement after the end of
    # the run's only segment cannot happen, one of another channel does not count.
    f, e, n = RUN_A
    r = match_run(f, [*e, refined(1500, "sensor", 0, {"bias": 0.51}),
                      refined(1600, "sensor", 3, {"bias": 9.0})], n, first_monitored=8)
    (o,) = r.faults
    assert o.error == pytest.approx(0.1) and o.final_error == pytest.approx(0.02)
    assert o.final_estimate == {"bias": 0.51}
    # B's twin candidate i_a (-1.2 for a true -1) moves as the named i_f_plus_i_a does:
    # 1.2 -> 1.02 makes it -1.02. A refinement of that channel in a later segment would not
    # count; here the run ends at 6500.
    f, e, n = RUN_B
    r = match_run(f, [*e, refined(4000, "sensor", 2, {"bias": 1.02})], n, first_monitored=8,
                  twins=TWINS, names=NAMES)
    twin = r.faults[1]
    assert twin.isolation == "candidate"
    assert twin.final_estimate == pytest.approx({"bias": -1.02})
    assert twin.final_error == pytest.approx(0.02)
    m = aggregate([r], DT)
    assert m["final_estimate_error_median"] == pytest.approx(0.02)
    assert m["estimate_error_median"] == pytest.approx(0.2)
    # Without refinements the final estimate is the accepted one.
    (a,) = _runs()[0].faults
    assert a.final_errors == a.errors


def test_a_refinement_after_the_next_onset_is_not_the_earlier_faults():
    f = [fault("sensor", 0, "sensor_bias", 100, 5.0, bias=1.0),
         fault("sensor", 1, "sensor_bias", 3000, 5.0, bias=1.0)]
    events = [det(105), acc(300, 105, "sensor", 0, {"bias": 1.1}),
              refined(3100, "sensor", 0, {"bias": 1.0})]
    first, _ = match_run(f, events, 5000, first_monitored=8).faults
    assert first.final_error == pytest.approx(0.1)


def test_each_estimate_carries_its_std_and_whether_the_truth_lies_within_3_of_them():
    # A: i_f 0.55 (sd 0.01) for a true 0.5: 5 sd off. B: i_f_plus_i_a +1.2 named with sd 0.1,
    # its twin candidate i_a -1.2 (ratio -1: sd 0.1) for a true -1: 2 sd, within.
    f, e, n = RUN_A
    e = [e[0], FaultEvent(**{**e[1].__dict__, "variances": {"bias": 1e-4}})]
    (a,) = match_run(f, e, n, first_monitored=8).faults
    assert a.estimate_std == pytest.approx({"bias": 0.01}) and a.within_3_std is False
    f, e, n = RUN_B
    e = [e[0], FaultEvent(**{**e[1].__dict__, "variances": {"bias": 0.01}}), e[2]]
    r = match_run(f, e, n, first_monitored=8, twins=TWINS, names=NAMES)
    twin = r.faults[1]
    assert twin.estimate_std == pytest.approx({"bias": 0.1}) and twin.within_3_std is True
    assert twin.as_dict()["estimate_std"] == pytest.approx({"bias": 0.1})
    m = aggregate([match_run(*RUN_A[:1], [RUN_A[1][0], FaultEvent(**{
        **RUN_A[1][1].__dict__, "variances": {"bias": 1e-4}})], RUN_A[2], first_monitored=8),
        r], DT)
    assert (m["estimates_within_3_std"], m["estimates_judged"]) == (0.5, 2)
    # The missed fault of B has no estimate to judge; a fault without variances neither.
    assert r.faults[0].within_3_std is None
    assert _runs()[0].faults[0].within_3_std is None


def test_a_second_fault_the_bus_takes_for_more_of_the_first_is_scored_by_its_own_size():
    # i_f +0.5 at 100 accepted 0.5; i_f +0.004 more at 3000, re-detected and folded as a
    # refinement (within the first estimate's uncertainty): 0.505 is the updated size of the
    # first, so the second's own estimate is 0.005 (error 0.25), not 0.505.
    f = [fault("sensor", 0, "sensor_bias", 100, 30.0, bias=0.5),
         fault("sensor", 0, "sensor_bias", 3000, 1.0, bias=0.004)]
    events = [det(105), acc(300, 105, "sensor", 0, {"bias": 0.5}), det(3050),
              FaultEvent(kind="refined", sample=3100, timestamp_ns=3100, target="sensor",
                         index=0, name="i_f", estimates={"bias": 0.505},
                         variances={"bias": 1e-6}, detected_sample=3050, accepted_sample=3100)]
    first, second = match_run(f, events, 5000, first_monitored=8, names=NAMES).faults
    assert first.estimate == {"bias": 0.5}
    assert second.decision == "accepted" and second.isolation == "exact"
    assert second.estimate == pytest.approx({"bias": 0.005})
    assert second.error == pytest.approx(0.25)


def test_a_fault_is_named_when_a_named_event_of_its_own_says_its_channel():
    # A: i_f named at 1012 (10 after its detection), accepted at 1202: named delay 12. A named
    # event of another channel does not count; without one, the acceptance names it.
    f, e, n = RUN_A

    def named(k, index):
        return FaultEvent(kind="named", sample=k, timestamp_ns=k, target="sensor", index=index,
                          name=NAMES["sensor"][index], estimates={"bias": 0.5},
                          detected_sample=1002, undecided=("size",))
    (o,) = match_run(f, [e[0], named(1012, 0), e[1]], n, first_monitored=8).faults
    assert (o.named_sample, o.named_delay) == (1012, 12)
    assert o.as_dict()["named_delay"] == 12
    (o,) = match_run(f, [e[0], named(1010, 3), e[1]], n, first_monitored=8).faults
    assert o.named_sample == 1202
    (o,) = match_run(f, [e[0], named(1012, 0)], n, first_monitored=8).faults
    assert o.decision == "none" and o.named_sample == 1012
    m = aggregate(_runs(), DT)
    # Named at acceptance: A 202, B's twin 210, C wrong (never named rightly).
    assert (m["named_delay_median_samples"], m["named_delay_p95_samples"]) == (
        206.0, pytest.approx(209.6))


def test_fnr_outside_the_bins_goes_to_the_end_bins():
    runs = [match_run([fault("sensor", 0, "sensor_bias", 100, fnr, bias=1.0)],
                      [det(101), acc(301, 101, "sensor", 0, {"bias": 1.0})], 3000)
            for fnr in (0.1, 80.0)]
    m = aggregate(runs, DT)
    assert m["by_fnr"][0]["faults"] == 1 and m["by_fnr"][-1]["faults"] == 1


def test_a_redetection_after_unexplained_stays_the_faults_own():
    f = [fault("sensor", 0, "sensor_bias", 100, 5.0, bias=1.0)]
    events = [det(105), unexp(2105, 105), det(2200), acc(2400, 2200, "sensor", 0, {"bias": 1.0})]
    r = match_run(f, events, 5000, first_monitored=8)
    (o,) = r.faults
    assert (o.detected_sample, o.delay, o.decision, o.isolation) == (105, 5, "accepted", "exact")
    assert r.false_alarms == ()
    assert r.fault_free_samples == (100 - 8) + (5000 - 2400)


def test_unexplained_and_undecided_decisions():
    f = [fault("sensor", 0, "sensor_bias", 100, 5.0, bias=1.0),
         fault("sensor", 1, "sensor_bias", 3000, 5.0, bias=1.0)]
    r = match_run(f, [det(110), unexp(2110, 110), det(3004)], 4000, first_monitored=8)
    first, second = r.faults
    assert (first.decision, first.diagnosed, first.delay) == ("unexplained", "unexplained", 10)
    assert (second.decision, second.diagnosed, second.delay) == ("none", "none", 4)
    assert r.fault_free_samples == 92  # only the lead-in: nothing was accepted
    m = aggregate([r], DT)
    assert (m["unexplained"], m["undecided"], m["accepted"]) == (1, 1, 0)
    assert m["isolation_accuracy"] is None and m["detection_rate"] == 1.0


def test_a_design_twin_is_counted_apart_from_wrong():
    names = {"actuator": ["u1", "u2", "u3"], "sensor": ["T1", "Omega2", "T3"]}
    f = [InjectedFault("actuator", 0, "u1", "actuator_bias", 100, {"eta": 1.0, "lambda": 0.002},
                       3.0)]
    ev = [det(103), FaultEvent(kind="accepted", sample=303, timestamp_ns=0, target="sensor",
                               index=0, name="T1", estimates={"bias": 0.001},
                               detected_sample=103, accepted_sample=303)]
    r = match_run(f, ev, 3000, twins={"a:u1": frozenset({"s:T1"})}, names=names)
    assert r.faults[0].isolation == "design_twin" and not r.faults[0].correct
    assert match_run(f, ev, 3000, names=names).faults[0].isolation == "wrong"


def test_relative_errors_of_each_kind():
    bias = fault("actuator", 0, "actuator_bias", 0, 1.0, eta=1.0, **{"lambda": 2.0})
    assert relative_errors(bias, {"eta": 1.1, "lambda": 1.5}) == pytest.approx(
        {"eta": 0.1, "lambda": 0.25})
    scale = fault("actuator", 0, "actuator_scale", 0, 1.0, eta=2.0, **{"lambda": 0.0})
    assert relative_errors(scale, {"eta": 1.8, "lambda": 0.3}) == pytest.approx({"eta": 0.1})
    sensor = fault("sensor", 0, "sensor_bias", 0, 1.0, bias=-0.5)
    assert relative_errors(sensor, {"bias": -0.4}) == pytest.approx({"bias": 0.2})


def _setup():
    channels = (Channel("actuator", 0, "V", 2.0, True), Channel("sensor", 0, "i_f", 100.0, True),
                Channel("sensor", 1, "i_a", 50.0, True), Channel("sensor", 2, "w", 0.0, False))
    return EvaluationSetup(plant="dc_motor", dt=DT, channels=channels, u_rms=np.array([60.0]),
                           measurement_std=np.full(3, 0.01), spacing=3000, lead=(300, 1000))


def test_plan_runs_is_seeded_and_draws_what_it_says():
    setup = _setup()
    specs = plan_runs(setup, 50, 7, max_faults=3, fnr_range=(1.0, 10.0), noise_spread=1.5)
    assert plan_runs(setup, 50, 7, max_faults=3, fnr_range=(1.0, 10.0),
                     noise_spread=1.5) == specs
    assert plan_runs(setup, 3, 7, max_faults=3, fnr_range=(1.0, 10.0),
                     noise_spread=1.5) == specs[:3]  # run i does not depend on --runs
    gaps = {c.label: c.gap for c in setup.channels}
    counts = set()
    for s in specs:
        counts.add(len(s.faults))
        assert 1 / 1.5 <= s.noise_scale <= 1.5
        labels = [f.label for f in s.faults]
        assert len(set(labels)) == len(labels) and "s:w" not in labels
        onsets = [f.onset_sample for f in s.faults]
        if onsets:
            assert 300 <= onsets[0] <= 1000
            assert all(3000 <= b - a <= 3300 for a, b in itertools.pairwise(onsets))
            assert s.samples >= onsets[-1] + 3000
        else:
            assert s.samples >= 3300
        for f in s.faults:
            assert 1.0 <= f.fnr <= 10.0
            if f.kind == "sensor_bias":
                size = abs(f.params["bias"])
            elif f.kind == "actuator_bias":
                size = abs(f.params["lambda"])
                assert f.params["eta"] == 1.0
            else:
                size = abs(f.params["eta"] - 1.0) * 60.0
                assert f.params["lambda"] == 0.0 and f.params["eta"] > 0
            assert size * gaps[f.label] / s.noise_scale == pytest.approx(f.fnr)
    assert counts == {0, 1, 2, 3}
    d = specs[1].scenario_dict("dc_motor", DT, setup.measurement_std)
    assert d["noise"]["measurement"] == pytest.approx([0.01 * specs[1].noise_scale] * 3)
    assert d["duration"] == pytest.approx(specs[1].samples * DT)


def test_plan_runs_only_the_kinds_asked():
    specs = plan_runs(_setup(), 30, 1, kinds=("sensor_bias",))
    assert all(f.kind == "sensor_bias" for s in specs for f in s.faults)
    with pytest.raises(ValueError):
        plan_runs(EvaluationSetup("dc_motor", DT, (Channel("sensor", 0, "w", 0.0, False),),
                                  np.ones(1), np.ones(1), 3000, (300, 1000)), 3, 1)

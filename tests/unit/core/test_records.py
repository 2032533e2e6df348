"""canfdi.core.records.fold: a diagnosis on a compensated channel is a fault of its own or what
the earlier estimate left, by the earlier estimate's uncertainty (issue 41)."""

import numpy as np
import pytest

from canfdi.core.records import Compensation, compensated, fold, latest_fault


def sensor(onset, bias, var, **kw):
    return Compensation("sensor", 2, onset, bias=bias, variances={"bias": var}, **kw)


def test_a_change_beyond_the_earlier_estimate_s_uncertainty_is_a_fault_of_its_own():
    comp = [sensor(100, -0.3377, 1e-6)]
    # 0.0553 against sd sqrt(1e-6 + 4e-6): 25 sd. Its own size, not the channel's -0.2824.
    assert fold(comp, sensor(3000, 0.0553, 4e-6)) == ("accepted", {"bias": 0.0553},
                                                      {"bias": pytest.approx(5e-6)})
    assert compensated(comp, "sensor", 2) == pytest.approx({"bias": -0.2824})
    # 2.9 sd of what is known: what the estimate left, the latest fault's size updated.
    kind, size, var = fold(comp, sensor(3000, 0.0065, 0.0))
    assert (kind, var) == ("refined", {"bias": 0.0})
    assert size == pytest.approx({"bias": 0.0618})
    assert latest_fault(comp, "sensor", 2) == pytest.approx({"bias": 0.0618})


def test_a_correction_refines_whatever_its_size():
    comp = [sensor(100, 1.0, 1e-6)]
    kind, size, _ = fold(comp, sensor(100, 0.5, 1e-6, correction=True))
    assert (kind, size) == ("refined", {"bias": 1.5})


def test_without_variances_a_second_diagnosis_refines():
    comp = [Compensation("sensor", 0, 100, bias=1.0)]
    assert fold(comp, Compensation("sensor", 0, 900, bias=0.5))[0] == "refined"


def test_a_scale_completing_an_accepted_bias_refines_it_a_bias_after_a_scale_is_new():
    # V accepted as a bias (eta held at 1, what the data knew of it its variance) while the
    # command stood still; once it moves, the diagnosis finds the scale: the same fault's
    # form, not a new one.
    comp = [Compensation("actuator", 0, 3629, eta=1.0, lam=-0.9486, scale=True,
                         variances={"eta": 2e-5, "lambda": 5.7e-4}, fixed=("eta",))]
    kind, size, _ = fold(comp, Compensation("actuator", 0, 4000, eta=0.987, lam=0.9363,
                                            scale=True,
                                            variances={"eta": 1e-6, "lambda": 1e-3}))
    assert kind == "refined"
    assert size == pytest.approx({"eta": 0.987, "lambda": 0.987 * -0.9486 + 0.9363})
    # A bias of its own on an actuator whose scale was estimated is a new fault.
    comp = [Compensation("actuator", 0, 100, eta=1.2, lam=0.0, scale=True,
                         variances={"eta": 1e-6, "lambda": 1e-4})]
    kind, size, var = fold(comp, Compensation("actuator", 0, 3000, eta=1.0, lam=2.0,
                                              scale=True,
                                              variances={"eta": 0.0, "lambda": 1e-2}))
    assert (kind, size) == ("accepted", {"eta": 1.0, "lambda": 2.0})
    assert var == pytest.approx({"eta": 1e-6, "lambda": 1e-2 + 1e-4})
    # The channel's total composes both in the order they act: eta 1.2, lambda 2.
    assert compensated(comp, "actuator", 0) == pytest.approx({"eta": 1.2, "lambda": 2.0})


def test_a_parameter_held_fixed_is_no_evidence_for_a_new_fault():
    # Two biases accepted alone on V (eta held at 1 both times, each with the variance the
    # data left it): the second is judged on lambda alone, one degree of freedom, as if eta
    # were not there; a lambda of 4.2 sd (beyond OWN_FAULT_SIGMA on one, within it on two) is
    # a fault of its own.
    held = {"eta": 1e-4, "lambda": 1e-4}
    comp = [Compensation("actuator", 0, 100, eta=1.0, lam=1.0, scale=True, variances=held,
                         fixed=("eta",))]
    second = Compensation("actuator", 0, 3000, eta=1.0, lam=4.2 * np.sqrt(2e-4), scale=True,
                          variances=held, fixed=("eta",))
    assert fold(comp, second)[0] == "accepted"


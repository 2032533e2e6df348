"""Nyberg and Nielsen: Theorems 2 and 3 on the paper's examples and on the DC motor."""

import numpy as np

from canfdi.core.detectability import fault_detectability, model_detectability
from canfdi.core.model import StateSpace
from tests.dc_motor import dc_motor

PENDULUM = StateSpace(
    A=[[0, 0, 1, 0], [0, 0, 0, 1], [0, -1.93, -1.99, 0.009], [0, 36.9, 6.26, -0.174]],
    B=[0, 0, -0.3205, -1.009], C=[[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0]],
    dt=0.01, continuous=True,
)


def _sensors(results):
    return {j: d for kind, j, d in results if kind == "sensor"}


def test_example_2_inverted_pendulum_continuous():
    s = _sensors(model_detectability(PENDULUM))
    assert all(d.detectable for d in s.values())
    assert not s[0].strongly_detectable and "Theorem 3" in s[0].reason
    assert s[1].strongly_detectable and s[2].strongly_detectable


def test_example_2_holds_for_the_discretised_model_too():
    s = _sensors(model_detectability(PENDULUM.discretize()))
    assert [d.detectable for d in s.values()] == [True, True, True]
    assert [d.strongly_detectable for d in s.values()] == [False, True, True]


def test_example_3_not_strongly_detectable_although_direct_term_nonzero():
    A = np.array([[-2.0, -3.0], [0.0, -1.0]])
    d = fault_detectability(
        A=A, B=np.array([[1.0], [0.0]]), C=np.array([[1.0, 4.0], [2.0, 4.0]]),
        D=np.zeros((2, 1)), E=np.array([[-2.0], [0.0]]), J=np.array([[6.0], [5.0]]),
        K=np.array([-6.0, -6.0]), L=np.array([-2.0, 0.0]), continuous=True,
    )
    assert d.n_z == 1  # x2 is reachable only from the fault
    assert d.detectable
    assert not d.strongly_detectable
    assert d.direct_steady_response > 1e-3  # N^T P v != 0 ...
    assert d.steady_response < 1e-10 * d.direct_steady_response  # ... yet the true term is 0


def test_dc_motor_sensor_4_not_detectable_with_w_decoupled():
    results = model_detectability(dc_motor())
    s = _sensors(results)
    assert [s[j].detectable for j in range(3)] == [True, True, True]
    assert not s[3].detectable and "Theorem 2" in s[3].reason
    act = next(d for kind, _, d in results if kind == "actuator")
    assert act.detectable and act.strongly_detectable


def test_disturbance_in_fault_direction_hides_the_fault():
    """A sensor bias exactly in the image of an output unknown input is not detectable."""
    m = StateSpace(A=[[0.5]], B=[[1.0]], C=[[1.0], [1.0]], G=[[1.0], [0.0]], dt=1.0)
    s = _sensors(model_detectability(m))
    assert not s[0].detectable
    assert s[1].detectable

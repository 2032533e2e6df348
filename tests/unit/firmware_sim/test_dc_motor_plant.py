"""The emulated DC motor: its ZOH discretisation is eq. 43, and it satisfies eq. 43 exactly."""

import numpy as np
from scipy.signal import cont2discrete

from canfdi.firmware_sim.plants.dc_motor import DcMotor
from tests.dc_motor import dc_motor

PRINTED_A = ([0.8825, 0.6839, 0.9948], 4)  # diag, decimals printed
PRINTED_B = ([0.002235, 0.0823, 0.0], [6, 4, 0])


def test_zoh_discretisation_reproduces_eq_43_to_the_printed_digits():
    p = DcMotor().params
    A, B = p.linear_part()
    Ad, Bd, *_ = cont2discrete((A, B, np.eye(3), np.zeros((3, 1))), p.dt, method="zoh")
    assert np.allclose(Ad - np.diag(np.diag(Ad)), 0.0)
    for value, printed in zip(np.diag(Ad), PRINTED_A[0], strict=True):
        assert round(value, PRINTED_A[1]) == printed
    for value, printed, decimals in zip(Bd.ravel(), *PRINTED_B, strict=True):
        assert round(value, decimals) == printed


def test_nonlinear_step_is_eq_43_plus_a_term_in_span_F():
    """x(k+1) - A x(k) - B u(k) lies in span(F) = span(e2, e3): the i_f channel is exact."""
    plant, model = DcMotor(), dc_motor()
    rng = np.random.default_rng(0)
    x = plant.initial_state()
    for _ in range(200):
        u = np.array([rng.uniform(20, 120)])
        x_next = plant.step(x, u)
        w = x_next - model.A @ x - model.B @ u
        assert abs(w[0]) < 1e-9 * max(1.0, abs(x_next[0]))
        x = x_next


def test_operating_point_and_outputs():
    plant = DcMotor()
    x = plant.steady_state(plant.voltage_for_speed(100.0))
    assert abs(x[2] - 100.0) < 1e-6
    np.testing.assert_allclose(plant.step(x, [plant.voltage_for_speed(100.0)]), x, rtol=1e-9)
    np.testing.assert_allclose(plant.output(x), [x[0], x[1], x[0] + x[1], x[2]])

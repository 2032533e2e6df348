"""The excitation bound (canfdi.methods.parity.settling.excitation_bound, issue 41): the first
sample at which least squares that knows a fault's form and onset settles on a run's commands.
Checked against the sums written out by hand, against the diagnoser's own per-sample
regressors, and on the DC motor, where an actuator's scale is known only as its command moves."""

from __future__ import annotations

import math

import numpy as np
import pytest

from canfdi.core.design import design_bank
from canfdi.core.model import StateSpace
from canfdi.core.residuals import ResidualBank
from canfdi.methods.parity.diagnoser import ParitySettings
from canfdi.methods.parity.hypotheses import Hypothesis, regressors, steady_response
from canfdi.methods.parity.settling import excitation_bound, settle_sizes
from canfdi.methods.parity.thresholds import long_run_covariance
from tests.conftest import REPO


def _tiny():
    model = StateSpace(A=[[0.5]], B=[[1.0]], C=[[1.0], [1.0]], dt=0.01)
    bank = ResidualBank(design_bank(model, ["u"], ["y0", "y1"]))
    return bank, long_run_covariance(bank, np.ones(2))


def test_a_sensor_bias_settles_when_the_sums_written_out_say():
    bank, omega = _tiny()
    assert bank.S == 1  # a window of two samples: the regressor is full one sample after onset
    settings = ParitySettings(settle_rel_std=0.005, settle_noise=0.0, min_samples=10,
                              max_samples=20000, prior_precision=1e-8)
    h, bias, onset = Hypothesis("sensor", 0, "y0"), 10.0, 100
    U = np.ones((onset + 20001, 1))
    got = excitation_bound(bank, settings, omega, None, h, np.array([bias]), onset, U,
                           noise_scale=1.5)
    # By hand: at the onset only the window's last sample is faulty (phi0), then n samples of
    # the steady signature g: J_n = prior + phi0'phi0 + n g'g, M_n = phi0' O phi0 + n g' O g,
    # sd_n = 1.5 sqrt(M_n) / J_n with the prior's pull 1e-8 bias / J_n beside it; the first n
    # with sd_n <= 0.5 % of 10 and n >= 10.
    phi0 = bank.Gz[0][:, 1] / bank.sigma
    g = steady_response(bank, "sensor", 0)
    n = 0
    while True:
        J = 1e-8 + phi0 @ phi0 + n * (g @ g)
        M = phi0 @ omega @ phi0 + n * (g @ omega @ g)
        if n >= 10 and math.hypot(1.5 * math.sqrt(M) / J, 1e-8 * bias / J) <= 0.005 * bias:
            break
        n += 1
    assert got == onset + n
    assert 50 < n < 20000  # the case is neither the minimum nor the cap
    # Asymptotically n = 2.25 g'Og / (g'g)^2 / 0.05^2.
    assert n == pytest.approx(2.25 * (g @ omega @ g) / (g @ g) ** 2 / 0.05 ** 2, rel=0.01)


def test_the_bound_is_what_the_diagnosers_own_regressors_give_sample_by_sample():
    bank, omega = _tiny()
    settings = ParitySettings(settle_rel_std=0.02, settle_noise=0.0, min_samples=10,
                              max_samples=3000)
    h, theta, onset = Hypothesis("actuator", 0, "u"), np.array([0.3, 2.0]), 200
    rng = np.random.default_rng(4)
    U = np.cumsum(rng.normal(0.0, 0.05, size=(3500, 1)), axis=0) + 1.0  # a wandering command
    got = excitation_bound(bank, settings, omega, None, h, theta, onset, U)
    J, M, u_abs = np.eye(2) * settings.prior_precision, np.zeros((2, 2)), 0.0
    want = None
    for k in range(onset, onset + settings.max_samples + 1):
        phi = regressors(bank, [h], 2, k, np.array([onset]), U[k - bank.S: k + 1])[0, 0]
        J, M = J + phi.T @ phi, M + phi.T @ omega @ phi
        u_abs += abs(U[k, 0])
        P = np.linalg.inv(J)
        sd = np.sqrt(np.diag(P @ M @ P) + (P @ (settings.prior_precision * theta)) ** 2)
        size = settle_sizes(h, theta, u_abs / (k - onset + 1))
        if k - onset >= 10 and np.all(sd <= 0.02 * size):
            want = k
            break
    assert want is not None and want - onset > 100 and got == want


def test_on_the_dc_motor_the_form_of_an_actuator_fault_is_known_only_as_the_command_moves():
    from canfdi.config import load_config
    from canfdi.methods import build_diagnoser

    config = load_config(REPO / "deploy" / "config" / "dc_motor.yaml")
    dg = build_diagnoser(config)
    onset, n = 500, 4000
    steady = np.full((n, 1), 40.0)
    moving = steady + 8.0 * np.sin(2 * np.pi * np.arange(n)[:, None] / 400.0)
    # A bias of 2 V fitted by the full form (eta - 1 and lambda): under a steady command it
    # acts as a scale of 1.05 would, and nothing tells them apart; a moving one does.
    full, bias = Hypothesis("actuator", 0, "V"), np.array([0.0, 2.0])

    def bound(U):
        return excitation_bound(dg.bank, dg.settings, dg.tracker.gamma, None, full, bias,
                                onset, U)

    assert bound(steady) is None
    assert bound(moving) is not None and bound(moving) - onset < dg.settings.max_samples
    # Known to be a bias (its true form): a few samples, steady or not.
    quick = dg.excitation_bound("actuator_bias", 0, {"eta": 1.0, "lambda": 2.0}, onset, steady)
    assert quick is not None and quick - onset < 50
    # A noisier drive needs more samples for the same precision (four times: the variance).
    i_a = {"bias": 0.05}
    base = dg.excitation_bound("sensor_bias", 1, i_a, onset, steady)
    louder = dg.excitation_bound("sensor_bias", 1, i_a, onset, steady, noise_scale=2.0)
    assert base is not None and louder is not None
    assert louder - onset == pytest.approx(4 * (base - onset), rel=0.1)

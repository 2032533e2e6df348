"""The sensor noise estimated through the parity space (canfdi.core.noise), on simulated
records whose noise is known: whatever the inputs and the unknown inputs do."""

import numpy as np
import pytest

from canfdi.config import load_config
from canfdi.core.noise import estimate_measurement_noise, parity_space_residuals
from tests.conftest import REPO

CONFIGS = REPO / "deploy" / "config"


def simulate(model, n, std, seed=0, covariance=None):
    """(U, Z) of a random-input, random-unknown-input run with sensor noise ``std`` (or the
    full ``covariance``)."""
    rng = np.random.default_rng(seed)
    model = model.discretize() if model.continuous else model
    U = np.cumsum(rng.normal(0, 0.3, (n, model.p)), axis=0)  # slow, large moves
    W = rng.normal(0, 1.0, (n, model.r)) if model.r else np.zeros((n, 0))
    x = np.zeros(model.n)
    X = np.zeros((n, model.n))
    for k in range(n):
        X[k] = x
        x = model.A @ x + model.B @ U[k] + (model.F @ W[k] if model.r else 0.0)
    cov = np.diag(np.asarray(std) ** 2) if covariance is None else covariance
    noise = rng.multivariate_normal(np.zeros(model.q), cov, n)
    return model, U, X @ model.C.T + noise


def test_every_sensor_of_the_winding_machine_is_recovered_within_5_percent():
    config = load_config(CONFIGS / "winding_machine.yaml")
    std = np.array([2e-4, 5e-5, 1e-4])
    model, U, Z = simulate(config.model, 9000, std)
    est = estimate_measurement_noise(model, 8, U, Z, prior_std=np.full(3, 1e-4))
    assert est.identifiable.all() and est.seen.all()
    np.testing.assert_allclose(est.std, std, rtol=0.05)
    assert (est.std_error < 0.05 * std).all()


def test_unknown_inputs_do_not_reach_the_estimate():
    # The DC motor's phi1, phi2 (unknown inputs, here large) are decoupled out of every
    # relation the estimate uses; i_f is identified alone.
    config = load_config(CONFIGS / "dc_motor.yaml")
    std = np.array([0.02, 0.03, 0.01, 0.05])
    model, U, Z = simulate(config.model, 9000, std, seed=1)
    est = estimate_measurement_noise(model, 8, U, Z, prior_std=np.full(4, 0.01))
    assert est.identifiable.tolist() == [True, False, False, False]
    assert est.std[0] == pytest.approx(0.02, rel=0.05)
    # i_a and i_f + i_a reach the residuals only as their difference: the sum of their
    # variances is what the data fix, split in the prior's proportions (equal here).
    assert est.std[1] ** 2 + est.std[2] ** 2 == pytest.approx(0.03**2 + 0.01**2, rel=0.05)
    assert est.std[1] == pytest.approx(est.std[2], rel=1e-3)
    # omega_r: no w-decoupled relation reads it; it keeps the prior times the others' scale.
    assert est.seen.tolist() == [True, True, True, False]


def test_a_uniformly_noisier_drive_is_recovered_whole():
    config = load_config(CONFIGS / "dc_motor.yaml")
    model, U, Z = simulate(config.model, 9000, np.full(4, 0.03), seed=2)
    est = estimate_measurement_noise(model, 8, U, Z, prior_std=np.full(4, 0.01))
    np.testing.assert_allclose(est.std, 0.03, rtol=0.05)


def test_sensors_sharing_noise_give_their_covariance():
    config = load_config(CONFIGS / "winding_machine.yaml")
    std = np.array([2e-4, 1e-4, 1e-4])
    cov = np.diag(std**2)
    cov[0, 2] = cov[2, 0] = 0.6 * std[0] * std[2]
    model, U, Z = simulate(config.model, 20000, std, seed=3, covariance=cov)
    est = estimate_measurement_noise(model, 8, U, Z, prior_std=np.full(3, 1e-4), full=True)
    np.testing.assert_allclose(est.std, std, rtol=0.05)
    corr = est.covariance[0, 2] / np.sqrt(est.covariance[0, 0] * est.covariance[2, 2])
    assert corr == pytest.approx(0.6, abs=0.05)
    assert abs(est.covariance[0, 1]) < 0.1 * std[0] * std[1]


def test_lost_samples_drop_only_their_windows():
    config = load_config(CONFIGS / "winding_machine.yaml")
    std = np.array([2e-4, 5e-5, 1e-4])
    model, U, Z = simulate(config.model, 9000, std, seed=4)
    Z[np.random.default_rng(0).random(9000) < 0.01, 1] = np.nan
    r, _ = parity_space_residuals(model, 8, U, Z)
    assert np.isnan(r).any(axis=1).mean() < 0.2
    est = estimate_measurement_noise(model, 8, U, Z, prior_std=np.full(3, 1e-4))
    np.testing.assert_allclose(est.std, std, rtol=0.05)


def test_too_short_a_record_is_refused():
    config = load_config(CONFIGS / "winding_machine.yaml")
    model, U, Z = simulate(config.model, 50, np.full(3, 1e-4))
    with pytest.raises(ValueError, match="too few"):
        estimate_measurement_noise(model, 8, U, Z, prior_std=np.full(3, 1e-4))

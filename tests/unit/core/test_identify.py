"""canfdi.core.identify: the one least squares (information-form RLS, Chan et al. 2006 eqs.
30-32)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.lib.stride_tricks import sliding_window_view

from canfdi.core.identify import least_squares, rls_batch, rls_init, rls_solve, rls_update


def _eqs_30_32(theta: np.ndarray, P: np.ndarray, Phi: np.ndarray, R: np.ndarray):
    """Eqs. 30-32 written out (covariance form, forgetting 1): the reference the information
    form must equal. Returns theta (N, d) and P (N, d, d) after each sample."""
    thetas, Ps = [], []
    for phi, r in zip(Phi, R, strict=True):
        K = P @ phi.T @ np.linalg.inv(np.eye(len(r)) + phi @ P @ phi.T)  # eq. 31
        theta = theta + K @ (r - phi @ theta)  # eq. 30
        P = (np.eye(len(theta)) - K @ phi) @ P  # eq. 32
        thetas.append(theta)
        Ps.append(P)
    return np.array(thetas), np.array(Ps)


def _actuator_data(rng, N: int, eta: float, lam: float, s: int = 2):
    """Chan et al. 2006 eqs. 26-29: an actuator residual r = (eta - 1) g.Uc + lambda sum(g), and its
    regressor phi = [g.Uc, sum(g)] (N, 1, 2)."""
    g = rng.normal(size=s + 1)
    Uc = sliding_window_view(rng.normal(size=N + s), s + 1)
    r = (eta * Uc + lam - Uc) @ g
    Phi = np.stack([Uc @ g, np.full(N, g.sum())], axis=-1)[:, None, :]
    return Phi, r


# --- the information form is eqs. 30-32 --------------------------------------------------------


@pytest.mark.parametrize(("m", "d"), [(1, 2), (4, 3)])
def test_information_form_equals_eqs_30_to_32_with_p_reset(m: int, d: int) -> None:
    rng = np.random.default_rng(m + d)
    Phi = rng.normal(size=(60, m, d))
    R = Phi @ rng.normal(size=d) + 0.1 * rng.normal(size=(60, m))
    prior = 1e-4  # P0 = 1e4 I, the reset value
    ref_theta, ref_P = _eqs_30_32(np.zeros(d), np.eye(d) / prior, Phi, R)
    batch = rls_batch(rls_init(d, prior), Phi, R)
    np.testing.assert_allclose(batch.theta, ref_theta, rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(batch.variances, np.diagonal(ref_P, axis1=1, axis2=2),
                               rtol=1e-7, atol=1e-12)


def test_actuator_fault_identified_exactly() -> None:
    Phi, r = _actuator_data(np.random.default_rng(1), N=2000, eta=2.0, lam=10.0)
    fit = rls_solve(rls_batch(rls_init(2), Phi, r).state)
    np.testing.assert_allclose(fit.theta, [1.0, 10.0], atol=1e-6)  # [eta - 1, lambda]
    assert fit.cost == pytest.approx(0.0, abs=1e-6)


def test_sensor_biases_identified_by_step_and_batch() -> None:
    """Chan et al. 2006 eq. 41: r = V I* f, constant in time."""
    rng = np.random.default_rng(3)
    q, s, m, N = 4, 2, 4, 500
    V = rng.normal(size=(m, (s + 1) * q))
    for i in range(m):
        V[i, i::q] = 0.0  # row i is the residual insensitive to sensor i (eq. 37)
    f = np.array([10.0, 10.0, 0.1, 0.0])
    phi = V.reshape(m, s + 1, q).sum(axis=1)  # V I*
    r = V @ np.tile(f, s + 1)
    batch = rls_batch(rls_init(q), np.broadcast_to(phi, (N, m, q)), np.broadcast_to(r, (N, m)))
    np.testing.assert_allclose(rls_solve(batch.state).theta, f, atol=1e-6)
    state = rls_init(q)
    for _ in range(N):
        state = rls_update(state, phi, r)
    np.testing.assert_allclose(rls_solve(state).theta, f, atol=1e-6)


# --- batch == step, chunks, missing rows, batched estimators ----------------------------------


def _stepped(state, Phi, R):
    """rls_update sample by sample; the innovation is r - phi theta before the sample."""
    thetas, costs, innovs = [], [], []
    for phi, r in zip(Phi, R, strict=True):
        e = r - phi @ rls_solve(state).theta
        state = rls_update(state, phi, r)
        sol = rls_solve(state)
        thetas.append(sol.theta)
        costs.append(sol.cost)
        innovs.append(e)
    return np.array(thetas), np.array(costs), np.array(innovs), state


def test_batch_equals_steps_chunk_by_chunk_with_missing_rows() -> None:
    rng = np.random.default_rng(4)
    Phi = rng.normal(size=(300, 3, 2))
    R = Phi @ np.array([0.5, -1.0]) + 0.05 * rng.normal(size=(300, 3))
    R[rng.random((300, 3)) < 0.1] = np.nan  # lost values: those rows are no equation
    thetas, costs, innovs, final = _stepped(rls_init(2), Phi, R)
    state, parts = rls_init(2), []
    for a, b in ((0, 7), (7, 7), (7, 150), (150, 300)):
        parts.append(rls_batch(state, Phi[a:b], R[a:b]))
        state = parts[-1].state
    np.testing.assert_allclose(np.concatenate([p.theta for p in parts]), thetas, rtol=1e-9,
                               atol=1e-12)
    np.testing.assert_allclose(np.concatenate([p.cost for p in parts]), costs, rtol=1e-9,
                               atol=1e-9)
    np.testing.assert_allclose(np.concatenate([p.innovations for p in parts]), innovs,
                               rtol=1e-9, atol=1e-12)
    assert np.isnan(innovs[np.isnan(R)]).all()
    assert state.n == final.n == 300 and state.n_eq == final.n_eq == int((~np.isnan(R)).sum())


@settings(max_examples=40, deadline=None)
@given(n=st.integers(1, 40), m=st.integers(1, 3), d=st.integers(1, 3),
       seed=st.integers(0, 2**31 - 1))
def test_property_batch_equals_steps(n: int, m: int, d: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    Phi, R = rng.normal(size=(n, m, d)), rng.normal(size=(n, m))
    thetas, costs, _, _ = _stepped(rls_init(d, 1e-2), Phi, R)
    batch = rls_batch(rls_init(d, 1e-2), Phi, R)
    np.testing.assert_allclose(batch.theta, thetas, rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(batch.cost, costs, rtol=1e-7, atol=1e-9)


def test_cost_is_the_residual_sum_of_squares_plus_the_prior_term() -> None:
    rng = np.random.default_rng(5)
    Phi, R = rng.normal(size=(50, 2, 3)), rng.normal(size=(50, 2))
    theta0, prior = np.array([1.0, 0.0, -1.0]), 0.3
    sol = rls_solve(rls_batch(rls_init(3, prior, theta0), Phi, R).state)
    resid = R - Phi @ sol.theta
    expected = (resid**2).sum() + prior * ((sol.theta - theta0) ** 2).sum()
    assert sol.cost == pytest.approx(expected, rel=1e-10)


def test_leading_batch_dimensions_are_independent_estimators() -> None:
    """The diagnosers fit every hypothesis and onset at once: one state of shape (H, K)."""
    rng = np.random.default_rng(6)
    Phi = rng.normal(size=(40, 2, 3, 4, 2))  # (N, H, K, m, d)
    R = rng.normal(size=(40, 4))  # the same residual rows for every estimator
    state = rls_init(2, shape=(2, 3))
    for phi, r in zip(Phi, R, strict=True):
        state = rls_update(state, phi, r)
    together = rls_solve(state)
    for h in range(2):
        for k in range(3):
            alone = rls_solve(rls_batch(rls_init(2), Phi[:, h, k], R).state)
            np.testing.assert_allclose(together.theta[h, k], alone.theta, rtol=1e-10)
            np.testing.assert_allclose(together.cost[h, k], alone.cost, rtol=1e-10)


def test_covariance_reset_follows_an_abrupt_change_within_d_plus_one_samples() -> None:
    rng = np.random.default_rng(7)
    d = 2
    theta_a, theta_b = np.array([1.0, -2.0]), np.array([4.0, 3.0])
    Phi = rng.normal(size=(300 + d + 1, 1, d))
    R = np.concatenate([Phi[:300] @ theta_a, Phi[300:] @ theta_b])
    plain = rls_batch(rls_init(d), Phi[:300], R[:300]).state
    theta = rls_solve(plain).theta
    np.testing.assert_allclose(theta, theta_a, atol=1e-6)
    reset = rls_init(d, theta0=theta)
    assert reset.n == 0
    np.testing.assert_allclose(rls_solve(reset).P, 1e8 * np.eye(d))
    for k in range(300, 300 + d + 1):
        reset = rls_update(reset, Phi[k], R[k])
        plain = rls_update(plain, Phi[k], R[k])
    np.testing.assert_allclose(rls_solve(reset).theta, theta_b, atol=1e-6)
    # Without the reset, 300 samples of history hold the estimate near the old value.
    assert np.abs(rls_solve(plain).theta - theta_b).max() > 0.5


def test_update_is_functional() -> None:
    state = rls_init(2, theta0=[1.0, 2.0])
    J, h = state.J.copy(), state.h.copy()
    new = rls_update(state, np.ones((1, 2)), [3.0])
    np.testing.assert_array_equal(state.J, J)
    np.testing.assert_array_equal(state.h, h)
    assert new.n == 1 and state.n == 0


def test_an_empty_batch_returns_the_state() -> None:
    state = rls_init(3)
    result = rls_batch(state, np.zeros((0, 2, 3)), np.zeros((0, 2)))
    assert result.state is state and result.theta.shape == (0, 3)


# --- one-shot least squares --------------------------------------------------------------------


def test_least_squares_is_weighted_lstsq_and_skips_nan_rows() -> None:
    rng = np.random.default_rng(8)
    X, y = rng.normal(size=(80, 3)), rng.normal(size=80)
    w = rng.integers(0, 2, 80).astype(float)
    fit = least_squares(X, y, weights=w)
    ref = np.linalg.lstsq(X * w[:, None], y * w, rcond=None)[0]
    np.testing.assert_allclose(fit.theta, ref, rtol=1e-12)
    assert fit.cost == pytest.approx(float((w * (y - X @ ref) ** 2).sum()), rel=1e-12)
    np.testing.assert_allclose(fit.covariance, np.linalg.inv((X * w[:, None]).T @ X),
                               rtol=1e-9)
    y_nan = y.copy()
    y_nan[w == 0] = np.nan
    np.testing.assert_allclose(least_squares(X, y_nan).theta, ref, rtol=1e-10)
    # It is the same estimator as the recursive form with no prior.
    rec = rls_solve(rls_batch(rls_init(3, 1e-300), X[w == 1][:, None, :], y[w == 1]).state)
    np.testing.assert_allclose(rec.theta, ref, rtol=1e-8)


@pytest.mark.parametrize(("call", "match"), [
    (lambda: rls_batch(rls_init(2), np.zeros((3, 1, 3)), np.zeros((3, 1))),
     r"Phi: expected shape \(N, m, 2\), got \(3, 1, 3\)"),
    (lambda: rls_batch(rls_init(2), np.zeros((3, 2, 2)), np.zeros((3, 1))),
     r"R: expected shape \(3, 2\), got \(3, 1\)"),
    (lambda: rls_update(rls_init(2), np.zeros((1, 3)), [0.0]), r"phi: expected shape"),
    (lambda: least_squares(np.zeros(3), np.zeros(3)), r"X: expected shape \(N, d\), got \(3,\)"),
    (lambda: rls_init(0), r"d: expected an integer >= 1"),
    (lambda: rls_init(2, prior_precision=0.0), r"prior_precision"),
])
def test_bad_arguments_are_named(call, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        call()

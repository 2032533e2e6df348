"""Tests of canfdi.core.identify: recursive least-squares fault identification (eqs. 23-41)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.lib.stride_tricks import sliding_window_view

from canfdi.core.identify import (
    RecursiveLeastSquares,
    RlsBatchResult,
    RlsState,
    actuator_estimate,
    actuator_regressor,
    rls_batch,
    rls_init,
    rls_step,
    sensor_regressor,
)


def _sequential(
    state: RlsState, Phi: np.ndarray, R: np.ndarray, lam: float = 1.0, trace_max: float = 1e8
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, RlsState]:
    """rls_step over every sample: (theta (N, d), P (N, d, d), innovations (N, m), state)."""
    N, m, d = Phi.shape
    thetas = np.empty((N, d))
    Ps = np.empty((N, d, d))
    innovs = np.empty((N, m))
    for k in range(N):
        state, innovs[k] = rls_step(state, Phi[k], R[k], lam, trace_max)
        thetas[k] = state.theta
        Ps[k] = state.P
    return thetas, Ps, innovs, state


def _variances(Ps: np.ndarray) -> np.ndarray:
    return np.diagonal(Ps, axis1=1, axis2=2)


def _actuator_data(
    rng: np.random.Generator, N: int, eta: float, lam: float, s: int = 2
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """g, commanded-input windows Uc (N, s+1) and residuals through eqs. 26-27."""
    g = rng.normal(size=s + 1)
    u_c = rng.normal(size=N + s)
    Uc = sliding_window_view(u_c, s + 1)
    U = eta * Uc + lam  # eq. 27: U = eta Uc + lambda E
    r = (U - Uc) @ g  # eq. 26: r = v^T Hc (U - Uc), g = v^T Hc on actuator i's columns
    return g, Uc, r


# --- convergence on noise-free data -------------------------------------------------------


def test_actuator_fault_identified_by_step_and_batch() -> None:
    rng = np.random.default_rng(1)
    g, Uc, r = _actuator_data(rng, N=2000, eta=2.0, lam=10.0)
    Phi = actuator_regressor(g, Uc)
    assert Phi.shape == (2000, 1, 2)

    batch = rls_batch(rls_init(2), Phi, r)
    eta_b, lam_b = actuator_estimate(batch.state.theta)
    assert abs(eta_b - 2.0) < 1e-6
    assert abs(lam_b - 10.0) < 1e-6

    est = RecursiveLeastSquares(2)
    for k in range(Uc.shape[0]):
        phi = actuator_regressor(g, Uc[k])
        assert phi.shape == (1, 2)
        np.testing.assert_allclose(phi, Phi[k], rtol=1e-12, atol=1e-15)
        est.update(phi, r[k])
    eta_s, lam_s = actuator_estimate(est.theta)
    assert abs(eta_s - 2.0) < 1e-6
    assert abs(lam_s - 10.0) < 1e-6

    eta_traj, lam_traj = actuator_estimate(batch.theta)
    assert eta_traj.shape == lam_traj.shape == (2000,)
    assert eta_traj[-1] == pytest.approx(eta_b)


def test_sensor_faults_identified_by_step_and_batch() -> None:
    rng = np.random.default_rng(3)
    q, s, m, N = 4, 2, 4, 500
    V = rng.normal(size=(m, (s + 1) * q))
    for i in range(m):
        V[i, i::q] = 0.0  # row i is the residual insensitive to sensor i (eq. 37)
    f = np.array([10.0, 10.0, 0.1, 0.0])
    # eqs. 36-39: with v^T H0 = 0 and healthy actuators only the fault term is left.
    r = V @ np.tile(f, s + 1)
    phi = sensor_regressor(V, q, s)
    I_star = np.vstack([np.eye(q)] * (s + 1))
    np.testing.assert_allclose(phi, V @ I_star, rtol=1e-14)
    np.testing.assert_array_equal(np.diag(phi), 0.0)
    # phi is constant, so what is left after N samples is the prior's pull towards 0,
    # about |f| / (p0 N sigma_min(phi)^2): p0 = 1e6 and a not too ill-conditioned phi.
    assert np.linalg.svd(phi, compute_uv=False).min() ** 2 > 0.5

    Phi = np.broadcast_to(phi, (N, m, q))
    R = np.broadcast_to(r, (N, m))
    batch = rls_batch(rls_init(q, p0=1e6), Phi, R)
    np.testing.assert_allclose(batch.state.theta, f, rtol=0, atol=1e-6)

    state = rls_init(q, p0=1e6)
    for _ in range(N):
        state, _ = rls_step(state, phi, r)
    np.testing.assert_allclose(state.theta, f, rtol=0, atol=1e-6)


# --- batch form == sequential form ---------------------------------------------------------


@pytest.mark.parametrize("lam", [1.0, 0.98])
def test_batch_equals_sequential_and_chunking_does_not_matter(lam: float) -> None:
    rng = np.random.default_rng(3)
    N, m, d = 400, 2, 3
    Phi = rng.normal(size=(N, m, d))
    R = rng.normal(size=(N, m))
    start = rls_init(d, theta0=rng.normal(size=d))
    thetas, Ps, innovs, final = _sequential(start, Phi, R, lam)

    whole = rls_batch(start, Phi, R, lam)
    assert whole.fallback_samples == 0
    np.testing.assert_allclose(whole.theta, thetas, rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(whole.variances, _variances(Ps), rtol=1e-8, atol=1e-14)
    np.testing.assert_allclose(whole.innovations, innovs, rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(whole.state.P, final.P, rtol=1e-8, atol=1e-14)
    assert whole.state.n == final.n == N

    state = start
    parts: list[RlsBatchResult] = []
    for lo, hi in [(0, 7), (7, 150), (150, 151), (151, 151), (151, N)]:
        part = rls_batch(state, Phi[lo:hi], R[lo:hi], lam)
        parts.append(part)
        state = part.state
    np.testing.assert_allclose(np.concatenate([p.theta for p in parts]), thetas, rtol=1e-8)
    np.testing.assert_allclose(
        np.concatenate([p.innovations for p in parts]), innovs, rtol=1e-8, atol=1e-12
    )
    np.testing.assert_allclose(state.P, final.P, rtol=1e-8, atol=1e-14)
    assert state.n == N


@settings(max_examples=60, deadline=None)
@given(
    d=st.integers(1, 4),
    m=st.integers(1, 3),
    n=st.integers(1, 40),
    lam=st.floats(0.9, 1.0),
    p0=st.floats(1.0, 1e4),
    bound=st.sampled_from([None, 0.5, 1.5]),
    split=st.floats(0.0, 1.0),
    seed=st.integers(0, 2**32 - 1),
)
def test_property_batch_equals_sequential(
    d: int,
    m: int,
    n: int,
    lam: float,
    p0: float,
    bound: float | None,
    split: float,
    seed: int,
) -> None:
    rng = np.random.default_rng(seed)
    Phi = rng.normal(size=(n, m, d))
    R = rng.normal(size=(n, m))
    # A bound near trace(P0) makes the trace bound active and exercises the fallback.
    trace_max = 1e8 if bound is None else bound * d * p0
    start = rls_init(d, p0, rng.normal(size=d))
    thetas, Ps, innovs, final = _sequential(start, Phi, R, lam, trace_max)

    cut = int(split * n)
    first = rls_batch(start, Phi[:cut], R[:cut], lam, trace_max)
    second = rls_batch(first.state, Phi[cut:], R[cut:], lam, trace_max)
    scale = p0 * d
    np.testing.assert_allclose(
        np.concatenate([first.theta, second.theta]), thetas, rtol=1e-8, atol=1e-10
    )
    np.testing.assert_allclose(
        np.concatenate([first.variances, second.variances]),
        _variances(Ps),
        rtol=1e-8,
        atol=1e-12 * scale,
    )
    np.testing.assert_allclose(
        np.concatenate([first.innovations, second.innovations]), innovs, rtol=1e-8, atol=1e-10
    )
    np.testing.assert_allclose(second.state.P, final.P, rtol=1e-8, atol=1e-12 * scale)
    assert second.state.n == n


# --- forgetting, wind-up and the trace bound -----------------------------------------------


def _poorly_excited(rng: np.random.Generator, N: int) -> tuple[np.ndarray, np.ndarray]:
    """Bursts of rich excitation between long zero and long constant regressor stretches."""
    Phi = np.zeros((N, 1, 2))
    for start in range(0, N, 10_000):
        Phi[start : start + 300, 0] = rng.normal(size=(300, 2))
        # Constant: only one direction excited, the other winds up.
        Phi[start + 3000 : start + 6000, 0] = [1.0, 0.5]
    R = Phi @ np.array([1.0, 10.0]) + 0.01 * rng.normal(size=(N, 1))
    return Phi, R


def test_forgetting_with_poor_excitation_stays_bounded_and_batch_matches() -> None:
    rng = np.random.default_rng(4)
    N, lam, trace_max = 100_000, 0.95, 1e8
    Phi, R = _poorly_excited(rng, N)
    start = rls_init(2)

    batch = rls_batch(start, Phi, R, lam, trace_max)
    thetas, Ps, innovs, final = _sequential(start, Phi, R, lam, trace_max)

    # Without the bound P would reach lam^-10000 ~ 1e222 within one zero stretch.
    assert batch.fallback_samples > 0
    traces = np.trace(Ps, axis1=1, axis2=2)
    assert np.isclose(traces.max(), trace_max, rtol=1e-12)
    assert np.all(traces <= trace_max * (1 + 1e-12))
    assert np.all(np.isfinite(Ps)) and np.all(np.isfinite(thetas))
    asym = np.abs(Ps - np.swapaxes(Ps, 1, 2)).max(axis=(1, 2))
    assert np.all(asym <= 1e-12 * np.abs(Ps).max(axis=(1, 2)))
    eig = np.linalg.eigvalsh(Ps)
    assert np.all(eig >= -1e-12 * traces[:, None])

    assert np.all(np.isfinite(batch.theta)) and np.all(np.isfinite(batch.variances))
    np.testing.assert_array_equal(batch.state.P, batch.state.P.T)
    assert np.all(np.linalg.eigvalsh(batch.state.P) >= -1e-12 * trace_max)
    # While one direction is wound up to trace_max, P phi^T rounds by about
    # eps * trace_max * |phi| in every step of the sequential form itself, which moves the
    # unidentifiable part of theta by ~1e-8; hence rtol 1e-7 for theta here.
    np.testing.assert_allclose(batch.theta, thetas, rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(batch.variances, _variances(Ps), rtol=1e-9)
    np.testing.assert_allclose(batch.innovations, innovs, rtol=1e-7, atol=1e-8)
    np.testing.assert_allclose(batch.state.P, final.P, rtol=1e-9)
    # The bursts of excitation still identify the parameters despite the wind-up.
    np.testing.assert_allclose(thetas[-10_000 + 299], [1.0, 10.0], atol=0.05)


def test_trace_bound_scales_p_to_trace_max_without_excitation() -> None:
    state = rls_init(3, p0=10.0)
    zero = np.zeros((1, 3))
    for _ in range(400):
        state, _ = rls_step(state, zero, 0.0, forgetting=0.9, trace_max=1e5)
    assert np.trace(state.P) == pytest.approx(1e5, rel=1e-12)
    # Scaling keeps the shape of P (here the identity): no direction is favoured.
    np.testing.assert_allclose(state.P, np.eye(3) * 1e5 / 3, rtol=1e-12)


def test_forgetting_tracks_a_slow_change_that_lam_one_does_not() -> None:
    rng = np.random.default_rng(5)
    N = 3000
    Phi = rng.normal(size=(N, 1, 2))
    truth = np.where(np.arange(N)[:, None] < N // 2, [1.0, 2.0], [3.0, -1.0])
    R = np.einsum("kmi,ki->km", Phi, truth)
    forgetting = rls_batch(rls_init(2), Phi, R, 0.95)
    plain = rls_batch(rls_init(2), Phi, R, 1.0)
    np.testing.assert_allclose(forgetting.state.theta, [3.0, -1.0], atol=1e-6)
    assert np.abs(plain.state.theta - [3.0, -1.0]).max() > 0.1


# --- covariance reset ----------------------------------------------------------------------


def test_covariance_reset_follows_an_abrupt_change_within_d_plus_one_samples() -> None:
    rng = np.random.default_rng(6)
    d = 2
    theta_a, theta_b = np.array([1.0, -2.0]), np.array([4.0, 3.0])
    Phi = rng.normal(size=(300 + d + 1, 1, d))
    R = np.concatenate([Phi[:300] @ theta_a, Phi[300:] @ theta_b])

    reset = RecursiveLeastSquares(d, forgetting=1.0, p0=1e8, trace_max=1e10)
    plain = RecursiveLeastSquares(d, forgetting=1.0, p0=1e8, trace_max=1e10)
    reset.update_batch(Phi[:300], R[:300])
    plain.update_batch(Phi[:300], R[:300])
    np.testing.assert_allclose(reset.theta, theta_a, atol=1e-6)

    reset.reset(theta0=reset.theta)
    assert reset.n_samples == 0
    np.testing.assert_array_equal(reset.covariance, 1e8 * np.eye(d))
    for k in range(300, 300 + d + 1):
        reset.update(Phi[k], R[k])
        plain.update(Phi[k], R[k])
    np.testing.assert_allclose(reset.theta, theta_b, atol=1e-6)
    # Without the reset, 300 samples of history hold the estimate near the old value.
    assert np.abs(plain.theta - theta_b).max() > 0.5


# --- state, wrapper and edge cases ---------------------------------------------------------


def test_state_is_immutable_and_step_is_functional() -> None:
    state = rls_init(2, p0=5.0, theta0=[1.0, 2.0])
    assert state.n == 0 and state.d == 2
    np.testing.assert_array_equal(state.P, 5.0 * np.eye(2))
    with pytest.raises(ValueError, match="read-only"):
        state.theta[0] = 3.0
    new, innov = rls_step(state, [[1.0, 0.0]], 4.0)
    assert innov.shape == (1,)
    assert innov[0] == pytest.approx(3.0)
    np.testing.assert_array_equal(state.theta, [1.0, 2.0])
    assert new.n == 1
    assert new.theta[0] == pytest.approx(1.0 + 3.0 * 5.0 / 6.0)


def test_wrapper_matches_functions_and_exposes_variances() -> None:
    rng = np.random.default_rng(7)
    Phi = rng.normal(size=(50, 2, 3))
    R = rng.normal(size=(50, 2))
    est = RecursiveLeastSquares(3, forgetting=0.99, p0=100.0)
    innovs = np.array([est.update(Phi[k], R[k]) for k in range(50)])
    thetas, _, seq_innovs, final = _sequential(rls_init(3, 100.0), Phi, R, 0.99)
    np.testing.assert_array_equal(est.theta, final.theta)
    np.testing.assert_array_equal(est.covariance, final.P)
    np.testing.assert_array_equal(est.variances, np.diag(final.P))
    np.testing.assert_array_equal(innovs, seq_innovs)
    assert est.n_samples == 50 and est.state.n == 50

    other = RecursiveLeastSquares(3, forgetting=0.99, p0=100.0)
    result = other.update_batch(Phi, R)
    np.testing.assert_allclose(other.theta, est.theta, rtol=1e-8)
    np.testing.assert_allclose(result.theta, thetas, rtol=1e-8)

    est.reset()
    np.testing.assert_array_equal(est.theta, np.zeros(3))
    np.testing.assert_array_equal(est.covariance, 100.0 * np.eye(3))


def test_empty_batch_returns_the_state_unchanged() -> None:
    state = rls_init(2, theta0=[1.0, 2.0])
    result = rls_batch(state, np.empty((0, 1, 2)), np.empty((0, 1)))
    assert result.theta.shape == (0, 2)
    assert result.variances.shape == (0, 2)
    assert result.innovations.shape == (0, 1)
    np.testing.assert_array_equal(result.state.theta, state.theta)
    np.testing.assert_array_equal(result.state.P, state.P)
    assert result.state.n == 0


# --- boundary validation -------------------------------------------------------------------

_S2 = rls_init(2)


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda: rls_step(_S2, np.ones(2), 1.0), r"phi must have shape \(m, d\) = \(m, 2\)"),
        (lambda: rls_step(_S2, np.ones((1, 3)), 1.0), r"phi must have shape \(m, d\) = \(m, 2\)"),
        (lambda: rls_step(_S2, np.ones((2, 2)), np.ones(3)), r"r must have shape \(m,\) = \(2,\)"),
        (lambda: rls_step(_S2, np.ones((2, 2)), 1.0), r"r must have shape \(m,\) = \(2,\)"),
        (lambda: rls_batch(_S2, np.ones((5, 2)), np.ones(5)), r"Phi must have shape \(N, m, d\)"),
        (
            lambda: rls_batch(_S2, np.ones((5, 1, 2)), np.ones(4)),
            r"R must have shape \(N, m\) = \(5, 1\)",
        ),
        (lambda: rls_init(2, theta0=[1.0, 2.0, 3.0]), r"theta0 must have shape \(d,\) = \(2,\)"),
        (lambda: RlsState(np.zeros(2), np.eye(3)), r"P must have shape \(d, d\) = \(2, 2\)"),
        (lambda: RlsState(np.zeros((2, 1)), np.eye(2)), r"theta must have shape \(d,\)"),
        (lambda: actuator_regressor(np.ones((3, 1)), np.ones(3)), r"g must have shape \(s\+1,\)"),
        (
            lambda: actuator_regressor(np.ones(3), np.ones((5, 4))),
            r"Uc must have shape \(s\+1,\) or \(N, s\+1\) with s\+1 = 3",
        ),
        (lambda: actuator_estimate(np.ones(3)), r"theta must have shape \(2,\) or \(N, 2\)"),
        (
            lambda: sensor_regressor(np.ones((4, 10)), 4, 2),
            r"V must have shape \(m, \(s\+1\) q\) = \(m, 12\)",
        ),
        (
            lambda: RecursiveLeastSquares(2).update(np.ones((1, 3)), 0.0),
            r"phi must have shape \(m, d\) = \(m, 2\)",
        ),
    ],
)
def test_shape_errors_name_the_argument_and_expected_shape(call, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        call()


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda: rls_step(_S2, np.ones((1, 2)), 1.0, forgetting=0.0), "forgetting"),
        (lambda: rls_step(_S2, np.ones((1, 2)), 1.0, forgetting=1.5), "forgetting"),
        (lambda: rls_batch(_S2, np.ones((1, 1, 2)), np.ones(1), trace_max=0.0), "trace_max"),
        (lambda: rls_init(2, p0=-1.0), "p0"),
        (lambda: rls_init(0), "d must be"),
        (lambda: RecursiveLeastSquares(2, forgetting=2.0), "forgetting"),
        (lambda: sensor_regressor(np.ones((4, 12)), 0, 2), "q must be"),
        (lambda: rls_step(_S2, [[np.nan, 1.0]], 1.0), "finite"),
        (lambda: rls_batch(_S2, np.ones((2, 1, 2)), [1.0, np.inf]), "finite"),
    ],
)
def test_out_of_range_values_are_rejected(call, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        call()

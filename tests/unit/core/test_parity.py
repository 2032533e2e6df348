"""Parity design: decoupling to 1e-10, existence exactly when the rank condition says so."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from canfdi.core.model import StateSpace
from canfdi.core.parity import (
    actuator_columns,
    block_toeplitz,
    design_actuator,
    design_sensor,
    identity_stack,
    parity_matrices,
    sensor_rows,
    smallest_window,
)
from tests.dc_motor import dc_motor

TOL = 1e-10


def test_block_toeplitz_layout():
    D, M1, M2 = np.full((2, 1), 9.0), np.full((2, 1), 1.0), np.full((2, 1), 2.0)
    T = block_toeplitz(D, [M1, M2])
    assert T.shape == (6, 3)
    np.testing.assert_array_equal(T[:, 0], [9, 9, 1, 1, 2, 2])
    np.testing.assert_array_equal(T[:, 2], [0, 0, 0, 0, 9, 9])


def test_window_equation_holds_on_a_simulated_trajectory():
    """Y(k) = H0 x(k-s) + Hc U(k) + Hw W(k) (eq. 2) on random inputs and unknown inputs."""
    rng = np.random.default_rng(3)
    m, s = dc_motor(), 3
    pm = parity_matrices(m, s)
    x = rng.normal(size=3)
    x0 = x.copy()
    Y, U, W = [], [], []
    for _ in range(s + 1):
        u, w = rng.normal(size=1), rng.normal(size=2)
        Y.append(m.C @ x)
        U.append(u)
        W.append(w)
        x = m.A @ x + m.B @ u + m.F @ w
    lhs = np.concatenate(Y)
    rhs = pm.H0 @ x0 + pm.Hc @ np.concatenate(U) + pm.Hw @ np.concatenate(W)
    np.testing.assert_allclose(lhs, rhs, atol=1e-12)


def test_dc_motor_actuator_needs_s1():
    m = dc_motor()
    assert not design_actuator(m, 0, 0).exists
    assert "Theorem 3" in design_actuator(m, 0, 0).reason
    best = smallest_window(design_actuator, m, 0, 10)
    assert best.exists and best.s == 1
    assert best.decoupling_residual < TOL
    pm = parity_matrices(m, 1)
    assert np.linalg.norm(best.vector @ np.hstack([pm.H0, pm.Hw])) < TOL
    assert abs(np.linalg.norm(best.vector) - 1) < 1e-12
    assert np.linalg.norm(best.vector @ pm.Hc) > 1e-3


def test_dc_motor_sensor_vectors_are_blind_to_their_sensor():
    m, s = dc_motor(), 4
    pm = parity_matrices(m, s)
    for i in range(4):
        d = design_sensor(m, i, s)
        assert d.exists
        np.testing.assert_array_equal(d.vector[sensor_rows(4, s, i)], 0.0)
        assert np.linalg.norm(d.vector @ np.hstack([pm.H0, pm.Hw])) < TOL
        assert d.gain[i] == 0.0
        np.testing.assert_allclose(d.gain, d.vector @ identity_stack(4, s))
        # No sensor residual can respond to sensor 4 (omega_r) once w is decoupled.
        assert abs(d.gain[3]) < 1e-12


def test_index_errors():
    with pytest.raises(ValueError, match="actuator index"):
        design_actuator(dc_motor(), 1, 1)
    with pytest.raises(ValueError, match="sensor index"):
        design_sensor(dc_motor(), 4, 1)


@st.composite
def systems(draw):
    n = draw(st.integers(1, 4))
    p = draw(st.integers(1, 2))
    q = draw(st.integers(2, 5))
    r = draw(st.integers(0, 2))
    r1 = draw(st.integers(0, 1))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(n, n))
    A /= max(1.0, np.max(np.abs(np.linalg.eigvals(A))) * 1.1)
    # Sparse structure makes exact decoupling (and its absence) likely in small systems.
    mask = lambda shape: rng.random(shape) < 0.6  # noqa: E731
    B = rng.normal(size=(n, p)) * mask((n, p))
    C = rng.normal(size=(q, n)) * mask((q, n))
    F = rng.normal(size=(n, r)) * mask((n, r))
    G = rng.normal(size=(q, r1)) * mask((q, r1))
    return StateSpace(A=A, B=B, C=C, F=F, G=G, dt=0.1)


def _rank(M):
    return np.linalg.matrix_rank(M, tol=1e-9 * max(1.0, np.linalg.norm(M, 2)))


@settings(max_examples=150, deadline=None)
@given(model=systems(), s=st.integers(0, 3))
def test_actuator_vectors_decouple_and_exist_when_rank_allows(model, s):
    pm = parity_matrices(model, s)
    for i in range(model.p):
        cols = actuator_columns(model.p, s, i)
        Hstar = np.hstack([pm.H0, pm.Hw, pm.Hpsi, np.delete(pm.Hc, cols, axis=1)])
        M = pm.Hc[:, cols]
        d = design_actuator(model, i, s)
        # Theorems 1 and 3: v exists with v^T H* = 0 and v^T M != 0 iff M adds rank to H*.
        should_exist = _rank(np.hstack([Hstar, M])) > _rank(Hstar)
        assert d.exists == should_exist
        if d.exists:
            scale = max(np.linalg.norm(Hstar, 2), 1e-300)
            assert np.linalg.norm(d.vector @ Hstar) <= TOL * scale
            assert np.linalg.norm(d.vector @ M) > 0


@settings(max_examples=150, deadline=None)
@given(model=systems(), s=st.integers(0, 3))
def test_sensor_vectors_decouple_and_exist_when_rank_allows(model, s):
    pm = parity_matrices(model, s)
    Istar = identity_stack(model.q, s)
    for i in range(model.q):
        rows = sensor_rows(model.q, s, i)
        Hstar = np.delete(np.hstack([pm.H0, pm.Hw, pm.Hpsi]), rows, axis=0)
        M = np.delete(Istar, rows, axis=0)
        d = design_sensor(model, i, s)
        should_exist = _rank(np.hstack([Hstar, M])) > _rank(Hstar)
        assert d.exists == should_exist
        if d.exists:
            assert np.all(d.vector[rows] == 0.0)
            Hfull = np.hstack([pm.H0, pm.Hw, pm.Hpsi])
            assert np.linalg.norm(d.vector @ Hfull) <= TOL * max(np.linalg.norm(Hfull, 2), 1e-300)


@settings(max_examples=100, deadline=None)
@given(model=systems())
def test_sufficient_condition_of_theorem_1_gives_a_null_space(model):
    """Eq. 15 (with our block-diagonal Hpsi): more rows than columns -> a decoupling vector."""
    for s in range(4):
        cols = model.n + (s + 1) * (model.r + model.r1 + model.p - 1)
        if (s + 1) * model.q > cols:
            assert design_actuator(model, 0, s).null_dim > 0

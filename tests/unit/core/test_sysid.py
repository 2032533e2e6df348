"""Issue 26: a drive's model learned from data (canfdi.core.subspace, unknown_inputs, sysid,
validation). What is tested is what is basis-free: Markov parameters, the unknown inputs'
span, the residuals' structure; never the matrices themselves."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from canfdi.core.design import design_bank
from canfdi.core.model import StateSpace
from canfdi.core.parity import left_null_space, parity_matrices
from canfdi.core.subspace import (
    canonical_correlations,
    input_matrices,
    order_from_correlations,
    pbsid,
)
from canfdi.core.sysid import first_noise_guess, identify_state_space
from canfdi.core.unknown_inputs import Record, fit_measured_state, row_excess, visible_order
from canfdi.core.validation import minimality, nrmse, persistence, stability


def markov(A, B, C, count=12):
    out, Ak = [], np.eye(len(A))
    for _ in range(count):
        out.append(C @ Ak @ B)
        Ak = A @ Ak
    return np.array(out)


def po_moesp(U, Y, n, past, future):
    """(A, C) by PO-MOESP (Verhaegen 1994), the open-loop method canfdi does not use: the column
    space of L32 of the LQ factorisation of [Uf; Up, Yp; Yf] (windows as rows, means removed),
    A by shift invariance. Single input and output."""
    from numpy.lib.stride_tricks import sliding_window_view

    wu = sliding_window_view(U[:, 0], past + future)
    wy = sliding_window_view(Y[:, 0], past + future)
    H = np.hstack([wu[:, past:], wu[:, :past], wy[:, :past], wy[:, past:]])
    L = np.linalg.qr(H - H.mean(axis=0), mode="r").T
    L32 = L[future + 2 * past:, future:future + 2 * past]
    Us, S, _ = np.linalg.svd(L32)
    G = Us[:, :n] * np.sqrt(S[:n])
    return np.linalg.lstsq(G[:-1], G[1:], rcond=None)[0], G[:1]


def random_system(rng, n, p, q, radius=(0.3, 0.9)):
    """A random stable (A, B, C): A similar to a block diagonal of real and complex poles."""
    poles = rng.uniform(*radius, size=n) * np.where(rng.random(n) < 0.5, 1, -1)
    T = rng.normal(size=(n, n))
    A = T @ np.diag(poles) @ np.linalg.inv(T)
    return A, rng.normal(size=(n, p)), rng.normal(size=(q, n))


def run(A, B, C, U, noise, rng, F=None, w=None):
    n = len(A)
    x = np.zeros(n)
    Y = np.empty((len(U), C.shape[0]))
    for k in range(len(U)):
        Y[k] = C @ x
        x = A @ x + B @ U[k] + (F @ w[k] if F is not None else 0.0)
    return Y + noise * rng.standard_normal(Y.shape)


def test_a_random_stable_system_is_recovered_up_to_its_markov_parameters():
    """No unknown input: the subspace path (every horizon of the data, not one step); its
    Markov parameters are the system's to a few parts in a thousand."""
    rng = np.random.default_rng(1)
    A, B, C = random_system(rng, 3, 2, 3)
    U = rng.standard_normal((20000, 2))
    Y = run(A, B, C, U, 0.01, rng)
    found = identify_state_space([Record(U, Y)], 0.01)
    assert found.path == "subspace (PBSID)" and found.order == 3
    m = found.model
    truth, got = markov(A, B, C), markov(m.A, m.B, m.C)
    assert np.max(np.abs(got - truth)) < 5e-3 * np.max(np.abs(truth))
    assert found.noise_std == pytest.approx(np.full(3, 0.01), rel=0.05)


def test_a_system_with_more_states_than_outputs_goes_the_subspace_way():
    rng = np.random.default_rng(2)
    A, B, C = random_system(rng, 4, 1, 2)
    U = rng.standard_normal((30000, 1))
    Y = run(A, B, C, U, 0.005, rng)
    found = identify_state_space([Record(U, Y)], 0.01)
    assert found.path == "subspace (PBSID)" and found.order == 4
    m = found.model
    truth, got = markov(A, B, C), markov(m.A, m.B, m.C)
    assert np.max(np.abs(got - truth)) < 2e-2 * np.max(np.abs(truth))


def test_several_records_and_lost_samples_give_the_same_model():
    rng = np.random.default_rng(3)
    A, B, C = random_system(rng, 3, 1, 3)
    records = []
    for _ in range(3):
        U = rng.standard_normal((8000, 1))
        Y = run(A, B, C, U, 0.01, rng)
        Y[rng.random(len(Y)) < 0.03] = np.nan  # lost samples
        records.append(Record(U, Y))
    m = identify_state_space(records, 0.01).model
    truth, got = markov(A, B, C), markov(m.A, m.B, m.C)
    assert np.max(np.abs(got - truth)) < 1e-2 * np.max(np.abs(truth))


def test_pbsid_stays_consistent_in_closed_loop_where_moesp_does_not():
    """A controller closing the loop on the noisy output: PO-MOESP's Markov parameters are
    biased by the feedback, PBSID's are not (D = 0: the controller's gain is not the
    plant's)."""
    rng = np.random.default_rng(3)
    A = np.array([[0.9, 0.2], [0.0, 0.6]])
    B = np.array([[0.0], [1.0]])
    C = np.array([[1.0, 0.0]])
    K = np.array([0.8, 0.5])
    N = 20000
    e, r = rng.normal(0, 0.3, N), rng.normal(0, 1, N)
    x, U, Y = np.zeros(2), np.zeros((N, 1)), np.zeros((N, 1))
    for k in range(N):
        y = C @ x + e[k]
        u = -0.8 * y + r[k]
        Y[k], U[k] = y, u
        x = A @ x + B @ u + K * e[k]
    truth = markov(A, B, C, 8)
    m, _ = pbsid([(U, Y)], 2, 20, 10)
    Am, Cm = po_moesp(U, Y, 2, 10, 10)
    Bm, _, _, _ = input_matrices([(U, Y)], Am, Cm)
    err_pbsid = np.max(np.abs(markov(m.A, m.B, m.C, 8) - truth))
    err_moesp = np.max(np.abs(markov(Am, Bm, Cm, 8) - truth))
    assert err_pbsid < 0.02
    assert err_moesp > 5 * err_pbsid


def test_the_order_is_read_from_the_canonical_correlations():
    rng = np.random.default_rng(4)
    A, B, C = random_system(rng, 4, 1, 2)
    U = rng.standard_normal((20000, 1))
    Y = run(A, B, C, U, 0.01, rng)
    rho = canonical_correlations([(U, Y)], 10, 10)
    assert order_from_correlations(rho, 10)[0] == 4


def test_a_large_unmeasured_input_is_found_and_decoupled():
    """w steps and drifts through F = [0, 1, 0.5]: the identified F spans it (to a tenth of a
    degree), the rows it does not reach are found, and the identified model's decoupled
    parity residuals are white noise of the sensors' variance, the load gone."""
    rng = np.random.default_rng(5)
    A = np.array([[0.8, 0.1, 0.0], [0.05, 0.9, 0.1], [0.0, 0.2, 0.7]])
    B = np.array([[1.0], [0.5], [0.0]])
    C = np.eye(3)
    F_true = np.array([[0.0], [1.0], [0.5]])
    N = 30000
    steps = np.repeat(rng.uniform(-5, 5, N // 500 + 1), 500)[:N]
    w = (steps + 2 * np.sin(np.arange(N) / 900))[:, None]
    U = rng.standard_normal((N, 1))
    Y = run(A, B, C, U, 0.01, rng, F_true, w)
    R = np.full(3, 1e-4)
    rec = [Record(U, Y)]
    excess = row_excess(rec, R, (0, 1, 2))
    assert excess[0] == pytest.approx(1.0, abs=0.05) and excess[1] > 2 and excess[2] > 2
    fit = fit_measured_state(rec, R, 3, 1, f_rows=(1, 2))
    f = fit.F[:, 0] / np.linalg.norm(fit.F[:, 0])
    g = F_true[:, 0] / np.linalg.norm(F_true[:, 0])
    assert np.degrees(np.arccos(min(abs(f @ g), 1.0))) < 0.1
    assert fit.f_rows == (1, 2)
    model = StateSpace(A=fit.A, B=fit.B, C=fit.C, F=fit.F, dt=0.01)
    pm = parity_matrices(model, 2)
    V = left_null_space(np.hstack([pm.H0, pm.Hw])).T
    from numpy.lib.stride_tricks import sliding_window_view
    wy = sliding_window_view(Y, (3, 3))[:, 0].reshape(-1, 9)
    wu = sliding_window_view(U, (3, 1))[:, 0].reshape(-1, 3)
    res = wy @ V.T - wu @ (V @ pm.Hc).T
    # Each residual's variance against the sensors' noise through its vector: the load's
    # steps of +/-5 would be thousands of times that.
    predicted = np.sum(V**2, axis=1) * 1e-4
    assert np.var(res, axis=0) == pytest.approx(predicted, rel=0.1)


def test_without_the_unknown_input_the_load_stays_in_the_residuals():
    rng = np.random.default_rng(6)
    A = np.diag([0.8, 0.9, 0.7])
    B = np.array([[1.0], [0.5], [0.2]])
    F_true = np.array([[0.0], [1.0], [0.5]])
    N = 20000
    w = np.repeat(rng.uniform(-5, 5, N // 400 + 1), 400)[:N, None]
    U = rng.standard_normal((N, 1))
    Y = run(A, B, np.eye(3), U, 0.01, rng, F_true, w)
    with_w = identify_state_space([Record(U, Y)], 0.01, unknown_inputs=1)
    without = identify_state_space([Record(U, Y)], 0.01, unknown_inputs=0, order=3)
    # The noise each learns: with w decoupled, the sensors' own (the two that the load
    # reaches are seen together only, in the relation x2 - x1 / 2 that w does not reach:
    # 0.25 var1 + var2 is what the data give); without, the load inflates it where it acts.
    s = with_w.noise_std
    assert s[0] == pytest.approx(0.01, rel=0.05)
    assert 0.25 * s[1] ** 2 + s[2] ** 2 == pytest.approx(1.25e-4, rel=0.05)
    assert np.max(without.noise_std) > 3 * 0.01


def test_twin_sensors_and_an_unseen_one_keep_their_structure():
    """The DC motor of Chan et al. 2006 (nonlinear, closed loop): learned with two unknown inputs,
    its
    design is the true one: i_a and i_f + i_a have the same signature and omega_r is not
    detectable, because coefficients the data cannot tell from zero are zero."""
    from canfdi.firmware_sim.scenario import load_scenario
    from canfdi.firmware_sim.simulate import simulate

    sc = dataclasses.replace(load_scenario("dc_motor_nominal"), duration=120.0)
    ch = simulate(sc)
    found = identify_state_space([Record(ch.u_c, ch.z)], 0.01, unknown_inputs=2)
    names = ["i_f", "i_a", "i_f_plus_i_a", "omega_r"]
    from canfdi.core.design import DesignOptions

    design = design_bank(found.model, ["V"], names,
                         DesignOptions(actuator_window=8, sensor_window=4,
                                       measurement_std=found.noise_std))
    confused = design.confused_with()
    assert confused[1 + 1] == [1 + 2] and confused[1 + 2] == [1 + 1]
    detect = {name: det.detectable for (_, j, det), name in
              zip(design.detectability[1:], names, strict=True)}
    assert detect == {"i_f": True, "i_a": True, "i_f_plus_i_a": True, "omega_r": False}
    assert found.noise_std[0] == pytest.approx(0.01, rel=0.05)


def test_the_first_noise_guess_is_close_on_a_smooth_and_a_fast_signal():
    rng = np.random.default_rng(7)
    A, B, C = random_system(rng, 2, 1, 2, radius=(0.5, 0.95))
    U = np.repeat(rng.standard_normal((2500, 1)), 4, axis=0)
    Y = run(A, B, C, U, 0.02, rng)
    assert np.sqrt(first_noise_guess([Record(U, Y)])) == pytest.approx([0.02, 0.02], rel=0.2)


def test_the_visible_order_counts_what_the_outputs_show():
    rng = np.random.default_rng(8)
    A, B, C3 = random_system(rng, 3, 1, 3)
    C = np.vstack([C3, C3[0] + C3[1]])  # a fourth, redundant output
    U = rng.standard_normal((5000, 1))
    Y = run(A, B, C, U, 0.01, rng)
    n, ev = visible_order([Record(U, Y)], np.full(4, 1e-4))
    assert n == 3 and ev[-1] == pytest.approx(1.0, abs=0.2)


def test_nrmse_is_matlab_compare_fit():
    y = np.array([[1.0], [2.0], [3.0], [4.0]])
    assert nrmse(y, y)[0] == pytest.approx(100.0)
    assert nrmse(y, np.full_like(y, 2.5))[0] == pytest.approx(0.0)
    yhat = y + np.array([[0.5], [-0.5], [0.5], [-0.5]])
    assert nrmse(y, yhat)[0] == pytest.approx(100 * (1 - 1.0 / np.sqrt(5.0)))


def test_persistence_stability_and_minimality_checks():
    rng = np.random.default_rng(9)
    stds, ratio = persistence([np.ones((500, 1))], 5)
    assert stds[0] == 0.0 and ratio == 0.0
    _, ratio = persistence([rng.standard_normal((5000, 1))], 5)
    assert ratio > 0.5
    unstable = StateSpace(A=np.array([[1.05]]), B=[[1.0]], C=[[1.0]], dt=0.01)
    assert stability(unstable)[1] == [pytest.approx(1.05)]
    integrator = StateSpace(A=np.array([[1.0]]), B=[[1.0]], C=[[1.0]], dt=0.01)
    assert stability(integrator)[1] == []
    # A mode the unknown input reaches is the fit's choice (A + F L is the same data); one
    # it does not reach is the drive's.
    rotor = StateSpace(A=np.array([[0.3, 0.0], [0.2, 1.002]]), B=[[1.0], [0.0]],
                       C=np.eye(2), F=[[0.0], [1.0]], dt=0.01)
    assert stability(rotor)[1] == []
    hidden_f = StateSpace(A=np.array([[0.3, 0.2], [0.0, 1.002]]), B=[[1.0], [1.0]],
                          C=np.eye(2), F=[[1.0], [0.0]], dt=0.01)
    assert stability(hidden_f)[1] == [pytest.approx(1.002)]
    hidden = StateSpace(A=np.diag([0.5, 0.7]), B=[[1.0], [0.0]], C=[[1.0, 0.0]], dt=0.01)
    bad = minimality(hidden)
    assert bad["unobservable"] == [pytest.approx(0.7)]
    assert bad["uncontrollable"] == [pytest.approx(0.7)]


def test_output_error_paths_realised_keep_their_zeros():
    """The winding machine's five paths (the output-error paper), realised block by block: its
    Markov
    parameters exactly, and a zero wherever a path is absent (T1 does not see u3)."""
    from canfdi.core.sysid import realise_paths
    from canfdi.firmware_sim.plants.winding_machine import CHANNELS, WindingMachine

    plant = WindingMachine()
    paths = [(c.output, c.input, c.b, c.f, 1) for c in CHANNELS]
    model, names = realise_paths(paths, 3, 3, np.zeros(3), np.full(3, 1e-4), 0.01)
    got = markov(model.A, model.B, model.C)
    np.testing.assert_allclose(got, markov(plant.A, plant.B, plant.C), atol=1e-12)
    assert np.all(got[:, 0, 2] == 0.0) and np.all(got[:, 1, 0] == 0.0)
    assert "1" not in names
    _, with_offset = realise_paths(paths, 3, 3, np.array([0.0, 1e-3, 0.0]),
                                   np.full(3, 1e-4), 0.01)
    assert with_offset[-1] == "1"

"""canfdi.methods.uio.design and the UioDiagnoser: (CE)^+ decoupling, the diagonal actuator map, the
GRGS fault angles, and update_block against update (NaN values and gaps included)."""

from __future__ import annotations

import numpy as np
import pytest

from canfdi.config import ConfigError, load_config
from canfdi.core.records import Sample
from canfdi.methods.uio.config import build as build_uio_diagnoser
from canfdi.methods.uio.config import parse_uio_options
from canfdi.methods.uio.design import decouple, design_uio, fault_angles, flag_function
from tests.reproduction.test_seed004_vtol import CONFIG


@pytest.fixture(scope="module")
def config():
    return load_config(CONFIG)


@pytest.fixture(scope="module")
def model(config):
    return config.model.discretize()


@pytest.fixture(scope="module")
def design(config, model):
    return design_uio(model.A, model.B, model.C, model.F, model.dt,
                      measurement_std=np.full(4, 0.01), input_names=config.inputs,
                      output_names=config.outputs)


def _simulate(model, n, d=None, u=None, f_act=None, f_sens=None, seed=0):
    rng = np.random.default_rng(seed)
    u = rng.standard_normal((n, model.p)) if u is None else u
    x = np.zeros(model.n)
    Y = np.empty((n, model.q))
    for k in range(n):
        Y[k] = model.C @ x + (0.0 if f_sens is None else f_sens[k])
        ua = u[k] + (0.0 if f_act is None else f_act[k])
        x = model.A @ x + model.B @ ua + (0.0 if d is None else model.F[:, 0] * d[k])
    return np.hstack([Y, u])


def test_decoupling_projects_out_the_unknown_input(model):
    dec = decouple(model.A, model.B, model.C, model.F)
    assert np.abs(dec.Pi @ model.F).max() < 1e-14  # Pi E = 0
    assert np.abs(dec.H @ model.C @ model.F).max() < 1e-14  # H CE = 0
    with pytest.raises(ValueError, match="rank"):
        decouple(model.A, model.B, model.C[:2], np.array([[0.0], [0.0], [1.0], [0.0]]))


def test_residuals_do_not_see_the_unknown_input(model, design):
    """Any d(k), however large, leaves every front-end output at round-off."""
    rng = np.random.default_rng(1)
    n = 2000
    u = rng.standard_normal((n, model.p))
    clean = design.fir.batch(_simulate(model, n, u=u))
    dist = design.fir.batch(_simulate(model, n, u=u, d=50.0 * rng.standard_normal(n)))
    scale = np.abs(dist - clean).max(axis=0) / design.front_std
    assert scale.max() < 1e-8
    assert np.abs(clean).max() < 1e-9


def test_actuator_map_is_diagonal_and_exact(model, design):
    """FIDF output j is actuator j's fault (one sample late), whatever the other does."""
    n = 400
    f = np.zeros((n, 2))
    f[100:, 0] = 1.0
    f[200:, 1] = -0.5 * np.sin(np.arange(200) * 0.1)
    o = design.fir.batch(_simulate(model, n, f_act=f))  # row j: sample j + S
    S = design.fir.S
    fhat = o[:, :2]  # fhat(k-1) at sample k
    np.testing.assert_allclose(fhat[:-1], f[S - 1: n - 1][:-1], atol=1e-8)
    np.testing.assert_allclose(design.fault_dc[:2, :2], np.eye(2), atol=1e-9)


@pytest.mark.parametrize("i", range(4))
def test_sensor_fault_direction_is_column_i_of_hf0(model, design, i):
    """A bias on sensor i leaves GRGS residual i at zero and moves the others along column i
    of Hf(0): its fault angle is zero, the smallest."""
    n = 300
    f = np.zeros((n, 4))
    f[100:, i] = 1.0
    o = design.fir.batch(_simulate(model, n, f_sens=f))
    r = o[-1, 2:]
    assert abs(r[i]) < 1e-10
    theta = fault_angles(r, design.Hf0)
    assert np.argmin(theta) == i and theta[i] < 1e-6
    assert np.all(np.abs(np.delete(design.Hf0[:, i], i)) > 0) and design.Hf0[i, i] == 0
    assert flag_function(r) > 0
    # A negative bias: eq 23's angle is 180 degrees, the unsigned one zero.
    assert fault_angles(-r, design.Hf0)[i] == pytest.approx(np.pi)
    assert fault_angles(-r, design.Hf0, signed=False)[i] < 1e-6


def _records(config, seed=3):
    from canfdi.firmware_sim.scenario import parse_scenario
    from canfdi.firmware_sim.simulate import Simulator

    sc = parse_scenario({"name": "t", "plant": "vtol", "duration": 6.0, "seed": seed,
                         "faults": [{"target": "actuator", "index": 0, "onset": 2.0,
                                     "lambda": 1.0},
                                    {"target": "sensor", "index": 3, "onset": 4.0,
                                     "bias": 1.0}]})
    ch = Simulator(sc).advance(600)
    k, U, Z = ch.k.copy(), ch.u_c.copy(), ch.z.copy()
    rng = np.random.default_rng(seed)
    Z[rng.random(Z.shape) < 0.01] = np.nan  # lost values
    U[rng.random(U.shape) < 0.005] = np.nan
    keep = np.ones(len(k), bool)
    keep[[50, 51, 52, 400]] = False  # a short gap and a one-sample gap
    keep[120:140] = False  # a long gap: the window restarts
    return k[keep], (k[keep] * 10_000_000), U[keep], Z[keep]


def test_nan_makes_only_the_residuals_reading_it_missing(config):
    dg = build_uio_diagnoser(config)
    z, u = np.zeros(4), np.zeros(2)
    for k in range(10):
        dg.update(Sample(k=k, timestamp_ns=k, u=u, z=z))
    z_lost = z.copy()
    z_lost[0] = np.nan  # v_h lost: GRGS scheme 0 (blind to v_h) still computes
    dg.update(Sample(k=10, timestamp_ns=10, u=u, z=z_lost))
    r = dg.last_residuals
    assert not np.isnan(r[2]) and np.isnan(r[3:]).all() and np.isnan(r[:2]).all()


@pytest.mark.parametrize(("options", "field"), [
    ({"angle_threshold": 0}, "uio.angle_threshold"),
    ({"sensor_pole": "fast"}, "uio.sensor_pole"),
    ({"min_samples": 2.5}, "uio.min_samples"),
    ({"min_samples": 50, "max_samples": 10}, "uio.max_samples"),
    ({"poles": [1]}, "uio.poles"),
    ([1, 2], "uio"),
])
def test_bad_options_name_their_field(options, field):
    with pytest.raises(ConfigError) as info:
        parse_uio_options(options)
    assert info.value.field == field


def test_front_end_covariances_are_the_ones_of_its_moving_average(design):
    """front_cov (diagonal: front_std^2) against the front end's outputs on white sensor
    noise; long_run_cov (diagonal: long_run_std^2) against the moving average's own long-run
    form, its DC gain's H(1)^T S H(1) (an empirical long-run figure is too noisy here: the
    outputs difference the noise away, long-run variance 1/600 of the variance)."""
    np.testing.assert_allclose(np.diag(design.front_cov), design.front_std**2, rtol=1e-12)
    np.testing.assert_allclose(np.diag(design.long_run_cov), design.long_run_std**2,
                               rtol=1e-9, atol=1e-15)
    m, p, var = design.m, design.p, np.full(design.m, 0.01**2)
    dc = design.fir.coef[:, :m, :].sum(axis=0)  # (m, p+m)
    np.testing.assert_allclose(design.long_run_cov, dc.T @ np.diag(var) @ dc,
                               rtol=1e-9, atol=1e-12 * np.abs(design.long_run_cov).max())
    rng = np.random.default_rng(0)
    n = 400_000
    v = np.hstack([0.01 * rng.standard_normal((n, m)), np.zeros((n, p))])
    o = design.fir.batch(v)[design.fir.S:]
    scale = np.sqrt(np.outer(design.front_std, design.front_std))
    assert np.abs(np.cov(o.T) - design.front_cov).max() / scale.max() < 0.02


@pytest.mark.slow  # 40 seeds of the VTOL: about 20 s
def test_a_sensor_bias_estimate_varies_as_its_reported_std_says(config):
    """Over seeds, (estimate - truth) / reported std has about unit spread: the std counts
    the outputs' correlation and the random walk under the hinge's slope."""
    from canfdi.firmware_sim.scenario import parse_scenario
    from canfdi.firmware_sim.simulate import Simulator

    z = []
    for seed in range(40):
        sc = parse_scenario({"name": "t", "plant": "vtol", "duration": 6.0, "seed": seed,
                             "faults": [{"target": "sensor", "index": 1, "onset": 2.0,
                                         "bias": 0.2}]})
        ch = Simulator(sc).advance(600)
        dg = build_uio_diagnoser(config)
        events = dg.update_block(ch.k, ch.k * 10_000_000, ch.u_c, ch.z).events
        accepted = [e for e in events if e.kind == "accepted"]
        assert accepted and accepted[0].index == 1
        e = accepted[0]
        z.append((e.estimates["bias"] - 0.2) / np.sqrt(e.variances["bias"]))
    rms = float(np.sqrt(np.mean(np.square(z))))
    assert 0.65 < rms < 1.4, (rms, np.round(z, 2))

"""Each fault kind changes exactly the signal it should, from its onset (and until its end)."""

import numpy as np
import pytest

from canfdi.firmware_sim.faults import Fault, FaultInjector
from canfdi.firmware_sim.scenario import parse_scenario
from canfdi.firmware_sim.simulate import Simulator, simulate

DT, N, Q = 0.01, 400, 4
ONSET, END = 1.0, 3.0  # samples 100 and 300


def _run_sensors(fault: Fault, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(1)
    y = rng.normal(size=(N, Q)) + np.arange(Q)
    inj = FaultInjector([fault], DT, np.random.default_rng(seed))
    return y, np.array([inj.sensors(k, y[k]) for k in range(N)])


@pytest.mark.parametrize(
    ("fault", "expected"),
    [
        (Fault("sensor", 2, "bias", ONSET, END, bias=3.5), lambda y, k: y + 3.5),
        (Fault("sensor", 2, "drift", ONSET, END, rate=0.05),
         lambda y, k: y + 0.05 * (k - 100) * DT),
        (Fault("sensor", 2, "stuck", ONSET, END, value=7.0), lambda y, k: np.full_like(y, 7.0)),
        (Fault("sensor", 2, "scale", ONSET, END, scale=1.2), lambda y, k: 1.2 * y),
    ],
)
def test_sensor_fault_changes_only_its_channel_in_its_interval(fault, expected):
    y, z = _run_sensors(fault)
    k = np.arange(N)
    active = (k >= 100) & (k < 300)
    np.testing.assert_array_equal(np.delete(z, 2, axis=1), np.delete(y, 2, axis=1))
    np.testing.assert_array_equal(z[~active, 2], y[~active, 2])
    np.testing.assert_allclose(z[active, 2], expected(y[active, 2], k[active]), rtol=1e-12)
    assert not np.allclose(z[active, 2], y[active, 2])


def test_stuck_without_value_holds_the_onset_value():
    y, z = _run_sensors(Fault("sensor", 1, "stuck", ONSET, None))
    np.testing.assert_array_equal(z[100:, 1], y[100, 1])
    np.testing.assert_array_equal(z[:100, 1], y[:100, 1])


def test_noise_fault_adds_noise_of_the_given_std():
    y, z = _run_sensors(Fault("sensor", 0, "noise", 0.0, None, std=0.5))
    extra = z[:, 0] - y[:, 0]
    assert abs(extra.std() - 0.5) < 0.05
    np.testing.assert_array_equal(z[:, 1:], y[:, 1:])


def test_actuator_faults():
    u_c = np.linspace(10, 50, N)[:, None] * np.ones((1, 2))
    inj = FaultInjector([Fault("actuator", 1, "scale_bias", ONSET, END, eta=2.0, lam=10.0),
                         Fault("actuator", 0, "stuck", 2.0, None)], DT,
                        np.random.default_rng(0))
    u = np.array([inj.actuators(k, u_c[k]) for k in range(N)])
    k = np.arange(N)
    active = (k >= 100) & (k < 300)
    np.testing.assert_allclose(u[active, 1], 2.0 * u_c[active, 1] + 10.0)
    np.testing.assert_array_equal(u[~active, 1], u_c[~active, 1])
    np.testing.assert_array_equal(u[:200, 0], u_c[:200, 0])
    np.testing.assert_array_equal(u[200:, 0], u_c[200, 0])


def test_closed_loop_actuator_fault_from_its_onset():
    sc = parse_scenario({"plant": "dc_motor", "duration": 2.0, "seed": 3, "faults": [
        {"target": "actuator", "index": 0, "onset": 1.0, "eta": 2.0, "lambda": 10.0}]})
    r = simulate(sc)
    np.testing.assert_array_equal(r.u[:100], r.u_c[:100])
    np.testing.assert_allclose(r.u[100:], 2.0 * r.u_c[100:] + 10.0)
    clean = simulate(parse_scenario({"plant": "dc_motor", "duration": 2.0, "seed": 3}))
    np.testing.assert_array_equal(clean.z[:101], r.z[:101])  # u(100) first shows in y(101)
    assert not np.allclose(clean.z[102:], r.z[102:])


def test_chunked_simulation_equals_one_run():
    sc = parse_scenario({"plant": "dc_motor", "duration": 5.0, "seed": 7, "faults": [
        {"target": "sensor", "index": 0, "onset": 1.0, "kind": "noise", "std": 0.1}]})
    whole = simulate(sc)
    sim = Simulator(sc)
    parts = [sim.advance(n) for n in (1, 99, 250, 150)]
    for name in ("x", "y", "z", "u_c", "u", "ref"):
        np.testing.assert_array_equal(getattr(whole, name),
                                      np.concatenate([getattr(p, name) for p in parts]))
    assert whole.truth[0]["onset_sample"] == 100 and whole.truth[0]["name"] == "i_f"

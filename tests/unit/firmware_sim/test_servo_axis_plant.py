"""The emulated servo axis (issue 26): its linear part is its ZOH model `linear_model` exactly,
the setpoint echo, the load schedule, the friction, the master's velocity loop on both
reference programs, and its plant options (as keywords and as a scenario's plant_options)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from canfdi.firmware_sim.plants import PlantOptionError, make_plant
from canfdi.firmware_sim.plants.servo_axis import ServoAxis, ServoAxisParameters
from canfdi.firmware_sim.scenario import ScenarioError, parse_scenario
from canfdi.firmware_sim.simulate import simulate

TWO_PI = 2.0 * math.pi


def _scenario(duration: float, noise: float | None = None, **options):
    data = {"plant": "servo_axis", "duration": duration, "seed": 5,
            "bus": {"profile": "float_node"}, "plant_options": options}
    if noise is not None:
        data["noise"] = {"measurement": noise}
    return parse_scenario(data)


def _simulate_linear(model: dict, z0: np.ndarray, u: np.ndarray) -> np.ndarray:
    """(N + 1, 4) outputs of z(k+1) = A z(k) + B u(k), y = C z, from z0."""
    z = np.empty((len(u) + 1, 4))
    z[0] = z0
    for k, uk in enumerate(u):
        z[k + 1] = model["A"] @ z[k] + model["B"][:, 0] * uk
    return z @ model["C"].T


# --- the linear part and its discretisation ---------------------------------------------------


def test_without_friction_and_load_the_plant_is_its_linear_model():
    """Open loop from a state away from rest, random torques: every sampled output equals the
    linear model's, so its units (turns, 2 pi), the echo row and the ZOH agree with the ODE."""
    plant = ServoAxis(load=False)
    model = plant.linear_model()
    rng = np.random.default_rng(0)
    x = np.array([3.0, -2.0, 40.0, 7.0, 0.0])
    u = rng.uniform(-1.6, 1.6, 400)
    ys = [plant.output(x)]
    for uk in u:
        x = plant.step(x, np.array([uk]))
        ys.append(plant.output(x))
    # The drive acts on the setpoint as the bus carries it: a float32.
    want = _simulate_linear(model, ys[0], u.astype(np.float32).astype(float))
    np.testing.assert_allclose(np.array(ys), want, rtol=1e-9, atol=1e-9)
    # The run went somewhere: the position moved by turns, the current by amperes.
    assert np.ptp(want[:, 3]) > 1.0 and np.ptp(want[:, 1]) > 5.0


def test_closed_loop_scenario_without_load_matches_the_linear_model():
    """The same through the simulator, closed loop, noise-free: the commands it sent drive the
    linear model to the outputs the master measured."""
    run = simulate(_scenario(20.0, noise=0.0, reference="commissioning", load=False))
    model = make_plant("servo_axis", {"load": False}).linear_model()
    want = _simulate_linear(model, run.z[0], run.u[:-1, 0].astype(np.float32).astype(float))
    np.testing.assert_allclose(run.z, want, rtol=1e-9, atol=1e-9)


def test_linear_model_is_the_documented_drive():
    p = ServoAxisParameters()
    m = ServoAxis().linear_model()
    assert {k: v.shape for k, v in m.items()} == {"A": (4, 4), "B": (4, 1), "C": (4, 4),
                                                  "F": (4, 1)}
    np.testing.assert_array_equal(m["C"], np.eye(4))
    # The echo row: Iq_sp(k+1) = u(k) / Kt, no state.
    np.testing.assert_array_equal(m["A"][0], 0.0)
    assert m["B"][0, 0] == 1.0 / p.Kt == 12.5
    # The fast current pole, the mechanical pole (b / J) and the position's integrator.
    assert round(m["A"][1, 1], 4) == 0.2865
    np.testing.assert_allclose(sorted(np.linalg.eigvals(m["A"]).real),
                               [0.0, math.exp(-p.dt / p.tau_i), math.exp(-p.b / p.J * p.dt),
                                1.0], atol=1e-12)
    # The current loop's static gain is 1 / Kt; the load torque enters speed and position only,
    # against the motor's torque: F is the hold of -T_L through the inertia.
    assert m["B"][1, 0] / (1 - m["A"][1, 1]) == pytest.approx(1.0 / p.Kt, rel=1e-12)
    assert m["F"][0, 0] == m["F"][1, 0] == 0.0
    assert m["F"][2, 0] == pytest.approx(-(1 - math.exp(-p.b / p.J * p.dt)) / (p.b * TWO_PI),
                                         rel=1e-9)
    assert m["F"][3, 0] < 0


def test_the_rk4_integration_of_friction_and_load_converges():
    """Each period of a closed-loop run (load steps, zero crossings, standstill) stepped with
    the plant's 10 substeps and with 400 from the same state: the friction and load are
    integrated well below the sensors' noise, the current (no nonlinear term) exactly. The
    worst periods are at standstill, inside the tanh's band, where the friction is a damper
    faster than a substep (the module docstring)."""
    plant = ServoAxis(reference="operation", load_seed=4)
    fine = ServoAxis(reference="operation", load_seed=4, substeps=400)
    run = simulate(_scenario(40.0, load_seed=4))
    error = np.array([np.abs(plant.output(plant.step(x, u)) - fine.output(fine.step(x, u)))
                      for x, u in zip(run.x, run.u, strict=True)])
    noise = plant.noise_defaults().measurement
    assert error[:, 2].max() < noise[2] / 10 and error[:, 3].max() < noise[3] / 10
    assert np.percentile(error[:, 2], 99.9) < 2e-5  # turns/s, away from standstill
    assert error[:, 1].max() < 1e-12 and error[:, 0].max() == 0.0


# --- the setpoint echo --------------------------------------------------------------------------


def test_the_echo_is_the_last_torque_over_kt_exactly():
    run = simulate(_scenario(10.0, reference="commissioning", load_seed=2))
    kt = ServoAxisParameters().Kt
    # The received setpoint: a float32 on the bus, which the drive divides by Kt.
    np.testing.assert_array_equal(run.z[1:, 0],
                                  run.u[:-1, 0].astype(np.float32).astype(float) / kt)
    assert run.z[0, 0] == ServoAxis(load_seed=2).initial_state()[0]
    # The measured current has its noise, the echo none.
    assert np.std(run.z[1:, 1] - run.x[1:, 1]) > 0.03


# --- the load torque ----------------------------------------------------------------------------


def test_the_load_schedule_is_deterministic_in_its_seed():
    a, b, other = ServoAxis(load_seed=7), ServoAxis(load_seed=7), ServoAxis(load_seed=8)
    for x, y in zip(a.load_steps, b.load_steps, strict=True):
        np.testing.assert_array_equal(x, y)
    times, levels = a.load_steps
    assert not np.array_equal(times, other.load_steps[0])
    assert not np.array_equal(levels[:5], other.load_steps[1][:5])
    # Settled start, steps 4-12 s apart on the sample grid, levels within +/-0.3 Nm, 10,000 s.
    assert times[0] == 2.0
    gaps = np.diff(times)
    assert gaps.min() >= 4.0 - 0.005 and gaps.max() <= 12.0 + 0.005
    np.testing.assert_allclose(times * 100, np.round(times * 100), atol=1e-9)
    assert np.abs(levels).max() <= 0.3 and np.ptp(levels) > 0.4
    assert times[-1] < 10_000.0 < times[-1] + 12.0
    t = np.arange(0.0, 200.0, 0.37)
    torque = np.array([a.load_torque(s) for s in t])
    np.testing.assert_array_equal(torque, [b.load_torque(s) for s in t])
    assert np.abs(torque - [other.load_torque(s) for s in t]).max() > 0.1
    # The first 2 s carry the drift alone; beyond the horizon the last level holds.
    for s in (0.0, 0.5, 1.99):
        assert a.load_torque(s) == pytest.approx(0.1 * math.sin(TWO_PI * s / 90.0), abs=1e-15)
    for s in (20_000.0, 30_000.0):
        assert a.load_torque(s) - 0.1 * math.sin(TWO_PI * s / 90.0) == pytest.approx(levels[-1])
    assert ServoAxis(load=False).load_torque(50.0) == 0.0


def test_the_load_acts_on_the_shaft():
    """At a standstill held by nothing (no current), the shaft turns the way the load pushes."""
    plant = ServoAxis(load_seed=7)
    times, levels = plant.load_steps
    k = int(np.flatnonzero(np.abs(levels) > 0.2)[0])  # beyond the drift and T_c together
    t0 = times[k] + 0.5
    x = np.array([0.0, 0.0, 0.0, 0.0, t0])
    for _ in range(20):
        x = plant.step(x, np.array([0.0]))
    assert np.sign(x[2]) == -np.sign(plant.load_torque(t0)) and abs(x[2]) > 1.0


# --- friction -----------------------------------------------------------------------------------


@pytest.mark.parametrize("omega0", [12.0, -12.0, 0.8, -0.8])
def test_friction_opposes_motion(omega0):
    """Coasting with no current and no load (none before the first step at 2 s, no drift): the
    Coulomb friction takes up to T_c dt / J = 0.6 rad/s a period off the speed, on top of the
    viscous loss of the frictionless plant, and stops the shaft without turning it back."""
    p = ServoAxisParameters(load_drift=0.0)
    plant, bare = ServoAxis(params=p), ServoAxis(load=False)
    x0 = np.array([0.0, 0.0, omega0, 0.0, 0.0])
    one, free = plant.step(x0, np.array([0.0])), bare.step(x0, np.array([0.0]))
    loss = (free[2] - one[2]) * math.copysign(1.0, omega0)
    # A constant friction torque T_c through the viscous inertia, over one period.
    full = p.T_c * (1.0 - math.exp(-p.b / p.J * p.dt)) / p.b
    if abs(omega0) - p.T_c * p.dt / p.J > 20 * p.omega_s:  # tanh = 1 over the whole period
        assert loss == pytest.approx(full, rel=1e-9)
    else:
        assert 0.5 * full < loss < full
    x, speeds = x0, [omega0]
    for _ in range(100):
        x = plant.step(x, np.array([0.0]))
        speeds.append(x[2])
    speeds = np.array(speeds)
    assert (speeds * omega0 >= 0).all()  # never the other way
    assert (np.diff(np.abs(speeds)) <= 0).all()  # slows down, monotonically
    assert abs(speeds[-1]) < 1e-6  # and stops
    assert plant.friction(omega0) * omega0 > 0 and bare.friction(omega0) == p.b * omega0


# --- the master's velocity loop -----------------------------------------------------------------


def _velocity_error(run, plant: ServoAxis, hold: float = 1.5):
    """(error of the true velocity in turns/s (N,), mask of samples at least ``hold`` seconds
    after any change of the reference or step of the load)."""
    dt = plant.dt
    vel = run.x[:, 2] / TWO_PI
    ref = run.ref[:, 0]
    k = run.k
    changed = np.r_[True, np.abs(np.diff(ref)) > 1e-12]
    last_change = np.maximum.accumulate(np.where(changed, k, 0))
    steps = np.round(plant.load_steps[0] / dt).astype(int)
    last_step = np.r_[0, steps][np.searchsorted(steps, k, side="right")]
    settled = (k - np.maximum(last_change, last_step) >= hold / dt)
    return ref - vel, settled


def test_the_velocity_loop_tracks_the_operation_moves():
    run = simulate(_scenario(100.0, reference="operation", load_seed=2))
    plant = make_plant("servo_axis", {"reference": "operation", "load_seed": 2})
    error, settled = _velocity_error(run, plant)
    assert settled.mean() > 0.4
    assert abs(error[settled].mean()) < 0.01 and np.abs(error[settled]).mean() < 0.05
    assert abs(error[200:].mean()) < 0.05  # no bias overall, load steps and ramps included
    # It went through every speed of the program, both ways, and never hit the torque limit.
    assert set(np.round(run.ref[:, 0], 6)) >= {0.0, 5.0, 10.0, -5.0, 2.0}
    assert np.abs(run.u_c).max() < 1.6


def test_the_velocity_loop_tracks_the_commissioning_program():
    run = simulate(_scenario(60.0, reference="commissioning", load_seed=1))
    plant = make_plant("servo_axis", {"reference": "commissioning", "load_seed": 1})
    error, settled = _velocity_error(run, plant)
    steps = settled & (run.t < 30.0)
    assert steps.sum() > 300
    # The +/-0.02 Nm dither shakes the speed by a few hundredths of a turn/s.
    assert abs(error[steps].mean()) < 0.05 and np.abs(error[steps]).mean() < 0.2
    assert abs(error[200:].mean()) < 0.05
    # The chirp's slow start is followed (well inside the loop's bandwidth).
    chirp = (run.t >= 30.0) & (run.t < 35.0)
    vel = run.x[:, 2] / TWO_PI
    assert np.corrcoef(run.ref[chirp, 0], vel[chirp])[0, 1] > 0.9
    # The dither: the commands alternate by 0.04 Nm around the PI's torque.
    assert np.percentile(np.abs(np.diff(run.u_c[:, 0])), 50) > 0.015
    operation = simulate(_scenario(10.0, reference="operation", load_seed=1))
    assert np.percentile(np.abs(np.diff(operation.u_c[:, 0])), 50) < 0.01


def test_references_of_the_two_programs():
    op = ServoAxis().controller()
    ref = np.array([op.reference(k)[0] for k in range(0, 3200)])
    # 0 for 6 s, a 20 turns/s^2 ramp to 5 (0.25 s), 5 for 6 s, a ramp to 10, ...
    assert (ref[:600] == 0).all() and ref[625] == 5.0 and (ref[625:1225] == 5.0).all()
    assert np.abs(np.diff(ref)).max() == pytest.approx(0.2)  # 20 turns/s^2 x 10 ms
    com = ServoAxis(reference="commissioning").controller()
    ref = np.array([com.reference(k)[0] for k in range(0, 6000)])
    np.testing.assert_array_equal(ref[:200], 1.0)
    np.testing.assert_array_equal(ref[200:400], 7.0)
    assert set(ref[:3000]) == {1.0, 7.0}
    assert ref[3000:].min() >= 2.0 - 1e-12 and ref[3000:].max() <= 6.0 + 1e-12
    np.testing.assert_allclose(ref, [com.reference(k + 6000)[0] for k in range(6000)],
                               rtol=0, atol=1e-9)


# --- plant options ------------------------------------------------------------------------------


@pytest.mark.parametrize(("options", "option", "words"), [
    ({"reference": "tuning"}, "reference", "operation, commissioning"),
    ({"load_seed": -1}, "load_seed", "integer >= 0"),
    ({"load_seed": 1.5}, "load_seed", "integer >= 0"),
    ({"load_seed": True}, "load_seed", "integer >= 0"),
    ({"load": "yes"}, "load", "true or false"),
    ({"inertia": 1e-3}, "inertia", "load, load_seed, reference"),
])
def test_invalid_plant_options_name_the_option(options, option, words):
    with pytest.raises(PlantOptionError) as err:
        make_plant("servo_axis", options)
    assert err.value.option == option and words in str(err.value)
    assert isinstance(err.value, ValueError) and str(err.value).startswith(f"{option}: ")
    data = {"plant": "servo_axis", "duration": 1.0, "bus": {"profile": "float_node"},
            "plant_options": options}
    with pytest.raises(ScenarioError) as scenario_err:
        parse_scenario(data)
    assert scenario_err.value.field == f"plant_options.{option}"
    assert words in str(scenario_err.value)


def test_plants_without_options_refuse_any():
    with pytest.raises(PlantOptionError, match="load: not an option of plant dc_motor"):
        make_plant("dc_motor", {"load": False})
    with pytest.raises(ScenarioError) as err:
        parse_scenario({"plant": "vtol", "duration": 1.0, "plant_options": {"s_dA": 0.0}})
    assert err.value.field == "plant_options.s_dA"
    with pytest.raises(ScenarioError) as err:
        parse_scenario({"plant": "servo_axis", "duration": 1.0, "bus": {"profile": "float_node"},
                        "plant_options": ["commissioning"]})
    assert err.value.field == "plant_options"


def test_scenario_plant_options_reach_every_plant_it_builds():
    sc = _scenario(2.0, reference="commissioning", load_seed=9, load=False)
    assert sc.plant_options == {"reference": "commissioning", "load_seed": 9, "load": False}
    plant = sc.make_plant()
    assert (plant.reference, plant.load_seed, plant.load) == ("commissioning", 9, False)
    assert sc.drive_scenario(0).make_plant().reference == "commissioning"
    # The default program without options, and no options for a plant that takes none.
    assert _scenario(2.0).make_plant().reference == "operation"
    assert parse_scenario({"plant": "dc_motor", "duration": 1.0}).plant_options == {}
    # The servo axis speaks the float_node bus only: canfdi's own has no DBC for it.
    with pytest.raises(ScenarioError, match="profiles for servo_axis: float_node") as err:
        parse_scenario({"plant": "servo_axis", "duration": 1.0})
    assert err.value.field == "bus.profile"

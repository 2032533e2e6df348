"""Grey-box templates (issue 26): a template fitted to a healthy log recovers the datasheet
parameters within its confidence, and gives the monitor's linear model with its unknown-input
directions.

The DC motor's log comes from the emulator (Chan et al. 2006's motor, no load torque; the template
does
not know that). The servo axis's log comes from a small simulation written here (the physics of
the template plus Coulomb friction and a stepping, drifting load torque, the velocity loop
closed by a master on the noisy measured velocity), so that the test does not depend on an
emulated servo plant.
"""

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml

from canfdi.core.greybox import FD_STEP, TEMPLATES, fit_template, get_template
from canfdi.core.model import StateSpace, zoh
from canfdi.firmware_sim.plants.dc_motor import DcMotor, DcMotorParameters
from canfdi.firmware_sim.scenario import load_scenario
from canfdi.firmware_sim.simulate import simulate

CONFIG = Path(__file__).resolve().parents[3] / "deploy" / "config" / "dc_motor.yaml"
DC_ROLES = {"field_current": 0, "armature_current": 1, "speed": 3}  # column 2: i_f + i_a
SERVO_ROLES = {"current_setpoint": 0, "current": 1, "velocity": 2, "position": 3}
TWO_PI = 2 * math.pi


def _dc_truth() -> dict[str, float]:
    p = DcMotorParameters()
    return {"R_f": p.Rf, "L_f": p.Lf, "R_a": p.Ra, "L_a": p.La, "M": p.M, "J": p.J, "D": p.D}


def monitor_model(template, theta: dict[str, float], dt: float) -> StateSpace:
    """The template's monitor model over all its roles, default settings, at ``theta`` (names
    left out: their defaults)."""
    template = get_template(template) if isinstance(template, str) else template
    th = np.array([theta.get(p.name, p.default) for p in template.parameters])
    A, B, C, F = template.linear_model(th, dt, template.outputs,
                                       {s.name: s.default for s in template.settings})
    return StateSpace(A=A, B=B, C=C, F=F, dt=dt)


def model_std(fit):
    """Standard deviations of the fitted model's A, B, F: the delta method over the fit's
    log-parameter covariance, central differences in the log parameters."""
    theta = np.array([p.value for p in fit.parameters])

    def flat(th):
        A, B, _C, F = fit.template.linear_model(th, fit.model.dt, fit.states, fit.settings)
        return np.concatenate([A.ravel(), B.ravel(), F.ravel()])

    idx = np.flatnonzero(np.diag(fit.log_covariance) > 0)
    D = np.empty((flat(theta).size, idx.size))
    for col, j in enumerate(idx):
        up, down = theta.copy(), theta.copy()
        up[j] *= math.exp(FD_STEP)
        down[j] *= math.exp(-FD_STEP)
        D[:, col] = (flat(up) - flat(down)) / (2 * FD_STEP)
    std = np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", D, fit.log_covariance[np.ix_(idx, idx)],
                                       D), 0.0))
    n, p, r = fit.model.n, fit.model.p, fit.model.r
    return (std[: n * n].reshape(n, n), std[n * n: n * n + n * p].reshape(n, p),
            std[n * n + n * p:].reshape(n, r))


def _off_start(template, factor=1.5):
    """Every parameter at its default times ``factor``: not the truth."""
    return {p.name: p.default * factor for p in template.parameters}


# ----------------------------------------------------------------------------- the DC motor


@pytest.fixture(scope="module")
def dc_log():
    return simulate(replace(load_scenario("dc_motor_nominal"), duration=120.0))


@pytest.fixture(scope="module")
def dc_fit(dc_log):
    return fit_template("dc_motor", dc_log.u, dc_log.y, DC_ROLES, 0.01,
                        start=_off_start(TEMPLATES["dc_motor"]))


def test_dc_motor_template_is_the_emulated_plant_without_load():
    """The template at the plant's parameters predicts each step of DcMotor.step: held at the
    truth, a fit's one-step prediction errors on the plant's noise-free states vanish."""
    plant, template = DcMotor(), get_template("dc_motor")
    rng = np.random.default_rng(3)
    U = rng.uniform(40.0, 140.0, (200, 1))
    X = np.empty((len(U), 3))
    x = plant.initial_state()
    for k in range(len(U)):
        X[k] = x
        x = plant.step(x, U[k])
    fit = fit_template(template, U, X, dict(zip(template.outputs, range(3), strict=True)), 0.01,
                       start=_dc_truth(), fixed=list(template.parameter_names))
    assert fit.substeps == 10 and fit.theta == _dc_truth()
    errors = fit.residuals[1:]
    assert np.isfinite(errors).all()
    assert np.allclose(errors, 0.0, atol=1e-12 * np.abs(X).max())


def test_dc_motor_monitor_model_at_the_truth_is_eq_43():
    model = monitor_model("dc_motor", _dc_truth(), 0.01)
    assert np.allclose(model.A, np.diag([0.8825, 0.6839, 0.9948]), atol=1e-12)
    assert np.allclose(model.B.ravel(), [0.002235, 0.0823, 0.0], atol=1e-12)
    assert model.F[0].tolist() == [0.0, 0.0] and model.F[1, 1] == 0 and model.F[2, 0] == 0


def test_dc_motor_recovers_the_datasheet_parameters_within_their_confidence(dc_fit):
    """Start 1.5x off; every parameter comes back within 3 of its reported standard
    deviations. What the 120 s log determines: the electrical parameters and M to better than
    0.7 %, J to about 0.5 %, D only to about 8 % (the speed loop's +/-10 rad/s steps are what
    tells the viscous torque D omega from a slowly varying load, which the template must
    allow and which the differenced speed row cancels, D omega's slow part with it)."""
    truth = _dc_truth()
    assert dc_fit.undetermined == ()
    for p in dc_fit.parameters:
        assert p.status == "estimated"
        assert abs(p.start / truth[p.name] - 1) > 0.4  # the fit had somewhere to go
        assert abs(p.value - truth[p.name]) < 3 * p.std, (p.name, p.value, truth[p.name], p.std)
        assert p.low < p.value < p.high
        assert p.rel_std < (0.2 if p.name == "D" else 0.01), (p.name, p.rel_std)


def test_dc_motor_monitor_model_matches_the_shipped_config(dc_fit):
    """A and B agree with deploy/config/dc_motor.yaml (b2 = 0.0823, not eq. 43's printed
    0.0832) within 4 of their standard deviations from the fit; F has the config's
    directions (e2, e3), scaled by the zero-order hold; C is the config's, the i_f + i_a
    sensor's row found by the fit."""
    config = StateSpace.from_dict(yaml.safe_load(CONFIG.read_text())["model"])
    model = dc_fit.model
    A_std, B_std, F_std = model_std(dc_fit)
    assert model.dt == config.dt == 0.01 and not model.continuous
    assert np.all(model.A[~np.eye(3, dtype=bool)] == 0)
    assert np.all(np.abs(model.A - config.A) <= 4 * A_std + 1e-12)
    assert np.all(np.abs(model.B - config.B) <= 4 * B_std + 1e-12)
    assert abs(model.B[1, 0] - 0.0832) > 20 * B_std[1, 0]  # the misprint is told apart
    scale = np.linalg.lstsq(config.F, model.F, rcond=None)[0]
    assert np.allclose(model.F, config.F @ scale, atol=1e-15)
    assert np.all(np.diag(scale) > 0) and scale[0, 1] == scale[1, 0] == 0
    truth = monitor_model("dc_motor", _dc_truth(), 0.01)
    assert np.all(np.abs(model.F - truth.F) <= 4 * F_std + 1e-15)
    assert dc_fit.unknown_inputs == ("phi1", "phi2")
    (row,) = dc_fit.static_rows
    assert row.column == 2 and np.all(np.abs(row.row - [1.0, 1.0, 0.0]) < 4 * row.std)
    assert np.allclose(model.C, config.C, atol=0.01)
    assert abs(row.residual_std - math.sqrt(3) * 0.01) < 0.002  # three sensors' noise


def test_dc_motor_residuals_and_row_std(dc_fit, dc_log):
    """The one-step errors are the sensor noise seen through one period: 0.01 x sqrt(1 + a^2)
    on the field current, more where the row is differenced (the speed)."""
    assert dc_fit.residuals.shape == (len(dc_log.y), 3)
    assert np.all(np.isnan(dc_fit.residuals[0]))
    std = np.nanstd(dc_fit.residuals[1:], axis=0)
    assert abs(std[0] - 0.01 * math.sqrt(1 + 0.8825**2)) < 0.001
    assert dc_fit.row_std[2] > dc_fit.row_std[0]
    assert dc_fit.samples == len(dc_log.y) - 1 and dc_fit.rejected < 10


def test_fixing_a_parameter_holds_it(dc_log):
    template = get_template("dc_motor")
    start = _off_start(template, 1.0) | {"M": 0.21}
    fit = fit_template(template, dc_log.u[:3000], dc_log.y[:3000], DC_ROLES, 0.01, start=start,
                       fixed=["M"])
    (m,) = [p for p in fit.parameters if p.name == "M"]
    assert m.value == 0.21 and m.status == "fixed" and m.std == 0.0
    i = template.parameter_names.index("M")
    assert np.all(fit.log_covariance[i] == 0) and np.all(fit.log_covariance[:, i] == 0)
    assert all(p.status == "estimated" for p in fit.parameters if p.name != "M")
    table = fit.parameters_table()
    assert [row["name"] for row in table] == list(template.parameter_names)
    assert table[i]["status"] == "fixed" and table[i]["value"] == 0.21


def test_lost_samples_are_left_out(dc_log):
    """NaN rows (lost samples) take their one-step pairs with them; the fit still recovers the
    parameters."""
    N = 6000
    Y = dc_log.y[:N].copy()
    lost = np.random.default_rng(7).random(N) < 0.05
    Y[lost] = np.nan
    Y[100:160, 0] = np.nan  # a signal lost for a while, the others not
    fit = fit_template("dc_motor", dc_log.u[:N], Y, DC_ROLES, 0.01)
    complete = ~np.isnan(Y[:, [0, 1, 3]]).any(axis=1)
    some = ~np.isnan(Y[:, [0, 1, 3]]).all(axis=1)
    assert fit.samples == int((complete[:-1] & some[1:]).sum())  # a pair with x(k) and a row
    truth = _dc_truth()
    for p in fit.parameters:
        if p.status == "estimated":
            assert abs(p.value - truth[p.name]) < 3 * p.std, (p.name, p.value, p.std)
    assert {p.name for p in fit.parameters if p.status == "estimated"} >= {
        "R_f", "L_f", "R_a", "L_a", "M", "J"}


def test_given_sensor_noise_only_weights_the_rows(dc_log):
    """noise_std sets the rows' weights instead of the residuals' robust spread; on sensors
    that are what they say, the estimate hardly moves (the weights change its efficiency, not
    what it estimates)."""
    args = ("dc_motor", dc_log.u[:3000], dc_log.y[:3000], DC_ROLES, 0.01)
    own, given = fit_template(*args), fit_template(*args, noise_std=np.full(4, 0.01))
    for a, b in zip(own.parameters, given.parameters, strict=True):
        assert abs(a.value - b.value) < 0.5 * a.std and b.std == pytest.approx(a.std, rel=0.2)
    with pytest.raises(ValueError, match=r"noise_std: expected shape \(4,\), got \(3,\)"):
        fit_template(*args, noise_std=np.full(3, 0.01))
    with pytest.raises(ValueError, match="noise_std: must be non-negative"):
        fit_template(*args, noise_std=np.array([0.01, -0.01, 0.01, 0.01]))


def test_a_fit_is_deterministic(dc_log):
    args = ("dc_motor", dc_log.u[:2000], dc_log.y[:2000], DC_ROLES, 0.01)
    a, b = fit_template(*args), fit_template(*args)
    assert [p.value for p in a.parameters] == [p.value for p in b.parameters]
    assert [p.std for p in a.parameters] == [p.std for p in b.parameters]
    assert np.array_equal(a.log_covariance, b.log_covariance)
    assert np.array_equal(a.residuals, b.residuals, equal_nan=True)
    assert np.array_equal(a.model.A, b.model.A) and np.array_equal(a.model.C, b.model.C)
    assert a.cost == b.cost and a.iterations == b.iterations


# ----------------------------------------------------------------------------- the servo axis

KT, TAU, J, B = 0.08, 0.008, 5e-4, 1e-4
COULOMB, OMEGA_S = 0.03, 0.05


def _servo_log(seconds=100.0, dt=0.01, seed=0):
    """A commissioning log of a servo axis in torque control: U (N, 1) torque commands (N m),
    Y (N, 4) = [Iq_sp (float32 echo), Iq (A), velocity (turns/s), position (turns)].

    The plant: the template's physics plus Coulomb friction 0.03 tanh(omega / 0.05) N m and a
    load torque that steps by +/-0.3 N m every 4 to 6 s (levels -0.3, 0, 0.3) and drifts by
    0.05 sin(2 pi t / 60 s); RK4, 10 substeps. The master: a PI velocity loop on the measured
    velocity (noise 0.01 turns/s), its reference 12 +/- 3 turns/s switching every 2 s, plus a
    +/-0.1 N m PRBS dither on the command (a commissioning log; without it the loop's feedback
    of the velocity noise into the command biases J by ~1.7 sigma, see the module notes). The
    speed stays positive, where the Coulomb friction is a constant torque that the unknown
    input absorbs.
    """
    rng = np.random.default_rng(seed)
    N = round(seconds / dt)
    t = np.arange(N) * dt
    load = np.zeros(N)
    level, k = 0.0, round(2.0 / dt)
    while k < N:
        level = float(np.clip(level + rng.choice([-0.3, 0.3]), -0.3, 0.3))
        load[k:] = level
        k += round(rng.uniform(4.0, 6.0) / dt)
    load += 0.05 * np.sin(TWO_PI * t / 60.0)
    ref = 12.0 + np.where((t // 2.0) % 2 == 0, 3.0, -3.0)
    noise = rng.standard_normal((N, 3)) * (0.05, 0.01, 1e-4)
    dither = 0.1 * np.sign(rng.standard_normal(N))
    kp, ki, limit = 0.05, 0.5, 1.6

    def f(iq, w, T, TL):
        return ((T / KT - iq) / TAU,
                (KT * iq - B * w - COULOMB * math.tanh(w / OMEGA_S) - TL) / J,
                w)

    iq = w = th = 0.0
    integral = T_prev = 0.0
    h = dt / 10
    U, Y = np.empty((N, 1)), np.empty((N, 4))
    for k in range(N):
        Y[k] = (np.float32(T_prev / KT), iq + noise[k, 0], w / TWO_PI + noise[k, 1],
                th / TWO_PI + noise[k, 2])
        e = ref[k] - Y[k, 2]
        integral += e * dt
        T = kp * e + ki * integral
        if abs(T) > limit:
            integral -= e * dt
            T = math.copysign(limit, T)
        T += dither[k]
        U[k, 0] = T
        for _ in range(10):
            a1 = f(iq, w, T, load[k])
            a2 = f(iq + h / 2 * a1[0], w + h / 2 * a1[1], T, load[k])
            a3 = f(iq + h / 2 * a2[0], w + h / 2 * a2[1], T, load[k])
            a4 = f(iq + h * a3[0], w + h * a3[1], T, load[k])
            iq += h / 6 * (a1[0] + 2 * a2[0] + 2 * a3[0] + a4[0])
            w += h / 6 * (a1[1] + 2 * a2[1] + 2 * a3[1] + a4[1])
            th += h / 6 * (a1[2] + 2 * a2[2] + 2 * a3[2] + a4[2])
        T_prev = T
    return U, Y


@pytest.fixture(scope="module")
def servo_log():
    return _servo_log()


@pytest.fixture(scope="module")
def servo_fit(servo_log):
    U, Y = servo_log
    return fit_template("servo_axis", U, Y, SERVO_ROLES, 0.01,
                        start=_off_start(TEMPLATES["servo_axis"]))


def test_servo_log_keeps_the_speed_positive(servo_log):
    U, Y = servo_log
    assert Y[50:, 2].min() > 1.0 and np.ptp(U) > 1.0


def test_servo_axis_recovers_kt_tau_j_within_their_confidence(servo_fit):
    """Kt, tau_i and J come back within 3 standard deviations under an unknown load that
    steps and drifts, Coulomb friction and a closed loop; b is recovered or said to be not
    determined. Kt comes from the setpoint echo, whose float32 rounding is not random noise:
    below the rounding's resolution (6e-8) 3 sigma is not the measure."""
    truth = {"Kt": KT, "tau_i": TAU, "J": J, "b": B}
    est = {p.name: p for p in servo_fit.parameters}
    for name in ("Kt", "tau_i", "J"):
        p = est[name]
        assert p.status == "estimated" and p.rel_std < 0.01, (name, p.rel_std)
        error = abs(p.value - truth[name])
        assert error < 3 * p.std or (name == "Kt" and error < 6e-8 * KT), (name, p.value, p.std)
    b = est["b"]
    assert (b.status == "not determined" and b.value == b.start) or (
        b.status == "estimated" and abs(b.value - B) < 3 * b.std)
    assert servo_fit.rejected > 0  # the load steps' spikes in the differenced rows


def test_servo_echo_row_is_at_float32_rounding(servo_fit, servo_log):
    """The drive's setpoint echo Iq_sp(k+1) = u(k) / Kt, sent as float32: with the fitted Kt
    its one-step error is the float32 rounding and nothing else."""
    _, Y = servo_log
    echo = servo_fit.residuals[1:, 0]
    assert np.all(np.abs(echo) <= 1.5 * 2.0**-24 * np.abs(Y[1:, 0]) + 1e-300)
    assert servo_fit.row_std[0] < 1e-6 * np.sqrt(np.mean(Y[:, 0] ** 2))


def test_servo_monitor_model_f_is_the_zoh_torque_column(servo_fit):
    """State [Iq_sp, Iq, velocity, position] in the drive's units (turns), C = I; F is the
    zero-order hold of a load torque into velocity and position, zero in the current rows;
    the echo row is Iq_sp(k+1) = u(k) / Kt."""
    theta = servo_fit.theta
    Kt, tau, Jf, b = (theta[k] for k in ("Kt", "tau_i", "J", "b"))
    Ac = np.array([[-1 / tau, 0, 0], [Kt / Jf, -b / Jf, 0], [0, 1, 0]])
    Bc = np.array([[1 / (Kt * tau)], [0], [0]])
    Fc = np.array([[0], [-1 / Jf], [0]])
    Ad, BFd = zoh(Ac, np.hstack([Bc, Fc]), 0.01)
    Bd, Fd = BFd[:, :1], BFd[:, 1:]
    model = servo_fit.model
    assert servo_fit.states == ("current_setpoint", "current", "velocity", "position")
    assert servo_fit.unknown_inputs == ("load_torque",)
    assert np.array_equal(model.C, np.eye(4))
    assert model.F[0, 0] == 0 and model.F[1, 0] == 0
    assert np.allclose(model.F[2:, 0], Fd[1:, 0] / TWO_PI, rtol=1e-12, atol=0)
    assert np.all(model.A[0] == 0) and model.B[0, 0] == pytest.approx(1 / Kt, rel=1e-15)
    assert np.allclose(model.B[1:, 0], Bd[:, 0] / [1, TWO_PI, TWO_PI], rtol=1e-12, atol=0)
    assert np.allclose(model.A[1:, 1:], [[Ad[0, 0], 0, 0], [Ad[1, 0] / TWO_PI, Ad[1, 1], 0],
                                         [Ad[2, 0] / TWO_PI, Ad[2, 1], 1]], rtol=1e-12, atol=1e-15)
    # and at the truth, within the fit's uncertainty
    truth = monitor_model("servo_axis", {"Kt": KT, "tau_i": TAU, "J": J, "b": B}, 0.01)
    A_std, B_std, F_std = model_std(servo_fit)
    assert np.all(np.abs(model.F - truth.F) <= 4 * F_std + 1e-15)
    assert np.all(np.abs(model.B - truth.B) <= 4 * B_std + 1e-15)
    assert np.all(np.abs(model.A - truth.A) <= 4 * A_std + 1e-15)


def test_servo_optional_roles_and_radians(servo_log):
    """Without the echo and the position, the state is [current, velocity]; in radians the
    fit is the same fit (its weights scale with the units)."""
    U, Y = servo_log
    n = 3000
    roles = {"current": 0, "velocity": 1}
    turns = fit_template("servo_axis", U[:n], Y[:n, 1:3], roles, 0.01, fixed=["b"])
    Y_rad = Y[:n, 1:3] * [1.0, TWO_PI]
    rad = fit_template("servo_axis", U[:n], Y_rad, roles, 0.01, fixed=["b"],
                       settings={"unit": "rad"})
    assert turns.states == ("current", "velocity") and turns.model.F.shape == (2, 1)
    for a, b in zip(turns.parameters, rad.parameters, strict=True):
        assert a.value == pytest.approx(b.value, rel=1e-6) and a.status == b.status
    assert turns.model.F[1, 0] * TWO_PI == pytest.approx(rad.model.F[1, 0], rel=1e-6)
    assert np.all(np.isnan(turns.residuals[:, [0, 3]]))
    for p in turns.parameters[:3]:
        assert abs(p.value - {"Kt": KT, "tau_i": TAU, "J": J}[p.name]) < 3 * p.std


# ----------------------------------------------------------------------------- the registry


def test_an_optional_role_enters_no_other_derivative():
    """What lets the fit fill an absent optional role with zeros."""
    rng = np.random.default_rng(1)
    for template in TEMPLATES.values():
        n = len(template.outputs)
        x, u = rng.standard_normal((50, n)), rng.standard_normal((50, len(template.inputs)))
        for role in template.optional:
            i = template.outputs.index(role)
            y = x.copy()
            y[:, i] += rng.standard_normal(50)
            others = [j for j in range(n) if j != i]
            datasheet = np.array([p.default for p in template.parameters])
            dx, dy = template.ode(datasheet, x, u), template.ode(datasheet, y, u)
            assert np.array_equal(dx[:, others], dy[:, others]), (template.name, role)


def test_parameters_have_positive_bounds_around_their_defaults():
    for template in TEMPLATES.values():
        for p in template.parameters:
            assert 0 < p.lower < p.default < p.upper, (template.name, p.name)
        assert len(template.unknown_inputs) == monitor_model(template, {}, 0.01).r


# ----------------------------------------------------------------------------- refusals


@pytest.fixture(scope="module")
def short(dc_log):
    return dc_log.u[:500], dc_log.y[:500]


def test_unknown_template_names_the_nearest(short):
    with pytest.raises(ValueError, match=r"unknown template 'dc_moter' \(did you mean dc_motor"):
        fit_template("dc_moter", *short, DC_ROLES, 0.01)
    with pytest.raises(ValueError, match="known: dc_motor, servo_axis"):
        get_template("pendulum")


def test_missing_or_unknown_role(short):
    with pytest.raises(ValueError, match=r"missing role 'speed'.*needs field_current"):
        fit_template("dc_motor", *short, {"field_current": 0, "armature_current": 1}, 0.01)
    with pytest.raises(ValueError, match=r"no output role 'sped'.*did you mean speed"):
        fit_template("dc_motor", *short, DC_ROLES | {"sped": 2}, 0.01)
    with pytest.raises(ValueError, match=r"roles\['speed'\]: expected a column of Y in 0..3"):
        fit_template("dc_motor", *short, DC_ROLES | {"speed": 4}, 0.01)


def test_unknown_parameter_names(short):
    with pytest.raises(ValueError, match=r"fixed parameter 'Rf' is not a parameter.*R_f"):
        fit_template("dc_motor", *short, DC_ROLES, 0.01, fixed=["Rf"])
    with pytest.raises(ValueError, match=r"no parameter 'La'.*L_a"):
        fit_template("dc_motor", *short, DC_ROLES, 0.01, start={"La": 0.1})
    with pytest.raises(ValueError, match=r"no setting 'units'.*did you mean unit"):
        fit_template("servo_axis", short[0], short[1][:, :2], {"current": 0, "velocity": 1},
                     0.01, settings={"units": "rad"})
    with pytest.raises(ValueError, match="setting unit must be one of turn, rad"):
        fit_template("servo_axis", short[0], short[1][:, :2], {"current": 0, "velocity": 1},
                     0.01, settings={"unit": "deg"})


def test_start_outside_bounds(short):
    with pytest.raises(ValueError, match=r"start value of J = -0.05 kg m\^2 is outside"):
        fit_template("dc_motor", *short, DC_ROLES, 0.01, start={"J": -0.05})


def test_too_few_samples(short):
    U, Y = short
    with pytest.raises(ValueError, match=r"too few usable samples: 49 one-step pairs.*\(70\)"):
        fit_template("dc_motor", U[:50], Y[:50], DC_ROLES, 0.01)
    Y_lost = Y.copy()
    Y_lost[::2] = np.nan  # every other sample lost: no one-step pair left
    with pytest.raises(ValueError, match="too few usable samples: 0 "):
        fit_template("dc_motor", U, Y_lost, DC_ROLES, 0.01)
    # with six of seven parameters fixed, 20 pairs are enough
    fit = fit_template("dc_motor", U[:21], Y[:21], DC_ROLES, 0.01,
                       fixed=["R_f", "L_f", "R_a", "L_a", "M", "J"])
    assert fit.samples == 20


def test_bad_arrays(short):
    U, Y = short
    with pytest.raises(ValueError, match=r"U: expected shape \(N, 1\), got \(500, 2\)"):
        fit_template("dc_motor", np.hstack([U, U]), Y, DC_ROLES, 0.01)
    with pytest.raises(ValueError, match=r"Y: expected shape \(500, q\)"):
        fit_template("dc_motor", U, Y[:-1], DC_ROLES, 0.01)
    with pytest.raises(ValueError, match="U: must be finite"):
        fit_template("dc_motor", np.where(np.arange(500)[:, None] == 3, np.nan, U), Y, DC_ROLES,
                     0.01)
    with pytest.raises(ValueError, match="dt: must be a positive number"):
        fit_template("dc_motor", U, Y, DC_ROLES, 0.0)

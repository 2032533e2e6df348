"""The residual bank of the DC motor: structure, isolability and estimability facts."""

import numpy as np

from canfdi.core.design import DesignOptions, design_bank, design_to_dict
from canfdi.core.parity import identity_stack, parity_matrices
from tests.dc_motor import dc_motor

NAMES_IN = ["V"]
NAMES_OUT = ["i_f", "i_a", "i_f_plus_i_a", "omega_r"]


def _design(**kw):
    opts = DesignOptions(measurement_std=np.full(4, 0.01), **kw)
    return design_bank(dc_motor(), NAMES_IN, NAMES_OUT, opts)


def test_default_windows_are_the_smallest_admissible():
    d = _design()
    assert d.actuator_window == 1
    assert d.sensor_window == 1  # the largest of the per-sensor minima (1, 1, 1, 0)
    assert [r.min_window for r in d.sensors] == [1, 1, 1, 0]


def test_fixed_window_and_noise_gain():
    d = _design(sensor_window=4)
    assert d.sensor_window == 4
    V = d.sensor_matrix()
    assert V.shape == (4, 20)
    # Unit vectors and white measurement noise 0.01: residual noise std is exactly 0.01.
    np.testing.assert_allclose([r.noise_std for r in d.sensors], 0.01, rtol=1e-12)
    np.testing.assert_allclose(d.gain[1:, 1:], V @ identity_stack(4, 4), atol=1e-12)


def test_process_noise_raises_residual_noise():
    quiet = design_bank(dc_motor(), NAMES_IN, NAMES_OUT,
                        DesignOptions(measurement_std=np.full(4, 0.01)))
    noisy = design_bank(dc_motor(), NAMES_IN, NAMES_OUT,
                        DesignOptions(measurement_std=np.full(4, 0.01),
                                      process_std=np.array([0.1, 0.0, 0.0])))
    v = noisy.actuators[0].vector.vector
    pm = parity_matrices(noisy.model, 1)
    assert noisy.actuators[0].noise_std > quiet.actuators[0].noise_std
    # i_f's process noise reaches y(k) through C; check the variance by hand for s = 1.
    Hx = np.zeros((8, 6))
    Hx[4:, :3] = noisy.model.C
    want = v @ (np.eye(8) * 1e-4 + Hx @ np.diag([0.01, 0, 0, 0, 0, 0]) @ Hx.T) @ v
    assert abs(noisy.actuators[0].noise_std ** 2 - want) < 1e-15
    assert pm.H0.shape == (8, 3)


def test_isolability_and_estimability_of_the_dc_motor_sensors():
    d = _design(sensor_window=4)
    out = design_to_dict(d)
    det = {(e["kind"], e["index"]): e for e in out["detectability"]}
    # omega_r: no residual decoupled from w responds to it.
    assert det[("sensor", 3)]["detectable"] is False
    assert det[("sensor", 3)]["residuals"] == []
    # i_a and i_f + i_a enter every residual only through their difference (i_a carries the
    # unknown phi1): same signature, and neither bias is jointly estimable (eq. 41).
    assert det[("sensor", 1)]["confused_with"] == ["i_f_plus_i_a"]
    assert det[("sensor", 1)]["jointly_estimable"] is False
    assert det[("sensor", 2)]["jointly_estimable"] is False
    assert det[("sensor", 0)]["jointly_estimable"] is True and det[("sensor", 0)]["isolable"]
    Phi = d.sensor_matrix() @ identity_stack(4, 4)
    np.testing.assert_allclose(Phi[:, 1], -Phi[:, 2], atol=1e-12)


def test_json_contract_fields():
    out = design_to_dict(_design())
    for key in ("actuators", "sensors"):
        for e in out[key]:
            for field in ("index", "name", "window", "exists", "vector", "sensitivity", "reason"):
                assert field in e
    for e in out["detectability"]:
        for field in ("kind", "index", "name", "detectable", "strongly_detectable"):
            assert field in e
    assert [e["index"] for e in out["sensors"]] == [0, 1, 2, 3]


def test_window_comparison_shows_larger_windows_gain_sensitivity():
    d = _design()
    act = next(c for c in d.window_comparison if c["kind"] == "actuator")
    ratios = [w["fault_to_noise"] for w in act["by_window"]]
    assert ratios == sorted(ratios) and ratios[-1] > ratios[0]


def test_sensors_of_very_different_noise_get_vectors_per_unit_of_noise():
    """A servo axis whose echo is exact to 1e-7 beside a 0.05 A current: Chan et al. 2006's raw-gain
    vectors all take the echo relation and the velocity sensor's bias goes unseen; chosen per
    unit of noise, the velocity is seen and the measured current told apart from it. Sensors
    of alike noise keep the paper's vectors exactly."""
    from canfdi.config import load_config
    from canfdi.core.model import StateSpace
    from canfdi.firmware_sim.plants.servo_axis import ServoAxis
    from tests.conftest import REPO

    m = ServoAxis().linear_model()
    model = StateSpace(A=m["A"], B=m["B"], C=m["C"], F=m["F"], dt=0.01)
    names = ["Iq_Setpoint", "Iq_Measured", "Vel_Estimate", "Pos_Estimate"]
    noise = np.array([1.4e-7, 0.05, 0.01, 1e-4])
    design = design_bank(model, ["Input_Torque"], names,
                         DesignOptions(measurement_std=noise))
    best = {name: float(np.max(np.abs(design.gain[:, 1 + j])
                               / [r.noise_std for r in design.actuators + design.sensors]))
            for j, name in enumerate(names)}
    assert best["Vel_Estimate"] > 20 and best["Iq_Measured"] > 5
    confused = design.confused_with()
    assert confused[1 + 1] == []  # Iq_Measured isolable
    plain = design_bank(model, ["Input_Torque"], names)
    assert np.max(np.abs(plain.gain[:, 1 + 2])) < 1e-5  # the raw-gain bank does not see it
    dc = load_config(REPO / "deploy" / "config" / "dc_motor.yaml")
    a = design_bank(dc.model, dc.inputs, dc.outputs, dc.design)
    b = design_bank(dc.model, dc.inputs, dc.outputs,
                    DesignOptions(actuator_window=8, sensor_window=4))
    np.testing.assert_array_equal(a.sensor_matrix(), b.sensor_matrix())


def test_a_fault_unseen_at_the_smallest_window_grows_the_window_until_seen():
    """A servo axis identified from 300 s of commissioning (its matrices as written): at the
    smallest sensor window no residual decoupled from the load and the setpoint's echo can
    move with the velocity sensor's bias (two constraints on the position and velocity rows
    leave no vector); at s = 2 one does. A fixed window stays as given."""
    from canfdi.core.model import StateSpace

    A = [[9.525528145e-10, 0.0, -1.429979565e-10, 0.0],
         [0.0, 0.2870760169, 0.0, 0.0],
         [0.3499175213, -0.3236013612, 1.00015743, 3.595434366e-05],
         [0.001756021422, -0.001478719291, 0.01000104871, 1.000000178]]
    model = StateSpace(A=A, B=[[12.49999999], [8.913854031], [-0.04673848401],
                               [-0.002056809998]], C=np.eye(4),
                       F=[[0.0], [0.0], [1.0], [0.005010224352]], dt=0.01)
    names = ["Iq_Setpoint", "Iq_Measured", "Vel_Estimate", "Pos_Estimate"]
    noise = [1.377e-07, 0.05031, 0.01009, 9.984e-05]
    grown = design_bank(model, ["Input_Torque"], names, DesignOptions(measurement_std=noise))
    fixed = design_bank(model, ["Input_Torque"], names,
                        DesignOptions(measurement_std=noise, sensor_window=1))
    vel = 1 + 2
    assert fixed.sensor_window == 1 and not fixed.responds[:, vel].any()
    assert grown.actuator_window == 1 and grown.sensor_window == 2
    assert grown.responds[:, vel].any()
    ratio = np.abs(grown.gain[:, vel]) / [r.noise_std for r in grown.actuators + grown.sensors]
    assert ratio.max() > 20


def test_a_vector_sign_is_fixed_by_a_rule_that_survives_ties():
    """Every shipped config's residuals: the largest gain entry is positive, and of entries
    equal to it up to rounding the first in index order (the DC motor's residual blind to i_f
    sees i_a and i_f + i_a alike: an argmax between them is the BLAS's choice, and flipped the
    residual's sign between two numpy releases)."""
    from canfdi.config import load_config
    from tests.conftest import REPO

    seen_tie = False
    for path in sorted((REPO / "deploy" / "config").glob("*.yaml")):
        config = load_config(path, allow_unidentified=True)
        if config.model is None or config.method != "parity":
            continue
        design = design_bank(config.model, config.inputs, config.outputs, config.design)
        for residual in design.actuators + design.sensors:
            gain = residual.vector.gain
            if gain is None or not np.abs(gain).max() > 0:
                continue
            mag = np.abs(gain)
            tied = np.flatnonzero(mag >= (1 - 1e-9) * mag.max())
            seen_tie |= len(tied) > 1 and len(set(np.sign(gain[tied]))) > 1
            assert gain[tied[0]] > 0, (path.name, residual.name)
    assert seen_tie  # the case the rule is for is among them

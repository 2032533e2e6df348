"""An ODrive-like servo axis in torque control, its velocity loop closed by the bus master.

The drive of issue 26: a model of it is learned from a commissioning log, then the monitor
diagnoses sensor biases with that model. The drive closes its own current loop and reports its
current setpoint, its measured current and its encoder estimates; the master (a host on the CAN
bus) closes a velocity loop on the drive's velocity estimate and sends a torque setpoint every
period (the float_node bus profile, as ODrive's CAN Simple protocol does). The plant is not
linear: Coulomb friction, an unknown load torque, and the loop closed on a measured signal.

    Iq_sp(k+1)  = u(k) / Kt                     the setpoint the drive holds (and reports); u(k) as
                                                the bus carried it, a float32
    dIq/dt      = (u / Kt - Iq) / tau_i         the closed current loop, first order
    J domega/dt = Kt Iq - b omega - T_c tanh(omega / omega_s) - T_L(t)
    dtheta/dt   = omega

x = [Iq_sp, Iq, omega, theta, t] (A, A, rad/s, rad, s); t is the plant's own clock, so that
``step`` (which gets no sample index) can evaluate the load torque. u = Input_Torque (Nm), held
over the whole period (zero-order hold). y = [Iq_Setpoint, Iq_Measured, Vel_Estimate,
Pos_Estimate] = [Iq_sp, Iq, omega / 2 pi, theta / 2 pi] (A, A, turns/s, turns), in the units
ODrive reports. The setpoint echo is exact: y_0(k+1) = u(k) / Kt.

Parameters (`ServoAxisParameters`, dt = 0.01 s):

=============== ============ ============ ====================================================
name            value        unit         meaning
=============== ============ ============ ====================================================
Kt              0.08         Nm/A         torque constant
tau_i           0.008        s            closed current loop time constant (the fast current
                                          pole: exp(-dt / tau_i) = 0.2865)
J               5e-4         kg m^2       rotor and load inertia
b               1e-4         Nm s/rad     viscous friction
T_c             0.03         Nm           Coulomb friction
omega_s         0.05         rad/s        speed of the tanh that smooths the Coulomb friction
                                          (the ODE stays smooth through standstill)
torque_limit    1.6          Nm           the master clips its command to +/- this
load_settle     2.0          s            no load step before this (a settled start)
load_interval   (4, 12)      s            load steps at intervals uniform in this range
load_level      0.3          Nm           step levels uniform in [-0.3, 0.3]
load_drift      0.1          Nm           amplitude of the slow drift sin(2 pi t / 90 s)
load_period     90.0         s            period of the drift
load_horizon    10000.0      s            schedule precomputed this far; the last level holds
kp              0.05         Nm/(turn/s)  the master's proportional velocity gain
ki              0.2          Nm/turn      the master's integral velocity gain
dither          0.02         Nm           +/- PRBS torque dither (commissioning only)
=============== ============ ============ ====================================================

Load torque T_L(t): piecewise-constant steps plus the drift 0.1 sin(2 pi t / 90 s). The first
step is at load_settle, later ones at intervals uniform in load_interval, each step's level
uniform in [-load_level, load_level]; all drawn at construction from
``numpy.random.default_rng(load_seed)``. Step times are rounded to the sample grid, so the load
is smooth inside every control period and the integration below keeps its order.

Integration. Each period is 10 substeps of RK4 in plain floats (numpy's per-call overhead on
3-vectors would dominate, as in DcMotor.step), in Lawson's integrating-factor form: the linear
part (current loop, inertia, viscous friction, the held command) is carried by its exact flow
exp(A_c h), and RK4 integrates only the friction and load torque. Plain RK4 at h = 1 ms would
miss the current pole by 2.5e-7 per substep (h / tau_i = 0.125), about 3e-6 of the current per
period; in this form the plant without friction and load (``load=False``) is its zero-order
hold model `linear_model` to round-off, and the nonlinear terms are integrated to RK4 accuracy.
At standstill, inside the tanh's band |omega| < omega_s, the friction is a damper of time
constant omega_s J / T_c = 0.8 ms, shorter than a substep: RK4 stays stable there (h / 0.8 ms =
1.2 < 2.78) and its error, at most about 5e-4 turns/s in such a period, is a twentieth of the
velocity noise (elsewhere below 1e-5 turns/s).

Controller (`ServoVelocityController`): the master's PI velocity loop on the measured
Vel_Estimate, in turns/s, T = kp e + ki int(e dt) (+ dither), e = Vel_Ref - z_2, clipped to
+/- torque_limit, the integrator stopped while the PI part saturates. Two reference programs
(plant option ``reference``):

- ``"operation"`` (default): trapezoidal moves through the speeds 0, 5, 10, -5, 2 turns/s (then
  back to 0, cyclically), each held 6 s, ramps of 20 turns/s^2 between them.
- ``"commissioning"`` (an engineer recording a commissioning log): a 60 s program, repeated:
  for 30 s velocity steps of +/-3 turns/s around 4 turns/s every 2 s (1 turn/s first), then for
  30 s a chirp 4 + 2 sin(phase) whose frequency sweeps linearly from 0.1 to 8 Hz; plus the
  +/-0.02 Nm PRBS dither (a 16-bit LFSR, as PiSpeedController's) so that the torque is rich.
  The reference stays within 1..7 turns/s, where the Coulomb friction is a constant torque
  (the steps down undershoot to near standstill for a moment).

Plant options (scenario ``plant_options``): ``reference`` ("operation" | "commissioning"),
``load_seed`` (integer >= 0, default 0), ``load`` (default true; false: no load torque and no
Coulomb friction, the plant is then its linear model exactly, viscous friction included; for
tests).

Noise: the setpoint echo has none (exact up to float32 on the bus). A scenario that adds
process noise should give it per state, with zeros for Iq_sp (overwritten every period) and t
(the load's clock).
"""

from __future__ import annotations

import math
from bisect import bisect_right
from dataclasses import dataclass

import numpy as np

from canfdi.core.model import zoh
from canfdi.firmware_sim.plants.base import Controller, NoiseDefaults, Plant, PlantOptionError

__all__ = ["OPTIONS", "REFERENCES", "ServoAxis", "ServoAxisParameters",
           "ServoVelocityController"]

TWO_PI = 2.0 * math.pi
REFERENCES = ("operation", "commissioning")
"""The reference programs of the master's velocity loop (plant option ``reference``)."""
OPTIONS = ("load", "load_seed", "reference")
"""The plant options a scenario may give (``plant_options``)."""

OPERATION_SPEEDS = (0.0, 5.0, 10.0, -5.0, 2.0)  # turns/s, cycled in this order
OPERATION_HOLD = 6.0  # s at each speed
OPERATION_ACCEL = 20.0  # turns/s^2 on the ramps between them
COMMISSIONING_PERIOD = 60.0  # s: steps for the first half, the chirp for the second
COMMISSIONING_LEVEL = 4.0  # turns/s, the centre of the steps and of the chirp
COMMISSIONING_STEP = 3.0  # turns/s either side of the level
COMMISSIONING_STEP_EVERY = 2.0  # s
COMMISSIONING_CHIRP = (2.0, 0.1, 8.0)  # amplitude (turns/s), start and end frequency (Hz)


@dataclass(frozen=True)
class ServoAxisParameters:
    """The drive's, the load's and the master's parameters (module docstring: the table)."""

    dt: float = 0.01
    Kt: float = 0.08
    tau_i: float = 0.008
    J: float = 5e-4
    b: float = 1e-4
    T_c: float = 0.03
    omega_s: float = 0.05
    torque_limit: float = 1.6
    load_settle: float = 2.0
    load_interval: tuple[float, float] = (4.0, 12.0)
    load_level: float = 0.3
    load_drift: float = 0.1
    load_period: float = 90.0
    load_horizon: float = 10000.0
    kp: float = 0.05
    ki: float = 0.2
    dither: float = 0.02

    def continuous(self) -> tuple[np.ndarray, np.ndarray]:
        """The linear part in output units, without Coulomb friction: (3, 3) A_c, (3, 2) B_c.

        State [Iq (A), vel (turns/s), pos (turns)]; inputs [u (Nm), T_L (Nm)]:
        dIq/dt = (u / Kt - Iq) / tau_i, dvel/dt = (Kt Iq - b 2 pi vel - T_L) / (2 pi J),
        dpos/dt = vel.
        """
        A = np.array([[-1.0 / self.tau_i, 0.0, 0.0],
                      [self.Kt / (TWO_PI * self.J), -self.b / self.J, 0.0],
                      [0.0, 1.0, 0.0]])
        B = np.array([[1.0 / (self.Kt * self.tau_i), 0.0],
                      [0.0, -1.0 / (TWO_PI * self.J)],
                      [0.0, 0.0]])
        return A, B


def _check_options(reference: object, load_seed: object, load: object) -> None:
    if reference not in REFERENCES:
        raise PlantOptionError("reference", f"must be one of {', '.join(REFERENCES)}, got "
                                            f"{reference!r}")
    if isinstance(load_seed, bool) or not isinstance(load_seed, int) or load_seed < 0:
        raise PlantOptionError("load_seed", f"must be an integer >= 0, got {load_seed!r}")
    if not isinstance(load, bool):
        raise PlantOptionError("load", f"must be true or false, got {load!r}")


class ServoVelocityController(Controller):
    """The master's PI velocity loop on the measured Vel_Estimate (output 2), in turns/s.

    T(k) = clip(kp e(k) + ki dt sum_{j<=k} e(j) + dither(k), +/- torque_limit),
    e = Vel_Ref(k) - z_2(k); the sum stops while the PI part saturates.

    Parameters
    ----------
    params : the gains, limit and dither.
    program : "operation" or "commissioning" (the module docstring); the dither is on in
        commissioning only.
    initial_torque : the torque the loop starts from (its integrator is preset to it), Nm.

    Examples
    --------
    >>> ctrl = ServoVelocityController(ServoAxisParameters(), "operation")
    >>> [round(float(ctrl.reference(k)[0]), 6) for k in (0, 600, 610, 625, 1300)]
    [0.0, 0.0, 2.0, 5.0, 10.0]
    >>> round(float(ctrl.command(0, np.array([0.0, 0.0, -1.0, 0.0]))[0]), 6)  # 1 turn/s slow
    0.052
    """

    def __init__(self, params: ServoAxisParameters, program: str = "operation",
                 initial_torque: float = 0.0) -> None:
        if program not in REFERENCES:
            raise ValueError(f"program must be one of {', '.join(REFERENCES)}, got {program!r}")
        self.params = params
        self.program = program
        self.dt = params.dt
        self.dither = params.dither if program == "commissioning" else 0.0
        self._integral0 = initial_torque / params.ki
        self._integral = self._integral0
        self._lfsr = 0xACE1
        # Operation: the (start, end, speed at start, speed at end) of each hold and ramp of
        # one cycle, so that a reference is a short scan, not a search over the whole run.
        segments = []
        t = 0.0
        speeds = OPERATION_SPEEDS
        for i, v in enumerate(speeds):
            nxt = speeds[(i + 1) % len(speeds)]
            segments.append((t, t + OPERATION_HOLD, v, v))
            t += OPERATION_HOLD
            ramp = abs(nxt - v) / OPERATION_ACCEL
            if ramp > 0:
                segments.append((t, t + ramp, v, nxt))
                t += ramp
        self._segments = tuple(segments)
        self._cycle = t

    def reset(self) -> None:
        self._integral = self._integral0
        self._lfsr = 0xACE1

    def velocity_reference(self, t: float) -> float:
        """Vel_Ref (turns/s) at time t (s) of the controller's program."""
        # On a microsecond grid, so that k dt lands on the programs' breakpoints (2 s, 60 s,
        # ...) whatever its rounding.
        t = round(t * 1e6) / 1e6
        if self.program == "operation":
            tau = t % self._cycle
            for t0, t1, v0, v1 in self._segments:
                if tau < t1:
                    return v0 + (v1 - v0) * (tau - t0) / (t1 - t0) if v1 != v0 else v0
            return self._segments[-1][3]
        tau = t % COMMISSIONING_PERIOD
        half = COMMISSIONING_PERIOD / 2
        if tau < half:
            up = int(tau // COMMISSIONING_STEP_EVERY) % 2
            return COMMISSIONING_LEVEL + (COMMISSIONING_STEP if up else -COMMISSIONING_STEP)
        s = tau - half
        amplitude, f0, f1 = COMMISSIONING_CHIRP
        phase = TWO_PI * (f0 * s + (f1 - f0) * s * s / (2.0 * half))
        return COMMISSIONING_LEVEL + amplitude * math.sin(phase)

    def reference(self, k: int) -> np.ndarray:
        return np.array([self.velocity_reference(k * self.dt)])

    def _prbs(self) -> float:
        # 16-bit Fibonacci LFSR (taps 16, 14, 13, 11), PiSpeedController's: deterministic,
        # period 65535 samples.
        bit = ((self._lfsr >> 0) ^ (self._lfsr >> 2) ^ (self._lfsr >> 3) ^ (self._lfsr >> 5)) & 1
        self._lfsr = (self._lfsr >> 1) | (bit << 15)
        return 1.0 if bit else -1.0

    def command(self, k: int, z: np.ndarray) -> np.ndarray:
        p = self.params
        error = self.velocity_reference(k * self.dt) - float(z[2])
        self._integral += error * self.dt
        torque = p.kp * error + p.ki * self._integral
        if abs(torque) > p.torque_limit:
            # Anti-windup: stop integrating while the command saturates.
            self._integral -= error * self.dt
            torque = math.copysign(p.torque_limit, torque)
        if self.dither:
            torque = min(max(torque + self.dither * self._prbs(), -p.torque_limit),
                         p.torque_limit)
        return np.array([torque])


class ServoAxis(Plant):
    """An ODrive-like servo axis in torque control (the module docstring says it all).

    Parameters
    ----------
    reference : the master's reference program, "operation" (default) or "commissioning".
    load_seed : seed of the load torque's step schedule (integer >= 0).
    load : False: no load torque and no Coulomb friction (the plant is then exactly
        `linear_model`).
    params : the physical and controller parameters.
    substeps : RK4 substeps per control period.

    Raises
    ------
    PlantOptionError (a ValueError) : naming the option with a bad value.

    Examples
    --------
    >>> plant = ServoAxis(reference="commissioning", load_seed=1)
    >>> model = plant.linear_model()
    >>> round(float(model["A"][1, 1]), 4)  # the fast current pole
    0.2865
    >>> x = plant.step(plant.initial_state(), np.array([0.4]))
    >>> round(float(plant.output(x)[0]), 6)  # the setpoint echo: u / Kt, as a float32 on the wire
    5.0
    """

    name = "servo_axis"
    dt = 0.01
    state_names = ("Iq_sp", "Iq", "omega", "theta", "t")
    input_names = ("Input_Torque",)
    output_names = ("Iq_Setpoint", "Iq_Measured", "Vel_Estimate", "Pos_Estimate")
    reference_names = ("Vel_Ref",)
    dbc = None  # no DBC of canfdi's own bus: the drive speaks float_node (servo_axis_float.dbc)
    config = "servo_axis_odrive.yaml"

    def __init__(self, reference: str = "operation", load_seed: int = 0, load: bool = True,
                 params: ServoAxisParameters | None = None, substeps: int = 10) -> None:
        _check_options(reference, load_seed, load)
        self.reference = reference
        self.load_seed = load_seed
        self.load = load
        self.params = params or ServoAxisParameters(dt=self.dt)
        if self.params.dt != self.dt:
            raise ValueError(f"params.dt {self.params.dt} is not the plant's {self.dt}")
        self.substeps = substeps
        self._flows = tuple(self._flow(self.params.dt / substeps * f) for f in (0.5, 1.0))
        self._step_k, self._levels = self._load_schedule(load_seed)

    # --- the load ---------------------------------------------------------------------------

    def _load_schedule(self, seed: int) -> tuple[list[int], list[float]]:
        """Sample indices of the load steps (ascending) and the level from each on."""
        p = self.params
        rng = np.random.default_rng(seed)
        lo, hi = p.load_interval
        count = math.ceil((p.load_horizon - p.load_settle) / lo) + 1
        intervals = rng.uniform(lo, hi, count)
        levels = rng.uniform(-p.load_level, p.load_level, count)
        times = p.load_settle + np.concatenate([[0.0], np.cumsum(intervals[:-1])])
        keep = times < p.load_horizon
        return ([round(t / p.dt) for t in times[keep]], [float(v) for v in levels[keep]])

    @property
    def load_steps(self) -> tuple[np.ndarray, np.ndarray]:
        """(M,) step times (s, on the sample grid) and (M,) levels (Nm) of the load torque."""
        return (np.array(self._step_k) * self.params.dt, np.array(self._levels))

    def _level(self, k: int) -> float:
        i = bisect_right(self._step_k, k) - 1
        return self._levels[i] if i >= 0 else 0.0

    def _drift(self, t: float) -> float:
        p = self.params
        return p.load_drift * math.sin(TWO_PI * t / p.load_period)

    def load_torque(self, t: float) -> float:
        """T_L(t) in Nm: the step level of t's control period plus the drift (0 without load)."""
        if not self.load:
            return 0.0
        return self._level(math.floor(t / self.params.dt + 1e-9)) + self._drift(t)

    def friction(self, omega: float) -> float:
        """The friction torque (Nm) at speed omega (rad/s): viscous plus smoothed Coulomb."""
        p = self.params
        coulomb = p.T_c * math.tanh(omega / p.omega_s) if self.load else 0.0
        return p.b * omega + coulomb

    # --- Plant ------------------------------------------------------------------------------

    def noise_defaults(self) -> NoiseDefaults:
        # The setpoint echo has no noise: it is exact up to float32.
        return NoiseDefaults(measurement=np.array([0.0, 0.05, 0.01, 1e-4]),
                             process=np.zeros(self.n))

    def initial_state(self) -> np.ndarray:
        # At rest the Coulomb term is tanh(0) = 0: the current balances the load alone.
        current = self.load_torque(0.0) / self.params.Kt
        return np.array([current, current, 0.0, 0.0, 0.0])

    def _flow(self, s: float) -> tuple[tuple[float, ...], ...]:
        """The linear part's exact flow over s seconds, in the plant's units (A, rad/s, rad)
        with the current command i_c held: x(s) = E x(0) + G i_c; returns E (3 rows) and G."""
        p = self.params
        A = np.array([[-1.0 / p.tau_i, 0.0, 0.0],
                      [p.Kt / p.J, -p.b / p.J, 0.0],
                      [0.0, 1.0, 0.0]])
        B = np.array([[1.0 / p.tau_i], [0.0], [0.0]])
        E, G = zoh(A, B, s)
        return (*(tuple(float(v) for v in row) for row in E), tuple(float(v) for v in G[:, 0]))

    def step(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        p = self.params
        # The drive acts on the setpoint it received: Input_Torque is a float32 on the bus.
        torque = float(np.float32(u[0]))
        i_c = torque / p.Kt
        i, w, th, t = float(x[1]), float(x[2]), float(x[3]), float(x[4])
        h = p.dt / self.substeps
        # The flows over h / 2 (e, g) and h (f, gf) are lower triangular: the current feeds
        # the speed, the speed the angle.
        (_, e1, e2, g), (f0, f1, f2, gf) = self._flows
        nonlinear = self.load
        if nonlinear:
            level = self._level(round(t / p.dt))
            inv_j, tc, ws = 1.0 / p.J, p.T_c, p.omega_s
            drift, rate = p.load_drift, TWO_PI / p.load_period
        for j in range(self.substeps):
            bi = f0[0] * i + gf[0] * i_c
            bw = f1[0] * i + f1[1] * w + gf[1] * i_c
            bth = f2[0] * i + f2[1] * w + th + gf[2] * i_c
            if not nonlinear:
                i, w, th = bi, bw, bth
                continue
            # Lawson RK4 on the friction and load torque n(omega, t) / J, which act on the
            # speed only, so that E (0, n, 0) = n (0, E_11, E_21). The current has no
            # nonlinear term: its flow is exact.
            aw = e1[0] * i + e1[1] * w + g[1] * i_c
            ts = t + j * h
            load_m = level + drift * math.sin(rate * (ts + h / 2))
            k1 = -(tc * math.tanh(w / ws) + level + drift * math.sin(rate * ts)) * inv_j
            k2 = -(tc * math.tanh((aw + e1[1] * h / 2 * k1) / ws) + load_m) * inv_j
            k3 = -(tc * math.tanh((aw + h / 2 * k2) / ws) + load_m) * inv_j
            k4 = -(tc * math.tanh((bw + e1[1] * h * k3) / ws) + level
                   + drift * math.sin(rate * (ts + h))) * inv_j
            i = bi
            w = bw + h / 6 * (f1[1] * k1 + 2 * e1[1] * (k2 + k3) + k4)
            th = bth + h / 6 * (f2[1] * k1 + 2 * e2[1] * (k2 + k3))
        return np.array([i_c, i, w, th, t + p.dt])

    def output(self, x: np.ndarray) -> np.ndarray:
        return np.array([x[0], x[1], x[2] / TWO_PI, x[3] / TWO_PI])

    def controller(self) -> ServoVelocityController:
        return ServoVelocityController(self.params, self.reference,
                                       initial_torque=self.load_torque(0.0))

    def linear_model(self) -> dict[str, np.ndarray]:
        """The drive's discrete linear model without Coulomb friction and load, in output units.

        State [Iq_sp (A), Iq (A), vel (turns/s), pos (turns)], input u (Nm), unknown input the
        load torque T_L (Nm), y = the state (C = I). The echo row is Iq_sp(k+1) = u(k) / Kt;
        the other rows are the zero-order-hold discretisation of `ServoAxisParameters.continuous`
        over dt, read off scipy.linalg.expm of the augmented matrix [[A_c, B_c], [0, 0]] dt
        (canfdi.core.model.zoh); F is the hold of a constant T_L over the period, which
        reaches only the speed and position rows.

        Returns
        -------
        dict with A (4, 4), B (4, 1), C (4, 4) and F (4, 1), numpy arrays.
        """
        p = self.params
        Ac, Bc = p.continuous()
        Ad, Gd = zoh(Ac, Bc, p.dt)
        A = np.zeros((4, 4))
        A[1:, 1:] = Ad + 0.0  # expm leaves -0.0 above the diagonal; print it as 0
        B = np.zeros((4, 1))
        B[0, 0] = 1.0 / p.Kt
        B[1:, 0] = Gd[:, 0]
        F = np.zeros((4, 1))
        F[1:, 0] = Gd[:, 1]
        return {"A": A, "B": B, "C": np.eye(4), "F": F}

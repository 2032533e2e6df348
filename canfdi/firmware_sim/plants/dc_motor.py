"""The shunt-field DC motor of Chan et al. 2006 (eq. 42), nonlinear, with a PI speed loop.

    di_f/dt = -(R_f/L_f) i_f + V/L_f
    di_a/dt = -(R_a/L_a) i_a - (M/L_a) i_f omega_r + V/L_a
    domega_r/dt = (M/J) i_f i_a - (D/J) omega_r

x = [i_f, i_a, omega_r], u = V, y = [i_f, i_a, i_f + i_a, omega_r] (eq. 44).

Parameters. The linear part's zero-order-hold discretisation at dt must give eq. 43:
diag(A) = (0.8825, 0.6839, 0.9948) and B = (0.002235, 0.0823, 0). For a first-order channel
a = exp(-(R/L) dt) and b = (1 - a)/R, so with dt = 0.01 s:

    R_f = (1 - 0.8825) / 0.002235 = 52.573 ohm,   L_f = R_f dt / -ln(0.8825) = 4.2059 H
    R_a = (1 - 0.6839) / 0.0823   = 3.8408 ohm,   L_a = R_a dt / -ln(0.6839) = 0.10109 H
    D/J = -ln(0.9948) / dt = 0.52136 1/s

b2 = 0.0823, not the 0.0832 printed in eq. 43: every H matrix printed in Section V is computed
with 0.0823 (see ../shared/seeds/README.md), and the monitor config uses the same value.
J, D and M do not enter eq. 43; we choose J = 0.05 kg m^2 (so D = 0.026068 N m s) and
M = 0.2 H, which puts the operating point at omega_r = 100 rad/s with V near 100 V, i_f near
1.9 A and i_a near 10 A, inside the DBC ranges with room for the papers' faults.

Because A is diagonal and the nonlinear terms enter only the i_a and omega_r equations, their
effect over one period lies exactly in span(F) with F = [e2, e3]: the sampled plant is
x(k+1) = A x(k) + B u(k) + F w(k) with w(k) the "discrete versions" of phi1 and phi2, which is
why the decoupled parity residuals of the monitor are exactly zero apart from noise.

The PI speed loop tracks omega_ref, a 100 rad/s level with +/-10 rad/s steps every 4 s, and
adds a deterministic +/-8 V pseudo-random binary dither to the command so that the actuator's
scale and bias can be told apart (with a constant command they are collinear in eq. 29): the
standard deviation of lambda's estimate scales with 1/std(u_c), and at +/-2 V an eta = 1.5,
lambda = 5 fault needed far more than the 10 s between the consecutive scenario's faults to be
known to a few per cent. The motor's inertia filters the 100 Hz dither to a speed ripple of
about +/-0.3 rad/s.
"""

from __future__ import annotations

import math

import numpy as np

from canfdi.firmware_sim.plants.base import Controller, NoiseDefaults, Plant

__all__ = ["DcMotor", "DcMotorParameters", "PiSpeedController"]

DT = 0.01
A_DIAG = (0.8825, 0.6839, 0.9948)
B_COL = (0.002235, 0.0823, 0.0)


class DcMotorParameters:
    """Physical parameters derived from eq. 43 (see the module docstring)."""

    def __init__(self, dt: float = DT, J: float = 0.05, M: float = 0.2) -> None:
        a_f, a_a, a_w = A_DIAG
        b_f, b_a, _ = B_COL
        self.dt = dt
        self.Rf = (1.0 - a_f) / b_f
        self.Lf = self.Rf * dt / -math.log(a_f)
        self.Ra = (1.0 - a_a) / b_a
        self.La = self.Ra * dt / -math.log(a_a)
        self.J = J
        self.D = J * -math.log(a_w) / dt
        self.M = M

    def linear_part(self) -> tuple[np.ndarray, np.ndarray]:
        """Continuous (A, B) of eq. 42 without the nonlinear terms: (3, 3), (3, 1)."""
        A = np.diag([-self.Rf / self.Lf, -self.Ra / self.La, -self.D / self.J])
        B = np.array([[1.0 / self.Lf], [1.0 / self.La], [0.0]])
        return A, B


class PiSpeedController(Controller):
    """PI speed loop on the measured omega_r (sensor 3), with feed-forward and dither.

    u_c(k) = V_ff + Kp e(k) + Ki dt sum_{j<=k} e(j) + dither(k),  e = omega_ref - z_omega
    """

    def __init__(self, params: DcMotorParameters, kp: float = 1.0, ki: float = 2.0,
                 level: float = 100.0, step: float = 10.0, step_period: float = 8.0,
                 dither: float = 8.0, v_ff: float = 0.0, v_max: float = 300.0) -> None:
        self.dt = params.dt
        self.kp, self.ki = kp, ki
        self.level, self.step, self.step_period = level, step, step_period
        self.dither = dither
        self.v_ff = v_ff
        self.v_max = v_max
        self._integral = 0.0
        self._lfsr = 0xACE1

    def reset(self) -> None:
        self._integral = 0.0
        self._lfsr = 0xACE1

    def reference(self, k: int) -> np.ndarray:
        t = k * self.dt
        half = int(t // (self.step_period / 2)) % 2
        return np.array([self.level + (self.step if half else -self.step)])

    def _prbs(self) -> float:
        # 16-bit Fibonacci LFSR (taps 16, 14, 13, 11): deterministic, period 65535 samples.
        bit = ((self._lfsr >> 0) ^ (self._lfsr >> 2) ^ (self._lfsr >> 3) ^ (self._lfsr >> 5)) & 1
        self._lfsr = (self._lfsr >> 1) | (bit << 15)
        return 1.0 if bit else -1.0

    def command(self, k: int, z: np.ndarray) -> np.ndarray:
        error = float(self.reference(k)[0] - z[3])
        self._integral += error * self.dt
        v = self.v_ff + self.kp * error + self.ki * self._integral
        if abs(v) > self.v_max:
            # Anti-windup: stop integrating while the command saturates.
            self._integral -= error * self.dt
            v = math.copysign(self.v_max, v)
        return np.array([v + self.dither * self._prbs()])


class DcMotor(Plant):
    """Chan et al. 2006's shunt-field DC motor, integrated with RK4 over substeps of each period."""

    name = "dc_motor"
    dt = DT
    state_names = ("i_f", "i_a", "omega_r")
    input_names = ("V",)
    output_names = ("i_f", "i_a", "i_f_plus_i_a", "omega_r")
    reference_names = ("omega_ref",)
    dbc = "motor_drive.dbc"
    config = "dc_motor.yaml"

    def __init__(self, params: DcMotorParameters | None = None, substeps: int = 10,
                 operating_voltage: float = 100.0) -> None:
        self.params = params or DcMotorParameters()
        self.substeps = substeps
        self.operating_voltage = operating_voltage

    def noise_defaults(self) -> NoiseDefaults:
        return NoiseDefaults(measurement=np.full(4, 0.01), process=np.zeros(3))

    def _derivative(self, i_f: float, i_a: float, w: float, v: float) -> tuple[float, ...]:
        p = self.params
        return (
            (-p.Rf * i_f + v) / p.Lf,
            (-p.Ra * i_a - p.M * i_f * w + v) / p.La,
            (p.M * i_f * i_a - p.D * w) / p.J,
        )

    def step(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        # Plain floats: this runs once per sample in Python, and numpy's per-call overhead on
        # 3-vectors would dominate.
        i_f, i_a, w = float(x[0]), float(x[1]), float(x[2])
        v = float(u[0])
        h = self.params.dt / self.substeps
        f = self._derivative
        for _ in range(self.substeps):
            k1 = f(i_f, i_a, w, v)
            k2 = f(i_f + h / 2 * k1[0], i_a + h / 2 * k1[1], w + h / 2 * k1[2], v)
            k3 = f(i_f + h / 2 * k2[0], i_a + h / 2 * k2[1], w + h / 2 * k2[2], v)
            k4 = f(i_f + h * k3[0], i_a + h * k3[1], w + h * k3[2], v)
            i_f += h / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
            i_a += h / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
            w += h / 6 * (k1[2] + 2 * k2[2] + 2 * k3[2] + k4[2])
        return np.array([i_f, i_a, w])

    def output(self, x: np.ndarray) -> np.ndarray:
        return np.array([x[0], x[1], x[0] + x[1], x[2]])

    def steady_state(self, v: float) -> np.ndarray:
        """(3,) equilibrium of eq. 42 at constant voltage v."""
        p = self.params
        i_f = v / p.Rf
        i_a = v / (p.Ra + p.M**2 * i_f**2 / p.D)
        return np.array([i_f, i_a, p.M * i_f * i_a / p.D])

    def voltage_for_speed(self, speed: float) -> float:
        """The constant voltage whose equilibrium speed is ``speed`` (bisection on [0, 300])."""
        lo, hi = 0.0, 300.0
        for _ in range(100):
            mid = (lo + hi) / 2
            lo, hi = (mid, hi) if self.steady_state(mid)[2] < speed else (lo, mid)
        return (lo + hi) / 2

    def initial_state(self) -> np.ndarray:
        return self.steady_state(self.voltage_for_speed(90.0))

    def controller(self) -> PiSpeedController:
        # Feed-forward at the mean operating point so the integrator only trims.
        return PiSpeedController(self.params, v_ff=self.voltage_for_speed(100.0))

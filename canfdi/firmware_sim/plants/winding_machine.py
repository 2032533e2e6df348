"""The three-motor winding machine of the output-error paper (Fig. 4), as linear output-error
models.

The output-error paper identifies three MISO output-error models (its eqs. 20-22), each with a unit
delay,

    T1(k)     = G_T1u1(q) q^-1 u1(k) + G_T1u2(q) q^-1 u2(k)
    Omega2(k) = G_W2u2(q) q^-1 u2(k)
    T3(k)     = G_T3u2(q) q^-1 u2(k) + G_T3u3(q) q^-1 u3(k)

but the identified transfer functions (eqs. 20-23) are lost in the extraction. We choose
plausible ones, G = B(q) / F(q) with B(q) = b0 + b1 q^-1 and F(q) = 1 + f1 q^-1 + f2 q^-2:

    pair        B(q)                F(q)                           static gain  time constant
    T1 <- u1    0.45                1 - 0.85 q^-1                   3.0         6.2 samples
    T1 <- u2    0.16                1 - 0.92 q^-1                   2.0        12.0 samples
    Om2 <- u2   0.10 + 0.05 q^-1    (1 - 0.95 q^-1)(1 - 0.7 q^-1)  10.0        19.5 + 2.8
    T3 <- u2   -0.15                1 - 0.90 q^-1                  -1.5         9.5 samples
    T3 <- u3    0.80                1 - 0.80 q^-1                   4.0         4.5 samples

Why these. The motors are torque (current) commanded: u1 is the unwinder's hold-back torque
and raises T1; u2 drives the middle reel, so it speeds up Omega2, stretches span 1 (T1 up) and
slackens span 2 (T3 down); u3 is the rewinder's pulling torque and raises T3. The speed loop
is second order (a slow mechanical pole and a faster electrical one, with the zero at -0.5 that
sampling a second-order system with a hold typically adds); the tensions follow their torques
with one dominant pole each. Every pole is distinct, so the block-diagonal realisation below
is minimal (6 states).

Sample period dt = 0.01 s: the same 10 ms bus cycle as the motor drive, and fast enough for
web-tension dynamics of a few tens of milliseconds to span 5-20 samples, which is the time
scale the paper's results imply (an actuator fault reaches the detector within about 5 samples,
k_d = 605 for k_f = 600, and the identified residual response settles within about 50 samples,
the residual being back near zero at k = 650-655).

Magnitudes follow the paper's fault sizes. The output-error paper says the u1 fault of 0.002 is 20
% of
u1(400), so the commands sit near 0.01 (normalised units): the operating point is
u_op = (0.01, 0.01, 0.01), giving T1 = 0.05, Omega2 = 0.10 and T3 = 0.025. The T1 sensor fault
of 0.0095 is then 19 % of T1, and the u1 fault moves T1 by 0.006 in steady state (0.0009 one
sample after the fault, 0.0033 five samples after). The nominal measurement noise is a standard
deviation of 1e-4 on every sensor (0.2 % of T1). On the paper's output-error residual the sensor
fault is then 95 sigma (detected on the first sample, as in the paper) and the actuator fault's
effect is 9 sigma one sample after the fault and 33 sigma five samples after. The monitor's
fully decoupled parity residuals see a constant fault much less than that (they must cancel the
slow dynamics of the other channels): `canfdi design` reports, for the paper's faults at window
order 6, about 1.7 sigma per sample for u1 and 2.7 sigma for the T1 bias, which a Page-Hinkley
test accumulates within a few samples; at the smallest admissible windows (3 and 2) it would be
ten times less, hence the windows fixed in the monitor config. There is no process noise
(the output-error paper's e(k) is measurement noise only).

Input profile: around u_op, each command carries a square wave of +/-0.001 (periods 8, 10 and
12 s, so the three inputs are not collinear) and a +/-0.0005 maximum-length PRBS held for 3
samples (9-, 10- and 11-bit sequences, so the inputs are uncorrelated). Together they excite
every pole at the range of frequencies an output-error identification needs, and every value is
a pure function of k.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import max_len_seq

from canfdi.firmware_sim.plants.base import Controller, NoiseDefaults, Plant

__all__ = [
    "CHANNELS",
    "DT",
    "MEASUREMENT_STD",
    "U_OP",
    "OeChannel",
    "WindingMachine",
    "WindingProfile",
    "realise",
]

DT = 0.01
U_OP = (0.01, 0.01, 0.01)
MEASUREMENT_STD = 1e-4


@dataclass(frozen=True)
class OeChannel:
    """One input-output pair y_j(k) += B(q) / F(q) q^-1 u_i(k) of an output-error model.

    output, input : 0-based indices j of y and i of u.
    b : (m,) numerator coefficients b0 .. b_{m-1} of B(q) = b0 + b1 q^-1 + ...
    f : (m,) denominator coefficients f1 .. f_m of F(q) = 1 + f1 q^-1 + ... (monic, so the
        leading 1 is implied).
    """

    output: int
    input: int
    b: tuple[float, ...]
    f: tuple[float, ...]

    @property
    def order(self) -> int:
        return len(self.f)

    @property
    def static_gain(self) -> float:
        """B(1) / F(1): the steady-state change of y_j per unit step of u_i."""
        return sum(self.b) / (1.0 + sum(self.f))


# (1 - 0.95 q^-1)(1 - 0.7 q^-1) = 1 - 1.65 q^-1 + 0.665 q^-2.
CHANNELS: tuple[OeChannel, ...] = (
    OeChannel(output=0, input=0, b=(0.45,), f=(-0.85,)),
    OeChannel(output=0, input=1, b=(0.16,), f=(-0.92,)),
    OeChannel(output=1, input=1, b=(0.10, 0.05), f=(-1.65, 0.665)),
    OeChannel(output=2, input=1, b=(-0.15,), f=(-0.90,)),
    OeChannel(output=2, input=2, b=(0.80,), f=(-0.80,)),
)


def realise(channels: tuple[OeChannel, ...], p: int, q: int
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Block-diagonal state-space realisation of parallel output-error channels.

    Each channel of order m gets the observable canonical block

        A_c = [[-f1, 1, 0, ...], [-f2, 0, 1, ...], ..., [-f_m, 0, ..., 0]],
        B_c = [b0, ..., b_{m-1}]^T in column ``input``,  C_c = [1, 0, ..., 0] in row ``output``,

    whose transfer function is C_c (zI - A_c)^-1 B_c = q^-1 B(q) / F(q): the unit delay comes
    out of the state update itself, so D = 0 as the plant interface requires.

    Parameters
    ----------
    channels : the pairs, in state order.
    p, q : number of inputs and outputs.

    Returns
    -------
    A : (n, n), B : (n, p), C : (q, n) with n the sum of the channel orders.
    """
    n = sum(ch.order for ch in channels)
    A, B, C = np.zeros((n, n)), np.zeros((n, p)), np.zeros((q, n))
    row = 0
    for ch in channels:
        m = ch.order
        if len(ch.b) > m:
            raise ValueError(f"channel y{ch.output}<-u{ch.input}: B(q) has {len(ch.b)} "
                             f"coefficients, more than the order {m} allows")
        block = slice(row, row + m)
        A[block, row] = -np.asarray(ch.f)
        A[row:row + m - 1, row + 1:row + m] += np.eye(m - 1)
        B[row:row + len(ch.b), ch.input] = ch.b
        C[ch.output, row] = 1.0
        row += m
    return A, B, C


class WindingProfile(Controller):
    """Open-loop commands: operating point + square waves + held maximum-length PRBS.

    u_i(k) = u_op_i + step_i * square_i(k) + prbs_i * s_i(floor(k / hold))

    with square_i(k) = +1 on the first half of each period and -1 on the second, and s_i a
    +/-1 maximum-length sequence. Stateless: the command is a pure function of k.

    Parameters
    ----------
    u_op : (3,) operating point.
    step : (3,) square-wave amplitudes; periods : (3,) their periods in samples.
    prbs : (3,) PRBS amplitudes; hold : samples each PRBS bit is held.
    prbs_bits : (3,) register lengths of the three sequences (distinct, so that they are
        mutually uncorrelated over a long run).
    """

    def __init__(self, u_op: tuple[float, ...] = U_OP,
                 step: tuple[float, ...] = (0.001, 0.001, 0.001),
                 periods: tuple[int, ...] = (800, 1000, 1200),
                 prbs: tuple[float, ...] = (0.0005, 0.0005, 0.0005), hold: int = 3,
                 prbs_bits: tuple[int, ...] = (9, 10, 11)) -> None:
        sizes = {len(u_op), len(step), len(periods), len(prbs), len(prbs_bits)}
        if sizes != {3}:
            raise ValueError("u_op, step, periods, prbs and prbs_bits need 3 values each")
        if hold < 1 or any(period < 2 for period in periods):
            raise ValueError("hold must be >= 1 and every period >= 2 samples")
        self.u_op = np.asarray(u_op, dtype=float)
        self.step = np.asarray(step, dtype=float)
        self.periods = tuple(int(period) for period in periods)
        self.prbs = np.asarray(prbs, dtype=float)
        self.hold = int(hold)
        # max_len_seq with its default all-ones initial register is deterministic.
        self._sequences = [2.0 * max_len_seq(bits)[0].astype(float) - 1.0 for bits in prbs_bits]

    def reset(self) -> None:
        """Nothing to reset: the profile has no state."""

    def command(self, k: int, z: np.ndarray) -> np.ndarray:
        """(3,) commands u_c(k); ``z`` is ignored (open loop)."""
        u = self.u_op.copy()
        for i, (period, seq) in enumerate(zip(self.periods, self._sequences, strict=True)):
            square = 1.0 if (k % period) < period // 2 else -1.0
            u[i] += self.step[i] * square + self.prbs[i] * seq[(k // self.hold) % seq.size]
        return u


class WindingMachine(Plant):
    """The output-error paper's winding machine: the linear block-diagonal realisation of
    `CHANNELS`.

    x(k+1) = A x(k) + B u(k),  y(k) = C x(k), exactly the model of
    deploy/config/winding_machine.yaml.
    """

    name = "winding_machine"
    dt = DT
    state_names = ("x_T1_u1", "x_T1_u2", "x_Omega2_u2_1", "x_Omega2_u2_2", "x_T3_u2", "x_T3_u3")
    input_names = ("u1", "u2", "u3")
    output_names = ("T1", "Omega2", "T3")
    dbc = "winding_machine.dbc"
    config = "winding_machine.yaml"

    def __init__(self, channels: tuple[OeChannel, ...] = CHANNELS,
                 u_op: tuple[float, ...] = U_OP,
                 measurement_std: float = MEASUREMENT_STD) -> None:
        self.channels = channels
        self.A, self.B, self.C = realise(channels, self.p, self.q)
        if self.A.shape[0] != self.n:
            raise ValueError(f"the channels realise {self.A.shape[0]} states, the plant names "
                             f"{self.n}")
        self.u_op = np.asarray(u_op, dtype=float)
        self.measurement_std = measurement_std
        for M in (self.A, self.B, self.C):
            M.setflags(write=False)

    def noise_defaults(self) -> NoiseDefaults:
        return NoiseDefaults(measurement=np.full(self.q, self.measurement_std),
                             process=np.zeros(self.n))

    def steady_state(self, u: np.ndarray) -> np.ndarray:
        """(n,) equilibrium x = (I - A)^-1 B u for a constant (p,) input u."""
        return np.linalg.solve(np.eye(self.n) - self.A, self.B @ np.asarray(u, dtype=float))

    def static_gains(self) -> np.ndarray:
        """(q, p) steady-state gains C (I - A)^-1 B (one entry per `OeChannel`, else 0)."""
        return self.C @ np.linalg.solve(np.eye(self.n) - self.A, self.B)

    def initial_state(self) -> np.ndarray:
        return self.steady_state(self.u_op)

    def step(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        return self.A @ x + self.B @ u

    def output(self, x: np.ndarray) -> np.ndarray:
        return self.C @ x

    def controller(self) -> WindingProfile:
        return WindingProfile(u_op=tuple(self.u_op))

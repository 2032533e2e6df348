"""Many independent fault-free closed-loop runs of the DC motor at once, vectorised across runs.

`Simulator.advance` runs one closed loop sample by sample in Python (about 50 µs a sample): a
10^7-sample soak would take ten minutes there. The loop is sequential in time but the runs are
independent, so here every state of every run is a (K,) array and each numpy operation advances
all K runs: only time is a Python loop. The arithmetic is `DcMotor.step`,
`PiSpeedController.command` and `Simulator.advance`'s, written operation for operation in the
same order, so a single run equals `Simulator.advance` to the last bit or so (tested).

What makes the runs differ:

- noise: run i draws from its own generator, ``default_rng(SeedSequence(seed).spawn(K)[i])``
  (child i does not depend on K). Child 0 is the generator `Simulator` uses for a scenario with
  the same seed, and per chunk each run draws one (N, q [+ n]) block, which is the same stream
  in the same order as `Simulator`'s q measurement [then n process] draws per sample. So run 0
  is the scenario's own run, and any run i can be replayed alone (``noise_seeds=[child i]``).
- dither: the PI loop's PRBS comes from a 16-bit LFSR of period 65535 started at 0xACE1. Run i
  starts at offset ``i * 65535 // K`` in that sequence (run 0 at offset 0: the controller's own
  start), so the runs' dithers are shifted copies that do not line up (while K <= 65535).

All runs start at the plant's initial state, with the controller reset, at k = 0: the
reference steps (every step_period / 2) fall on the same samples in every run.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from canfdi.firmware_sim.plants.dc_motor import DcMotor, PiSpeedController
from canfdi.firmware_sim.scenario import Scenario

__all__ = ["PRBS_PERIOD", "PRBS_START", "DcMotorEnsemble", "EnsembleChunk", "prbs_sequence"]

PRBS_PERIOD = 65535
PRBS_START = 0xACE1  # PiSpeedController's initial LFSR state


def prbs_sequence(start: int = PRBS_START, length: int = PRBS_PERIOD) -> np.ndarray:
    """(length,) the +/-1 values PiSpeedController's LFSR gives from state ``start``.

    The same 16-bit Fibonacci LFSR (taps 16, 14, 13, 11) as ``PiSpeedController._prbs``,
    stepped in Python once: the ensemble then looks its dither up by index.
    """
    if not 0 < start < 1 << 16:
        raise ValueError(f"start: a nonzero 16-bit LFSR state, got {start!r}")
    out = np.empty(length)
    state = start
    for i in range(length):
        bit = ((state >> 0) ^ (state >> 2) ^ (state >> 3) ^ (state >> 5)) & 1
        state = (state >> 1) | (bit << 15)
        out[i] = 1.0 if bit else -1.0
    return out


@dataclass(frozen=True)
class EnsembleChunk:
    """Samples k0 .. k0+N-1 of K runs.

    k : (N,) sample indices (the same for every run); x : (K, N, n) states at k;
    z : (K, N, q) measured outputs (noise included, no fault); u_c : (K, N, p) commands.
    """

    k: np.ndarray
    x: np.ndarray
    z: np.ndarray
    u_c: np.ndarray

    @property
    def runs(self) -> int:
        return self.z.shape[0]

    def __len__(self) -> int:
        return len(self.k)


class DcMotorEnsemble:
    """K fault-free closed loops of the DC motor, advanced together on demand.

    Parameters
    ----------
    runs : K.
    seed : master seed; run i's noise generator is ``SeedSequence(seed).spawn(K)[i]``.
    measurement_std : (q,) measurement noise standard deviations (a scenario's).
    process_std : (n,) process noise standard deviations, added to x(k+1); zeros: none drawn.
    plant : the plant (parameters, substeps, controller settings); default DcMotor().
    noise_seeds : (K,) SeedSequences overriding ``seed`` (to replay chosen runs).
    dither_offsets : (K,) offsets of each run's start in the 65535-sample PRBS sequence
        (default ``i * 65535 // K``).
    """

    def __init__(self, runs: int, seed: int = 0, *, measurement_std: np.ndarray,
                 process_std: np.ndarray | None = None, plant: DcMotor | None = None,
                 noise_seeds: Sequence[np.random.SeedSequence] | None = None,
                 dither_offsets: Sequence[int] | np.ndarray | None = None) -> None:
        if runs < 1:
            raise ValueError(f"runs: at least 1, got {runs}")
        self.plant = plant or DcMotor()
        self.runs = runs
        n, q = self.plant.n, self.plant.q
        self.measurement_std = _vector(measurement_std, q, "measurement_std")
        self.process_std = _vector(np.zeros(n) if process_std is None else process_std, n,
                                   "process_std")
        self._has_process = bool(np.any(self.process_std))
        if noise_seeds is None:
            noise_seeds = np.random.SeedSequence(seed).spawn(runs)
        if len(noise_seeds) != runs:
            raise ValueError(f"noise_seeds: {runs} expected, got {len(noise_seeds)}")
        self._rngs = [np.random.default_rng(s) for s in noise_seeds]
        if dither_offsets is None:
            dither_offsets = np.arange(runs, dtype=np.int64) * PRBS_PERIOD // runs
        offsets = np.asarray(dither_offsets, dtype=np.int64)
        if offsets.shape != (runs,):
            raise ValueError(f"dither_offsets: shape ({runs},) expected, got {offsets.shape}")
        self.dither_offsets = offsets % PRBS_PERIOD
        # The settings of the controller the plant would build, read once; the integrators
        # (one per run) live here.
        self._ctrl: PiSpeedController = self.plant.controller()
        self._prbs = prbs_sequence(PRBS_START) * self._ctrl.dither
        x0 = self.plant.initial_state()
        self._x = [np.full(runs, float(v)) for v in x0]  # n arrays of (K,)
        self._integral = np.zeros(runs)
        self.k = 0

    @classmethod
    def from_scenario(cls, scenario: Scenario, runs: int, seed: int | None = None,
                      **kwargs) -> DcMotorEnsemble:
        """K runs of a fault-free dc_motor scenario: its noise, and its seed unless given."""
        if scenario.plant != "dc_motor":
            raise ValueError(f"plant: the ensemble emulates dc_motor, not {scenario.plant!r}")
        if scenario.faults:
            raise ValueError(f"faults: the ensemble runs fault-free, the scenario has "
                             f"{len(scenario.faults)}")
        return cls(runs, scenario.seed if seed is None else seed,
                   measurement_std=scenario.measurement_std, process_std=scenario.process_std,
                   **kwargs)

    def _draw(self, count: int) -> tuple[np.ndarray, np.ndarray | None]:
        """(K, count, q) scaled measurement noise and (K, count, n) process noise or None.

        One (count, q [+ n]) block per run: row-major, it is exactly the q [then n] draws
        per sample that `Simulator.advance` makes, in its order.
        """
        q, n = self.plant.q, self.plant.n
        width = q + (n if self._has_process else 0)
        raw = np.stack([rng.standard_normal((count, width)) for rng in self._rngs])
        meas = self.measurement_std * raw[:, :, :q]
        proc = self.process_std * raw[:, :, q:] if self._has_process else None
        return meas, proc

    def advance(self, count: int) -> EnsembleChunk:
        """Run ``count`` more samples of every run; chunked runs equal one long run."""
        K, T = self.runs, count
        plant, ctrl = self.plant, self._ctrl
        p = plant.params
        dt, h = p.dt, p.dt / plant.substeps
        ks = np.arange(self.k, self.k + T)
        meas, proc = self._draw(T)
        # The reference is the same in every run: the controller's own function, per sample.
        ref = [float(ctrl.reference(int(k))[0]) for k in ks]
        dither = self._prbs[(self.dither_offsets[:, None] + ks[None, :]) % PRBS_PERIOD]
        xs = np.empty((K, T, plant.n))
        zs = np.empty((K, T, plant.q))
        ucs = np.empty((K, T, plant.p))
        i_f, i_a, w = self._x
        integral = self._integral
        for i in range(T):
            xs[:, i, 0], xs[:, i, 1], xs[:, i, 2] = i_f, i_a, w
            # y = output(x) + noise; no fault, so z = y.
            zs[:, i, 0] = i_f + meas[:, i, 0]
            zs[:, i, 1] = i_a + meas[:, i, 1]
            zs[:, i, 2] = (i_f + i_a) + meas[:, i, 2]
            z_w = w + meas[:, i, 3]
            zs[:, i, 3] = z_w
            # PiSpeedController.command, with its anti-windup, for every run.
            error = ref[i] - z_w
            integral = integral + error * dt
            v = ctrl.v_ff + ctrl.kp * error + ctrl.ki * integral
            sat = np.abs(v) > ctrl.v_max
            if sat.any():
                integral = np.where(sat, integral - error * dt, integral)
                v = np.where(sat, np.copysign(ctrl.v_max, v), v)
            u = v + dither[:, i]
            ucs[:, i, 0] = u
            i_f, i_a, w = _rk4(p, i_f, i_a, w, u, h, plant.substeps)
            if proc is not None:
                i_f = i_f + proc[:, i, 0]
                i_a = i_a + proc[:, i, 1]
                w = w + proc[:, i, 2]
        self._x = [i_f, i_a, w]
        self._integral = integral
        self.k += T
        return EnsembleChunk(k=ks, x=xs, z=zs, u_c=ucs)


def _rk4(p, i_f: np.ndarray, i_a: np.ndarray, w: np.ndarray, v: np.ndarray, h: float,
         substeps: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """DcMotor.step on (K,) arrays: the same expressions in the same order, so the same bits."""
    Rf, Lf, Ra, La, M, D, J = p.Rf, p.Lf, p.Ra, p.La, p.M, p.D, p.J

    def f(i_f, i_a, w):
        return ((-Rf * i_f + v) / Lf,
                (-Ra * i_a - M * i_f * w + v) / La,
                (M * i_f * i_a - D * w) / J)

    h2, h6 = h / 2, h / 6
    for _ in range(substeps):
        k1 = f(i_f, i_a, w)
        k2 = f(i_f + h2 * k1[0], i_a + h2 * k1[1], w + h2 * k1[2])
        k3 = f(i_f + h2 * k2[0], i_a + h2 * k2[1], w + h2 * k2[2])
        k4 = f(i_f + h * k3[0], i_a + h * k3[1], w + h * k3[2])
        i_f = i_f + h6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
        i_a = i_a + h6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
        w = w + h6 * (k1[2] + 2 * k2[2] + 2 * k3[2] + k4[2])
    return i_f, i_a, w


def _vector(value, size: int, name: str) -> np.ndarray:
    arr = np.broadcast_to(np.asarray(value, dtype=float), (size,)).copy()
    if not np.all(np.isfinite(arr)) or np.any(arr < 0):
        raise ValueError(f"{name}: finite standard deviations >= 0 expected")
    return arr


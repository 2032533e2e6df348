"""Run a scenario to numpy arrays, with no bus: batch mode, and the emitter's data source.

At sample k: y(k) = output(x(k)) + xi(k); z(k) = sensor faults on y(k); u_c(k) = controller
on z(k); u(k) = actuator faults on u_c(k); x(k+1) = step(x(k), u(k)) + varsigma(k).
The closed loop makes this sequential; ``Simulator.advance`` runs any number of samples and
chunked runs equal one long run (same random draws, in the same order).
"""

from __future__ import annotations

import numpy as np

from canfdi.firmware_sim.chunk import SimChunk
from canfdi.firmware_sim.faults import FaultInjector, onset_sample
from canfdi.firmware_sim.plants import Plant
from canfdi.firmware_sim.scenario import Scenario

__all__ = ["Simulator", "simulate"]


class Simulator:
    """A scenario's closed loop, advanced on demand (one drive: a scenario with several
    drives runs each through ``scenario.drive_scenario(i)``)."""

    def __init__(self, scenario: Scenario, plant: Plant | None = None) -> None:
        if len(scenario.drives) != 1:
            raise ValueError(f"scenario {scenario.name} has {len(scenario.drives)} drives: "
                             "simulate each one, scenario.drive_scenario(i)")
        self.scenario = scenario
        self.plant = plant or scenario.make_plant()
        seeds = np.random.SeedSequence(scenario.seed).spawn(2)
        self._noise_rng = np.random.default_rng(seeds[0])
        self.injector = FaultInjector(list(scenario.faults), self.plant.dt,
                                      np.random.default_rng(seeds[1]))
        self.controller = self.plant.controller()
        self._x = self.plant.initial_state()
        self.k = 0

    @property
    def total_samples(self) -> int:
        """Samples in the scenario's duration."""
        return onset_sample(self.scenario.duration, self.plant.dt)

    def truth(self) -> list[dict]:
        """The injected faults, JSON-ready."""
        names = {"actuator": self.plant.input_names, "sensor": self.plant.output_names}
        return [f.truth(self.plant.dt, names[f.target]) for f in self.scenario.faults]

    def advance(self, count: int) -> SimChunk:
        """Run ``count`` more samples."""
        plant, meas, proc = self.plant, self.scenario.measurement_std, self.scenario.process_std
        n_ref = len(plant.reference_names)
        xs = np.empty((count, plant.n))
        ys, zs = np.empty((count, plant.q)), np.empty((count, plant.q))
        ucs, us = np.empty((count, plant.p)), np.empty((count, plant.p))
        refs = np.empty((count, n_ref))
        has_proc = bool(np.any(proc))
        x = self._x
        for i in range(count):
            k = self.k + i
            y = plant.output(x) + meas * self._noise_rng.standard_normal(plant.q)
            z = self.injector.sensors(k, y)
            u_c = self.controller.command(k, z)
            u = self.injector.actuators(k, u_c)
            xs[i], ys[i], zs[i], ucs[i], us[i] = x, y, z, u_c, u
            refs[i] = self.controller.reference(k) if n_ref else ()
            x = plant.step(x, u)
            if has_proc:
                x = x + proc * self._noise_rng.standard_normal(plant.n)
        ks = np.arange(self.k, self.k + count)
        self._x = x
        self.k += count
        return SimChunk(k=ks, t=ks * plant.dt, x=xs, y=ys, z=zs, u_c=ucs, u=us, ref=refs,
                        truth=self.truth())


def simulate(scenario: Scenario, duration: float | None = None) -> SimChunk:
    """The whole scenario (or its first ``duration`` seconds) as arrays."""
    sim = Simulator(scenario)
    total = sim.total_samples if duration is None else onset_sample(duration, sim.plant.dt)
    return sim.advance(total)

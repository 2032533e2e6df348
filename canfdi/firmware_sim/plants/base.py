"""What every emulated plant provides: pure step functions and a controller, no bus.

A plant is simulated one control period at a time. At sample k the firmware

1. measures y(k) = output(x(k)) (sensor faults and measurement noise are added outside),
2. computes the command u_c(k) = controller.command(k, z(k)) from the measured z(k),
3. applies u(k) (actuator faults are applied outside) held over [k dt, (k+1) dt),
4. advances x(k+1) = step(x(k), u(k), w) (process noise is added outside).

So u(k) reaches y(k+1) at the earliest: the monitor's model has no feedthrough (D = 0).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np

__all__ = ["Controller", "NoiseDefaults", "Plant", "PlantOptionError"]


class PlantOptionError(ValueError):
    """A plant option that the plant does not take, or a bad value; ``option`` names it.

    Examples
    --------
    >>> error = PlantOptionError("load", "must be true or false, got 2")
    >>> error.option, str(error), isinstance(error, ValueError)
    ('load', 'load: must be true or false, got 2', True)
    """

    def __init__(self, option: str, message: str) -> None:
        super().__init__(f"{option}: {message}")
        self.option = option


@dataclass(frozen=True)
class NoiseDefaults:
    """Default noise standard deviations of a plant.

    measurement : (q,) per sensor; process : (n,) per state, added to x(k+1).
    """

    measurement: np.ndarray
    process: np.ndarray


class Controller(ABC):
    """Computes the command u_c(k) from the measurements; may keep state (an integrator)."""

    @abstractmethod
    def reset(self) -> None:
        """Back to the initial controller state."""

    @abstractmethod
    def command(self, k: int, z: np.ndarray) -> np.ndarray:
        """Command for sample k.

        Parameters
        ----------
        k : sample index (time k * dt).
        z : (q,) measured outputs at sample k (faults and noise included).

        Returns
        -------
        (p,) commanded inputs u_c(k).
        """

    def reference(self, k: int) -> np.ndarray:
        """(len(reference_names),) reference values at sample k, published with the command."""
        return np.zeros(0)


class Plant(ABC):
    """A plant of the papers, emulated.

    Class attributes
    ----------------
    name : the scenario's ``plant:`` key (dc_motor, winding_machine, vtol, servo_axis).
    dt : control period in seconds.
    state_names, input_names, output_names : names of x, u and y; input and output names are
        the DBC signal names of the commands and measurements.
    reference_names : DBC signal names of the controller's references (may be empty).
    dbc : file name in dbc/ that describes this plant's bus (canfdi's own bus profile), or None
        when the plant does not speak that bus (its scenarios name another ``bus.profile``).
    config : file name in deploy/config/ of the monitor config for this plant.
    """

    name: str
    dt: float
    state_names: tuple[str, ...]
    input_names: tuple[str, ...]
    output_names: tuple[str, ...]
    reference_names: tuple[str, ...] = ()
    dbc: str | None
    config: str

    @property
    def n(self) -> int:
        return len(self.state_names)

    @property
    def p(self) -> int:
        return len(self.input_names)

    @property
    def q(self) -> int:
        return len(self.output_names)

    @abstractmethod
    def noise_defaults(self) -> NoiseDefaults:
        """The plant's nominal noise levels."""

    @abstractmethod
    def initial_state(self) -> np.ndarray:
        """(n,) state at k = 0 (the steady state of the initial operating point)."""

    @abstractmethod
    def step(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Advance one control period with u held (zero-order hold); noise-free.

        Parameters
        ----------
        x : (n,) state at k; u : (p,) applied input over the period.

        Returns
        -------
        (n,) state at k + 1.
        """

    @abstractmethod
    def output(self, x: np.ndarray) -> np.ndarray:
        """(q,) noise-free outputs y = g(x)."""

    @abstractmethod
    def controller(self) -> Controller:
        """A fresh controller (closed loop) or open-loop input profile for this plant."""

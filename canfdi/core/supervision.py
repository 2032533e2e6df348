"""A method's diagnoser as the monitor runs it: a `Supervisor` (canfdi.core.protocol) that
passes everything through and says the drive's state from the diagnoser's mode.

The monitor's other supervisors derive from it and change what they run around the method's
diagnoser: the noise watchdog (canfdi.core.watched) wraps it, teach-in (canfdi.core.teachin)
stands in for it until it has learned.
"""

from __future__ import annotations

import numpy as np

from canfdi.core.protocol import Diagnoser, diagnosis_state
from canfdi.core.records import BlockResult, Compensation, FaultEvent, Sample

__all__ = ["Supervision"]


class Supervision:
    """A diagnoser run as it is: every call and attribute its ``inner``'s; the state
    "diagnosing" while it diagnoses, "monitoring" otherwise.

    Parameters
    ----------
    inner : the diagnoser to run (a method's, or another supervisor).

    Examples
    --------
    >>> from canfdi.core.protocol import Supervisor
    >>> class Quiet:  # the least a Diagnoser is
    ...     mode, compensation, events = "monitor", [], []
    ...     last_residuals = last_normalized = None
    ...     residual_names, thresholds, statistics = ["r"], np.ones(1), np.zeros(1)
    ...     noise_scale = 1.0
    ...     def update(self, sample): return []
    ...     def update_block(self, k, t_ns, U, Z, gap=None): ...
    ...     def reset(self): pass
    >>> run = Supervision(Quiet())
    >>> isinstance(run, Supervisor), run.state, run.residual_names
    (True, 'monitoring', ['r'])
    """

    def __init__(self, inner: Diagnoser) -> None:
        self._inner = inner

    # -- what the monitor asks of a supervisor ---------------------------------------------
    @property
    def state(self) -> str:
        """"diagnosing" while the diagnoser diagnoses a detected change ("named" once it named
        the fault: protocol.diagnosis_state), else "monitoring"."""
        return diagnosis_state(self._inner) or "monitoring"

    @property
    def diagnoser(self) -> Diagnoser:
        """The method's diagnoser run."""
        return self._inner

    # -- the Diagnoser protocol, passed through --------------------------------------------
    @property
    def mode(self) -> str:
        return self._inner.mode

    @property
    def compensation(self) -> list[Compensation]:
        return self._inner.compensation

    @property
    def events(self) -> list[FaultEvent]:
        return self._inner.events

    @property
    def last_residuals(self) -> np.ndarray | None:
        return self._inner.last_residuals

    @property
    def last_normalized(self) -> np.ndarray | None:
        return self._inner.last_normalized

    @property
    def residual_names(self) -> list[str]:
        return self._inner.residual_names

    @property
    def thresholds(self) -> np.ndarray:
        return self._inner.thresholds

    @thresholds.setter
    def thresholds(self, value: np.ndarray) -> None:
        self._inner.thresholds = value

    @property
    def statistics(self) -> np.ndarray:
        return self._inner.statistics

    @property
    def noise_scale(self) -> np.ndarray:
        return self._inner.noise_scale

    @noise_scale.setter
    def noise_scale(self, value: np.ndarray | float) -> None:
        self._inner.noise_scale = value

    def update(self, sample: Sample) -> list[FaultEvent]:
        return self._inner.update(sample)

    def update_block(self, k: np.ndarray, t_ns: np.ndarray, U: np.ndarray, Z: np.ndarray,
                     gap: np.ndarray | None = None) -> BlockResult:
        return self._inner.update_block(k, t_ns, U, Z, gap)

    def reset(self) -> None:
        self._inner.reset()

"""The Diagnoser protocol: what the monitor, the tools and the conformance suite need of a
diagnosis method.

Every method of canfdi.methods builds an object of this shape from a config; the monitor drives
it live one sample at a time (`update`) or a block at a time (`update_block`), replay and the
tools a block at a time. tests/methods/ checks every registered method against it: the block
path gives exactly the streaming path's results chunk by chunk (lost samples included), `reset`
restores the first run exactly, events are well formed, a bad option is named.

Residual arrays are (m,) in `residual_names` order, normalised by each residual's noise
standard deviation (times `noise_scale`, which the noise watchdog widens); `statistics` are the
method's detection statistics in the units of `thresholds` (a residual alarms when its
statistic reaches its threshold). Events follow the FaultEvent contract
(canfdi.core.records): kinds "detected", "accepted", "unexplained"; estimates "eta"/"lambda"
for actuators, "bias" for sensors.

The monitor runs a method's diagnoser inside a `Supervisor` (canfdi.core.supervision): a
diagnoser itself, which also says the drive's state (FDI_STATUS) and which method diagnoser it
runs: the noise watchdog wraps one, teach-in stands in for one until it has learned.
"""

from __future__ import annotations

import copy
from typing import Any, Protocol, runtime_checkable

import numpy as np

from canfdi.core.records import BlockResult, Compensation, FaultEvent, Sample

__all__ = ["DIAGNOSE", "MODES", "MONITOR", "STATES", "Diagnoser", "Supervisor", "deepcopy_sharing",
           "diagnosis_state"]

MONITOR, DIAGNOSE = "monitor", "diagnose"
MODES = (MONITOR, DIAGNOSE)
"""`Diagnoser.mode`: watching for a change, or diagnosing one that was detected."""

STATES = ("monitoring", "diagnosing", "named", "teaching", "checking", "mismatch", "quiet")
"""`Supervisor.state`: what a drive's diagnosis is doing (FDI_STATUS's State names)."""


def diagnosis_state(diagnoser: Any) -> str | None:
    """"named" while a diagnosis has named its fault and waits to identify it (a diagnoser
    that names, such as the parity method's, says so by a true ``named``), "diagnosing" while
    it diagnoses, None while it monitors.

    >>> class Busy:
    ...     mode, named = DIAGNOSE, True
    >>> diagnosis_state(Busy()), Busy.__name__
    ('named', 'Busy')
    """
    if diagnoser.mode != DIAGNOSE:
        return None
    return "named" if getattr(diagnoser, "named", False) else "diagnosing"


@runtime_checkable
class Diagnoser(Protocol):
    """A streaming diagnoser: ``update(sample) -> events``, with a block form that agrees.

    Attributes
    ----------
    mode : str
        `MONITOR` or `DIAGNOSE`.
    compensation : sequence of Compensation
        The accepted faults folded into the data, oldest first.
    events : list of FaultEvent
        Every event since construction or the last `reset`.
    last_residuals, last_normalized : (m,) ndarray or None
        The latest sample's raw and normalised residuals (None when it gave none).

    Examples
    --------
    The protocol is structural and checkable at run time: a class with these members is a
    Diagnoser, whatever it derives from (the methods' are in canfdi.methods).

    >>> from canfdi.core.records import BlockResult
    >>> class Silent:  # residuals = the measurements; never alarms
    ...     mode, compensation, events = MONITOR, [], []
    ...     last_residuals = last_normalized = None
    ...     residual_names, thresholds, statistics = ["r"], np.ones(1), np.zeros(1)
    ...     noise_scale = 1.0
    ...     def update(self, sample): return []
    ...     def update_block(self, k, t_ns, U, Z, gap=None):
    ...         return BlockResult([], Z, Z, np.zeros_like(Z))
    ...     def reset(self): pass
    >>> isinstance(Silent(), Diagnoser), isinstance(object(), Diagnoser)
    (True, False)
    >>> Silent().update_block(np.arange(2), np.zeros(2), np.zeros((2, 0)), np.ones((2, 1))).events
    []
    """

    mode: str
    compensation: list[Compensation]
    events: list[FaultEvent]
    last_residuals: np.ndarray | None
    last_normalized: np.ndarray | None

    @property
    def residual_names(self) -> list[str]:
        """(m,) residual names, e.g. ``"a:V"``, ``"oe:T1"``."""
        ...

    @property
    def thresholds(self) -> np.ndarray:
        """(m,) alarm thresholds on `statistics` (settable, e.g. scaled by a sensitivity
        check)."""
        ...

    @thresholds.setter
    def thresholds(self, value: np.ndarray) -> None: ...

    @property
    def statistics(self) -> np.ndarray:
        """(m,) the detection statistic of each residual after the latest sample."""
        ...

    @property
    def noise_scale(self) -> np.ndarray:
        """(m,) each residual's noise over its configured value, what detection normalises
        with (ones as built or reset; settable to (m,) or a scalar: the noise watchdog widens
        it where the noise rose). The normalised residuals times this are the residuals
        against the configured noise."""
        ...

    @noise_scale.setter
    def noise_scale(self, value: np.ndarray | float) -> None: ...

    def update(self, sample: Sample) -> list[FaultEvent]:
        """Process one sample; returns the events it caused (usually none)."""
        ...

    def update_block(self, k: np.ndarray, t_ns: np.ndarray, U: np.ndarray, Z: np.ndarray,
                     gap: np.ndarray | None = None) -> BlockResult:
        """Process N samples at once: the same events and state as N calls of `update`.

        k, t_ns : (N,) increasing sample indices and timestamps; U : (N, p) commands; Z : (N, q)
        measurements, NaN where a value was lost; gap : (N,) samples missing before each
        (informational: the indices say it).
        """
        ...

    def reset(self) -> None:
        """Back to the state after construction: monitoring, no compensation, no events, empty
        windows."""
        ...


@runtime_checkable
class Supervisor(Diagnoser, Protocol):
    """A diagnoser that runs a method's diagnoser for the monitor (wrapping it, or standing in
    for it) and says what the drive is doing.

    Attributes
    ----------
    state : str
        One of `STATES`.
    diagnoser : Diagnoser
        The method's diagnoser it runs now (its design, its isolations: what the tools read).

    Examples
    --------
    canfdi.core.supervision.Supervision runs a method's diagnoser as it is; the monitor reads
    the drive's state from it.

    >>> from canfdi.core.supervision import Supervision
    >>> class Silent:
    ...     mode, compensation, events = MONITOR, [], []
    ...     last_residuals = last_normalized = None
    ...     residual_names, thresholds, statistics = ["r"], np.ones(1), np.zeros(1)
    ...     noise_scale = 1.0
    ...     def update(self, sample): return []
    ...     def update_block(self, k, t_ns, U, Z, gap=None): ...
    ...     def reset(self): pass
    >>> method = Silent()
    >>> run = Supervision(method)
    >>> isinstance(run, Supervisor), run.state in STATES, run.diagnoser is method
    (True, True, True)
    """

    @property
    def state(self) -> str:
        """What the drive's diagnosis is doing, one of `STATES`."""
        ...

    @property
    def diagnoser(self) -> Diagnoser:
        """The method's diagnoser it runs now."""
        ...


def deepcopy_sharing(obj: Any, memo: dict[int, Any], *shared: object) -> Any:
    """A deep copy of ``obj`` whose ``shared`` parts are the original's, for a diagnoser's
    ``__deepcopy__``: its design or models never change once built, and the noise watchdog's
    undo (canfdi.core.watched) copies the diagnoser on every block it runs at once.

    Examples
    --------
    >>> class Run:
    ...     def __init__(self): self.design, self.state = np.eye(2), np.zeros(2)
    ...     def __deepcopy__(self, memo): return deepcopy_sharing(self, memo, self.design)
    >>> a = Run()
    >>> b = copy.deepcopy(a)
    >>> b.design is a.design, b.state is a.state
    (True, False)
    """
    for part in shared:
        memo[id(part)] = part
    new = object.__new__(type(obj))
    memo[id(obj)] = new
    new.__dict__.update({name: copy.deepcopy(value, memo) for name, value in vars(obj).items()})
    return new

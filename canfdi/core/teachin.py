"""Teach-in (`canfdi run --teach`): a diagnoser that stands in for the drive's until it has
learned the drive's noise from its first samples, then hands over to the diagnoser learned.

While teaching (state "teaching") it records the samples and diagnoses nothing; the `Teacher`
(canfdi.tools.calibrate.Teach) learns from them, and the diagnoser it returns runs from the next
sample on. When the samples cannot be learned from (too few, a fault in them) the drive is
diagnosed as configured. Either way the learned values (or the reason) go to ``on_learned`` (the
monitor writes them to the log's metadata) and an event says it: "taught" (estimates: each
sensor's noise std learned) or "teach_failed" (the reason as its candidate).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from typing import Protocol, runtime_checkable

import numpy as np

from canfdi.core.protocol import Diagnoser, Supervisor
from canfdi.core.records import BlockResult, FaultEvent, Sample
from canfdi.core.supervision import Supervision

__all__ = ["TeachIn", "Teacher"]


@runtime_checkable
class Teacher(Protocol):
    """How many samples to learn from, and how (canfdi.tools.calibrate.Teach fits).
    ``learn`` returns the diagnoser built on what it learned and the learned values as strings
    (``"status": "learned"``, ``"noise_json"``: [{"sensor", "std"}], ...); it raises ValueError
    when the samples cannot be learned from.

    Examples
    --------
    A teacher that takes the measurements' std as the noise (the diagnoser it returns is the
    one it was given; canfdi.tools.calibrate.Teach builds one on the noise learned):

    >>> class StdTeacher:
    ...     samples = 100
    ...     def __init__(self, diagnoser): self.diagnoser = diagnoser
    ...     def learn(self, k, U, Z):
    ...         if len(k) < self.samples:
    ...             raise ValueError(f"{len(k)} samples, {self.samples} needed")
    ...         return self.diagnoser, {"status": "learned", "std": f"{Z.std():.2f}"}
    >>> teacher = StdTeacher(diagnoser=None)
    >>> isinstance(teacher, Teacher)
    True
    >>> Z = np.random.default_rng(4).normal(0.0, 0.5, (100, 1))
    >>> teacher.learn(np.arange(100), np.zeros((100, 0)), Z)[1]
    {'status': 'learned', 'std': '0.51'}
    """

    samples: int

    def learn(self, k: np.ndarray, U: np.ndarray, Z: np.ndarray
              ) -> tuple[Diagnoser, dict[str, str]]: ...


class TeachIn(Supervision):
    """A stand-in diagnoser: the first ``teacher.samples`` samples are recorded, not diagnosed;
    then ``then(learned diagnoser)`` (``then(configured)`` when learning failed) diagnoses.

    Parameters
    ----------
    configured : the diagnoser built from the config (its residual names and thresholds are
        what the drive has until it has learned).
    teacher : what learns (`Teacher`).
    then : how a diagnoser is run once it has learned (the monitor's supervisor for it, e.g.
        the noise watchdog without a check: the noise was just learned).
    on_learned : called once with the learned values (or {"status": "failed", "reason", ...}).

    Examples
    --------
    >>> class Echo:  # a diagnoser whose thresholds say what it was built on
    ...     mode, compensation, events = "monitor", [], []
    ...     last_residuals = last_normalized = None
    ...     residual_names, statistics, noise_scale = ["r"], np.zeros(1), 1.0
    ...     def __init__(self, h): self.thresholds = np.array([h])
    ...     def update(self, sample): return []
    ...     def update_block(self, k, t_ns, U, Z, gap=None):
    ...         return BlockResult([], Z, Z, np.zeros_like(Z))
    ...     def reset(self): pass
    >>> class Learn:
    ...     samples = 3
    ...     def learn(self, k, U, Z):
    ...         noise = '[{"sensor": "z", "std": 0.5}]'
    ...         return Echo(9.0), {"status": "learned", "noise_json": noise}
    >>> said = []
    >>> teach = TeachIn(Echo(5.0), Learn(), then=Supervision, on_learned=said.append)
    >>> teach.state, teach.thresholds.tolist()
    ('teaching', [5.0])
    >>> k = np.arange(5)
    >>> result = teach.update_block(k, k, np.zeros((5, 1)), np.ones((5, 1)))
    >>> [(e.kind, e.sample, e.estimates) for e in result.events], result.residuals[:, 0].tolist()
    ([('taught', 2, {'z': 0.5})], [nan, nan, nan, 1.0, 1.0])
    >>> teach.state, teach.thresholds.tolist(), said[0]["status"]
    ('monitoring', [9.0], 'learned')
    """

    def __init__(self, configured: Diagnoser, teacher: Teacher,
                 then: Callable[[Diagnoser], Supervisor],
                 on_learned: Callable[[dict[str, str]], None] | None = None) -> None:
        self.configured = configured
        self.teacher = teacher
        self.then = then
        self.on_learned = on_learned
        super().__init__(then(configured))
        self._start()

    def _start(self) -> None:
        self._rows: list[tuple[np.ndarray, np.ndarray, np.ndarray]] | None = []
        self._said: list[FaultEvent] = []

    def reset(self) -> None:
        """Teaching again, the configured diagnoser standing by."""
        self.configured.reset()
        self._inner = self.then(self.configured)
        self._start()

    @property
    def teaching(self) -> bool:
        """Whether it is still recording samples to learn from."""
        return self._rows is not None

    @property
    def state(self) -> str:
        """"teaching", then the state of the diagnoser that took over."""
        return "teaching" if self.teaching else self._inner.state

    @property
    def diagnoser(self) -> Diagnoser:
        """The method's diagnoser: the configured one while teaching, then the one run."""
        return self._inner.diagnoser

    @property
    def events(self) -> list[FaultEvent]:
        """Its own event ("taught" or "teach_failed"), then those of the diagnoser run."""
        return self._said + self._inner.events

    def update(self, sample: Sample) -> list[FaultEvent]:
        if not self.teaching:
            return self._inner.update(sample)
        _, said = self._learn(np.array([sample.k]), np.array([sample.timestamp_ns]),
                              np.asarray(sample.u, float)[None, :],
                              np.asarray(sample.z, float)[None, :])
        return said

    def update_block(self, k: np.ndarray, t_ns: np.ndarray, U: np.ndarray, Z: np.ndarray,
                     gap: np.ndarray | None = None) -> BlockResult:
        if not self.teaching:
            return self._inner.update_block(k, t_ns, U, Z, gap)
        n, said = self._learn(k, t_ns, U, Z)
        m = len(self.residual_names)
        nan = np.full((n, m), np.nan)
        if n == len(k):
            return BlockResult(said, nan, nan.copy(), np.zeros((n, m)))
        rest = self._inner.update_block(k[n:], t_ns[n:], U[n:], Z[n:],
                                        None if gap is None else gap[n:])
        return BlockResult(said + rest.events, np.vstack([nan, rest.residuals]),
                           np.vstack([nan, rest.normalized]),
                           np.vstack([np.zeros((n, m)), rest.statistic]))

    def _learn(self, k: np.ndarray, t_ns: np.ndarray, U: np.ndarray, Z: np.ndarray
               ) -> tuple[int, list[FaultEvent]]:
        """Record samples until there are enough, then learn and hand over; returns how many
        of these samples it recorded (the rest are to be diagnosed) and the event saying what
        was learned, once."""
        have = sum(len(rows[0]) for rows in self._rows)
        n = min(len(k), self.teacher.samples - have)
        self._rows.append((k[:n], U[:n], Z[:n]))
        if have + n < self.teacher.samples:
            return n, []
        kk, UU, ZZ = (np.concatenate([rows[i] for rows in self._rows]) for i in range(3))
        self._rows = None
        try:
            diagnoser, learned = self.teacher.learn(kk, UU, ZZ)
        except ValueError as exc:
            learned = {"status": "failed", "reason": str(exc),
                       "samples": str(len(kk)), "first_sample": str(int(kk[0]))}
        else:
            self._inner = self.then(diagnoser)
        if self.on_learned is not None:
            self.on_learned(learned)
        noise = json.loads(learned.get("noise_json", "[]"))
        reason = ({"reason": learned["reason"]},) if "reason" in learned else ()
        self._said = [FaultEvent(
            kind="taught" if learned["status"] == "learned" else "teach_failed",
            sample=int(kk[-1]), timestamp_ns=int(t_ns[n - 1]), candidates=reason,
            estimates={row["sensor"]: row["std"] for row in noise})]
        return n, list(self._said)

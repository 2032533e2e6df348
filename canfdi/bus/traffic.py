"""Whether the drives' frames are arriving: a dead or silent bus is a state, not a quiet zero.

`TrafficWatch` is fed the count of mapped frames (frames of the bus map or the sample clock:
not foreign IDs) and the time now, and says when the traffic changes: the first mapped frame,
silence for ``timeout`` seconds (before the first frame too), and traffic that resumes. The
service logs each change, reports "no_traffic" on FDI_STATUS, systemd's STATUS= and the live
view while silent.

>>> watch = TrafficWatch(timeout=1.0, start=0.0)
>>> watch.update(0.4, 0) is None
True
>>> watch.update(0.5, 3)
TrafficChange(kind='first', seconds=0.5)
>>> watch.update(1.2, 3) is None, watch.update(1.6, 3)
(True, TrafficChange(kind='silent', seconds=1.1))
>>> watch.silent, watch.update(2.0, 4), watch.silent
(True, TrafficChange(kind='resumed', seconds=1.5), False)
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = [
    "NO_TRAFFIC_MIN_S",
    "NO_TRAFFIC_PERIODS",
    "TrafficChange",
    "TrafficWatch",
    "no_traffic_default",
]

NO_TRAFFIC_PERIODS = 50
"""Control periods without a mapped frame after which the bus is said silent (default)."""
NO_TRAFFIC_MIN_S = 1.0
"""...but never sooner than this many seconds: a loaded host's pause is not a dead bus."""


def no_traffic_default(dt: float | None) -> float:
    """The default --no-traffic: `NO_TRAFFIC_PERIODS` control periods of ``dt`` seconds, at
    least `NO_TRAFFIC_MIN_S` (1 s for a 100 Hz drive, 2.5 s for a 20 Hz one).

    >>> no_traffic_default(0.01), no_traffic_default(0.05), no_traffic_default(None)
    (1.0, 2.5, 1.0)
    """
    return max(NO_TRAFFIC_MIN_S, NO_TRAFFIC_PERIODS * (dt or 0.0))


@dataclass(frozen=True)
class TrafficChange:
    """A change of the traffic: ``kind`` "first" (the first mapped frame, ``seconds`` after the
    watch started), "silent" (no mapped frame for ``seconds``) or "resumed" (after ``seconds``
    of silence).

    Examples
    --------
    >>> change = TrafficChange("silent", 1.25)
    >>> change.kind, change.seconds, change == TrafficChange("silent", 1.25)
    ('silent', 1.25, True)
    """

    kind: str
    seconds: float


class TrafficWatch:
    """Silence of the mapped frames, from their running count and a monotonic clock.

    Parameters
    ----------
    timeout : seconds without a new mapped frame after which the traffic is silent (0 or
        less: never).
    start : the clock's value when watching began (the bus opened).

    Examples
    --------
    Silent before the first frame, and again after a reopened bus's restart:

    >>> watch = TrafficWatch(timeout=2.0, start=10.0)
    >>> watch.waiting, watch.update(12.0, 0), watch.silent
    (True, TrafficChange(kind='silent', seconds=2.0), True)
    >>> watch.update(12.5, 1), watch.waiting
    (TrafficChange(kind='first', seconds=2.5), False)
    >>> watch.restart(20.0)
    >>> watch.update(21.0, 1) is None, watch.update(22.0, 1)
    (True, TrafficChange(kind='silent', seconds=2.0))
    """

    def __init__(self, timeout: float, start: float) -> None:
        self.timeout = timeout
        self.silent = False
        self._count = 0
        self._since = start  # the last new mapped frame (or the start)
        self._started = start
        self._first = True

    def update(self, now: float, mapped: int) -> TrafficChange | None:
        """The change at ``now`` given ``mapped`` frames so far, or None."""
        if mapped > self._count:
            self._count = mapped
            quiet, self._since = now - self._since, now
            if self._first:
                self._first = False
                self.silent = False
                return TrafficChange("first", round(now - self._started, 6))
            if self.silent:
                self.silent = False
                return TrafficChange("resumed", round(quiet, 6))
            return None
        if not self.silent and self.timeout > 0 and now - self._since >= self.timeout:
            self.silent = True
            return TrafficChange("silent", round(now - self._since, 6))
        return None

    @property
    def waiting(self) -> bool:
        """No mapped frame yet."""
        return self._first

    def restart(self, now: float) -> None:
        """The bus was reopened: silence is counted from ``now`` again."""
        self._since = now

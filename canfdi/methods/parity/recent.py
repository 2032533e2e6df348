"""The latest samples' residual windows, kept so that a diagnosis can start at the fault's onset
rather than at its alarm.

A small fault may be detected hundreds of samples after it began (a CUSUM integrates it), while
the detector's change point dates it within a few samples. Fitting the hypotheses from that
onset uses the samples between onset and alarm too: the onset is reported right and the
estimates start from all the data the fault has produced.

What is kept are the compensated samples as the residual bank saw them (a missing sample as a
row of NaN, as `ResidualBank.skip` pushes it), with each sample's normalised residuals; a
sample's window is rebuilt from the S rows before it when a diagnosis asks (rarely), so the
vectorised path only copies rows. Fixed arrays (a ring): memory is bounded by the capacity (the
config's identification.max_samples: a fault is looked for as far back as a diagnosis may
last), never by the data.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

__all__ = ["RecentWindows"]


class RecentWindows:
    """The last ``capacity`` samples' windows of (S + 1) rows and their residuals.

    Parameters
    ----------
    capacity : samples whose windows are kept; rows : S + 1; width : q + p; m : residuals.

    Examples
    --------
    >>> ring = RecentWindows(3, rows=2, width=1, m=1)
    >>> for k in range(5):
    ...     ring.push(np.array([k]), np.full((1, 1), float(k)), np.array([[k / 10]]))
    >>> [(k, w.ravel().tolist()) for k, w, _ in ring.since(3)]
    [(3, [2.0, 3.0]), (4, [3.0, 4.0])]
    >>> ring.skip(6, 1)  # sample 5 lost
    >>> ring.push(np.array([6]), np.full((1, 1), 6.0), np.array([[0.6]]))
    >>> [(k, w.ravel().tolist()) for k, w, _ in ring.since(6)]
    [(6, [nan, 6.0])]
    >>> ring.first
    3
    """

    def __init__(self, capacity: int, rows: int, width: int, m: int) -> None:
        self.capacity = int(capacity)
        self._rows = int(rows)
        size = self.capacity + self._rows  # room for the oldest kept window's earlier rows
        self._k = np.zeros(size, dtype=np.int64)
        self._x = np.zeros((size, width))
        self._rn = np.zeros((size, m))
        self._has = np.zeros(size, dtype=bool)
        self.clear()

    def clear(self) -> None:
        """Forget everything (the bank restarted: earlier rows are missing)."""
        self._next = 0  # the slot the next row goes to
        self._count = 0  # rows held
        self._wrapped = False  # whether rows were overwritten since the last clear

    @property
    def first(self) -> int:
        """The oldest sample whose window and residuals are kept (IndexError when none)."""
        for k, _, _ in self._entries(None):
            return k
        raise IndexError("no sample kept")

    def push(self, k: np.ndarray, x: np.ndarray, rn: np.ndarray,
             has: np.ndarray | None = None) -> None:
        """N consecutive samples k (N,): their compensated rows x (N, width), normalised
        residuals rn (N, m) and whether they have residuals (N,) (default: all)."""
        n = len(k)
        if n == 0:
            return
        size = len(self._k)
        keep = min(n, size)
        slots = (self._next + (n - keep) + np.arange(keep)) % size
        self._k[slots] = k[n - keep:]
        self._x[slots] = x[n - keep:]
        self._rn[slots] = rn[n - keep:]
        self._has[slots] = True if has is None else has[n - keep:]
        self._next = int((self._next + n) % size)
        self._wrapped |= self._count + n > size
        self._count = min(self._count + n, size)

    def skip(self, k: int, count: int) -> None:
        """``count`` samples before sample k are lost: rows of NaN with no residuals."""
        ks = np.arange(k - count, k)
        nan = np.full((count, self._x.shape[1]), np.nan)
        self.push(ks, nan, np.full((count, self._rn.shape[1]), np.nan),
                  np.zeros(count, dtype=bool))

    def since(self, k0: int) -> Iterator[tuple[int, np.ndarray, np.ndarray]]:
        """(sample, window (rows, width), rn (m,)) of the kept samples with residuals from k0
        on, oldest first."""
        return self._entries(k0)

    def _entries(self, k0: int | None) -> Iterator[tuple[int, np.ndarray, np.ndarray]]:
        size = len(self._k)
        order = (self._next - self._count + np.arange(self._count)) % size
        # Rows before the first held one are missing after a clear; once rows were
        # overwritten they are unknown, so a window reaching them is not offered.
        start = self._rows - 1 if self._wrapped else 0
        pad = np.full((self._rows - 1, self._x.shape[1]), np.nan)
        picks = np.flatnonzero(self._has[order])
        picks = picks[picks >= start]
        if k0 is not None:
            picks = picks[self._k[order[picks]] >= k0]
        for p in picks.tolist():
            lo = p - self._rows + 1
            rows = self._x[order[max(lo, 0): p + 1]]
            window = rows if lo >= 0 else np.vstack([pad[: -lo], rows])
            yield int(self._k[order[p]]), window, self._rn[order[p]]

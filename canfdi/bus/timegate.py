"""A drive's time, checked: a frame whose timestamp leaves the drive's clock is dropped, and a
step of the clock itself is followed without inventing samples for it.

A gateway booted without a real-time clock, NTP stepping the wall clock, a merged or
re-exported log with one frame stamped an hour ahead: a timestamp is data, and as wrong as any.
A sample clock unwraps counters, counts lost periods and lays grid instants by time, so one wild
timestamp would become hundreds of thousands of missing samples (or a grid of millions). Every
sample clock therefore passes its drive's valid frames through a `TimeGate` first:

* A frame within ``bound`` of the drive's time (the latest accepted frame's, corrected) is
  accepted: jitter, bursts and outages up to the bound are the clock's to count, as before.
* A frame further away, ahead or behind, is a ``time_jump``: counted and dropped, not sampled.
* ``confirm`` such frames in a row that agree with each other (each within ``bound`` of the one
  before) are a step of the clock, not a stray frame: the gate re-anchors. From the last of them
  on, times are shifted so that it lands ``bound`` after the drive's time: the clock sees a
  pause of the bound (its windows restart, at most a bound's worth of samples is counted
  missing) rather than the step, and the step is recorded once in ``steps``. A log cannot tell
  a clock step from an outage longer than the bound; both are treated as a step and said.

Pure and deterministic: `step` takes one frame, `apply` a block of them, with the same result
(tested on every cut); normal traffic goes through `apply` as a few numpy passes, only the
frames around a jump one by one.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

__all__ = ["CONFIRM_FRAMES", "MIN_BOUND_PERIODS", "TimeGate"]

MIN_BOUND_PERIODS = 64
"""The smallest bound, in control periods (a counter clock's is its counter's modulus, if
larger: within it the counter itself says how many periods passed)."""

CONFIRM_FRAMES = 8
"""Frames in a row beyond the bound, agreeing with each other, that make a clock step."""

_FIRST_CHUNK = 256
_SAFE = 1 << 61  # below it differences of times, offsets and references cannot wrap int64


class TimeGate:
    """The time check of one drive's valid frames (module docstring).

    Parameters
    ----------
    bound_ns : the largest distance from the drive's time a frame may have, ns (> 0).
    confirm : frames in a row beyond it that make a clock step.

    Examples
    --------
    >>> gate = TimeGate(bound_ns=100)
    >>> [gate.step(t) for t in (0, 10, 3_600_000, 20)]  # one frame an hour ahead
    [0, 10, None, 20]
    >>> gate.jumps, gate.steps
    (1, [])
    """

    def __init__(self, bound_ns: int, confirm: int = CONFIRM_FRAMES) -> None:
        if bound_ns <= 0 or confirm < 1:
            raise ValueError(f"bound_ns and confirm must be positive, got {bound_ns}, {confirm}")
        self.bound = int(bound_ns)
        self.confirm = int(confirm)
        self.offset = 0  # subtracted from every raw time since the last step
        self.ref: int | None = None  # the drive's time: the latest accepted frame's, corrected
        # The latest frames beyond the bound, in a row: how many, the first's and the last's
        # raw times.
        self.chain = (0, 0, 0)
        self.jumps = 0
        # (raw time of the first frame after the step, the step's size), ns
        self.steps: list[tuple[int, int]] = []
        # The block form `apply` runs: this reference, unless canfdi.core.kernel installed
        # another that gives the same (its C core's).
        self.block: Callable[[TimeGate, NDArray[np.int64], NDArray[np.intp]],
                             tuple[NDArray[np.int64], NDArray[np.intp]]] = \
            TimeGate.apply_reference

    def step(self, t: int) -> int | None:
        """One valid frame's raw time: its corrected time, or None (a time jump: drop it)."""
        t = int(t)
        c = t - self.offset
        if self.ref is None:
            self.ref = c
            return c
        if abs(c - self.ref) <= self.bound:
            self.chain = (0, 0, 0)
            self.ref = max(self.ref, c)
            return c
        count, first, last = self.chain
        self.chain = (count + 1, first, t) if count and abs(t - last) <= self.bound else (1, t, t)
        if self.chain[0] < self.confirm:
            self.jumps += 1
            return None
        # Confirmed: the clock stepped (by as much as the chain's first frame jumped). Land
        # this frame a bound after the drive's time.
        first = self.chain[1]
        landed = self.ref + self.bound
        self.steps.append((first, first - self.offset - self.ref))
        self.offset += c - landed
        self.chain = (0, 0, 0)
        self.ref = landed
        return landed

    def apply(self, t: NDArray[np.int64], rows: NDArray[np.intp]
              ) -> tuple[NDArray[np.int64], NDArray[np.intp]]:
        """`step` over the frames ``rows`` of a block, in order (on the kernel installed:
        `apply_reference`'s answers)."""
        return self.block(self, t, rows)

    def apply_reference(self, t: NDArray[np.int64], rows: NDArray[np.intp]
                        ) -> tuple[NDArray[np.int64], NDArray[np.intp]]:
        """`step` over the frames ``rows`` of a block, in order, in numpy (the reference).

        Parameters
        ----------
        t : (N,) raw times of the block's frames.
        rows : (V,) ascending positions of its valid frames of this drive.

        Returns
        -------
        (N,) int64 times with the valid frames' corrected (the others as they came: no sample
        reads them), and the positions among ``rows`` of the frames dropped.
        """
        times = np.asarray(t, dtype=np.int64)
        out = times.copy()
        n = len(rows)
        if n == 0:
            return out, np.zeros(0, dtype=np.intp)
        tv = times[rows]
        dropped: list[int] = []
        pos, chunk = 0, _FIRST_CHUNK
        while pos < n:
            part = tv[pos: pos + chunk]
            # Near a jump (or at times near the int64 limits, where differences could wrap):
            # one frame at a time, exactly as `step`.
            one = (self.ref is None or self.chain[0] > 0
                   or max(abs(int(part.min())), abs(int(part.max())), abs(self.offset),
                          abs(self.ref)) >= _SAFE)
            if not one:
                # Normal traffic: every frame within the bound of the running maximum before it.
                c = part - self.offset
                before = np.maximum.accumulate(np.concatenate([[self.ref], c[:-1]]))
                bad = np.abs(c - before) > self.bound
                good = int(np.argmax(bad)) if bad.any() else len(c)
                if good:
                    out[rows[pos: pos + good]] = c[:good]
                    self.ref = max(self.ref, int(c[:good].max()))
                pos += good
                if good == len(c):
                    chunk *= 2
                    continue
                chunk = _FIRST_CHUNK
            got = self.step(int(tv[pos]))
            if got is None:
                dropped.append(pos)
            else:
                out[rows[pos]] = got
            pos += 1
        return out, np.array(dropped, dtype=np.intp)

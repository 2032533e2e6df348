"""The record a simulated run comes in: what the simulator makes and the bus profiles encode.

A leaf module (numpy only), so that the profiles, the scenario, the simulator and the emitter
can all name it without importing one another.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["SimChunk"]


@dataclass(frozen=True)
class SimChunk:
    """Samples k0 .. k0+N-1 of a run.

    k : (N,) sample indices; t : (N,) seconds; x : (N, n) states; y : (N, q) true outputs with
    measurement noise; z : (N, q) measured outputs (faults applied); u_c : (N, p) commands;
    u : (N, p) applied inputs; ref : (N, n_ref) controller references.

    Examples
    --------
    Two samples of a one-state plant with one sensor, one input and no reference:

    >>> k = np.arange(5, 7)
    >>> chunk = SimChunk(k=k, t=k * 0.01, x=np.zeros((2, 1)), y=np.ones((2, 1)),
    ...                  z=np.ones((2, 1)), u_c=np.zeros((2, 1)), u=np.zeros((2, 1)),
    ...                  ref=np.empty((2, 0)))
    >>> len(chunk), chunk.t.tolist(), chunk.truth
    (2, [0.05, 0.06], [])
    """

    k: np.ndarray
    t: np.ndarray
    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    u_c: np.ndarray
    u: np.ndarray
    ref: np.ndarray
    truth: list[dict] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.k)

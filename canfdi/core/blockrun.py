"""The block form every diagnoser shares: whole stretches of monitoring at once where a method
can vectorise them, every other sample through its own streaming ``update``.

A diagnoser's ``update_block`` must give exactly the events, residuals and statistics of
``update`` called sample by sample. The samples that cannot be vectorised (one that breaks
continuity, those of a diagnosis, the one that raises an alarm) go through ``update`` itself;
the continuous monitoring stretches between them go to the method's ``stretch`` function, which
handles as many as it can and says where it stopped (at an alarm). A method with no vectorised
stretch passes none: every sample goes through ``update``.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from canfdi.core.protocol import DIAGNOSE, Diagnoser
from canfdi.core.records import BlockResult, FaultEvent, Sample

__all__ = ["BlockRows", "Stretch", "continuity_breaks", "has_values", "run_block"]


class BlockRows:
    """The (N, m) rows a block fills: raw and normalised residuals (NaN where a sample gave
    none) and statistics.

    Examples
    --------
    >>> rows = BlockRows(3, 2)
    >>> rows.R.shape, bool(np.isnan(rows.Rn).all()), float(rows.stat.sum())
    ((3, 2), True, 0.0)
    """

    def __init__(self, n: int, m: int) -> None:
        self.R = np.full((n, m), np.nan)
        self.Rn = np.full((n, m), np.nan)
        self.stat = np.zeros((n, m))


# (first row, end row (exclusive), rows) -> the row it stopped at: the end when the whole
# stretch was monitored, else the row of the alarm (which run_block hands to ``update``).
Stretch = Callable[[int, int, BlockRows], int]


def continuity_breaks(k: np.ndarray, last_k: int | None, first_breaks: bool) -> np.ndarray:
    """(N,) bool: sample i does not follow the one before it (sample -1: ``last_k``); the first
    sample of a diagnoser that saw none counts as a break when ``first_breaks``."""
    prev = np.concatenate([[last_k if last_k is not None else -2], k[:-1]])
    breaks = k != prev + 1
    if last_k is None:
        breaks[0] = first_breaks
    return breaks


def has_values(x: np.ndarray) -> np.ndarray:
    """(N,) bool: the rows of x (N, m) not all NaN (those ``update`` gives residuals for).
    Column by column: a reduction along a short row costs a pass per row."""
    nan = np.isnan(x)
    if not nan.any():
        return np.ones(len(x), dtype=bool)
    out = ~nan[:, 0]
    for j in range(1, x.shape[1]):
        out |= ~nan[:, j]
    return out


def run_block(dg: Diagnoser, k: np.ndarray, t_ns: np.ndarray, U: np.ndarray, Z: np.ndarray,
              gap: np.ndarray | None, breaks: np.ndarray | None = None,
              stretch: Stretch | None = None) -> BlockResult:
    """``dg.update_block``'s result for N samples, through ``stretch`` where it can.

    Parameters
    ----------
    dg : the diagnoser; k, t_ns : (N,) sample indices and timestamps; U : (N, p); Z : (N, q),
        NaN where lost; gap : (N,) samples missing before each, or None.
    breaks : (N,) bool, the samples ``update`` must take whatever the mode (see
        `continuity_breaks`); ignored without a stretch.
    stretch : the method's vectorised monitoring of continuous samples, or None.
    """
    n, m = len(k), len(dg.residual_names)
    rows = BlockRows(n, m)
    events: list[FaultEvent] = []
    gap = np.zeros(n, dtype=np.int64) if gap is None else np.asarray(gap)
    alarm_row = -1  # the row a stretch stopped at: its alarm goes through update
    i = 0
    while i < n:
        if stretch is None or dg.mode == DIAGNOSE or breaks[i] or i == alarm_row:
            events += dg.update(Sample(k=int(k[i]), timestamp_ns=int(t_ns[i]), u=U[i], z=Z[i],
                                       gap=int(gap[i])))
            if dg.last_residuals is not None:
                rows.R[i], rows.Rn[i] = dg.last_residuals, dg.last_normalized
            rows.stat[i] = dg.statistics
            i += 1
            continue
        later = np.flatnonzero(breaks[i + 1:])
        j = i + 1 + int(later[0]) if len(later) else n
        stop = stretch(i, j, rows)
        alarm_row = stop if stop < j else -1
        i = stop
    return BlockResult(events=events, residuals=rows.R, normalized=rows.Rn, statistic=rows.stat)

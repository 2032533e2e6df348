"""The noise watchdog: each residual's noise against its calibrated value, online.

A fault is a change of mean that a fault model explains; a change of the noise (a sensor gone
noisy, interference) or of the model (a drive whose dynamics drifted) changes the residuals'
spread instead. The watchdog measures that spread robustly and says "mismatch" when it leaves
the calibrated value by more than ``factor``; it never starts a fault diagnosis.

Samples are cut into blocks of ``block`` consecutive sample indices (``k // block``, so the
cut is the same whatever blocks the data arrive in). A block's statistic is each residual's
variance about the block's own mean: a fault's step moves the mean, not the spread, and shows in
at most one block. The normalised residuals the watchdog sees have unit variance when the noise
is what the config (or calibration) says, so ``sqrt(variance)`` is the noise's scale against
its calibrated value. Samples a diagnosis is running on are held back (a fault the diagnosis
has not yet folded into the compensation, such as a scale fault under a varying command or an
actuator step's transient, would otherwise count as noise): dropped when it finds a fault,
counted (`add_late`) when it ends with none, for that alarm was the noise.

A residual enters mismatch when each of its last ``blocks`` blocks is out of
[1/factor, factor] (in std; one block may hold a fault's step, several in a row are no step),
and leaves it when each is back within [1/sqrt(factor), sqrt(factor)] (hysteresis: no flapping
at the edge). While in mismatch its ratio (from the window's quietest block: a fault's step
inflates one block, noise all) is the scale by which that residual's noise is widened for
detection (`scale`), so the Page-Hinkley tests keep their false-alarm interval and a real
fault, a change of mean, is still detected. A residual quieter than calibrated is in mismatch
too ("quiet", said as such) but is never detected against a narrower noise.

canfdi.core.watched runs a diagnoser under it: it feeds the watchdog, holds the rows of a
diagnosis back, says the verdicts and widens the diagnoser's noise.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from itertools import pairwise

import numpy as np
from numpy.typing import NDArray

from canfdi.core._check import check_shape

__all__ = ["DECISIONS", "NoiseWatchdog", "WatchdogChange", "block_runs", "monitoring_rows",
           "watch_runs"]


@dataclass(frozen=True)
class WatchdogChange:
    """The set of residuals in mismatch changed at the block that ended before sample ``k``.

    entered, left : (m,) bool, the residuals that entered / left mismatch; ratio : (m,) each
    residual's noise std over its calibrated value (the window's quietest block; NaN while
    unknown).

    Examples
    --------
    Residual 0 entered mismatch at the block that ended before sample 200, its noise twice
    the calibrated value:

    >>> change = WatchdogChange(k=200, entered=np.array([True, False]),
    ...                         left=np.array([False, False]), ratio=np.array([2.0, 1.0]))
    >>> int(np.flatnonzero(change.entered)[0]), change.ratio.tolist()
    (0, [2.0, 1.0])
    """

    k: int
    entered: NDArray[np.bool_]
    left: NDArray[np.bool_]
    ratio: NDArray[np.float64]


class NoiseWatchdog:
    """Streaming noise watchdog over m normalised residuals.

    Parameters
    ----------
    m : number of residuals.
    factor : ratio of noise std to its calibrated value beyond which (or below 1/factor) a
        residual is in mismatch, > 1.
    block : sample indices per block; blocks : consecutive blocks that must agree (the window
        is block * blocks samples).

    Attributes
    ----------
    ratio : (m,) each residual's noise std over its calibrated value at the last block end
        (NaN while its window has no block to tell).
    known : (m,) each residual's last ratio that was not NaN: the noise of a residual in
        mismatch while its blocks are held back under a diagnosis (`scale`).
    mismatch : (m,) bool, the residuals in mismatch.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> wd = NoiseWatchdog(2, factor=1.5, block=100, blocks=2)
    >>> k = np.arange(1000)
    >>> rn = rng.standard_normal((1000, 2)) * [1.0, 2.0]  # the second twice as noisy
    >>> changes = wd.update(k, rn)
    >>> changes[0].k, changes[0].entered.tolist()
    (200, [False, True])
    >>> bool(abs(wd.ratio[0] - 1) < 0.1), bool(abs(wd.ratio[1] - 2) < 0.2)
    (True, True)
    """

    def __init__(self, m: int, factor: float = 1.5, block: int = 250, blocks: int = 2) -> None:
        if not factor > 1.0:
            raise ValueError(f"factor must be > 1, got {factor}")
        if block < 2 or blocks < 1:
            raise ValueError("need block >= 2 and blocks >= 1")
        self.m, self.factor, self.block, self.blocks = m, float(factor), int(block), int(blocks)
        self.reset()

    def reset(self) -> None:
        """Nothing seen: no block, no mismatch."""
        self._open: int | None = None  # the block index being accumulated
        # The open block's rows (k, rn) as they came: summed at its close in the order of k,
        # so that its variance has the same bits whatever chunks (and held rows) brought them.
        self._rows: list[tuple[NDArray[np.int64], NDArray[np.float64]]] = []
        self._variances: deque[NDArray[np.float64]] = deque(maxlen=self.blocks)
        self.ratio = np.full(self.m, np.nan)
        self.known = np.full(self.m, np.nan)
        self.mismatch = np.zeros(self.m, dtype=bool)

    @property
    def scale(self) -> NDArray[np.float64]:
        """(m,) the noise scale detection should use: the ratio of a residual whose noise rose,
        1 otherwise. A residual quieter than calibrated keeps its calibrated noise: a noise
        estimate never tightens a threshold below what the config (and the signals'
        resolution, which it includes) allow; rounding noise that shrinks with the values
        comes back when they grow. While a window has no verdict on a residual in mismatch
        (its blocks held back under a diagnosis), the ratio it last had (`known`)."""
        return np.where(self.mismatch, np.maximum(self.known, 1.0), 1.0)

    @property
    def judged(self) -> bool:
        """Whether the last window had a verdict on every residual: ``blocks`` blocks, none
        mostly lost or held back (NaN)."""
        return len(self._variances) == self.blocks and not bool(
            np.isnan(np.array(self._variances)).any())

    @property
    def quiet(self) -> NDArray[np.bool_]:
        """(m,) the residuals in mismatch because they are quieter than calibrated: said, but
        never detected against a narrower noise (`scale`)."""
        return self.mismatch & (self.ratio < 1.0)

    def due(self, k: int) -> bool:
        """Whether sample k closes the open block (call `close` before diagnosing it)."""
        return self._open is not None and k // self.block != self._open

    def close(self, k: int) -> WatchdogChange | None:
        """End the open block (sample k is in a later one): judge the window; the change, if
        the set of residuals in mismatch moved."""
        var = self._open_variance()
        # Sample k's block is open now, whether or not samples reach it (a diagnosis holds
        # them back).
        self._open, self._rows = k // self.block, []
        self._variances.append(var)
        recent = np.array(self._variances)
        self.ratio = _ratio(recent)
        seen = np.isfinite(self.ratio)
        self.known[seen] = self.ratio[seen]
        if len(recent) < self.blocks:
            return None
        out, inside = self._verdicts(recent)
        new = (self.mismatch | out) & ~inside
        entered, left = new & ~self.mismatch, self.mismatch & ~new
        self.mismatch = new
        if entered.any() or left.any():
            return WatchdogChange(k, entered, left, self.ratio.copy())
        return None

    def _verdicts(self, recent: NDArray[np.float64]
                  ) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
        """(out, inside), each recent.shape[1:], of windows of block variances ``recent``
        (blocks, ..., m): out of the band in each block (in: one block can hold a fault's step),
        each inside the narrower band (back: no flapping at the edge). A NaN is neither."""
        f2 = self.factor**2
        out = np.all(recent > f2, axis=0) | np.all(recent < 1.0 / f2, axis=0)
        inside = np.all((recent <= self.factor) & (recent >= 1.0 / self.factor), axis=0)
        return out, inside

    def add(self, k: NDArray[np.int64], rn: NDArray[np.float64]) -> None:
        """Accumulate samples k (N,) of one block, normalised residuals rn (N, m) (NaN:
        missing); the caller has closed the previous block (`due`, `close`)."""
        rn = np.asarray(rn, dtype=float)
        check_shape("rn", rn, (len(k), self.m))
        if not len(k):
            return
        self._open = int(k[-1]) // self.block
        self._rows.append((np.array(k, dtype=np.int64), rn.copy()))

    def _open_variance(self) -> NDArray[np.float64]:
        """(m,) the open block's variance (`_variance`), its rows summed in the order of k."""
        if not self._rows:
            return np.full(self.m, np.nan)
        k = np.concatenate([r[0] for r in self._rows])
        rn = np.concatenate([r[1] for r in self._rows])[np.argsort(k, kind="stable")]
        n, s1, s2 = _run_sums(rn, [(0, len(rn))], self.block)
        return _variance(n[0], s1[0], s2[0], self.block)

    def add_late(self, k: NDArray[np.int64], rn: NDArray[np.float64]) -> None:
        """Samples k (N,), rn (N, m) held back while a diagnosis ran that ended with no fault
        (they are noise after all): those of the open block join it, each earlier block's
        variance joins the recent ones (as the newest: the blocks closed meanwhile had none of
        them). The verdict waits for the next `close`, as for any sample."""
        k = np.asarray(k, dtype=np.int64)
        rn = np.asarray(rn, dtype=float)
        check_shape("rn", rn, (len(k), self.m))
        for lo, hi in block_runs(k, self.block):
            if self._open is not None and int(k[lo]) // self.block >= self._open:
                self.add(k[lo:hi], rn[lo:hi])
                continue
            n, s1, s2 = _run_sums(rn[lo:hi], [(0, hi - lo)], self.block)
            self._variances.append(_variance(n[0], s1[0], s2[0], self.block))

    def update(self, k: NDArray[np.int64], rn: NDArray[np.float64],
               stop_on_change: bool = False) -> list[WatchdogChange]:
        """Samples k (N,) increasing, rn (N, m): the changes they caused, in order (the batch
        form of `due`/`close`/`add`: the same state and changes whatever the chunks). With
        ``stop_on_change`` it stops at the first change, in the state `close` left: the samples
        from that change's ``k`` on are not taken.

        Vectorised over the blocks: their sums, variances, windows and verdicts are whole-array
        operations (the same arithmetic as `close` and `add` over whole blocks; samples added one
        at a time are summed in another order, equal to rounding), and the set of
        residuals in mismatch is a latch each verdict sets or resets.
        """
        k = np.asarray(k, dtype=np.int64)
        rn = np.asarray(rn, dtype=float)
        check_shape("rn", rn, (len(k), self.m))
        runs = block_runs(k, self.block)
        if not runs:
            return []
        out: list[WatchdogChange] = []
        lo, hi = runs[0]
        if self.due(int(k[lo])):
            change = self.close(int(k[lo]))
            if change is not None:
                out.append(change)
                if stop_on_change:
                    return out
        self.add(k[lo:hi], rn[lo:hi])
        if len(runs) == 1:
            return out
        # Each later run closes the block before it: the first closed holds what was open
        # before these samples, the others are runs 1..R-2 whole.
        starts = np.array([a for a, _ in runs[1:]])
        var = np.empty((len(starts), self.m))
        var[0] = self._open_variance()
        if len(runs) > 2:
            n, s1, s2 = _run_sums(rn, runs[1:-1], self.block)
            var[1:] = _variance(n, s1, s2, self.block)
        # Window c (the recent blocks at close c, var[c] the newest) is rows c+1 .. c+B of the
        # earlier variances NaN-padded to B in front, then these: a missing block is unseen,
        # as in `close`.
        B, before = self.blocks, list(self._variances)
        seq = np.concatenate([np.full((B - len(before), self.m), np.nan),
                              np.array(before).reshape(-1, self.m), var])
        C = len(var)
        windows = np.stack([seq[j + 1: j + 1 + C] for j in range(B)])  # (B, C, m)
        ratio = _ratio(windows)  # (C, m)
        up, inside = self._verdicts(windows)
        # The latch: out sets, inside resets, neither keeps the state before.
        row = np.arange(C)[:, None]
        last = np.maximum.accumulate(np.where(up | inside, row, -1), axis=0)
        state = np.where(last >= 0, up[np.maximum(last, 0), np.arange(self.m)],
                         self.mismatch[None, :])
        prev = np.vstack([self.mismatch[None, :], state[:-1]])
        moved = np.flatnonzero((state != prev).any(axis=1))
        stop = stop_on_change and len(moved) > 0
        end = int(moved[0]) + 1 if stop else C
        for c in moved[moved < end].tolist():
            out.append(WatchdogChange(int(k[starts[c]]), state[c] & ~prev[c],
                                      prev[c] & ~state[c], ratio[c].copy()))
        # The state the closes leave (the last one, or the change it stopped at).
        self._variances.extend(var[max(0, end - B): end].copy())
        self.ratio = ratio[end - 1].copy()
        seen = np.isfinite(ratio[:end])
        last = end - 1 - np.argmax(seen[::-1], axis=0)  # each residual's last known close
        self.known = np.where(seen.any(axis=0), ratio[last, np.arange(self.m)], self.known)
        self.mismatch = state[end - 1].copy()
        self._open = int(k[starts[end - 1]]) // self.block
        self._rows = []
        if not stop:
            self.add(k[runs[-1][0]:], rn[runs[-1][0]:])
        return out


def _ratio(recent: NDArray[np.float64]) -> NDArray[np.float64]:
    """recent.shape[1:]: each residual's noise std over its calibrated value from windows of
    block variances ``recent`` (blocks, ..., m): the smallest block's, NaN (unknown) blocks
    left out; NaN when all are. A fault's step (or an actuator fault's transient) inflates the
    block it falls in, a change of the noise every block: the smallest is the noise (a fault in
    the window would otherwise widen detection many times, the fault itself then unseen)."""
    low = np.where(np.isnan(recent), np.inf, recent).min(axis=0)
    return np.where(np.isfinite(low), np.sqrt(low), np.nan)


def _run_sums(rn: NDArray[np.float64], runs: list[tuple[int, int]], block: int
              ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """(R, m) count, sum and sum of squares of the non-NaN values of each run of rows of rn,
    the same bits for a block whatever runs it is summed among (a block's rows at its close,
    `NoiseWatchdog._open_variance`, or many blocks at once in `NoiseWatchdog.update`)."""
    a, b = runs[0][0], runs[-1][1]
    have = ~np.isnan(rn[a:b])
    full = bool(have.all())
    x = rn[a:b] if full else np.where(have, rn[a:b], 0.0)
    if b - a == block * len(runs):  # whole blocks
        shape = (len(runs), block, rn.shape[1])
        n = (np.full((len(runs), rn.shape[1]), float(block)) if full
             else have.reshape(shape).sum(axis=1).astype(float))
        if rn.shape[1] == 1:  # numpy sums one column pairwise: each block's as add's
            return n, x.reshape(shape).sum(axis=1), (x * x).reshape(shape).sum(axis=1)
        # Several columns numpy sums row after row. The blocks side by side, (block, R, m):
        # the same order along rows R m long (a sum along a short row costs a pass per row).
        side = np.ascontiguousarray(x.reshape(shape).transpose(1, 0, 2))
        return n, side.sum(axis=0), (side * side).sum(axis=0)
    sums = [(have[lo - a: hi - a].sum(axis=0), x[lo - a: hi - a].sum(axis=0),
             (x[lo - a: hi - a] * x[lo - a: hi - a]).sum(axis=0)) for lo, hi in runs]
    n, s1, s2 = (np.array(v, dtype=float) for v in zip(*sums, strict=True))
    return n, s1, s2


def _variance(n: NDArray[np.float64], s1: NDArray[np.float64], s2: NDArray[np.float64],
              block: int) -> NDArray[np.float64]:
    """(m,) a block's variance about its mean from its count and sums; NaN for a block mostly
    lost or diagnosed (no verdict from a few samples)."""
    enough = n >= max(2, block // 2)
    return np.where(enough, (s2 - s1**2 / np.maximum(n, 1)) / np.maximum(n - 1, 1), np.nan)


def block_runs(k: NDArray[np.int64], block: int) -> list[tuple[int, int]]:
    """[(lo, hi)] row ranges of k (N,) increasing that share ``k // block``."""
    if not len(k):
        return []
    b = np.asarray(k, dtype=np.int64) // block
    cuts = np.flatnonzero(np.diff(b)) + 1
    edges = [0, *cuts.tolist(), len(k)]
    return list(pairwise(edges))


def watch_runs(k: NDArray[np.int64], block: int, quiet: NDArray[np.bool_]
               ) -> list[tuple[int, int, bool]]:
    """[(lo, hi, plain)] the `block_runs` of k (N,) increasing, consecutive runs whose rows
    are all ``quiet`` (N,) (`monitoring_rows`) merged into one ``plain`` range (what
    `NoiseWatchdog.update` takes at once), each other run on its own."""
    runs = block_runs(k, block)
    if len(runs) < 2:  # (a live block of a few samples: no array work)
        return [(a, b, bool(np.all(quiet[a:b]))) for a, b in runs]
    starts = np.array([a for a, _ in runs])
    plain = np.logical_and.reduceat(np.asarray(quiet, dtype=bool), starts).tolist()
    out: list[tuple[int, int, bool]] = []
    for (a, b), p in zip(runs, plain, strict=True):
        if p and out and out[-1][2]:
            out[-1] = (out[-1][0], b, True)
        else:
            out.append((a, b, p))
    return out


DECISIONS = ("accepted", "refined", "unexplained")
"""The event kinds that end a diagnosis."""


def monitoring_rows(k: NDArray[np.int64], events: list, diagnosing_before: bool
                    ) -> NDArray[np.bool_]:
    """(N,) the rows of samples k (N,) a diagnoser spent watching: not from a detection to its
    decision (both included), not at a sample with any event. ``events`` are the block's
    FaultEvents in order; ``diagnosing_before``: a diagnosis was open before the first row.
    One sample at a time or all at once, the same rows."""
    k = np.asarray(k, dtype=np.int64)
    out = np.ones(len(k), dtype=bool)
    start = int(k[0]) if diagnosing_before and len(k) else None
    for e in events:
        out[k == e.sample] = False
        if e.kind == "detected":
            start = e.sample
        elif e.kind in DECISIONS and start is not None:
            out[(k >= start) & (k <= e.sample)] = False
            start = None
    if start is not None:
        out[k >= start] = False
    return out

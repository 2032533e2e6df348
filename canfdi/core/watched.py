"""A diagnoser wrapped in the noise watchdog (canfdi.core.watchdog): it diagnoses as the
method's diagnoser does, against the noise the watchdog says, and says the watchdog's verdicts.

The watchdog sees each sample's residuals against the configured noise. Those of a diagnosis
are held back until it ends: dropped when it found a fault, counted when it found none (the
alarm was the noise). At each block end the watchdog judges its window; a change of the
residuals in mismatch is an event ("mismatch", "quiet", "matched") and sets the noise the
diagnoser detects against (`Diagnoser.noise_scale`).

Armed after a check: the first samples are held while the watchdog checks the configured noise
on them (state "checking"), so that no detection made against a wrong noise is said; the
diagnoser runs on them meanwhile as a probe (its residuals are the ones recorded, its diagnoses
hold rows back as any). When the watchdog has judged a whole window, the diagnoser is reset,
takes the noise found, and diagnoses the kept samples: their events (after the watchdog's
verdicts of the check) come out then.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field

import numpy as np

from canfdi.core.protocol import DIAGNOSE, Diagnoser, diagnosis_state
from canfdi.core.records import BlockResult, Compensation, FaultEvent, Sample
from canfdi.core.supervision import Supervision
from canfdi.core.watchdog import (
    DECISIONS,
    NoiseWatchdog,
    WatchdogChange,
    block_runs,
    monitoring_rows,
    watch_runs,
)

__all__ = ["NoiseWatched"]


@dataclass
class _NoiseCheck:
    """The check of the configured noise on a drive's first samples: ``kept`` holds them
    (k, t_ns, U, Z, gap) for the diagnoser once the check is over, ``changes`` the watchdog's
    verdicts meanwhile, said when it is. The check is over at the first block end from block
    ``end`` on (``blocks`` whole blocks from the first sample, after the first sample's block
    when the drive started inside one) where the watchdog has a whole window to judge
    (`NoiseWatchdog.judged`: none of its blocks mostly lost or held back under a diagnosis),
    or at block ``cap`` whatever it has (a diagnosis of the probe's may hold samples back up to
    ``longest_diagnosis``); None before the first sample."""

    kept: list[tuple[np.ndarray, ...]] = field(default_factory=list)
    changes: list[WatchdogChange | None] = field(default_factory=list)
    end: int | None = None
    cap: int | None = None


class NoiseWatched(Supervision):
    """A method's diagnoser under the noise watchdog: the same `Diagnoser` protocol, the
    watchdog's events among its own, the state "checking", "mismatch" or "quiet" where the
    watchdog says so.

    Parameters
    ----------
    diagnoser : the method's diagnoser, as built (fresh).
    factor, block, blocks : the watchdog's (canfdi.core.watchdog.NoiseWatchdog).
    check : armed after a check of the configured noise on the first samples (see the module);
        False: armed at once (a diagnoser built on a noise just learned).
    longest_diagnosis : the most samples a diagnosis holds back (identification.max_samples):
        how long the check may wait for a window with a verdict.

    Examples
    --------
    A diagnoser that never alarms, on a drive twice as noisy as configured: "checking" for
    two blocks of 100 samples, then the verdict at the block end, said as an event.

    >>> from canfdi.core.protocol import MONITOR
    >>> class Echo:  # residuals = the measurements, normalised by noise_scale
    ...     mode, compensation, events, noise_scale = MONITOR, [], [], 1.0
    ...     last_residuals = last_normalized = None
    ...     residual_names, thresholds, statistics = ["a", "b"], np.ones(2), np.zeros(2)
    ...     def update(self, sample): ...
    ...     def update_block(self, k, t_ns, U, Z, gap=None):
    ...         return BlockResult([], Z, Z / self.noise_scale, np.zeros_like(Z))
    ...     def reset(self): self.noise_scale = 1.0
    >>> watched = NoiseWatched(Echo(), factor=1.5, block=100, blocks=2)
    >>> k = np.arange(1000)
    >>> Z = np.random.default_rng(0).standard_normal((1000, 2)) * [1.0, 2.0]
    >>> watched.state
    'checking'
    >>> events = watched.update_block(k, k * 10**7, np.zeros((1000, 1)), Z).events
    >>> [(e.kind, e.sample, e.residuals) for e in events]
    [('mismatch', 200, ('b',))]
    >>> watched.state, float(watched.noise_scale[0]), bool(watched.noise_scale[1] > 1.5)
    ('mismatch', 1.0, True)
    """

    def __init__(self, diagnoser: Diagnoser, factor: float = 1.5, block: int = 250,
                 blocks: int = 2, check: bool = True, longest_diagnosis: int = 2000) -> None:
        super().__init__(diagnoser)
        self.watchdog = NoiseWatchdog(len(diagnoser.residual_names), factor, block, blocks)
        self.check = check
        self.longest_diagnosis = int(longest_diagnosis)
        self._start()

    def _start(self) -> None:
        self._events: list[FaultEvent] = []
        # Rows (k, residuals against the configured noise) of a diagnosis not yet ended.
        self._held: list[tuple[np.ndarray, np.ndarray]] = []
        self._check = _NoiseCheck() if self.check else None

    def reset(self) -> None:
        """Back to the state after construction (checking again if it checked)."""
        self._inner.reset()
        self.watchdog.reset()
        self._widen()
        self._start()

    # -- what the monitor reads ------------------------------------------------------------
    @property
    def state(self) -> str:
        """"checking", "diagnosing" (or "named": protocol.diagnosis_state), "mismatch",
        "quiet" (every residual in mismatch is quieter than configured) or "monitoring"."""
        if self._check is not None:
            return "checking"
        diagnosing = diagnosis_state(self._inner)
        if diagnosing is not None:
            return diagnosing
        wd = self.watchdog
        if not wd.mismatch.any():
            return "monitoring"
        return "quiet" if bool(wd.quiet[wd.mismatch].all()) else "mismatch"

    @property
    def events(self) -> list[FaultEvent]:
        """Every event it returned since construction or the last `reset`: the watchdog's and
        the diagnoser's."""
        return self._events

    @property
    def compensation(self) -> list[Compensation]:
        """The diagnoser's; none while checking (the probe's diagnoses are not the drive's
        yet)."""
        return [] if self._check is not None else self._inner.compensation

    @property
    def last_residuals(self) -> np.ndarray | None:
        """The diagnoser's; while checking, None where they have no value (the check records
        the rows with one, as a block's)."""
        r = self._inner.last_residuals
        if self._check is not None and r is not None and bool(np.isnan(r).all()):
            return None
        return r

    # -- the Diagnoser protocol ------------------------------------------------------------
    def update(self, sample: Sample) -> list[FaultEvent]:
        """One sample: the watchdog's block end before it, then the diagnoser's update."""
        out: list[FaultEvent] = []
        if self._check is not None:
            taken, out, _ = self._checked(
                np.array([sample.k]), np.array([sample.timestamp_ns]),
                np.asarray(sample.u, float)[None, :], np.asarray(sample.z, float)[None, :],
                np.array([sample.gap]))
            if taken == 1:
                self._events += out
                return out
        out += self._close_before(sample.k, sample.timestamp_ns)
        dg = self._inner
        before = dg.mode == DIAGNOSE
        events = dg.update(sample)
        if dg.last_normalized is not None:
            k = np.array([sample.k])
            self._watch(k, dg.last_normalized[None, :] * dg.noise_scale,
                        monitoring_rows(k, events, before), events)
        out += events
        self._events += out
        return out

    def update_block(self, k: np.ndarray, t_ns: np.ndarray, U: np.ndarray, Z: np.ndarray,
                     gap: np.ndarray | None = None) -> BlockResult:
        """N samples: as N calls of `update`. The block is cut where the watchdog's blocks end
        (the same cuts whatever blocks the samples arrive in) wherever the noise the diagnoser
        detects against may change there."""
        gap = np.zeros(len(k), dtype=np.int64) if gap is None else np.asarray(gap)
        m = len(self.residual_names)
        R, Rn, stat = np.full((len(k), m), np.nan), np.full((len(k), m), np.nan), \
            np.zeros((len(k), m))
        events: list[FaultEvent] = []

        def take(lo: int, result: BlockResult) -> None:
            hi = lo + len(result.residuals)
            R[lo:hi], Rn[lo:hi], stat[lo:hi] = (result.residuals, result.normalized,
                                                result.statistic)
            events.extend(result.events)

        lo = 0
        if self._check is not None and len(k):
            lo, said, probed = self._checked(k, t_ns, U, Z, gap)
            take(0, probed)
            events += said
        while lo < len(k):
            events += self._close_before(int(k[lo]), int(t_ns[lo]))
            pieces = block_runs(k[lo:], self.watchdog.block)
            if self.watchdog.mismatch.any() or len(pieces) <= 2:
                # The noise scale may change where each block ends: one block at a time.
                hi = lo + pieces[0][1]
                take(lo, self._span(k[lo:hi], t_ns[lo:hi], U[lo:hi], Z[lo:hi], gap[lo:hi]))
                lo = hi
                continue
            # Not in mismatch, the scale stays 1 until a block ends in one (rare): run the rest
            # at once; should a block end in mismatch inside it, go back and stop there.
            saved = copy.deepcopy((self._inner, self.watchdog, self._held))
            got = self._span(k[lo:], t_ns[lo:], U[lo:], Z[lo:], gap[lo:], stop_on_change=True)
            if isinstance(got, BlockResult):
                take(lo, got)
                break
            self._inner, self.watchdog, self._held = saved
            hi = lo + got
            take(lo, self._span(k[lo:hi], t_ns[lo:hi], U[lo:hi], Z[lo:hi], gap[lo:hi]))
            lo = hi
        self._events += events
        return BlockResult(events, R, Rn, stat)

    # -- the watchdog beside the diagnosis -------------------------------------------------
    def _widen(self) -> None:
        """Give the diagnoser the noise the watchdog says detection should use."""
        self._inner.noise_scale = self.watchdog.scale

    def _close_before(self, k: int, t_ns: int) -> list[FaultEvent]:
        """Before sample k: close the watchdog's block if k ends it; a change of the residuals
        in mismatch is said, and sets the noise the diagnoser detects against."""
        wd = self.watchdog
        if not wd.due(k):
            return []
        change = wd.close(k)
        self._widen()
        if change is None:
            return []
        return self._said(change, t_ns)

    def _said(self, change: WatchdogChange, t_ns: int) -> list[FaultEvent]:
        """The events of a change of the residuals in mismatch, said at time t_ns."""
        names = self._inner.residual_names
        out = []
        quieter = change.ratio < 1.0
        for kind, which in (("mismatch", change.entered & ~quieter),
                            ("quiet", change.entered & quieter), ("matched", change.left)):
            if which.any():
                idx = np.flatnonzero(which)
                out.append(FaultEvent(kind=kind, sample=change.k, timestamp_ns=t_ns,
                                      residuals=tuple(names[i] for i in idx),
                                      estimates={names[i]: float(change.ratio[i]) for i in idx}))
        return out

    def _span(self, k: np.ndarray, t_ns: np.ndarray, U: np.ndarray, Z: np.ndarray,
              gap: np.ndarray, stop_on_change: bool = False) -> BlockResult | int:
        """One update_block of the diagnoser over the samples, the watchdog fed block by
        block (its block ends inside closed as they come). With ``stop_on_change``, a block
        end inside that changes the residuals in mismatch stops it: its row is returned
        instead (the caller goes back)."""
        dg, wd = self._inner, self.watchdog
        before = dg.mode == DIAGNOSE
        result = dg.update_block(k, t_ns, U, Z, gap)
        raw = result.normalized * dg.noise_scale
        quiet = monitoring_rows(k, result.events, before)
        for a, b, plain in watch_runs(k, wd.block, quiet):
            if plain:
                # Blocks the diagnoser only watched (no event, no row held back): the
                # watchdog takes them at once.
                changes = wd.update(k[a:b], raw[a:b], stop_on_change=stop_on_change)
                if changes and stop_on_change:
                    return int(np.searchsorted(k, changes[0].k))
                continue
            if a > 0 and wd.due(int(k[a])):
                change = wd.close(int(k[a]))
                if change is not None and stop_on_change:
                    return a
                # Without it, the span ends before any block end that changes anything (the
                # caller cut it there, or it is one block long).
            self._watch(k[a:b], raw[a:b], quiet[a:b],
                        [e for e in result.events if k[a] <= e.sample <= k[b - 1]])
        return result

    def _watch(self, k: np.ndarray, raw: np.ndarray, quiet: np.ndarray,
               events: list[FaultEvent]) -> None:
        """Samples k (N,) of one watchdog block, their residuals against the configured noise
        (N, m), to the watchdog: those the diagnoser watched (quiet (N,),
        core.watchdog.monitoring_rows) at once; those of a diagnosis held until it ends, then
        counted if it found no fault ("unexplained": the alarm was the noise), dropped if it
        found one. events: the events of these samples."""
        wd = self.watchdog
        wd.add(k[quiet], raw[quiet])
        if not quiet.all():
            self._held.append((k[~quiet], raw[~quiet]))
        for e in events:
            if e.kind not in DECISIONS or not self._held:
                continue
            kh, rh = self._held_rows()
            mine = kh <= e.sample
            if e.kind == "unexplained":
                wd.add_late(kh[mine], rh[mine])
            self._held = [(kh[~mine], rh[~mine])] if (~mine).any() else []

    def _held_rows(self) -> tuple[np.ndarray, np.ndarray]:
        """(k (N,), residuals (N, m)) of the rows held back under diagnoses, in order."""
        return (np.concatenate([h[0] for h in self._held]),
                np.concatenate([h[1] for h in self._held]))

    # -- the check of the configured noise -------------------------------------------------
    def _checked(self, k: np.ndarray, t_ns: np.ndarray, U: np.ndarray, Z: np.ndarray,
                 gap: np.ndarray) -> tuple[int, list[FaultEvent], BlockResult]:
        """While the configured noise is being checked: the samples go to the diagnoser as a
        probe and are kept, their residuals to the watchdog (those of the probe's diagnoses
        held back until they end: dropped if a fault explained them, noise if not or if still
        running when the window ends; a mismatch sets the probe's noise), block by block; the
        check ends (`_arm`) at the first block end from ``end`` on where the watchdog has a
        whole window to judge, or at ``cap`` whatever it has. Returns how many of these
        samples the check took, the events its end said and the probe's result on them.

        The probe runs one watchdog block at a time, after that block's start closed the one
        before: a mismatch found at a block end of the check widens it from the next sample
        on, whatever blocks the samples arrive in (its diagnoses, held rows and so the noise
        the check finds are the same)."""
        check, wd, probe = self._check, self.watchdog, self._inner
        if check.end is None:
            first = int(k[0])
            check.end = first // wd.block + wd.blocks + (1 if first % wd.block else 0)
            check.cap = check.end + wd.blocks + -(-self.longest_diagnosis // wd.block)
        parts: list[BlockResult] = []
        taken, said = len(k), []
        for a, b in block_runs(k, wd.block):
            if wd.due(int(k[a])):
                if int(k[a]) // wd.block >= check.end and self._held:
                    # A diagnosis of the probe's still running at the end of the window: its
                    # samples count as noise (a drive far noisier than configured alarms at
                    # once and would hold them all back; a real fault's step shows in one
                    # block only, and the quietest block sets the scale).
                    wd.add_late(*self._held_rows())
                    self._held = []
                check.changes.append(wd.close(int(k[a])))
                self._widen()
                block = int(k[a]) // wd.block
                if block >= check.cap or (block >= check.end and wd.judged):
                    taken = a
                    break
            before = probe.mode == DIAGNOSE
            result = probe.update_block(k[a:b], t_ns[a:b], U[a:b], Z[a:b], gap[a:b])
            self._watch(k[a:b], result.normalized * probe.noise_scale,
                        monitoring_rows(k[a:b], result.events, before), result.events)
            parts.append(result)
        if taken:
            check.kept.append((k[:taken], t_ns[:taken], U[:taken], Z[:taken], gap[:taken]))
        if taken < len(k):
            said = self._arm(int(t_ns[taken]))
        m = len(self.residual_names)
        probed = BlockResult(
            [], *(np.concatenate([np.empty((0, m))] + [getattr(r, f) for r in parts])
                  for f in ("residuals", "normalized", "statistic")))
        return taken, said, probed

    def _arm(self, t_ns: int) -> list[FaultEvent]:
        """End the check (the watchdog has just closed the block it ended with): what the
        watchdog found is said (at time t_ns) and sets the noise of the diagnoser, reset from
        its probing, which then diagnoses the kept samples; their events follow."""
        check = self._check
        self._check = None
        self._held = []  # what the probe's diagnoses held back: the diagnoser's own now
        self._inner.reset()
        self._widen()
        out: list[FaultEvent] = []
        for change in check.changes:
            if change is not None:
                out += self._said(change, t_ns)
        if not check.kept:
            return out
        kk, tt, UU, ZZ, gg = (np.concatenate(c) for c in zip(*check.kept, strict=True))
        # (Their residual rows were recorded as the check saw them, in time order: the log's
        # chunks keep increasing times, which is how a reader finds swapped ones.)
        return out + self._inner.update_block(kk, tt, UU, ZZ, gg).events

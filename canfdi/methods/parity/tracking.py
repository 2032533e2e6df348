"""Accepted faults go on being estimated: the data after the acceptance refine the compensation.

A fault is accepted as soon as its estimate has settled (within ``settle_rel_std`` of its size),
not when it is exact: what the estimate misses stays in the compensated residuals as a small
steady shift. Chan et al. 2006's recursive least squares would go on converging on it; re-detecting
it
instead (a Page-Hinkley alarm long after the acceptance, then a diagnosis that must isolate a
change far below the one it explained) is slow, and where the shift is below what the isolation
margin can tell apart it ends "unexplained": a false alarm after every large fault (seen on an
identified VTOL model, whose residuals the leftover moves five times more than the true model's).

So once a fault is accepted, every compensated channel is fitted again, jointly, on the
compensated residuals (the same regressors, each at its own onset, the parameters relative to
the compensation), starting from what the acceptances knew (their information matrices: a prior
centred on the compensation). At checkpoints 64, 128, 256, ... residual samples on, a channel's
correction is folded into the compensation when it is significant (chi-square at the 3-sigma
level on its marginal covariance), unless the segment since the previous checkpoint contradicts
the fit so far (the same test on the difference: a new fault that the detector has not seen
yet, which the fit must not absorb into a channel already compensated). Checkpoints double, so
a fault is refined a handful of times however long the drive runs, each time on twice the data.
The covariances are sandwiches, J^-1 (sum phi^T Gamma phi) J^-1 with Gamma the residuals'
long-run covariance: parity residuals over a window are correlated in time, and least squares
alone misjudges what a sum of them knows.

Only fault-free monitoring feeds the fit: while a diagnosis runs it pauses, and an acceptance
restarts it over the channels then compensated.

Tracking ends (with ``precise`` > 0) at the checkpoint where every tracked parameter is known to
within ``precise`` of its noise units (canfdi.methods.parity.hypotheses.noise_units), folding
the fit then whatever its significance: what the compensation can still miss is then far below
what detection sees, and a fit that went on would only risk taking a later small fault on a
channel of similar signature for more of the old one (the contradiction test cannot see a change
that is itself below its 3-sigma level).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from canfdi.core.identify import chi2_sigma
from canfdi.core.protocol import deepcopy_sharing
from canfdi.core.residuals import ResidualBank
from canfdi.methods.parity.hypotheses import (
    Hypothesis,
    noise_units,
    row_regressors,
    steady_response,
)

__all__ = ["AcceptedFaultTracker", "Correction", "Tracked", "steady_ratio"]

FIRST_CHECK = 64
"""Residual samples after an acceptance before the first check; each later one doubles it."""

PENDING = 256
"""Absorbed samples held before they are summed, all at once: the daemon's per-frame path
absorbs one sample at a time, and one sample's regressors and sums cost about what 256 do
together (numpy's fixed cost per call). Held samples are summed before a checkpoint reads the
sums; a hold never grows past this, whatever the distance to the next checkpoint."""


def steady_ratio(bank: ResidualBank, gamma: np.ndarray, target: str, index: int) -> float:
    """How much a sum of residuals along a channel's steady bias signature (``target``
    "sensor": sensor ``index``'s bias; otherwise actuator ``index``'s lambda) varies under the
    long-run covariance ``gamma`` over what least squares assumes (1: white, independent
    residuals): the factor an acceptance's information takes into its sandwich's middle.

    >>> from canfdi.core.design import design_bank
    >>> from canfdi.core.model import StateSpace
    >>> bank = ResidualBank(design_bank(StateSpace(A=[[0.9]], B=[[1.0]], C=[[1.0], [1.0]]),
    ...                                 ["u"], ["y0", "y1"]))
    >>> steady_ratio(bank, np.eye(bank.m), "sensor", 0)
    1.0
    """
    phi = steady_response(bank, target, index)
    norm = float(phi @ phi)
    return float(phi @ gamma @ phi) / norm if norm > 0.0 else 1.0


@dataclass(frozen=True)
class Tracked:
    """A compensated channel and how it is fitted: its hypothesis ("actuator",
    "actuator_bias" or "sensor"), its fault onset and the information its acceptance had
    about its parameters ((d, d), d = the hypothesis' parameters).

    Examples
    --------
    >>> t = Tracked(Hypothesis("sensor", 1, "y1"), onset=1000, precision=np.array([[4e4]]))
    >>> t.hypothesis.label, t.onset, float(1 / np.sqrt(t.precision[0, 0]))  # std at acceptance
    ('sensor:y1', 1000, 0.005)
    """

    hypothesis: Hypothesis
    onset: int
    precision: np.ndarray


@dataclass(frozen=True)
class Correction:
    """What a check folds into one channel's compensation: the parameters relative to it
    (a sensor's extra bias; an actuator's eta' - 1 and lambda', or lambda' alone) and their
    variances.

    Examples
    --------
    >>> t = Tracked(Hypothesis("sensor", 1, "y1"), onset=1000, precision=np.array([[4e4]]))
    >>> c = Correction(t, delta=np.array([0.004]), variances=np.array([1e-6]))
    >>> c.tracked.hypothesis.name, float(c.delta[0] / np.sqrt(c.variances[0]))  # 4 stds
    ('y1', 4.0)
    """

    tracked: Tracked
    delta: np.ndarray
    variances: np.ndarray


class AcceptedFaultTracker:
    """The joint fit of the compensated channels' remaining error (module docstring).

    ``restart(tracked)`` after each acceptance, ``absorb(k, u_windows, rn)`` for fault-free
    monitored samples, ``due`` at a checkpoint, ``correction()`` then.

    Parameters
    ----------
    bank : the residual bank.
    precise : end tracking at the checkpoint where every parameter's standard deviation is
        below this many of its noise units (0: track for ever).
    projection : (m, c) the detector's signature projections, which noise units count
        (hypotheses.noise_units); None: the residuals alone.
    long_run : (m, m) long-run covariance of the normalised residuals
        (canfdi.methods.parity.thresholds.long_run_covariance); the identity (white,
        independent residuals) when None. Parity residuals over a window are correlated in
        time and with each other, so the least-squares information overstates (or
        understates) what a sum of them knows: the covariances here are the sandwich
        J^-1 (sum phi^T Gamma phi) J^-1, and an acceptance's information is scaled by the
        same ratio along its channel's steady signature.

    Examples
    --------
    >>> from canfdi.core.model import StateSpace
    >>> from canfdi.core.design import design_bank
    >>> from canfdi.core.residuals import ResidualBank
    >>> m = StateSpace(A=[[0.9]], B=[[1.0]], C=[[1.0], [1.0]], dt=0.01)
    >>> bank = ResidualBank(design_bank(m, ["u"], ["y0", "y1"]))
    >>> t = AcceptedFaultTracker(bank)
    >>> t.restart([Tracked(Hypothesis("sensor", 0, "y0"), onset=0,
    ...                    precision=np.array([[1e-3]]))])
    >>> k, windows = np.arange(100, 164), np.zeros((64, bank.S + 1, 1))
    >>> phi = row_regressors(bank, [Hypothesis("sensor", 0, "y0")], [0], k, windows)
    >>> t.absorb(k, windows, 10.0 * phi[:, :, 0])  # a bias of 10 left over
    >>> t.due
    True
    >>> [round(float(c.delta[0]), 1) for c in t.correction()]
    [10.0]
    >>> t.samples_to_check()  # the next checkpoint is twice as far: 128 samples absorbed
    64
    """

    def __init__(self, bank: ResidualBank, long_run: np.ndarray | None = None,
                 precise: float = 0.0, projection: np.ndarray | None = None) -> None:
        self.bank = bank
        self.projection = projection
        self.gamma = np.eye(bank.m) if long_run is None else np.asarray(long_run, dtype=float)
        self.precise = float(precise)
        self._tracked: list[Tracked] = []
        self.clear()

    def __deepcopy__(self, memo: dict) -> AcceptedFaultTracker:
        """A copy that runs apart from this one, sharing the samples held (never written to)
        and the long-run covariance: the noise watchdog's undo copies the diagnoser, and with
        it this, on every block."""
        memo[id(self._pending)] = list(self._pending)
        return deepcopy_sharing(self, memo, self.gamma)

    @property
    def tracked(self) -> list[Tracked]:
        """The channels being fitted (a copy)."""
        return list(self._tracked)

    def clear(self) -> None:
        """Track nothing."""
        self.restart([])

    def _ratio(self, h: Hypothesis) -> float:
        """How much a sum of residuals along the channel's steady bias signature varies over
        what least squares assumes (`steady_ratio`)."""
        return steady_ratio(self.bank, self.gamma, h.target, h.index)

    def restart(self, tracked: list[Tracked]) -> None:
        """Fit these channels from now on, relative to the compensation as it now is, from
        the information of their acceptances."""
        self._tracked = list(tracked)
        sizes = [t.hypothesis.n_params for t in self._tracked]
        starts = np.cumsum([0, *sizes])[:-1]
        self._slices = [slice(int(a), int(a) + n) for a, n in zip(starts, sizes, strict=True)]
        D = sum(sizes)
        # The fit so far (information J, vector h, and the meat M of its sandwich covariance)
        # and the segment since the last checkpoint.
        self._J, self._h, self._M = np.zeros((D, D)), np.zeros(D), np.zeros((D, D))
        for t, s in zip(self._tracked, self._slices, strict=True):
            self._J[s, s] = t.precision
            self._M[s, s] = self._ratio(t.hypothesis) * t.precision
        self._new_segment()
        self._absorbed = 0
        self._next_check = FIRST_CHECK
        self._u_abs, self._u_n = np.zeros(self.bank.p), 0
        # (k, u_windows, rn, sigma) of samples absorbed but not yet summed (`_sum_pending`);
        # each row made by its caller and never written to (a copy may share them).
        self._pending: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
        self._pending_n = 0

    def _new_segment(self) -> None:
        D = len(self._h)
        self._seg_J, self._seg_h, self._seg_M = np.zeros((D, D)), np.zeros(D), np.zeros((D, D))

    @property
    def due(self) -> bool:
        """Whether a checkpoint is reached."""
        return bool(self._tracked) and self._absorbed >= self._next_check

    def samples_to_check(self) -> int | None:
        """Residual samples still to absorb before the next checkpoint (None: nothing is
        tracked)."""
        return max(self._next_check - self._absorbed, 0) if self._tracked else None

    def absorb(self, k: np.ndarray, u_windows: np.ndarray, rn: np.ndarray) -> None:
        """Absorb N monitored samples: (N,) k, (N, S+1, p) their compensated command windows,
        (N, m) normalised residuals (NaN: missing, no equation), each normalised by the
        bank's noise now. They are summed once `PENDING` are held, or when a checkpoint reads
        the sums (`correction`)."""
        if not self._tracked or len(k) == 0:
            return
        self._pending.append((np.asarray(k, dtype=np.int64), np.asarray(u_windows, dtype=float),
                              np.asarray(rn, dtype=float), self.bank.sigma))
        self._pending_n += len(k)
        self._absorbed += len(k)
        if self._pending_n >= PENDING:
            self._sum_pending()

    def _sum_pending(self) -> None:
        """Add the samples held into the segment's sums: one set of regressors and one
        product for all of them."""
        if not self._pending:
            return
        held, self._pending, self._pending_n = self._pending, [], 0
        k = np.concatenate([h[0] for h in held])
        u_windows = np.concatenate([h[1] for h in held])
        rn = np.concatenate([h[2] for h in held])
        sigma = np.concatenate([np.broadcast_to(h[3], (len(h[0]), self.bank.m)) for h in held])
        phi = row_regressors(self.bank, [t.hypothesis for t in self._tracked],
                             [t.onset for t in self._tracked], k, u_windows, sigma)
        valid = ~np.isnan(rn)
        phi = phi * valid[:, :, None]
        r = np.where(valid, rn, 0.0)
        self._seg_J += np.einsum("nmi,nmj->ij", phi, phi)
        self._seg_h += np.einsum("nmi,nm->i", phi, r)
        self._seg_M += np.einsum("nmi,mk,nkj->ij", phi, self.gamma, phi)
        self._u_abs += np.abs(np.nan_to_num(u_windows[:, -1, :])).sum(0)
        self._u_n += len(k)

    def correction(self) -> list[Correction]:
        """At a checkpoint: the channels whose correction is significant, now counted as
        folded in (none when the segment since the last checkpoint contradicts the fit so
        far: a new change, left to the detector); the next checkpoint is twice as far."""
        self._sum_pending()
        self._next_check *= 2
        sJ, sh, sM = self._seg_J, self._seg_h, self._seg_M
        self._new_segment()
        W = np.linalg.inv(self._J)
        before, P_before = W @ self._h, W @ self._M @ W
        # Under "the same remaining error throughout" the segment's information vector is
        # J_seg delta + noise with delta ~ N(before, P_before): v is N(0, spread).
        v = sh - sJ @ before
        spread = sM + sJ @ P_before @ sJ
        rank = int(np.linalg.matrix_rank(spread, hermitian=True))
        if rank and float(v @ np.linalg.pinv(spread, hermitian=True) @ v) > chi2_sigma(rank):
            return []
        self._J, self._h, self._M = self._J + sJ, self._h + sh, self._M + sM
        W = np.linalg.inv(self._J)
        theta, P = W @ self._h, W @ self._M @ W
        # The last checkpoint (every parameter precise) folds the fit whatever its size: it
        # is the best estimate there will be, and no later check can fold what it leaves.
        last = self.precise > 0.0 and self._precise(P)
        out, applied = [], np.zeros(len(theta))
        for t, s in zip(self._tracked, self._slices, strict=True):
            delta, Ps = theta[s], P[s, s]
            if not (last and np.any(delta)) and float(
                    delta @ np.linalg.solve(Ps, delta)) < chi2_sigma(len(delta)):
                continue
            applied[s] = delta
            out.append(Correction(t, delta.copy(), np.diag(Ps).copy()))
        # The fit is now relative to the new compensation: its mean moves, its information
        # stays.
        self._h = self._h - self._J @ applied
        if last:
            self.clear()
        return out

    def _precise(self, P: np.ndarray) -> bool:
        """Whether every tracked parameter's standard deviation (P: the fit's covariance) is
        within ``precise`` of its noise units."""
        u_mean = self._u_abs / max(self._u_n, 1)
        for t, s in zip(self._tracked, self._slices, strict=True):
            h = t.hypothesis
            unit = noise_units(self.bank, h, float(u_mean[h.index])
                               if h.target == "actuator" else None, self.projection)
            if np.any(np.sqrt(np.diag(P[s, s])) > self.precise * unit):
                return False
        return True

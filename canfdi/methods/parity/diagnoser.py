"""The per-sample diagnosis state machine: residuals -> detection -> identification -> isolation
-> acceptance -> compensation and reset -> on to the next fault.

MONITOR. Each sample's residuals (canfdi.core.residuals), normalised by their noise standard
deviation, feed a two-sided Page-Hinkley test per residual (thresholds calibrated on fault-free
residuals of the model for a stated false-alarm interval). With ``signature_drifts`` (the
config's detection.signatures) a CUSUM per fault signature across all the residuals runs beside
it (canfdi.methods.parity.signatures). An alarm at k_d starts a diagnosis, from onsets around
the detector's change point however long before the alarm it lies (the samples back to it are
kept: canfdi.methods.parity.recent).

DIAGNOSE. Every fault hypothesis (each actuator: u = eta u_c + lambda, eq. 24; each sensor:
z = y + b, eq. 34) predicts the residuals linearly in its parameters from the fault onset k_f on
(canfdi.core.residuals' signatures), so each hypothesis is identified by recursive least squares
in information form (P reset at the alarm, forgetting factor 1: the abrupt-fault setting of
DESIGN.md), over all residuals at once. As the output-error paper shifts its step to find k_f, each
hypothesis
is fitted for several onsets around the Page-Hinkley change point. From ``min_samples`` after the
alarm the fits are compared by their least-squares cost J: the best hypothesis is accepted when
every hypothesis outside its ambiguity group costs at least ``isolation_margin`` more (a
log-likelihood-ratio margin on the normalised residuals) and its estimates have settled (standard
deviation below ``settle_rel_std`` of their size) and it leaves about the noise (residual variance
per equation at most ``max_fit_variance`` times nominal: a transient such as one corrupt sample
is no persistent fault, and no step fits it). Hypotheses whose bias signatures over the window
are proportional fit equally well forever (the ambiguity group); the event then lists them all
as candidates, with the size each would have.
At ``max_samples`` a best hypothesis that fits but whose margin over some others was never
reached (near twins: signatures that differ only in a transient the noise hides) is accepted
with those others named as its candidates, each with its estimate; one that does not fit: an
"unexplained" event, and the detector restarts.

ACCEPT. The estimate is folded into a compensation applied from k_f on (z_j - b, or
u_j = eta u_cj + lambda), the residual window is rebuilt from compensated samples and the
detector restarts (the output-error paper's Section 3.3), so a later fault on any channel is
diagnosed on top of
the ones already found, repaired or not. A later diagnosis on a channel already compensated
is a fault of its own when its size differs from none beyond what the earlier estimate's
uncertainty explains ("accepted", its own size, whatever was accepted before on the channel or
on a look-alike the same name stands for); otherwise it is what a not quite exact estimate left
of the earlier fault and refines it: a "refined" event with that fault's updated size
(canfdi.core.records.fold). Between diagnoses the
accepted faults go on being estimated on the compensated residuals, and a significant
correction is folded in the same way (canfdi.methods.parity.tracking): a "refined" event with no
detection.
"""

from __future__ import annotations

import copy
from collections import deque
from dataclasses import dataclass, replace

import numpy as np

from canfdi.core.blockrun import BlockRows, continuity_breaks, has_values, run_block
from canfdi.core.design import Design
from canfdi.core.detect import ChangePointDetector, DetectorBacked, onset_candidates
from canfdi.core.identify import RlsState, rls_init, rls_solve
from canfdi.core.protocol import DIAGNOSE, MONITOR, deepcopy_sharing
from canfdi.core.records import (
    BlockResult,
    Compensation,
    FaultEvent,
    Sample,
    compensate,
    fault_onset,
    fold,
)
from canfdi.core.residuals import ResidualBank
from canfdi.methods.parity.decide import (
    ACCEPT_NEAR,
    NAME,
    UNEXPLAINED,
    WAIT,
    Decision,
    HypothesisTable,
    decide_reference,
    spread,
    unit_table,
)
from canfdi.methods.parity.hypotheses import (
    Hypothesis,
    independent_sensors,
    information_increments,
    proportional,
    regressor_columns,
    row_regressors,
)
from canfdi.methods.parity.recent import RecentWindows
from canfdi.methods.parity.settling import excitation_bound
from canfdi.methods.parity.signatures import SignatureColumns
from canfdi.methods.parity.thresholds import lagged_middle
from canfdi.methods.parity.tracking import AcceptedFaultTracker, Tracked

__all__ = ["Diagnosis", "ParityDiagnoser", "ParitySettings"]

@dataclass(frozen=True)
class ParitySettings:
    """Detection and acceptance settings (the config's detection: and identification:).

    drift : Page-Hinkley delta in residual noise standard deviations.
    false_alarm_interval : samples between false alarms per residual the thresholds target.
    min_samples, max_samples : samples after the alarm before a decision / before giving up.
    settle_rel_std : accept when each estimate's standard deviation is below this fraction of
        its size (an actuator's lambda: of max(|lambda|, 0.1 |eta - 1| mean|u_c|)),
    settle_noise : or below this many of its noise units (the size whose steady change in the
        most sensitive residual is one noise standard deviation: 1 / the channel's
        fault-to-noise ratio per unit): a small fault is then known well enough that what its
        compensation leaves is far below what detection sees, and the accepted fault's
        tracker refines it (0: the relative test alone).
    isolation_margin : cost margin over every hypothesis outside the best one's group.
    onset_before : onsets tried before the detector's change point; at most max_onsets in
        all, half from there on and half up to the alarm (the samples back to the change point
        are kept, up to max_samples of them: a fault detected late is still fitted from its
        onset).
    prior_precision : P reset value is 1 / prior_precision (information form: J0 = this * I).
    max_fit_variance : accept only a fit whose cost per residual equation (normalised residuals:
        1 is the noise) is at most this.
    signature_drifts : the drift ladder of the signature CUSUMs run beside the residuals'
        Page-Hinkley (canfdi.methods.parity.signatures, e.g. its DRIFTS); () (the default:
        the config's detection.signatures false) runs Page-Hinkley alone.
    lookback : samples before the first onset tried that a diagnosis also fits when channels
        are compensated (the config's identification.lookback): over them a compensated
        channel's leftover (acting from its fault's onset) and a new fault (acting from its
        own) differ. A drive's MCU keeps them all in its memory and absorbs them between the
        alarm and the first decision, so a smaller value there buys memory and time
        (docs/howto/mcu.md).

    Examples
    --------
    >>> settings = ParitySettings(max_samples=4000, signature_drifts=(0.25, 1.0))
    >>> settings.drift, settings.max_samples, settings.signature_drifts
    (0.5, 4000, (0.25, 1.0))
    """

    drift: float = 0.5
    false_alarm_interval: float = 1.0e7
    min_samples: int = 10
    max_samples: int = 2000
    settle_rel_std: float = 0.005
    settle_noise: float = 0.2
    isolation_margin: float = 50.0
    onset_before: int = 3
    max_onsets: int = 16
    prior_precision: float = 1e-8
    max_fit_variance: float = 2.25
    signature_drifts: tuple[float, ...] = ()
    lookback: int = 256


@dataclass(frozen=True)
class Diagnosis:
    """A diagnosis in progress: what the alarm at ``k_d`` started.

    onsets : (K,) candidate fault onsets; info : the information of every hypothesis and onset,
    batch shape (H, K) (canfdi.core.identify, P reset at the alarm); meat : (H, K, d, d) sum of
    phi^T Gamma phi, Gamma the residuals' long-run covariance: the middle of the estimates'
    sandwich covariance P meat P, which the settling test judges by; u_abs, n_u : (p,) sum of
    |u_c| and count of known commands since the alarm (the scale an actuator's lambda is judged
    against); named : whether the fault was named (`ParityDiagnoser._name`). (The same middle
    counting the residuals' correlation lag by lag, what the estimates the events report vary
    by, is formed only for the hypothesis an event reports: `ParityDiagnoser._lagged_meat`.)

    Examples
    --------
    >>> from canfdi.core.identify import rls_init
    >>> d = Diagnosis(k_d=1027, onsets=np.array([999, 1000]), info=rls_init(1, shape=(3, 2)),
    ...               meat=np.zeros((3, 2, 1, 1)), u_abs=np.zeros(1), n_u=np.zeros(1))
    >>> d.info.J.shape  # (hypotheses, onsets, d, d)
    (3, 2, 1, 1)
    """

    k_d: int
    onsets: np.ndarray
    info: RlsState
    meat: np.ndarray
    u_abs: np.ndarray
    n_u: np.ndarray
    named: bool = False


class ParityDiagnoser(DetectorBacked):
    """Streaming diagnoser: ``update(sample) -> events``.

    Parameters
    ----------
    design : the residual bank's design (canfdi.core.design.design_bank).
    settings : ParitySettings.
    thresholds : (m,) Page-Hinkley thresholds in noise-std units (calibrate_thresholds); with
        ``signatures``, (m + c,): the residuals', then the signature CUSUMs'.
    long_run : (m, m) long-run covariance of the normalised residuals (thresholds.
        long_run_covariance), which the refinement of accepted faults judges its fits by;
        None: white, independent residuals.
    signatures : the signature CUSUMs detection runs beside the residuals' (signatures.
        signature_columns); None: Page-Hinkley on the residuals alone.
    lagged : (S+1, m, m) the normalised residuals' autocovariances at lags 0..S (thresholds.
        lagged_covariance): a diagnosis' estimates then vary as the residuals' correlation
        across the fault's transient says; None: as ``long_run`` says at every sample (right
        for steady regressors only: the transient's information is overstated where the
        residuals' long-run variance is far below their variance, as on the winding machine).

    Examples
    --------
    >>> from canfdi.core.calibrate import threshold_for_long_run_variance
    >>> from canfdi.core.design import DesignOptions, design_bank
    >>> from canfdi.core.model import StateSpace
    >>> from canfdi.core.records import Sample
    >>> model = StateSpace(A=[[0.9]], B=[[1.0]], C=[[1.0], [1.0]], dt=0.01)  # two sensors of x
    >>> design = design_bank(model, ["u"], ["y0", "y1"],
    ...                      DesignOptions(measurement_std=np.array([0.01, 0.01])))
    >>> diag = ParityDiagnoser(design, ParitySettings(),
    ...                        threshold_for_long_run_variance(0.5, 1e7, np.ones(3)))
    >>> diag.residual_names
    ['a:u', 's:y0', 's:y1']
    >>> rng = np.random.default_rng(0)
    >>> x, events = 0.0, []
    >>> for k in range(1100):
    ...     u = np.sign(np.sin(k / 30))
    ...     z = x + 0.01 * rng.standard_normal(2)
    ...     z[1] += 0.1 if k >= 1000 else 0.0  # y1 reads 0.1 high from sample 1000
    ...     events += diag.update(Sample(k, 0, np.array([u]), z))
    ...     x = 0.9 * x + u
    >>> [(e.kind, e.sample, e.name, {n: round(v, 2) for n, v in e.estimates.items()})
    ...  for e in events]
    [('detected', 1027, None, {}), ('accepted', 1037, 'y1', {'bias': 0.1})]
    """

    def __init__(self, design: Design, settings: ParitySettings, thresholds: np.ndarray,
                 long_run: np.ndarray | None = None,
                 signatures: SignatureColumns | None = None,
                 lagged: np.ndarray | None = None) -> None:
        self.design = design
        self.settings = settings
        self.bank = ResidualBank(design)
        self._sigma0 = self.bank.sigma.copy()
        extra = 0 if signatures is None else signatures.count
        thresholds = np.asarray(thresholds, dtype=float).reshape(self.bank.m + extra)
        model = design.model
        self.q, self.p = model.q, model.p
        self.hypotheses = [Hypothesis("actuator", j, n) for j, n in
                           enumerate(design.input_names)]
        self.hypotheses += [Hypothesis("sensor", j, n) for j, n in enumerate(design.output_names)]
        # Hypotheses no residual responds to can never be identified: leave them out.
        responds = design.responds
        keep = []
        for h in self.hypotheses:
            col = h.index if h.target == "actuator" else model.p + h.index
            rows = [i for i, r in enumerate(design.actuators + design.sensors) if r.vector.exists]
            if responds[rows, col].any():
                keep.append(h)
        # A bias alone is the actuator fault with eta = 1: one parameter, so it settles far
        # sooner when the command's excitation cannot yet tell eta from lambda, and the
        # penalty on the second parameter makes it win unless eta really differs from 1.
        keep += [Hypothesis("actuator_bias", h.index, h.name) for h in keep
                 if h.target == "actuator"]
        self.hypotheses = keep
        joint = independent_sensors(self.bank, [h.index for h in keep if h.target == "sensor"])
        if len(joint) > 1:
            self.hypotheses.append(Hypothesis("sensors", joint[0], "+".join(
                design.output_names[j] for j in joint), members=tuple(joint)))
        self.d = max(h.n_params for h in self.hypotheses)
        # A diagnosis' regressors and sums (hypotheses.information_increments), or the same on
        # a kernel (use_kernel), from the hypotheses' columns.
        self._columns = regressor_columns(self.hypotheses, self.d)
        self.information = self.information_reference
        self.solve = self.solve_reference
        self.decide = self.decide_reference
        # Hypotheses whose bias signatures over the window are proportional (a sensor's Gz_j,
        # an actuator's lambda part Gu_j) fit a bias equally well forever: they are reported
        # together, never told apart. (The design's isolability table, which compares only
        # which residuals respond, is coarser: T1 and u1 of the winding machine share their
        # residuals but not their signatures, and the data tell them apart.)
        single = [h for h in self.hypotheses if h.target != "sensors"]
        signature = {h: (self.bank.Gz if h.target == "sensor" else self.bank.Gu)[h.index]
                     .ravel() for h in single}
        self._twins = {h: {g for g in single if g != h
                           and proportional(signature[h], signature[g])} for h in single}
        for h in self.hypotheses:
            self._twins.setdefault(h, set())
        # What a diagnosis' decision reads of the hypotheses (decide.py); the noise units are
        # remade when the bank's noise changes (the watchdog).
        self._table = HypothesisTable.of(self.hypotheses, self._twins, settings.isolation_margin)
        self._units: np.ndarray | None = None
        self._units_sigma: np.ndarray | None = None
        self._leftover_at = np.full(len(self.hypotheses), -1, dtype=np.int32)
        m = self.bank.m
        if signatures is None:
            self._detector = ChangePointDetector(m, settings.drift, thresholds)
            self._column_residuals = [(i,) for i in range(m)]
        else:
            self._detector = ChangePointDetector(
                m, settings.drift, thresholds[:m], projection=signatures.projection,
                drifts=signatures.drifts, h_projected=thresholds[m:])
            self._column_residuals = [(i,) for i in range(m)] + list(signatures.residuals)
        n_onsets = settings.max_onsets
        self._history: deque = deque(maxlen=self.bank.S + n_onsets + 8)
        # A diagnosis starts at the change point, however long before the alarm (recent.py).
        self._recent = RecentWindows(max(settings.max_samples, n_onsets + 8), self.bank.S + 1,
                                     self.q + self.p, self.bank.m)
        self.compensation: list[Compensation] = []
        self.events: list[FaultEvent] = []
        self._diag: Diagnosis | None = None
        # Tracking ends once the compensation is known to a quarter of what acceptance needed.
        self._projection = None if signatures is None else signatures.projection
        self.tracker = AcceptedFaultTracker(self.bank, long_run, settings.settle_noise / 4.0,
                                            self._projection)
        self._lagged = None if lagged is None else np.asarray(lagged, dtype=float).reshape(
            self.bank.S + 1, self.bank.m, self.bank.m)
        # (k, commands' window, residual seen, sigma) of every sample a diagnosis absorbed: the
        # lagged sandwich of the one hypothesis an event reports is formed from them when it
        # reports (lag by lag over every hypothesis and onset at each sample cost 4x the fit).
        self._absorbed: list[tuple[int, np.ndarray, np.ndarray, np.ndarray]] = []
        self.reset()

    information_reference = staticmethod(information_increments)
    """A diagnosis' regressors and sums in numpy: what ``information`` runs unless a kernel
    put its own there (`use_kernel`)."""
    solve_reference = staticmethod(rls_solve)
    """Every fit of a diagnosis solved, in numpy: what ``solve`` runs unless a kernel put its
    own there."""
    decide_reference = staticmethod(decide_reference)
    """A diagnosis' decision at one sample from its fits (decide.py), in numpy: what
    ``decide`` runs unless a kernel put its own there."""

    # -- state ---------------------------------------------------------------------------
    def __deepcopy__(self, memo: dict) -> ParityDiagnoser:
        """A copy that runs apart from this one, sharing what update never changes: the
        design, the hypotheses and their twins, the bank's and tracker's matrices, and the
        rows of the history and of the absorbed samples (each made once, never written to: the
        containers are copied, their rows shared). The noise watchdog's undo copies the
        diagnoser on every block it runs at once (canfdi.core.watched)."""
        bank = self.bank
        memo[id(self._history)] = copy.copy(self._history)
        memo[id(self._absorbed)] = list(self._absorbed)
        return deepcopy_sharing(
            self, memo, self.design, self.settings, self.hypotheses, self._twins,
            self._column_residuals, self._columns, self._sigma0, self._lagged, self._projection,
            bank.M, bank.blocks, bank.uses, bank._uses, bank.Gz, bank.Gu, bank.names,
            bank.kinds, bank.indices, self.tracker.gamma, self._table)

    def reset(self) -> None:
        """Back to the state after construction: monitoring, no compensation, no events, empty
        windows."""
        self.noise_scale = 1.0
        self.mode = MONITOR
        self.events = []
        self.bank.restart()
        self._history.clear()
        self._recent.clear()
        self.compensation = []
        self.tracker.clear()
        self._restart_detector()
        self._last_k: int | None = None
        self.last_residuals: np.ndarray | None = None
        self.last_normalized: np.ndarray | None = None

    def _restart_detector(self, k: int = -1) -> None:
        """Zero the Page-Hinkley statistics; a change point cannot predate sample k."""
        self._detector.reset(k)
        self._diag = None
        self._absorbed.clear()

    @property
    def residual_names(self) -> list[str]:
        return self.bank.names

    def use_kernel(self, kernel) -> None:
        """Run the residual bank's and the detector's block forms, and a diagnosis'
        regressors and sums (``information``), their solution (``solve``) and the decision
        over them (``decide``), on ``kernel`` (canfdi.core.kernel.Kernel)."""
        kernel.install(bank=self.bank, detectors=(self._detector,), fits=self)

    @property
    def noise_scale(self) -> np.ndarray:
        """(m,) each residual's noise over the design's (settable: the noise watchdog widens
        the noise of a residual in mismatch, canfdi.core.watchdog; 1 by default)."""
        return self.bank.sigma / self._sigma0

    @noise_scale.setter
    def noise_scale(self, value: np.ndarray) -> None:
        self.bank.sigma = self._sigma0 * np.broadcast_to(np.asarray(value, dtype=float),
                                                         self._sigma0.shape)

    # -- compensation ----------------------------------------------------------------------
    def _compensate(self, k: int, z: np.ndarray, u: np.ndarray) -> np.ndarray:
        """(q+p,) the sample [z, u] with the accepted faults undone."""
        return self._compensate_block(np.array([k]), z[None, :], u[None, :])[0]

    def _compensate_block(self, k: np.ndarray, Z: np.ndarray, U: np.ndarray) -> np.ndarray:
        """(N, q+p) compensated samples [Z, U]."""
        Zc, Uc = compensate(self.compensation, k, Z, U)
        return np.hstack([Zc, Uc])

    def update_block(self, k: np.ndarray, t_ns: np.ndarray, U: np.ndarray, Z: np.ndarray,
                     gap: np.ndarray | None = None) -> BlockResult:
        """Process N samples at once; the same events and state as N calls of ``update``.

        Fault-free stretches are vectorised (residuals as one matrix product over a sliding
        window view, Page-Hinkley in its cumulative-sum form); the sample that raises an alarm,
        the samples of a diagnosis and those after a missing sample go through ``update``
        itself.

        Parameters
        ----------
        k, t_ns : (N,) increasing sample indices and timestamps; U : (N, p); Z : (N, q), NaN
        where a value was lost; gap : (N,) samples missing before each (informational: the
        indices say it).
        """
        k = np.asarray(k, dtype=np.int64)
        U = np.asarray(U, dtype=float)
        Z = np.asarray(Z, dtype=float)
        breaks = continuity_breaks(k, self._last_k, first_breaks=False)
        return run_block(self, k, t_ns, U, Z, gap, breaks,
                         lambda i, j, rows: self._monitor_stretch(k, U, Z, i, j, rows))

    def _monitor_stretch(self, k: np.ndarray, U: np.ndarray, Z: np.ndarray, i: int, j: int,
                         rows: BlockRows) -> int:
        """Vectorised monitoring of the continuous samples i..j-1 (canfdi.core.blockrun):
        returns j, or the row of the alarm, which ``update`` then takes."""
        S = self.bank.S
        X = self._compensate_block(k[i:j], Z[i:j], U[i:j])
        E = np.vstack([self.bank.tail, X])
        res = self.bank.batch(E)  # row r: the residuals at X row r, as update would give them
        rn = res / self.bank.sigma
        have = has_values(rn)  # rows where update returns residuals
        cap = j - i
        to_check = self.tracker.samples_to_check()
        if to_check is not None:
            # The sample that reaches the tracker's checkpoint goes through update.
            reach = np.flatnonzero(np.cumsum(have) >= max(to_check, 1))
            if len(reach):
                cap = int(reach[0])
            if cap == 0:
                return i
        blk = self._detector.update_block(k[i: i + cap], rn[:cap])
        done = blk.done
        if done > 0:
            m = self.bank.m
            rows.stat[i: i + done] = np.maximum(blk.g_up[:done, :m], blk.g_down[:done, :m])
            rows.R[i: i + done] = res[:done]
            rows.Rn[i: i + done] = rn[:done]
            # Bring the streaming state up to date with rows i..i+done-1.
            self.bank.load(E[: S + done])
            for r in range(max(0, done - self._history.maxlen), done):
                self._history.append((int(k[i + r]), np.array(Z[i + r], dtype=float),
                                      np.array(U[i + r], dtype=float)))
            self._recent.push(k[i: i + done], X[:done], rn[:done], have[:done])
            if self.tracker.tracked:
                rows_u = np.lib.stride_tricks.sliding_window_view(
                    E[: S + done, self.q:], S + 1, axis=0).transpose(0, 2, 1)
                sel = np.flatnonzero(have[:done])
                self.tracker.absorb(k[i + sel], rows_u[sel], rn[sel])
            self._last_k = int(k[i + done - 1])
            if have[done - 1]:
                self.last_residuals, self.last_normalized = res[done - 1], rn[done - 1]
            else:
                self.last_residuals = self.last_normalized = None
        return i + done

    # -- the state machine -----------------------------------------------------------------
    def update(self, sample: Sample) -> list[FaultEvent]:
        """Process one sample; returns the events it caused (usually none)."""
        k = sample.k
        if self._last_k is not None and k != self._last_k + 1:
            missing = k - self._last_k - 1
            if 0 < missing <= self.bank.S:
                self.bank.skip(missing)  # residuals whose windows miss them are missing
                self._recent.skip(k, missing)
            else:
                self.bank.restart()
                self._recent.clear()
            self._history.clear()
        self._last_k = k
        self._history.append((k, np.asarray(sample.z, dtype=float).copy(),
                              np.asarray(sample.u, dtype=float).copy()))
        x = self._compensate(k, sample.z, sample.u)
        r = self.bank.update(x[: self.q], x[self.q :])
        self.last_residuals = r
        if r is None:
            self.last_normalized = None
            self._recent.push(np.array([k]), x[None, :], np.full((1, self.bank.m), np.nan),
                              np.zeros(1, dtype=bool))
            return []
        rn = r / self.bank.sigma
        self.last_normalized = rn
        self._recent.push(np.array([k]), x[None, :], rn[None, :])
        window = self.bank.window.copy()
        if self.mode != MONITOR:
            return self._diagnose(k, sample.timestamp_ns, window, rn)
        if self.tracker.tracked:
            self.tracker.absorb(np.array([k]), window[None, :, self.q:], rn[None, :])
        events = self._monitor(k, sample.timestamp_ns, rn)
        if self.mode == MONITOR and self.tracker.due:
            events += self._refine_tracked(k, sample.timestamp_ns)
        return events

    def _monitor(self, k: int, t: int, rn: np.ndarray) -> list[FaultEvent]:
        alarm = self._detector.update(k, rn)
        if not alarm.any():
            return []
        alarming = np.flatnonzero(alarm)
        change_point = self._detector.change_point(alarm)
        s = self.settings
        onsets = onset_candidates(change_point, k, self._recent.first, s.onset_before,
                                  s.max_onsets, keep="ends")
        # The compensated channels' faults are tried at their own onsets too, over the samples
        # before the change point: what an estimate left acts from that fault's onset on, a new
        # fault from its own (`_leftover`).
        earlier = sorted({o for c in self.compensation
                          if (o := fault_onset(self.compensation, c.target, c.index)) is not None
                          and o < onsets[0]})
        start = max(earlier[0], onsets[0] - s.lookback) if earlier else onsets[0]
        self._start_diagnosis(k, earlier + onsets)
        kept = list(self._recent.since(start))
        if kept:
            ks, windows, rns = zip(*kept, strict=True)
            self._accumulate(np.array(ks), np.stack(windows), np.stack(rns))
        event = FaultEvent(kind="detected", sample=k, timestamp_ns=t, detected_sample=k,
                           onset_sample=change_point,
                           residuals=tuple(self.bank.names[i] for i in sorted(
                               {r for c in alarming for r in self._column_residuals[c]})))
        self.events.append(event)
        return [event]

    def _start_diagnosis(self, k: int, onsets: list[int]) -> None:
        H, K = len(self.hypotheses), len(onsets)
        self.mode = DIAGNOSE
        self._absorbed.clear()
        # Each hypothesis' channel's latest accepted fault, dated at one of the onsets tried:
        # a fit from there that costs about as little is what its estimate left (decide.py).
        self._leftover_at = np.array(
            [_position(onsets, fault_onset(self.compensation, _channel(h), h.index))
             for h in self.hypotheses], dtype=np.int32)
        self._diag = Diagnosis(k_d=k, onsets=np.array(onsets),
                               info=rls_init(self.d, self.settings.prior_precision, shape=(H, K)),
                               meat=np.zeros((H, K, self.d, self.d)),
                               u_abs=np.zeros(self.p), n_u=np.zeros(self.p))

    def _accumulate(self, k: np.ndarray, windows: np.ndarray, rn: np.ndarray) -> None:
        """Absorb samples k (N,) into every hypothesis' fit: their windows (N, S+1, q+p) and
        normalised residuals (N, m), a missing residual no equation. (The information form is
        a sum: a block is absorbed at once, as sample by sample.)"""
        d = self._diag
        U = windows[:, :, self.q:]
        sums = self.information(self.bank, self.hypotheses, self._columns, self.d, d.onsets, k,
                                U, rn, self.tracker.gamma)
        if self._lagged is not None:
            sigma = self.bank.sigma.copy()
            self._absorbed.extend(zip(k.tolist(), U.copy(), ~np.isnan(rn), [sigma] * len(k),
                                      strict=True))
        u_now = U[:, -1]
        seen = ~np.isnan(u_now)
        self._diag = replace(d, info=sums.added_to(d.info, len(k)), meat=d.meat + sums.meat,
                             u_abs=d.u_abs + np.where(seen, np.abs(np.nan_to_num(u_now)),
                                                      0.0).sum(axis=0),
                             n_u=d.n_u + seen.sum(axis=0))

    def _diagnose(self, k: int, t: int, window: np.ndarray, rn: np.ndarray
                  ) -> list[FaultEvent]:
        self._accumulate(np.array([k]), window[None], rn[None])
        d, s = self._diag, self.settings
        since = k - d.k_d
        if since < s.min_samples:
            return []
        fit = self.solve(d.info)
        if self._units_sigma is None or not np.array_equal(self._units_sigma, self.bank.sigma):
            self._units = unit_table(self.bank, self.hypotheses, self.d, self._projection)
            self._units_sigma = self.bank.sigma.copy()
        dec = Decision(*self.decide(self._table, s, fit, d.info.rr, d.info.n_eq, d.meat,
                                    d.u_abs, d.n_u, self._units, self._leftover_at, since,
                                    d.named))
        if dec.action == WAIT:
            return []
        theta, best, kb = fit.theta, dec.best, dec.kb
        cost = np.broadcast_to(fit.cost, theta.shape[:2])
        if dec.action == UNEXPLAINED:
            return self._unexplained(k, t, theta, dec.best_onset, dec.order)
        if dec.action == NAME:
            return self._name(k, t, fit, cost, dec.best_onset, best, dec.size_known,
                              dec.form_known)
        # (ACCEPT_NEAR: what tells near twins apart, a transient, is buried in the noise and
        # max_samples of data did not decide. The fault is there and fits: the best is named
        # with every channel within the margin as its candidates rather than none.)
        near = [int(i) for i in dec.order if dec.near[i]] if dec.action == ACCEPT_NEAR else []
        return self._accept(k, t, best, kb, theta, self._reported(fit, cost, best, kb),
                            dec.scale, dec.best_onset, dec.cost_h, cost[best], near,
                            self._bias_eta_variance(fit, cost, dec.best_onset,
                                                    self.hypotheses[best]))

    def _name(self, k: int, t: int, fit, cost: np.ndarray, best_onset: np.ndarray, best: int,
              size_known: bool, form_known: bool) -> list[FaultEvent]:
        """NAMED: the sequential test names the faulty component (the best fit's group ahead
        of every other by the isolation margin, and a fault, not noise) before its form and
        size are known, once per diagnosis. Its size is the one it acts with now: a sensor's
        bias; an actuator's offset (its bias-only fit: a scale acts as one while the command
        holds). ``undecided``: "form" while a scale is not ruled out, "size" while the estimate
        has not settled. (A joint fit of several sensors is named when accepted.)"""
        d = self._diag
        self._diag = replace(d, named=True)
        h = self.hypotheses[best]
        src = best
        if h.target == "actuator":
            src = next((i for i, g in enumerate(self.hypotheses)
                        if g.target == "actuator_bias" and g.index == h.index), best)
        g = self.hypotheses[src]
        kb = int(best_onset[src])
        desc = self._describe(g, fit.theta[src, kb], self._reported(fit, cost, src, kb))
        estimates, variances = desc["estimates"], desc["variances"]
        candidates: tuple[dict, ...] = ()
        if g.target == "sensor":
            candidates = self._sensor_twins(g.index, estimates["bias"])
        else:  # the offset it acts as now; its scale is what "form" waits for
            estimates = {"lambda": estimates["lambda"]}
            variances = {"lambda": variances["lambda"]}
        undecided = (("form",) if not form_known else ()) + (("size",) if not size_known
                                                             else ())
        event = FaultEvent(kind="named", sample=k, timestamp_ns=t, target=desc["target"],
                           index=g.index, name=g.name, estimates=estimates,
                           variances=variances, onset_sample=int(d.onsets[kb]),
                           detected_sample=d.k_d, candidates=candidates, undecided=undecided)
        self.events.append(event)
        return [event]

    def _bias_eta_variance(self, fit, cost: np.ndarray, best_onset: np.ndarray,
                           h: Hypothesis) -> float:
        """The variance of eta = 1 in a bias accepted alone: what the full fit (eta and
        lambda) knows of eta at its own onset, as reported (`_reported`). The bias was taken
        because that fit found eta - 1 within 3 of its standard deviations of 0, so a scale
        of up to that size is still possible: eta = 1 is known this well, not exactly. 0 for
        any other hypothesis, or without a full one."""
        full = self._full_actuator(h.index) if h.target == "actuator_bias" else None
        if full is None:
            return 0.0
        return float(self._reported(fit, cost, full, int(best_onset[full]))[0])

    def _reported(self, fit, cost: np.ndarray, h: int, kb: int) -> np.ndarray:
        """(d,) the variances an event reports for hypothesis h at onset kb (`_spread`,
        lag by lag)."""
        return _spread(fit, cost, self._diag, h, kb, self.hypotheses[h].n_params,
                       self._lagged_meat(h, kb))[0]

    def _lagged_meat(self, h: int, kb: int) -> np.ndarray | None:
        """(d, d) the sandwich's middle of hypothesis h at onset kb counting the residuals'
        correlation lag by lag (thresholds.lagged_middle) over the samples the diagnosis
        absorbed; None without the lagged autocovariances."""
        if self._lagged is None or not self._absorbed:
            return None
        g = self.hypotheses[h]
        singles = ([Hypothesis("sensor", j, "") for j in g.members] if g.target == "sensors"
                   else [g])
        k, U, seen, sigma = (np.stack(c) for c in zip(*self._absorbed, strict=True))
        rows = row_regressors(self.bank, singles, [int(self._diag.onsets[kb])] * len(singles),
                              k, U, sigma) * seen[:, :, None]
        rows = np.pad(rows, ((0, 0), (0, 0), (0, self.d - rows.shape[-1])))
        return lagged_middle(rows, k, self._lagged)

    def excitation_bound(self, kind: str, index: int, params: dict[str, float], onset: int,
                         U: np.ndarray, noise_scale: float = 1.0) -> int | None:
        """The first sample at which least squares that knows the fault (``kind`` of
        canfdi.methods.FAULT_KINDS on channel ``index``, true ``params``) and its ``onset``
        settles on the commands ``U`` (N, p) of samples 0..N-1, the run's noise
        ``noise_scale`` times the config's (canfdi.methods.parity.settling.excitation_bound);
        None when not within max_samples."""
        if kind == "sensor_bias":
            h, theta = Hypothesis("sensor", index, ""), [params["bias"]]
        elif kind == "actuator_bias":
            h, theta = Hypothesis("actuator_bias", index, ""), [params["lambda"]]
        else:
            h, theta = (Hypothesis("actuator", index, ""),
                        [params["eta"] - 1.0, params.get("lambda", 0.0)])
        return excitation_bound(self.bank, self.settings, self.tracker.gamma, self._projection,
                                h, np.asarray(theta, dtype=float), onset, U, noise_scale)

    def c_tables(self) -> dict:
        """What a diagnosis reads, for the C drive loop (canfdi codegen, drive.h's
        cfdi_diag_tables): the hypotheses' decision table (decide.HypothesisTable) and
        regressor columns, the bank's signatures, the long-run covariance, the noise units
        at the configured noise, and the settings; the columns and pairs the events' lagged
        middles read (ctables.lagged_columns), the tracking's tables, each sensor's twins in
        the order its events list them (`_twin_ratios`), the own-fault quantiles, and how far
        back a diagnosis with compensated channels looks (settings.lookback)."""
        from canfdi.methods.parity import ctables

        s = self.settings
        H = len(self.hypotheses)
        position = {h: i for i, h in enumerate(self.hypotheses)}
        twin_order = np.full((H, H), -1, dtype=np.int32)
        twin_ratio = np.zeros((H, H))
        for i, h in enumerate(self.hypotheses):
            if h.target == "sensor":
                for n, (g, ratio) in enumerate(self._twin_ratios(h.index)):
                    twin_order[i, n], twin_ratio[i, n] = position[g], ratio
        channels = {("actuator" if h.target == "actuator_bias" else h.target, h.index)
                    for h in self.hypotheses if h.target != "sensors"}
        return {"table": self._table, "columns": self._columns, "d": self.d,
                "Gz": np.asarray(self.bank.Gz, dtype=float),
                "Gu": np.asarray(self.bank.Gu, dtype=float),
                "gamma": np.asarray(self.tracker.gamma, dtype=float),
                "units": unit_table(self.bank, self.hypotheses, self.d, self._projection),
                "settings": s, "recent": self._recent.capacity,
                "lagged": ctables.lagged_columns(self._columns, self._table.n_params),
                "track": ctables.tracking_tables(self.bank, self.tracker.gamma, self.hypotheses,
                                                 self.tracker.precise, self._projection),
                "own_chi2": ctables.own_fault_chi2(), "twin_order": twin_order,
                "twin_ratio": twin_ratio, "earlier_lookback": s.lookback,
                "max_earlier": len(channels)}

    @property
    def named(self) -> bool:
        """Whether the diagnosis under way has named its fault (FDI_STATUS "named")."""
        return self._diag is not None and self._diag.named

    def _full_actuator(self, j: int) -> int | None:
        """The index of actuator j's full hypothesis (eta and lambda), if it has one."""
        return next((i for i, h in enumerate(self.hypotheses)
                     if h.target == "actuator" and h.index == j), None)

    def _unexplained(self, k: int, t: int, theta: np.ndarray, best_onset: np.ndarray,
                     order: np.ndarray) -> list[FaultEvent]:
        event = FaultEvent(kind="unexplained", sample=k, timestamp_ns=t,
                           detected_sample=self._diag.k_d,
                           candidates=tuple(self._describe(self.hypotheses[i],
                                                           theta[i, best_onset[i]])
                                            for i in order[:3]))
        self.events.append(event)
        self.mode = MONITOR
        self._restart_detector(k)
        return [event]

    def _describe(self, h: Hypothesis, th: np.ndarray, var: np.ndarray | None = None,
                  eta_var: float = 0.0) -> dict:
        """{target, index, name, estimates (and variances)} of a hypothesis' parameters
        ``th`` (for an actuator, eta - 1 and lambda) and their variances ``var`` (diagonal);
        a bias alone gives eta = 1 with the variance ``eta_var`` (`_bias_eta_variance`)."""
        if h.target == "actuator":
            est = {"eta": float(1.0 + th[0]), "lambda": float(th[1])}
            variances = {"eta": float(var[0]), "lambda": float(var[1])} if var is not None else {}
        elif h.target == "actuator_bias":
            est = {"eta": 1.0, "lambda": float(th[0])}
            variances = {"eta": eta_var, "lambda": float(var[0])} if var is not None else {}
        elif h.target == "sensor":
            est = {"bias": float(th[0])}
            variances = {"bias": float(var[0])} if var is not None else {}
        else:
            names = self.design.output_names
            est = {names[j]: float(th[c]) for c, j in enumerate(h.members)}
            variances = ({names[j]: float(var[c]) for c, j in enumerate(h.members)}
                         if var is not None else {})
        target = "actuator" if h.target == "actuator_bias" else h.target
        out = {"target": target, "index": h.index, "name": h.name, "estimates": est}
        if var is not None:
            out["variances"] = variances
        return out

    def _sensor_twins(self, j: int, bias: float) -> tuple[dict, ...]:
        """Sensors whose bias shows in the residuals exactly like sensor j's, with the bias
        that would explain the data (their signature is a multiple of sensor j's)."""
        twins = self._twin_ratios(j)
        if not twins:
            return ()
        out = [{"target": "sensor", "index": j, "name": self.design.output_names[j],
                "estimates": {"bias": bias}}]
        for g, ratio in twins:
            out.append({"target": g.target, "index": g.index, "name": g.name,
                        "estimates": {"lambda" if g.target == "actuator" else "bias":
                                      bias * ratio}})
        return tuple(out)

    def _twin_ratios(self, j: int) -> list[tuple[Hypothesis, float]]:
        """Sensor j's twins by kind and index (an actuator once: its bias-only variant shares
        its signature), each with the size per unit of sensor j's bias that explains the data
        as well: an actuator twin's lambda enters through Gu as a sensor bias does through
        Gz. [] when sensor j has no hypothesis or no twin."""
        h = next((g for g in self.hypotheses if g.target == "sensor" and g.index == j), None)
        if h is None or not self._twins[h]:
            return []
        gj = self.bank.Gz[j].ravel()
        out = []
        for g in sorted((g for g in self._twins[h] if g.target != "actuator_bias"),
                        key=lambda g: (g.target, g.index)):
            gt = (self.bank.Gu if g.target == "actuator" else self.bank.Gz)[g.index].ravel()
            out.append((g, float(gt @ gj) / float(gt @ gt)))
        return out

    def _leftover(self, target: str, index: int, cost_k: np.ndarray, kb: int) -> bool:
        """Whether a diagnosis of a compensated channel finds what its latest fault's estimate
        left rather than a new fault: dated at that fault's onset, the fit costs less than the
        isolation margin more than at its best onset (``cost_k``: (K,) the hypothesis' cost at
        each onset, ``kb`` the best). A new fault leaves the samples before its onset as they
        were; what an estimate left was there all along."""
        onset = fault_onset(self.compensation, target, index)
        hit = np.flatnonzero(self._diag.onsets == onset) if onset is not None else []
        if len(hit) == 0:
            return False
        return float(cost_k[hit[0]] - cost_k[kb]) < self.settings.isolation_margin

    def _accept(self, k: int, t: int, best: int, kb: int, theta: np.ndarray, var: np.ndarray,
                scale: float, best_onset: np.ndarray, cost_h: np.ndarray, cost_k: np.ndarray,
                near: list[int] = (), eta_var: float = 0.0) -> list[FaultEvent]:
        d = self._diag
        h = self.hypotheses[best]
        onset = int(d.onsets[kb])
        th = theta[best, kb]
        named = self._describe(h, th)  # without variances: a candidate's form
        alike = [c for c in (self._describe(self.hypotheses[i], theta[i, best_onset[i]])
                             for i in near if self.hypotheses[i].target != "sensors")
                 if (c["target"], c["index"]) != (named["target"], named["index"])]
        faults = []  # (target, index, estimates, variances, candidates)
        if h.target in ("actuator", "actuator_bias"):
            desc = self._describe(h, th, var, eta_var)
            faults.append(("actuator", h.index, desc["estimates"], desc["variances"],
                           (named, *alike) if alike else ()))
        else:
            members = h.members if h.target == "sensors" else (h.index,)
            for c, j in enumerate(members):
                # In a joint fit a member with no significant bias is healthy.
                if h.target == "sensors" and abs(th[c]) <= 5.0 * np.sqrt(var[c]):
                    continue
                twins = self._sensor_twins(j, float(th[c]))
                if alike and h.target == "sensor":
                    twins = (*(twins or (named,)), *alike)
                faults.append(("sensor", j, {"bias": float(th[c])}, {"bias": float(var[c])},
                               twins))
        if not faults:
            # The best fit is a joint sensor bias with no member significant: no persistent
            # fault explains the alarm (a transient, such as one corrupt sample).
            return self._unexplained(k, t, theta, best_onset, np.argsort(cost_h, kind="stable"))
        events = []
        # What the fit knows about each accepted channel's parameters (normalised residuals:
        # the information over the cost's scale), for the tracker's prior.
        info = d.info.J[best, kb] / scale
        accepted_now = {}
        for target, index, est, variances, candidates in faults:
            names = self.design.input_names if target == "actuator" else self.design.output_names
            leftover = h.target != "sensors" and self._leftover(target, index, cost_k, kb)
            kind, shown, shown_var = self._fold(target, index, onset, est, variances, leftover,
                                                ("eta",) if h.target == "actuator_bias" else ())
            events.append(FaultEvent(
                kind=kind, sample=k, timestamp_ns=t, target=target, index=index,
                name=names[index], estimates=shown, variances=shown_var, onset_sample=onset,
                detected_sample=d.k_d, accepted_sample=k, candidates=candidates))
            if h.target == "sensors":
                hyp = Hypothesis("sensor", index, self.design.output_names[index])
                col = h.members.index(index)
                precision = info[col: col + 1, col: col + 1]
            elif (h.target == "actuator_bias" and self._projection is not None
                  and (full := self._full_actuator(index)) is not None):
                # A bias is a scale not yet ruled out over every command the drive will use.
                # The signature CUSUMs see the scale's leftover as the command moves, so the
                # tracker goes on fitting both (from what the full fit knew at the same onset)
                # and folds it rather than have it re-detected. (Page-Hinkley alone does not
                # see it, and there a two-parameter tracker only risks taking a later small
                # fault for a scale: one more missed fault in 131 on the DC motor.)
                hyp, precision = self.hypotheses[full], d.info.J[full, kb, :2, :2] / scale
            else:
                hyp, precision = h, info[: h.n_params, : h.n_params]
            accepted_now[(target, index)] = (hyp, precision, kind == "accepted")
        self._reload_window()
        self.mode = MONITOR
        self._restart_detector(k)
        self._track_compensated(accepted_now)
        self.events.extend(events)
        return events

    def _fold(self, target: str, index: int, onset: int, est: dict[str, float],
              variances: dict[str, float], correction: bool = False,
              fixed: tuple[str, ...] = ()) -> tuple[str, dict[str, float], dict[str, float]]:
        """Fold estimates and their variances (named as in FaultEvent) into the compensation:
        (kind, estimates, variances) of the event that says so (records.fold)."""
        return fold(self.compensation, Compensation(
            target, index, onset, eta=est.get("eta", 1.0), lam=est.get("lambda", 0.0),
            bias=est.get("bias", 0.0), scale=target == "actuator", variances=dict(variances),
            correction=correction, fixed=fixed))

    def _reload_window(self) -> None:
        """The output-error paper's Section 3.3: rebuild the window from compensated samples."""
        tail = []
        for kk, z, u in self._history:
            if tail and kk != tail[-1][0] + 1:
                tail = []
            tail.append((kk, z, u))
        x = np.array([self._compensate(kk, z, u) for kk, z, u in tail])
        self.bank.restart()
        self.bank.load(x)
        self._recent.clear()
        if tail:  # the windows of the samples to come start with these rows
            self._recent.push(np.array([kk for kk, _, _ in tail]), x,
                              np.full((len(tail), self.bank.m), np.nan),
                              np.zeros(len(tail), dtype=bool))

    def _track_compensated(self, accepted_now: dict) -> None:
        """Restart the tracker over every compensated channel: the ones just accepted with
        their fit's information (a refinement's added to what the channel's tracking knew; a
        new fault on a channel tracked already adds its uncertainty to the earlier one's: the
        channel's remaining error is the sum of both estimates' errors), the others as they
        were tracked."""
        tracked = {("actuator" if t.hypothesis.target == "actuator_bias"
                    else t.hypothesis.target, t.hypothesis.index): t
                   for t in self.tracker.tracked}
        for key, (hyp, precision, new_fault) in accepted_now.items():
            before = tracked.get(key)
            if before is not None and before.hypothesis.target == hyp.target:
                if new_fault:
                    precision = np.linalg.inv(np.linalg.inv(precision)
                                              + np.linalg.inv(before.precision))
                else:
                    precision = precision + before.precision
            onset = min(c.onset for c in self.compensation if (c.target, c.index) == key)
            tracked[key] = Tracked(hyp, onset, precision)
        self.tracker.restart([tracked[key] for key in sorted(tracked)])

    def _refine_tracked(self, k: int, t: int) -> list[FaultEvent]:
        """A tracker checkpoint: fold its significant corrections into the compensation,
        each announced as a "refined" event with the updated size of the channel's latest
        fault (records.latest_fault)."""
        corrections = self.tracker.correction()
        events = []
        for c in corrections:
            h = c.tracked.hypothesis
            desc = self._describe(h, c.delta, c.variances)
            _, size, variances = self._fold(desc["target"], h.index, c.tracked.onset,
                                            desc["estimates"], desc["variances"], correction=True)
            events.append(FaultEvent(
                kind="refined", sample=k, timestamp_ns=t, target=desc["target"], index=h.index,
                name=h.name, estimates=size, variances=variances,
                onset_sample=c.tracked.onset, accepted_sample=k))
        if events:
            self._reload_window()
            self.events.extend(events)
        return events


def _position(onsets: list[int], onset: int | None) -> int:
    """The first position of ``onset`` among ``onsets``; -1 when it is none of them."""
    return onsets.index(onset) if onset is not None and onset in onsets else -1


def _channel(h: Hypothesis) -> str:
    """The compensation's target of a hypothesis ("actuator" for a bias-only actuator)."""
    return "actuator" if h.target == "actuator_bias" else h.target


def _spread(fit, cost: np.ndarray, d: Diagnosis, h: int, kb: int, n_params: int,
            lagged: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """(d,) the variances of hypothesis h's estimates at onset kb, and the fit's noise scale
    (cost per degree of freedom). The sandwich: least squares takes the residuals for white
    and independent, but parity residuals over a window are correlated in time (and with each
    other), so a sum of them varies as the long-run covariance says, not as P alone. That holds
    for steady regressors; across a fault's transient the correlation lag by lag counts
    (``lagged``: (d, d) that middle, `ParityDiagnoser._lagged_meat`, what the events report;
    None: the long-run one, Diagnosis.meat). The settling test keeps the
    long-run form, which the shipped configs' settle_rel_std and settle_noise were set by: on
    the winding machine the lagged variances of a sensor bias 50 samples after its onset are
    40 times the long-run ones (and match the spread of the estimates over seeds)."""
    meat = d.meat[h, kb] if lagged is None else lagged
    return spread(fit.P[h, kb], cost[h, kb], d.info.n_eq, n_params, meat)

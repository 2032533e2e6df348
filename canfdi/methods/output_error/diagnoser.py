"""The output-error method of the output-error paper: OE residual, Page-Hinkley detection,
isolation by
identifying the residual's response to a step, decision tests, and the reset of Section 3.3.

RESIDUAL. The parallel OE models (canfdi.methods.output_error.model) are simulated from the
commands u_c alone; r_j(k) = z_j(k) - y_hat_j(k) for every output j (the output-error paper's eq.
9),
normalised by its fault-free standard deviation sigma_j. Under a single additive fault (eqs. 10-11)

    actuator i:  r_j(k) = G_ji(q) lambda U(k - k_f) + e_j(k)   for every output j it reaches,
    sensor j:    r_j(k) = b U(k - k_f) + e_j(k)                on output j only.

DETECTION (Section 3.1). A two-sided Page-Hinkley test on each normalised residual (drift delta
in noise stds). The OE residual of a well identified model is the measurement noise itself,
white, so Siegmund's threshold for the false-alarm interval applies; model error colours it,
so the threshold is also bounded by Siegmund's on the residual's long-run variance (the ratio
measured on the identification data by `canfdi identify`), as the parity method does for its
correlated residuals.

ISOLATION AND IDENTIFICATION (Section 3.2). At the alarm k_d, onsets k_f are tried from a few
samples before the Page-Hinkley change point up to k_d (the paper shifts its step back from
k_d). ``min_samples`` after the alarm (the paper's L - l0; the window also holds ``pre_samples``
= l0 samples before the earliest onset), the hypotheses are tested, actuators first:

* actuator i, each onset: (a) the amplitude: least squares of r_j = lambda s_ji(k - k_f) over
  every output j, s_ji the step response of the model G_ji (outputs without a path must stay at
  zero), weighted by 1/sigma_j^2. This is the amplitude reported (with its variance): it is the
  maximum-likelihood estimate under the hypothesis; the paper's B^(1)/F^(1)/K^ of the free
  fit is the same quantity estimated with more free parameters. (b) the free fit (the paper's
  G^Du): for each output j the path reaches, an OE model of the structure (nb, nf, d) of G_ji
  fitted to r_j with a unit step at k_f (canfdi.methods.output_error.model.fit_step), giving
  F^Du and the variances of its coefficients. Decision tests, as we read the output-error paper's
  eqs. 16-17 (the
  extraction lost them; gamma = 0.2 and kappa = 0.1 are its values):

    gamma (parameter variance bound, eq. 16): every coefficient of F^Du has
        sigma(f^Du_l) <= gamma ||f^||   (the model is well determined by the data; normalised
        by the size of the model's own F so that gamma is dimensionless, as the paper's 0.2
        must be for coefficients near 1);
    kappa (normalised parameter distance, eq. 17):
        D = ||f^Du - f^|| / ||f^|| <= kappa   (F^Du is close to the model's F^),
        or, ours, F^Du is that far only through noise: holding F at f^ (B refitted) costs at
        most the chi-square quantile of nf degrees of freedom at ``SHAPE_TAIL`` more than the
        free fit (a likelihood-ratio test of the model's shape: a small fault's second-order
        free fit can sit 17 % from f^ for 400 samples while f^ fits to the noise);
    the amplitude (eq. 16 for it, as for a sensor's bias): sigma(lambda) <= gamma |lambda|.

  An onset passes when these pass on every output the actuator reaches and the fit (a)
  leaves about the noise (cost per equation at most ``max_fit_variance``, normalised residuals:
  1 is the noise; the paper's "if the abrupt fault assumption is not valid"). Among passing
  onsets and actuators, the one with the smallest D is kept (the paper's choice of the shift j);
  k_f^ is its onset. A path with no denominator (nf = 0) has no F to compare: its gamma test
  is on the gain (sigma(K^Du) <= gamma |K^Du|) and D = 0.
* only when no actuator passes, sensor j, each onset: r_j = b U(k - k_f) by least squares
  (the other outputs must stay at zero); the onset of least cost is kept; the one test (eq. 16
  for a gain) is sigma(b) <= gamma |b|, i.e. b differs from zero, plus the fit-variance test.
  Of several passing sensors the one of least total cost wins. A sensor is not accepted while
  some actuator's step response (a), at any onset, fits better by more than
  ``EVIDENCE_MARGIN``: a small actuator fault's free fit is loose, so its kappa test can fail
  while its model's step response explains the data far better than any sensor's step (a u2
  bias of FNR 0.8 was accepted as an Omega2 bias with twice u2's cost); the diagnosis waits.

An accepted new fault names as its candidates (the FaultEvent's, found first) every other
channel whose hypothesis fits as well, within ``EVIDENCE_MARGIN`` (`alike`): near twins,
whose responses differ only in a transient the noise hides (a u3 bias and a T3 bias below
FNR 1), are named together rather than guessed between.

A channel compensated already (a diagnosis of it *refines* it) is tested on its amplitude
alone, its shape having been established when it was accepted, judged against the channel's
whole fault, and also from the accepted fault's own onset: what an estimate off by a little
leaves acts from there, through a slow path still rising when it is detected, which no step
from inside the new window fits (it was taken for a small bias of another output). Of several
refinements, the one of least cost; a new fault is accepted over it only when it fits better
by ``EVIDENCE_MARGIN`` (a rest that a small new bias fits about as well is a rest).

No hypothesis passing by ``max_samples``: an "unexplained" event and the detector restarts
(a transient, a multiplicative fault, or a fault outside the abrupt additive model). Tests are
repeated every ``check_every`` samples between min_samples and max_samples.

RESET (Section 3.3). The accepted fault is folded into a compensation from k_f on: a sensor
bias is subtracted from z_j; an actuator fault lambda is added to u_c,i at the model's input.
The model outputs are recomputed from k_f: the OE model is linear, so adding lambda from k_f to
the input adds lambda times each path's step response, and its state is moved by lambda times
the state a unit step from k_f would have put there (exact superposition, no replay of the
history). The Page-Hinkley test restarts, so a second fault is diagnosed on top of the first.

LOST DATA. A NaN measurement z_j makes r_j missing (NaN) for that sample: Page-Hinkley holds,
the fits take no equation. A NaN command u_i is replaced by its last known value (the model's
state keeps running, on the held input); the hold error then decays with the path's poles, so
the residual of every output u_i reaches is missing for that sample and the ``taint`` samples
after it (the time for the slowest pole of the path to fall to ``settle`` of a jump). A gap of
at most ``max_hold`` samples is bridged the same way (the model runs on held inputs, the
residuals are missing meanwhile and for the taint after); a longer gap (or k going backwards)
restarts the models at rest on the next input and the residuals are missing for ``warmup``
samples (the same settling time over every path), as at start-up.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field, replace

import numpy as np
from scipy import special  # chi-square quantiles: 30 ms to import where scipy.stats takes 0.6 s

from canfdi.core.blockrun import BlockRows, continuity_breaks, run_block
from canfdi.core.calibrate import threshold_for_long_run_variance
from canfdi.core.detect import ChangePointDetector, DetectorBacked, onset_candidates
from canfdi.core.identify import least_squares
from canfdi.core.protocol import DIAGNOSE, MONITOR, deepcopy_sharing
from canfdi.core.records import (
    BlockResult,
    Compensation,
    FaultEvent,
    Sample,
    compensate,
    compensated,
    fault_onset,
    fold,
)
from canfdi.methods.output_error.model import (
    OeModel,
    fit_step,
    lfilter,
    pair_initial_state,
    simulate,
)

EVIDENCE_MARGIN = 10.83
"""Least-squares cost (normalised, twice the log-likelihood) by which an actuator's step
response may fit better than a sensor's step and the sensor still be accepted: chi-square
with one degree of freedom at 0.001, odds of 225 to 1."""

SHAPE_TAIL = 1.0e-3
"""The likelihood-ratio test of an actuator's shape against its free fit (chi-square with nf
degrees of freedom) fails a right shape this rarely."""

__all__ = ["EVIDENCE_MARGIN", "SHAPE_TAIL", "HypothesisTest", "OeDiagnosis", "OeSettings",
           "OutputErrorDiagnoser", "oe_thresholds", "onset_spread", "settling_samples"]


@dataclass(frozen=True)
class OeSettings:
    """Settings of the output_error method (the config's output_error: section).

    drift : Page-Hinkley delta in residual noise stds; false_alarm_interval : samples between
        false alarms per residual the thresholds target.
    gamma, kappa : the decision tests (module docstring).
    min_samples : samples after the alarm before the first decision (L - l0).
    max_samples : samples after the alarm before giving up ("unexplained").
    pre_samples : samples before the earliest onset in the fitting window (l0).
    onset_before : onsets tried before the Page-Hinkley change point; max_onsets : at most this
        many onsets (the latest ones, up to the alarm).
    max_fit_variance : accept only a fit whose cost per equation (normalised) is at most this.
    check_every : samples between decisions after min_samples.
    max_hold : longest gap (samples) bridged on held inputs; longer ones restart the models.
    settle : fraction a transient must fall to before residuals count again (taint, warm-up).

    Examples
    --------
    >>> settings = OeSettings(max_samples=800)
    >>> settings.min_samples, settings.max_samples, settings.drift
    (48, 800, 0.5)
    """

    drift: float = 0.5
    false_alarm_interval: float = 1.0e7
    gamma: float = 0.2
    kappa: float = 0.1
    min_samples: int = 48
    max_samples: int = 400
    pre_samples: int = 10
    onset_before: int = 3
    max_onsets: int = 10
    max_fit_variance: float = 4.0
    check_every: int = 10
    max_hold: int = 10
    settle: float = 0.01


@dataclass(frozen=True)
class OeDiagnosis:
    """A diagnosis in progress: what the alarm at ``k_d`` started.

    onsets : candidate fault onsets; start : the first sample of the fitting window (l0 before
    the earliest onset); next_check : the sample of the next decision; k, r : the window's
    samples and normalised residual rows (q,), growing until the decision.

    Examples
    --------
    >>> from dataclasses import replace
    >>> d = OeDiagnosis(k_d=501, onsets=[498, 499, 500, 501], start=488, next_check=549)
    >>> d = replace(d, k=[*d.k, 502], r=[*d.r, np.array([4.2])])
    >>> d.k, d.start < min(d.onsets)
    ([502], True)
    """

    k_d: int
    onsets: list[int]
    start: int
    next_check: int
    k: list[int] = field(default_factory=list)
    r: list[np.ndarray] = field(default_factory=list)


@dataclass(frozen=True)
class HypothesisTest:
    """One hypothesis (a channel at its best onset) tested on the diagnosis window.

    estimates, variances : {"lambda"} for an actuator, {"bias"} for a sensor (physical units);
    cost : least-squares cost of the normalised residuals; distance : the kappa test's
    normalised parameter distance; gamma_ok, fits : the gamma and fit-variance tests; passes :
    all of them. extra_variance : what the estimate's reported variance adds to the tests'
    one, the noise's alone (their gamma was set on it): the identified models' gain
    uncertainty (OePair.gain_std) and the onset's (`onset_spread`).

    Examples
    --------
    >>> test = HypothesisTest("sensor", 0, "y", 500, {"bias": 0.1}, {"bias": 1e-6}, cost=48.0,
    ...                       distance=0.01, gamma_ok=True, fits=True, passes=True)
    >>> test.candidate()
    {'target': 'sensor', 'index': 0, 'name': 'y', 'estimates': {'bias': 0.1}, 'onset': 500}
    """

    target: str
    index: int
    name: str
    onset: int
    estimates: dict[str, float]
    variances: dict[str, float]
    cost: float
    distance: float
    gamma_ok: bool
    fits: bool
    passes: bool
    extra_variance: float = 0.0

    def candidate(self) -> dict:
        """The FaultEvent candidate entry of an "unexplained" event."""
        return {"target": self.target, "index": self.index, "name": self.name,
                "estimates": dict(self.estimates), "onset": self.onset}


def onset_spread(chosen: HypothesisTest, tried: list[HypothesisTest]) -> HypothesisTest:
    """``chosen`` with the onset's uncertainty in its extra variance: the onsets tried for
    its channel weighted by their likelihood, exp(-cost / 2) (normalised residuals), the
    mean square of their estimates about the chosen one, plus their own variances, less the
    chosen's. An actuator's first response sample is often at the noise's level: the onset a
    sample off moves a slow path's estimate by a few percent, several of its noise deviations.

    >>> tests = [HypothesisTest("sensor", 0, "y", kf, {"bias": b}, {"bias": 1e-6}, cost,
    ...                         0.0, True, True, True) for kf, b, cost in
    ...          [(499, 0.09, 50.0), (500, 0.1, 48.0), (501, 0.11, 60.0)]]
    >>> round(onset_spread(tests[1], tests).extra_variance, 7)  # about 0.01^2 e^-1 / (1 + e^-1)
    2.7e-05
    """
    key = "lambda" if chosen.target == "actuator" else "bias"
    ok = [h for h in tried if np.isfinite(h.cost) and np.isfinite(h.variances[key])]
    if len(ok) < 2:
        return chosen
    cost = np.array([h.cost for h in ok])
    w = np.exp(-(cost - cost.min()) / 2.0)
    w /= w.sum()
    est = np.array([h.estimates[key] for h in ok])
    var = np.array([h.variances[key] for h in ok])
    spread = float(w @ (var + (est - chosen.estimates[key]) ** 2)) - chosen.variances[key]
    return replace(chosen, extra_variance=chosen.extra_variance + max(spread, 0.0))


def settling_samples(radius: float, settle: float) -> int:
    """Samples for a transient of a pole of modulus ``radius`` to fall to ``settle``."""
    if radius <= 0.0:
        return 1
    if radius >= 1.0:
        raise ValueError(f"pole modulus {radius} >= 1: the model is not stable")
    return max(1, math.ceil(math.log(settle) / math.log(radius)))


def oe_thresholds(drift: float, interval: float, long_run: np.ndarray) -> np.ndarray:
    """(q,) Page-Hinkley thresholds (noise stds) for a false-alarm interval (samples).

    The OE residual is the measurement noise itself, white unless model error colours it:
    Siegmund's threshold, bounded for a residual of long-run variance ratio L > 1 as the
    parity diagnoser's (canfdi.core.detect.threshold_for_long_run_variance)."""
    return threshold_for_long_run_variance(drift, interval, long_run)


class OutputErrorDiagnoser(DetectorBacked):
    """Streaming OE diagnoser: ``update(sample) -> events`` (canfdi.monitor.DiagnoserLike).

    Parameters
    ----------
    model : the identified OeModel (p inputs, q outputs).
    sigma : (q,) fault-free residual standard deviations.
    thresholds : (q,) Page-Hinkley thresholds in noise stds (oe_thresholds).
    settings : OeSettings.
    input_names, output_names : channel names (p,), (q,).

    Examples
    --------
    >>> from scipy.signal import lfilter
    >>> from canfdi.core.records import Sample
    >>> from canfdi.methods.output_error.model import OeModel, OePair
    >>> model = OeModel((OePair(0, 0, (0.1,), (-0.9,)),), u0=[0.0], y0=[0.0])  # 0.1 / (q - 0.9)
    >>> diag = OutputErrorDiagnoser(model, np.array([0.01]), oe_thresholds(0.5, 1e7, np.ones(1)),
    ...                             OeSettings(), ["u"], ["y"])
    >>> rng = np.random.default_rng(0)
    >>> u = np.sign(np.sin(np.arange(1000) / 20.0))
    >>> y = lfilter([0.0, 0.1], [1.0, -0.9], u) + 0.01 * rng.standard_normal(1000)
    >>> y[500:] += 0.1  # the sensor reads 0.1 high from sample 500
    >>> events = [e for k in range(1000)
    ...           for e in diag.update(Sample(k, 0, u[k:k + 1], y[k:k + 1]))]
    >>> [(e.kind, e.sample, e.name, {n: round(v, 2) for n, v in e.estimates.items()})
    ...  for e in events]
    [('detected', 501, None, {}), ('accepted', 549, 'y', {'bias': 0.1})]
    """

    def __init__(self, model: OeModel, sigma: np.ndarray, thresholds: np.ndarray,
                 settings: OeSettings, input_names: list[str], output_names: list[str]) -> None:
        # scipy.signal (lfilter) imported now, at start, not at the first diagnosis: its 0.6 s
        # would stall the live path there.
        import scipy.signal  # noqa: F401

        self.model = model
        self.p, self.q = model.p, model.q
        if len(input_names) != self.p or len(output_names) != self.q:
            raise ValueError(f"names: expected {self.p} inputs and {self.q} outputs, got "
                             f"{len(input_names)} and {len(output_names)}")
        self.sigma = np.asarray(sigma, dtype=float).reshape(self.q)
        if np.any(~np.isfinite(self.sigma)) or np.any(self.sigma <= 0):
            raise ValueError("sigma: residual standard deviations must be finite and > 0")
        self._sigma0 = self.sigma.copy()
        thresholds = np.asarray(thresholds, dtype=float).reshape(self.q)
        self.settings = settings
        self.input_names, self.output_names = list(input_names), list(output_names)
        self._detector = ChangePointDetector(self.q, settings.drift, thresholds)
        s = settings
        self._paths = model.has_path()
        # taint[i, j]: samples residual j stays missing after a held (lost) command u_i.
        self._taint = np.zeros((self.p, self.q), dtype=np.int64)
        for pair in model.pairs:
            self._taint[pair.input, pair.output] = settling_samples(pair.pole_radius,
                                                                    s.settle) + pair.delay
        # The models start at rest on the input; the plant is wherever its excitation left
        # it, tens of noise stds away. Its transient must fall far below the noise before the
        # residuals count (settle^2), or Page-Hinkley's drift accumulates it: canfdi evaluate
        # found start-up alarms about 110 samples in, just after a settle-based warm-up.
        self.warmup = (max(settling_samples(pr.pole_radius, s.settle ** 2) + pr.delay
                           for pr in model.pairs) if model.pairs else 0)
        self._pair_of = {(pr.output, pr.input): pr for pr in model.pairs}
        self._recent: deque = deque(maxlen=s.max_onsets + s.onset_before + s.pre_samples + 8)
        self.compensation: list[Compensation] = []
        self.events: list[FaultEvent] = []
        self._diag: OeDiagnosis | None = None
        self.reset()

    # -- state ---------------------------------------------------------------------------
    def __deepcopy__(self, memo: dict) -> OutputErrorDiagnoser:
        """A copy that runs apart from this one; the models, which update never changes, shared."""
        return deepcopy_sharing(self, memo, self.model)

    def reset(self) -> None:
        """Back to the state after construction: monitoring, no compensation, no events; the
        models restart on the next sample."""
        self.noise_scale = 1.0
        self.mode = MONITOR
        self.events = []
        self.compensation = []
        self._states: list[np.ndarray] | None = None
        self._u_last = np.array(self.model.u0, dtype=float)
        self._taint_until = np.full(self.q, np.iinfo(np.int64).min // 2, dtype=np.int64)
        self._last_k: int | None = None
        self._recent.clear()
        self._restart_detector()
        self.last_residuals: np.ndarray | None = None
        self.last_normalized: np.ndarray | None = None

    def _restart_detector(self, k: int = -1) -> None:
        self._detector.reset(k)
        self._diag = None

    @property
    def noise_scale(self) -> np.ndarray:
        """(q,) each residual's noise over the calibrated sigma (settable: the noise watchdog
        widens the noise of a residual in mismatch, canfdi.core.watchdog; 1 by default)."""
        return self.sigma / self._sigma0

    @noise_scale.setter
    def noise_scale(self, value: np.ndarray) -> None:
        self.sigma = self._sigma0 * np.broadcast_to(np.asarray(value, dtype=float),
                                                    self._sigma0.shape)

    @property
    def residual_names(self) -> list[str]:
        return [f"oe:{name}" for name in self.output_names]

    # -- the residual ----------------------------------------------------------------------
    def _model_input(self, k: np.ndarray, U_held: np.ndarray) -> np.ndarray:
        """(N, p) the models' input deviation at samples k: the held commands with the
        accepted actuator faults added (the output-error paper's Section 3.3), less the operating
        point."""
        _, U = compensate(self.compensation, k, None, U_held)
        return U - self.model.u0

    def _start_models(self, k: int, u_held: np.ndarray) -> None:
        """Models at rest on the (compensated) input of sample k; residuals missing during the
        warm-up."""
        dev = self._model_input(np.array([k]), u_held[None, :])[0]
        self._states = [pair_initial_state(pr, dev[pr.input]) for pr in self.model.pairs]
        self._taint_until[:] = k + self.warmup - 1

    def _residuals(self, k: np.ndarray, U: np.ndarray, Z: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray]:
        """(N, q) residuals and normalised residuals of continuous samples k, advancing the
        models, the held commands and the taint (shared by update and update_block)."""
        n = len(k)
        nan_u = np.isnan(U)
        held = U.copy()
        if nan_u.any():
            # Forward fill from the last known command (vectorised).
            idx = np.where(~nan_u, np.arange(n)[:, None], -1)
            idx = np.maximum.accumulate(idx, axis=0)
            last = np.vstack([self._u_last[None, :], U])
            held = np.take_along_axis(last, idx + 1, axis=0)
            held = np.where(idx < 0, self._u_last[None, :], held)
        self._u_last = held[-1].copy()
        dev = self._model_input(k, held)
        Y, self._states = simulate(self.model, dev, self._states)
        Zc, _ = compensate(self.compensation, k, Z, None)
        R = Zc - Y
        # Residuals stay missing after a lost command, for the taint of its paths.
        until = np.empty((n, self.q), dtype=np.int64)
        for j in range(self.q):
            cand = np.full(n, np.iinfo(np.int64).min // 2, dtype=np.int64)
            for i in range(self.p):
                if self._taint[i, j] and nan_u[:, i].any():
                    cand = np.maximum(cand, np.where(nan_u[:, i], k + self._taint[i, j] - 1,
                                                     cand))
            until[:, j] = np.maximum.accumulate(np.maximum(cand, self._taint_until[j]))
        self._taint_until = until[-1].copy()
        R[k[:, None] <= until] = np.nan
        return R, R / self.sigma

    def _bridge(self, k: int) -> None:
        """Before sample k: a gap since the last sample is bridged on held inputs, or the
        models restart."""
        if self._states is None:
            return
        missing = k - self._last_k - 1 if self._last_k is not None else 0
        if missing == 0:
            return
        if 0 < missing <= self.settings.max_hold:
            ks = np.arange(self._last_k + 1, k)
            nan = np.full((missing, self.p), np.nan)
            self._residuals(ks, nan, np.full((missing, self.q), np.nan))
        else:
            self._states = None

    # -- streaming -------------------------------------------------------------------------
    def update(self, sample: Sample) -> list[FaultEvent]:
        """Process one sample; returns the events it caused (usually none)."""
        k = int(sample.k)
        u = np.asarray(sample.u, dtype=float).reshape(self.p)
        z = np.asarray(sample.z, dtype=float).reshape(self.q)
        self._bridge(k)
        if self._states is None:
            self._start_models(k, np.where(np.isnan(u), self._u_last, u))
        self._last_k = k
        R, Rn = self._residuals(np.array([k]), u[None, :], z[None, :])
        r, rn = R[0], Rn[0]
        if np.isnan(r).all():
            self.last_residuals = self.last_normalized = None
            return []
        self.last_residuals, self.last_normalized = r, rn
        self._recent.append((k, rn))
        if self.mode == MONITOR:
            return self._monitor(k, sample.timestamp_ns, rn)
        return self._diagnose(k, sample.timestamp_ns, rn)

    def update_block(self, k: np.ndarray, t_ns: np.ndarray, U: np.ndarray, Z: np.ndarray,
                     gap: np.ndarray | None = None) -> BlockResult:
        """Process N samples at once; the same events and state as N calls of ``update``.

        Continuous monitoring stretches are vectorised (the models over the whole stretch by
        lfilter, Page-Hinkley in its cumulative form); the sample that raises an alarm, the
        samples of a diagnosis and those after a gap go through ``update``.

        Parameters
        ----------
        k, t_ns : (N,) increasing sample indices and timestamps; U : (N, p); Z : (N, q), NaN
        where a value was lost; gap : (N,) informational (the indices say it).
        """
        k = np.asarray(k, dtype=np.int64)
        n = len(k)
        U = np.asarray(U, dtype=float).reshape(n, self.p)
        Z = np.asarray(Z, dtype=float).reshape(n, self.q)
        # The models restart (update's business) on the first sample they see.
        breaks = continuity_breaks(k, self._last_k, first_breaks=True)
        if self._states is None:
            breaks[0] = True
        return run_block(self, k, t_ns, U, Z, gap, breaks,
                         lambda i, j, rows: self._monitor_stretch(k, U, Z, i, j, rows))

    def _snapshot(self) -> tuple:
        return ([s.copy() for s in self._states], self._u_last.copy(),
                self._taint_until.copy())

    def _monitor_stretch(self, k: np.ndarray, U: np.ndarray, Z: np.ndarray, i: int, j: int,
                         rows: BlockRows) -> int:
        """Vectorised monitoring of continuous samples i..j-1 (canfdi.core.blockrun): returns
        j, or the row of the alarm, which ``update`` then takes."""
        before = self._snapshot()
        res, rn = self._residuals(k[i:j], U[i:j], Z[i:j])
        blk = self._detector.update_block(k[i:j], rn)
        done = blk.done
        alarmed = done < j - i
        if alarmed:
            # Redo the models up to the alarm row only: update() takes the alarm sample.
            self._states, self._u_last, self._taint_until = before
            if done:
                self._residuals(k[i:i + done], U[i:i + done], Z[i:i + done])
        if done > 0:
            rows.stat[i: i + done] = np.maximum(blk.g_up[:done], blk.g_down[:done])
            rows.R[i: i + done] = res[:done]
            rows.Rn[i: i + done] = rn[:done]
            have = ~np.isnan(rn[:done]).all(axis=1)
            for r in np.flatnonzero(have)[-self._recent.maxlen:].tolist():
                self._recent.append((int(k[i + r]), rn[r].copy()))
            self._last_k = int(k[i + done - 1])
            if have[-1]:
                self.last_residuals, self.last_normalized = res[done - 1], rn[done - 1]
            else:
                self.last_residuals = self.last_normalized = None
        return i + done

    # -- the state machine -----------------------------------------------------------------
    def _monitor(self, k: int, t: int, rn: np.ndarray) -> list[FaultEvent]:
        alarm = self._detector.update(k, rn)
        if not alarm.any():
            return []
        alarming = np.flatnonzero(alarm)
        change_point = self._detector.change_point(alarm)
        s = self.settings
        first = self._recent[0][0]
        onsets = onset_candidates(change_point, k, first, s.onset_before, s.max_onsets)
        start = max(first, min(onsets) - s.pre_samples)
        rows = [(kk, r) for kk, r in self._recent if kk >= start]
        self.mode = DIAGNOSE
        self._diag = OeDiagnosis(k_d=k, onsets=onsets, start=start, next_check=k + s.min_samples,
                                 k=[kk for kk, _ in rows], r=[r for _, r in rows])
        event = FaultEvent(kind="detected", sample=k, timestamp_ns=t, detected_sample=k,
                           onset_sample=change_point,
                           residuals=tuple(self.residual_names[i] for i in alarming))
        self.events.append(event)
        return [event]

    def _diagnose(self, k: int, t: int, rn: np.ndarray) -> list[FaultEvent]:
        d, s = self._diag, self.settings
        d.k.append(k)
        d.r.append(rn)
        since = k - d.k_d
        if k < d.next_check and since < s.max_samples:
            return []
        self._diag = d = OeDiagnosis(k_d=d.k_d, onsets=d.onsets, start=d.start,
                                     next_check=k + s.check_every, k=d.k, r=d.r)
        found, tried = self.isolate()
        if found is not None:
            return self._accept(k, t, found, self.alike(found, tried))
        if since >= s.max_samples:
            return self._unexplained(k, t, tried)
        return []

    # -- isolation -------------------------------------------------------------------------
    def isolate(self) -> tuple[HypothesisTest | None, list[HypothesisTest]]:
        """Test the hypotheses on the diagnosis window: (the accepted one or None, the best
        few tried, for an "unexplained" event)."""
        d = self._diag
        kk = np.asarray(d.k, dtype=np.int64)
        Rn = np.asarray(d.r, dtype=float)  # (N, q) normalised, NaN missing
        valid = ~np.isnan(Rn)
        Rv = np.where(valid, Rn, 0.0)
        n_eq = max(int(valid.sum()), 1)
        zero_cost = (Rv**2).sum(axis=0)  # (q,) cost of each output if it stays at zero
        tried: list[HypothesisTest] = []
        passing = []
        actuator_cost = math.inf  # the least cost of any actuator's step response, any onset
        for i in range(self.p):
            outs = np.flatnonzero(self._paths[:, i])
            if len(outs) == 0:
                continue
            # A new fault's onset is the one whose step response has the model's shape; a
            # refinement's, where the rest it measures fits best.
            rank = ((lambda h: (h.passes, -h.cost)) if self._accepted_onset("actuator", i)
                    is not None else (lambda h: (h.passes, -h.distance)))
            best_h, results = None, []
            for kf in self._onsets("actuator", i):
                res = self._actuator_test(i, outs, kf, kk, Rn, Rv, valid, zero_cost, n_eq)
                results.append(res)
                actuator_cost = min(actuator_cost, res.cost)
                if best_h is None or rank(res) > rank(best_h):
                    best_h = res
            best_h = onset_spread(best_h, results)
            tried.append(best_h)
            if best_h.passes:
                passing.append(best_h)
        # A refinement (its shape taken as known: distance 0) is told from another by its cost.
        found = min(passing, key=lambda h: (h.distance, h.cost)) if passing else None
        refines = found is not None and self._refines(found)
        # The sensors are tried even when an actuator is found: one that fits as well is
        # named beside it (`alike`).
        sensors = []
        for j in range(self.q):
            best_h, results = None, []
            for kf in self._onsets("sensor", j):
                res = self._sensor_test(j, kf, kk, Rv, valid, zero_cost, n_eq)
                results.append(res)
                if best_h is None or res.cost < best_h.cost:
                    best_h = res
            best_h = onset_spread(best_h, results)
            tried.append(best_h)
            # Not a sensor while an actuator's step response fits the data better by the
            # margin, even one whose shape tests fail: a small fault's free fit is loose,
            # and its model's step response is the likelihood that counts.
            if best_h.passes and best_h.cost <= actuator_cost + EVIDENCE_MARGIN:
                sensors.append(best_h)
        if found is not None and not refines:
            return found, tried
        # A refinement of an actuator (shape not retested) competes with the sensors on cost,
        # and a new fault must fit better than the rest of an accepted one by the margin: an
        # estimate a little off leaves a rest that a small new bias fits about as well.
        candidates = [*sensors, *([found] if refines else [])]
        rest = min((h for h in candidates if self._refines(h)), key=lambda h: h.cost,
                   default=None)
        if rest is not None:
            candidates = [h for h in candidates
                          if self._refines(h) or h.cost < rest.cost - EVIDENCE_MARGIN]
        found = min(candidates, key=lambda h: h.cost, default=None)
        if found is not None:
            return found, tried
        return None, sorted(tried, key=lambda h: h.cost)

    def alike(self, found: HypothesisTest, tried: list[HypothesisTest]
              ) -> tuple[dict, ...]:
        """The candidates of a new fault: ``found`` first, then every other channel whose
        hypothesis fits the data (cost per equation within ``max_fit_variance``, an
        amplitude that differs from zero by eq. 16) within ``EVIDENCE_MARGIN`` of its cost,
        by cost; () when there is none, or for a refinement. Two channels whose responses
        differ only in a transient buried in the noise (a u3 bias and a T3 bias below FNR 1:
        u3 reaches T3 alone, through a pole of 0.8) are told apart by nothing the data hold,
        so the diagnosis names both rather than guess."""
        if self._refines(found):
            return ()
        s = self.settings

        def significant(h: HypothesisTest) -> bool:
            key = "lambda" if h.target == "actuator" else "bias"
            return bool(np.sqrt(h.variances[key]) <= s.gamma * abs(h.estimates[key]))

        others = sorted((h for h in tried
                         if (h.target, h.index) != (found.target, found.index) and h.fits
                         and significant(h) and h.cost <= found.cost + EVIDENCE_MARGIN),
                        key=lambda h: (h.cost, h.target, h.index))
        return (found.candidate(), *(h.candidate() for h in others)) if others else ()

    def _refines(self, h: HypothesisTest) -> bool:
        """Whether h's channel is compensated already (its diagnosis would refine it)."""
        return bool(compensated(self.compensation, h.target, h.index))

    def _accepted_onset(self, target: str, index: int) -> int | None:
        """The onset of the latest fault accepted on this channel, None when there is none."""
        return fault_onset(self.compensation, target, index)

    def _onsets(self, target: str, index: int) -> list[int]:
        """The onsets tried for a hypothesis: the diagnosis' candidates and, for a channel
        compensated already, the accepted fault's own onset. What an estimate off by a little
        leaves acts from that onset on: through a slow path, a rest still rising when it is
        detected, which no step from inside the window fits (it was taken for a small bias
        of another output)."""
        onsets = list(self._diag.onsets)
        first = self._accepted_onset(target, index)
        if first is not None and first not in onsets:
            onsets.insert(0, first)
        return onsets

    def _actuator_test(self, i, outs, kf, kk, Rn, Rv, valid, zero_cost, n_eq) -> HypothesisTest:
        s = self.settings
        # (a) amplitude through the models: r_j / sigma_j = lambda s_ji(k - kf) / sigma_j.
        X = np.zeros_like(Rv)
        after = kk >= kf
        for j in outs:
            pair = self._pair_of[(int(j), i)]
            step = np.zeros(len(kk))
            step[after] = pair.step_response(int(kk[-1] - kf + 1))[kk[after] - kf]
            X[:, j] = step / self.sigma[j]
        X = X * valid
        model_var = 0.0
        if X.any():
            amp = least_squares(X.reshape(-1, 1), Rv.reshape(-1))
            lam, cost = float(amp.theta[0]), amp.cost
            var = cost / max(n_eq - 1, 1) * float(amp.covariance[0, 0])
            # lambda is seen through each path's gain: a relative error delta_j of it moves
            # the estimate by lambda delta_j times that output's share of the information.
            share = (X**2).sum(axis=0) / float((X**2).sum())
            rel = np.zeros(len(share))
            for j in outs:
                pair = self._pair_of[(int(j), i)]
                rel[j] = pair.gain_std / max(abs(pair.static_gain), 1e-300)
            model_var = lam**2 * float(np.sum((share * rel) ** 2))
        else:
            lam, cost, var = 0.0, float((Rv**2).sum()), np.inf
        scale = cost / max(n_eq - 1, 1)
        fits = scale <= s.max_fit_variance
        total = compensated(self.compensation, "actuator", i)
        if total:
            # A refinement: the path's shape was established when the fault was accepted; what
            # is left is an amplitude, judged against the channel's whole fault.
            passes = bool(fits and np.sqrt(var) <= s.gamma * max(abs(lam), abs(total["lambda"])))
            return HypothesisTest("actuator", i, self.input_names[i], int(kf), {"lambda": lam},
                                  {"lambda": float(var)}, cost, 0.0, True, fits, passes,
                                  model_var)
        # (b) the free fit of the residual's step response on each output the path reaches.
        gamma_ok, distance, shape_ok = True, 0.0, True
        for j in outs:
            pair = self._pair_of[(int(j), i)]
            # Samples without any residual have no row: index by sample number.
            r = np.full(int(kk[-1] - kk[0] + 1), np.nan)
            r[kk - kk[0]] = Rn[:, j]
            onset_row = int(kf - kk[0])
            fit = fit_step(r, onset_row, len(pair.b), len(pair.f), pair.delay,
                           f_starts=(np.asarray(pair.f),))
            f_hat = np.asarray(pair.f)
            if len(f_hat):
                norm = float(np.linalg.norm(f_hat))
                gamma_ok &= bool(np.all(np.sqrt(fit.var_f) <= s.gamma * norm))
                d_j = float(np.linalg.norm(fit.f - f_hat)) / norm
                distance = max(distance, d_j)
                # The model's F is the shape when the free F is that far only through noise:
                # holding F there costs less than the chi-square margin of its coefficients.
                shape_ok &= bool(d_j <= s.kappa or fit.held_costs[0] - fit.cost
                                 <= special.chdtri(len(f_hat), SHAPE_TAIL))
            else:
                g = fit.static_gain
                gamma_ok &= bool(np.sqrt(np.sum(fit.var_b)) <= s.gamma * abs(g))
        # Eq. 16 for the amplitude, as for a sensor's bias: a fault that differs from zero.
        passes = bool(fits and gamma_ok and shape_ok and np.sqrt(var) <= s.gamma * abs(lam))
        return HypothesisTest("actuator", i, self.input_names[i], int(kf), {"lambda": lam},
                              {"lambda": float(var)}, cost, distance, gamma_ok, fits, passes,
                              model_var)

    def _sensor_test(self, j, kf, kk, Rv, valid, zero_cost, n_eq) -> HypothesisTest:
        s = self.settings
        x = (kk >= kf) & valid[:, j]
        n_after = int(x.sum())
        # The step's amplitude on output j alone (normalised units).
        fit = least_squares(x[:, None].astype(float), Rv[:, j]) if n_after else None
        b = float(fit.theta[0]) if fit is not None else 0.0
        cost_j = fit.cost if fit is not None else float((Rv[:, j] ** 2).sum())
        cost = cost_j + float(zero_cost.sum() - zero_cost[j])
        scale = cost / max(n_eq - 1, 1)
        var = scale / n_after if n_after else np.inf
        fits = scale <= s.max_fit_variance
        sig = self.sigma[j]
        # A refinement is judged against the channel's whole fault (normalised units).
        total = compensated(self.compensation, "sensor", j).get("bias", 0.0) / sig
        gamma_ok = bool(np.sqrt(var) <= s.gamma * max(abs(b), abs(total)))
        return HypothesisTest("sensor", j, self.output_names[j], int(kf),
                              {"bias": float(b * sig)}, {"bias": float(var * sig**2)}, cost, 0.0,
                              gamma_ok, fits, bool(fits and gamma_ok))

    # -- outcomes --------------------------------------------------------------------------
    def _unexplained(self, k: int, t: int, tried: list[HypothesisTest]) -> list[FaultEvent]:
        event = FaultEvent(kind="unexplained", sample=k, timestamp_ns=t,
                           detected_sample=self._diag.k_d,
                           candidates=tuple(h.candidate() for h in tried[:3]))
        self.events.append(event)
        self.mode = MONITOR
        self._restart_detector(k)
        self._recent.clear()
        return [event]

    def _accept(self, k: int, t: int, h: HypothesisTest,
                candidates: tuple[dict, ...] = ()) -> list[FaultEvent]:
        d = self._diag
        onset = h.onset
        # Dated at the channel's fault's own onset (`_onsets` tries it), the diagnosis found
        # what that fault's estimate left.
        leftover = onset == self._accepted_onset(h.target, h.index)
        kind, estimates, variances = fold(self.compensation, Compensation(
            h.target, h.index, onset, lam=h.estimates.get("lambda", 0.0),
            bias=h.estimates.get("bias", 0.0),
            variances={key: v + h.extra_variance for key, v in h.variances.items()},
            correction=leftover))
        event = FaultEvent(kind=kind, sample=k, timestamp_ns=t, target=h.target,
                           index=h.index, name=h.name, estimates=estimates,
                           variances=variances, onset_sample=onset,
                           detected_sample=d.k_d, accepted_sample=k, candidates=candidates)
        if h.target == "actuator" and self._states is not None:
            # Section 3.3 by superposition: the models' state after sample k moves by lambda
            # times the state a unit step applied from the onset leaves in each path.
            lam, steps = h.estimates["lambda"], k - onset + 1
            new = []
            for pair, zi in zip(self.model.pairs, self._states, strict=True):
                if pair.input == h.index and pair.state_size and steps > 0:
                    _, zf = lfilter(pair.num, pair.den, np.ones(steps),
                                    zi=np.zeros(pair.state_size))
                    zi = zi + lam * zf
                new.append(zi)
            self._states = new
        self.mode = MONITOR
        self._restart_detector(k)
        self._recent.clear()
        self.events.append(event)
        return [event]


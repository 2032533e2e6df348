"""The Hwang, Chang and Hsu diagnoser: FIDF + GRGS residuals -> threshold -> fault angles -> accept.

MONITOR. Each sample goes through the deadbeat front end of canfdi.methods.uio.design (FIR over S+1
samples: the FIDF's fhat(k-1) and the GRGS scalars), then the first-order weights (the
paper's Hf(q) = (1 - a) / (q - a)); a weighted residual beyond h noise stds raises the alarm,
h set for the false-alarm interval from the noise model (`uio_thresholds`; the paper flags a
fault when psi(t) is large, eq 23a, reported as ``flag``).

ISOLATE. A step fault (an actuator or sensor bias) makes every front-end output a step after
at most S+1 samples (FIR), of size fault_dc[:, c] times the fault. From ``min_samples`` after
the alarm, the onset and the post-onset means mu of the front-end outputs are fitted (a hinge
on their cumulative sums, for every onset from ``onset_lookback`` samples before the alarm up
to it), and mu is compared with every fault column by its angle (eq 23b extended to the
actuator rows: for sensors the GRGS part is exactly the paper's theta_i against Hf(0)), in
units of mu's standard error. Exactly one column within ``angle_threshold`` and a settled
estimate accept it: actuator j's bias is its own FIDF residual (the diagonal map: residual j
estimates actuator j's fault), sensor i's bias is the projection of the GRGS means on column
i of Hf(0). None by ``max_samples``: "unexplained".

ACCEPT. The bias is folded into a compensation from its onset (u_j + lambda, or z_i - b), the
front end and the weights are re-run from the onset on compensated samples and the detector
restarts, so the next fault is diagnosed on top (the output-error paper's Section 3.3).

Missing data: a NaN value makes missing the front-end outputs whose window reads it; a missing
weighted residual holds its filter state and its statistic. A gap of at most S
samples counts as NaN rows; a longer one (or k going back) restarts the window.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np
from scipy import special  # quantiles: 30 ms to import where scipy.stats takes 0.6 s

from canfdi.core.blockrun import run_block
from canfdi.core.identify import least_squares
from canfdi.core.protocol import DIAGNOSE, MONITOR, deepcopy_sharing
from canfdi.core.records import (
    BlockResult,
    Compensation,
    FaultEvent,
    Sample,
    compensate,
    compensated,
    fold,
)
from canfdi.methods.uio.design import UioDesign, fault_angles, flag_function

__all__ = ["Isolation", "StepMeans", "UioDiagnoser", "UioDiagnosis", "UioSettings",
           "uio_thresholds"]


@dataclass(frozen=True)
class UioDiagnosis:
    """A diagnosis in progress: the alarm at ``k_d``, the change point it found, and the
    front-end output rows (k, o (p+m,)) since the first candidate onset, growing.

    Examples
    --------
    >>> d = UioDiagnosis(k_d=1500, change_point=1499)
    >>> d.rows.append((1500, np.array([0.0, 0.2, 0.0, 0.0])))
    >>> d.change_point, len(d.rows)
    (1499, 1)
    """

    k_d: int
    change_point: int
    rows: list[tuple[int, np.ndarray]] = field(default_factory=list)


@dataclass(frozen=True)
class StepMeans:
    """The hinge fit of the front-end outputs: the best onset (the first sample whose outputs
    carry the fault), the means mu (p+m,) after it, their standard errors se (p+m,), and the
    number n of samples after the onset's transient; cov (p+m, p+m) the means' covariance
    (None: independent, se^2 on the diagonal).

    Examples
    --------
    >>> fit = StepMeans(onset=1499, mu=np.array([0.0, 0.2, 0.0, 0.0]), se=np.full(4, 0.002), n=30)
    >>> fit.mu / fit.se  # in standard errors: the fault's column stands out
    array([  0., 100.,   0.,   0.])
    """

    onset: int
    mu: np.ndarray
    se: np.ndarray
    n: int
    cov: np.ndarray | None = None


@dataclass(frozen=True)
class Isolation:
    """How an accepted fault was isolated: its event and every hypothesis ranked by angle
    (each with its estimate, the FIDF's own lambda or the GRGS bias, and the paper's eq 23b
    angle theta_i), as `UioDiagnoser.isolations` keeps them.

    Examples
    --------
    >>> from canfdi.core.records import FaultEvent
    >>> event = FaultEvent("accepted", 1530, 0, target="sensor", index=0, name="y0")
    >>> iso = Isolation(event, ranking=(
    ...     {"target": "sensor", "index": 0, "name": "y0", "estimates": {"bias": 0.2},
    ...      "angle_deg": 0.4},
    ...     {"target": "actuator", "index": 0, "name": "u", "estimates": {"lambda": 1.9},
    ...      "angle_deg": 71.0}))
    >>> iso.event.name, [(c["name"], c["angle_deg"]) for c in iso.ranking]
    ('y0', [('y0', 0.4), ('u', 71.0)])
    """

    event: FaultEvent
    ranking: tuple[dict, ...]


@dataclass(frozen=True)
class UioSettings:
    """Detection and isolation settings (the config's detection: and uio: sections).

    false_alarm_interval : samples between false alarms per residual.
    angle_threshold : degrees; a fault column is a match when mu is within it.
    min_samples, max_samples : after the alarm, before a decision / before giving up.
    settle_rel_std : the estimate's standard error must be below this fraction of it.
    onset_lookback : samples before the alarm kept for the fit (onsets are tried from 10
        before the change point to the alarm).

    Examples
    --------
    >>> UioSettings(angle_threshold=10.0).angle_threshold, UioSettings().max_samples
    (10.0, 400)
    """

    false_alarm_interval: float = 1.0e7
    angle_threshold: float = 5.0
    min_samples: int = 30
    max_samples: int = 400
    settle_rel_std: float = 0.02
    onset_lookback: int = 50


def uio_thresholds(count: int, interval: float) -> np.ndarray:
    """(count,) thresholds h on |normalised residual| for a false-alarm interval (samples).

    The weighted residuals are Gaussian (linear in Gaussian noise) with unit variance once
    normalised, so P(|r| >= h) = 1 / interval per sample. They are strongly correlated in time
    (the first-order weights remember ~1 / (1 - a) samples), which only makes alarms come in
    runs: the number of false alarms (first crossings) is at most the number of samples beyond
    h, so the false-alarm interval is at least ``interval``. A Page-Hinkley test calibrated on
    these residuals was tried first: its extrapolation from a 10^5-sample record to 10^7 ran
    low by 5 to 10 times on the simulated aircraft (their correlation is at the scale of the
    test's own memory), while the fault gives 25 to 100 noise stds: a plain threshold loses
    little delay and its false-alarm rate needs no extrapolation.
    """
    return np.full(count, float(-special.ndtri(0.5 / float(interval))))  # norm.isf


class UioDiagnoser:
    """Streaming Hwang, Chang and Hsu diagnoser: ``update(sample) -> events``
    (canfdi.monitor.DiagnoserLike).

    Parameters
    ----------
    design : canfdi.methods.uio.design.design_uio's result; settings : UioSettings;
    thresholds : (p+m,) alarm thresholds on |normalised residual| (uio_thresholds);
    input_names, output_names : the model's channel names.

    Examples
    --------
    >>> from canfdi.core.records import Sample
    >>> from canfdi.methods.uio.design import design_uio
    >>> A = np.array([[0.9, 0.0], [0.1, 0.95]])
    >>> B, E = np.array([[0.1], [0.0]]), np.array([[0.0], [1.0]])  # E: an unmeasured load on x2
    >>> C = np.array([[1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
    >>> design = design_uio(A, B, C, E, 0.01, measurement_std=np.full(3, 0.01), input_names=["u"],
    ...                     output_names=["y0", "y1", "y2"])
    >>> diag = UioDiagnoser(design, UioSettings(), uio_thresholds(4, 1e7), ["u"],
    ...                     ["y0", "y1", "y2"])
    >>> rng = np.random.default_rng(0)
    >>> x, events = np.zeros(2), []
    >>> for k in range(1600):
    ...     u = np.array([np.sign(np.sin(k / 30))])
    ...     z = C @ x + 0.01 * rng.standard_normal(3)
    ...     z[0] += 0.2 if k >= 1500 else 0.0  # y0 reads 0.2 high from sample 1500
    ...     events += diag.update(Sample(k, 0, u, z))
    ...     x = A @ x + B @ u + E[:, 0] * 0.5 * np.sin(k / 100)  # the load, decoupled
    >>> [(e.kind, e.sample, e.name, {n: round(v, 2) for n, v in e.estimates.items()})
    ...  for e in events]
    [('detected', 1500, None, {}), ('accepted', 1530, 'y0', {'bias': 0.2})]
    >>> [(c["name"], round(c["angle_deg"], 1)) for c in diag.isolations[-1].ranking]
    [('y0', 0.5), ('u', 23.8), ('y1', 76.0), ('y2', 76.0)]
    """

    def __init__(self, design: UioDesign, settings: UioSettings, thresholds: np.ndarray,
                 input_names: list[str], output_names: list[str]) -> None:
        self.design = self._design0 = design
        self.settings = settings
        self.p, self.q = design.p, design.m
        self.thresholds = np.asarray(thresholds, dtype=float).reshape(self.p + self.q)
        self.input_names = list(input_names)
        self.output_names = list(output_names)
        self.S = design.fir.S
        coef = design.fir.coef
        self._coef_flat = coef.reshape(-1, coef.shape[2]).T  # (n_out, (S+1)(m+p))
        self._uses_flat = (self._coef_flat != 0).astype(float)
        self.hypotheses = ([("actuator", j, n) for j, n in enumerate(self.input_names)]
                           + [("sensor", i, n) for i, n in enumerate(self.output_names)])
        self._history: deque = deque(maxlen=settings.max_samples + settings.onset_lookback
                                     + self.S + 8)
        self._recent: deque = deque(maxlen=settings.onset_lookback + self.S + 1)
        self.events: list[FaultEvent] = []
        self.isolations: list[Isolation] = []
        self.compensation: list[Compensation] = []
        self._diag: UioDiagnosis | None = None
        self.reset()

    # -- state ----------------------------------------------------------------------------
    def __deepcopy__(self, memo: dict) -> UioDiagnoser:
        """A copy that runs apart from this one; the designs, which update never changes, shared."""
        return deepcopy_sharing(self, memo, self.design, self._design0)

    def reset(self) -> None:
        """Back to the state after construction: monitoring, no compensation, no events,
        empty window, filters at rest."""
        self.noise_scale = 1.0
        self.mode = MONITOR
        self.events = []
        self.isolations = []
        self._ring = np.full((self.S + 1, self.p + self.q), np.nan)
        self._lp = np.zeros(self.p + self.q)
        self._history.clear()
        self._recent.clear()
        self.compensation = []
        self._restart_detector()
        self._last_k: int | None = None
        self.last_residuals: np.ndarray | None = None
        self.last_normalized: np.ndarray | None = None

    def _restart_detector(self, k: int = -1) -> None:
        n = self.p + self.q
        self._stat = np.zeros(n)
        self._last_quiet = np.full(n, k, dtype=np.int64)
        self._diag = None

    @property
    def noise_scale(self) -> np.ndarray:
        """(p+m,) each residual's noise over the design's (settable: the noise watchdog widens
        the noise of a residual in mismatch, canfdi.core.watchdog; 1 by default)."""
        return self.design.noise_std / self._design0.noise_std

    @noise_scale.setter
    def noise_scale(self, value: np.ndarray) -> None:
        self.design = self._design0.scaled(value)

    @property
    def residual_names(self) -> list[str]:
        return list(self.design.names)

    @property
    def statistics(self) -> np.ndarray:
        """(p+m,) |normalised residual| (held while missing), compared with thresholds."""
        return self._stat.copy()

    @property
    def flag(self) -> float | None:
        """psi(t) of the GRGS residuals (eq 23a), None when missing."""
        r = self.last_residuals
        if r is None or np.isnan(r[self.p:]).any():
            return None
        return float(flag_function(r[self.p:]))

    # -- the residual pipeline ---------------------------------------------------------------
    def _compensate(self, k: int, z: np.ndarray, u: np.ndarray) -> np.ndarray:
        """(m+p,) the sample [z, u] with the accepted faults undone."""
        Z, U = compensate(self.compensation, np.array([k]), np.asarray(z, dtype=float)[None, :],
                          np.asarray(u, dtype=float)[None, :])
        return np.concatenate([Z[0], U[0]])

    def _push(self, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Advance window and weights by one compensated sample: (front end o, weighted r)."""
        ring = self._ring
        ring[:-1] = ring[1:]
        ring[-1] = v
        w = ring.reshape(-1)
        missing = np.isnan(w)
        if missing.any():
            o = self._coef_flat @ np.where(missing, 0.0, w)
            o[self._uses_flat @ missing > 0] = np.nan
        else:
            o = self._coef_flat @ w
        ok = ~np.isnan(o)
        a = self.design.a
        self._lp[ok] = a[ok] * self._lp[ok] + (1.0 - a[ok]) * o[ok]
        r = np.where(ok, self._lp, np.nan)
        return o, r

    def _gap(self, k: int) -> None:
        if self._last_k is None:
            return
        missing = k - self._last_k - 1
        if missing == 0:
            return
        if 0 < missing <= self.S:
            self._ring[:-missing] = self._ring[missing:].copy()
            self._ring[-missing:] = np.nan
        else:
            self._ring[:] = np.nan
        # Re-running across a gap would need the lost samples: no re-run before it.
        self._history.clear()

    # -- the state machine ----------------------------------------------------------------
    def update(self, sample: Sample) -> list[FaultEvent]:
        """Process one sample; returns the events it caused (usually none)."""
        k = int(sample.k)
        self._gap(k)
        self._last_k = k
        z = np.asarray(sample.z, dtype=float).copy()
        u = np.asarray(sample.u, dtype=float).copy()
        self._history.append((k, z, u, self._ring.copy(), self._lp.copy()))
        o, r = self._push(self._compensate(k, z, u))
        if np.isnan(r).all():
            self.last_residuals = self.last_normalized = None
            return []
        rn = r / self.design.noise_std
        self.last_residuals, self.last_normalized = r, rn
        if self.mode == MONITOR:
            self._recent.append((k, o))
            return self._monitor(k, sample.timestamp_ns, rn)
        self._diag.rows.append((k, o))
        return self._isolate(k, sample.timestamp_ns)

    def update_block(self, k: np.ndarray, t_ns: np.ndarray, U: np.ndarray, Z: np.ndarray,
                     gap: np.ndarray | None = None) -> BlockResult:
        """``update`` over N samples (k, t_ns (N,); U (N, p); Z (N, q), NaN = lost); the same
        results as N calls, gathered (residual rows NaN where update gave none)."""
        return run_block(self, np.asarray(k, dtype=np.int64), t_ns, U, Z, gap)

    def _monitor(self, k: int, t: int, rn: np.ndarray) -> list[FaultEvent]:
        s = self.settings
        seen = ~np.isnan(rn)
        self._stat[seen] = np.abs(rn[seen])
        # The change point: after the last sample each residual was within one noise std.
        self._last_quiet[seen & (self._stat <= 1.0)] = k
        alarm = self._stat >= self.thresholds
        if not alarm.any():
            return []
        alarming = np.flatnonzero(alarm)
        change_point = int(np.min(self._last_quiet[alarming])) + 1
        self.mode = DIAGNOSE
        first = max(change_point, k) - s.onset_lookback
        self._diag = UioDiagnosis(k_d=k, change_point=change_point,
                                  rows=[(kk, o) for kk, o in self._recent if kk >= first])
        event = FaultEvent(kind="detected", sample=k, timestamp_ns=t, detected_sample=k,
                           onset_sample=change_point,
                           residuals=tuple(self.design.names[i] for i in alarming))
        self.events.append(event)
        return [event]

    # -- isolation --------------------------------------------------------------------------
    def _fit(self) -> StepMeans | None:
        """Hinge fit of the front-end outputs since the first candidate onset.

        Returns the best onset (the first sample whose outputs carry the fault), the means mu
        (p+m,) after it and their standard errors, or None when too few rows are known."""
        d = self._diag
        rows = [(kk, o) for kk, o in d.rows if not np.isnan(o).any()]
        if len(rows) < 8:
            return None
        ks = np.array([kk for kk, _ in rows])
        O = np.array([o for _, o in rows])
        lr, fs = self.design.long_run_std, self.design.front_std
        scale = np.maximum(fs, 1e-300)
        # Cumulative sums of a step through the FIR front end: a level, then (the S samples
        # of the window's transient, left out) a jump, then a ramp of slope mu; moving-average
        # noise adds bounded noise to them.
        Cs = np.cumsum(O, axis=0) / scale
        # Onsets from a few samples before the change point (noise can lift a residual past
        # one std early) up to the alarm.
        onsets = np.arange(max(ks[0] + 1, d.change_point - 10), d.k_d + 1)
        best = None
        for kf in onsets:
            after = ks >= kf + self.S
            use = after | (ks < kf)
            n_post = int(after.sum())
            if n_post < 4 or int((ks < kf).sum()) < 2:
                continue
            X = np.column_stack([np.ones(use.sum()), after[use],
                                 np.maximum(ks[use] - kf + 1, 0)]).astype(float)
            fit = least_squares(X, Cs[use])
            coef = fit.theta
            # Compare onsets on the same rows: those left out for one onset are the S after it.
            cost = float(np.sum(fit.cost)) * len(ks) / use.sum()
            if best is None or cost < best[0]:
                best = (cost, int(kf), coef[2] * scale, n_post)
        if best is None:
            return None
        _, kf, mu, n_post = best
        # The slope of a line through n cumulative sums of correlated noise (a random walk
        # of the long-run covariance) varies as 6/5 of that covariance over n; the moving
        # average's bounded part as the white noise on a line, 12 / n^3.
        cov = 1.2 * self.design.long_run_cov / n_post + 12.0 * self.design.front_cov / n_post**3
        # The isolation's weights and the settling test keep the independent outputs' form
        # (the shipped settle_rel_std was set by it); the events report the covariance's.
        se = np.sqrt(lr**2 / n_post + 12.0 * fs**2 / n_post**3)
        return StepMeans(onset=kf, mu=mu, se=np.maximum(se, 1e-300), n=n_post, cov=cov)

    def _isolate(self, k: int, t: int) -> list[FaultEvent]:
        d, s = self._diag, self.settings
        since = k - d.k_d
        if since < s.min_samples:
            return []
        fit = self._fit()
        if fit is not None:
            D = self.design.fault_dc / fit.se[:, None]
            angles = np.degrees(fault_angles(fit.mu / fit.se, D, signed=False))
            order = np.argsort(angles)
            best = int(order[0])
            est, se = self._estimate(best, fit)
            unique = angles[best] <= s.angle_threshold and angles[order[1]] > s.angle_threshold
            target, index, _ = self.hypotheses[best]
            total = compensated(self.compensation, target, index)
            # A refinement settles against the channel's whole fault, not the small rest.
            size = max(abs(est), abs(total.get("lambda" if target == "actuator" else "bias",
                                               0.0)))
            settled = se <= s.settle_rel_std * size
            if unique and settled:
                return self._accept(k, t, best, fit, angles, order)
        if since >= s.max_samples:
            return self._unexplained(k, t, fit)
        return []

    def _estimate(self, c: int, fit: StepMeans) -> tuple[float, float]:
        """Bias of hypothesis c and its standard error: the weighted least-squares fit of its
        fault column to the means of every front-end output (weights 1 / se^2). For an
        actuator the FIDF's own residual carries the diagonal map (residual j estimates
        actuator j's fault: `_own_estimate`), but the GRGS outputs see the same step with
        far less noise, and a compensation that leaves them off by more than their noise
        raises the next alarm at once. (Its error takes the outputs for independent, as the
        settling test was set by; `_reported_std` does not.)"""
        col = self.design.fault_dc[:, c] / fit.se
        cc = float(col @ col)
        weights = col / fit.se / cc  # the estimate is weights @ mu
        return float(fit.mu @ weights), 1.0 / np.sqrt(cc)

    def _reported_std(self, c: int, fit: StepMeans) -> float:
        """The standard deviation of `_estimate`'s bias as the means' covariance says (the
        outputs correlated, the slope of a random walk's line 6/5 as uncertain as white
        noise's): what an event reports."""
        col = self.design.fault_dc[:, c] / fit.se
        weights = col / fit.se / float(col @ col)
        if fit.cov is None:
            return float(np.sqrt(weights**2 @ fit.se**2))
        return float(np.sqrt(max(float(weights @ fit.cov @ weights), 0.0)))

    def _own_estimate(self, c: int, fit: StepMeans) -> float:
        """The paper's estimate: actuator j's own FIDF residual, or sensor i's GRGS means
        projected on column i of Hf(0) (eq 23's direction)."""
        p = self.p
        if c < p:
            return float(fit.mu[c])
        h = self.design.Hf0[:, c - p]
        return float(fit.mu[p:] @ h) / float(h @ h)

    def _candidates(self, fit: StepMeans, angles: np.ndarray, order: np.ndarray
                    ) -> tuple[dict, ...]:
        p = self.p
        theta = np.degrees(fault_angles(fit.mu[p:], self.design.Hf0))  # eq 23b, GRGS only
        out = []
        for c in order.tolist():
            target, index, name = self.hypotheses[c]
            est, _ = self._estimate(c, fit)
            entry = {"target": target, "index": index, "name": name,
                     "estimates": {"lambda" if target == "actuator" else "bias": est},
                     "angle_deg": float(angles[c])}
            if target == "actuator":
                entry["fidf_lambda"] = self._own_estimate(c, fit)
            else:
                entry["grgs_bias"] = self._own_estimate(c, fit)
                entry["grgs_angle_deg"] = float(theta[index])
            out.append(entry)
        return tuple(out)

    def _unexplained(self, k: int, t: int, fit: StepMeans | None) -> list[FaultEvent]:
        candidates: tuple[dict, ...] = ()
        if fit is not None:
            D = self.design.fault_dc / fit.se[:, None]
            angles = np.degrees(fault_angles(fit.mu / fit.se, D, signed=False))
            candidates = self._candidates(fit, angles, np.argsort(angles))[:3]
        # As in canfdi.methods.parity.diagnoser, an unexplained event lists the best few hypotheses.
        event = FaultEvent(kind="unexplained", sample=k, timestamp_ns=t,
                           detected_sample=self._diag.k_d, candidates=candidates)
        self.events.append(event)
        self.mode = MONITOR
        self._restart_detector(k)
        return [event]

    def _accept(self, k: int, t: int, c: int, fit: StepMeans, angles: np.ndarray,
                order: np.ndarray) -> list[FaultEvent]:
        target, index, name = self.hypotheses[c]
        est, _ = self._estimate(c, fit)
        se = self._reported_std(c, fit)
        # The front end sees an actuator fault one sample after it acts (through x(k+1)),
        # a sensor fault at once.
        onset = fit.onset - (1 if target == "actuator" else 0)
        key = "lambda" if target == "actuator" else "bias"
        kind, estimates, variances = fold(self.compensation, Compensation(
            target, index, onset, lam=est if target == "actuator" else 0.0,
            bias=est if target == "sensor" else 0.0, variances={key: se**2}))
        event = FaultEvent(kind=kind, sample=k, timestamp_ns=t, target=target,
                           index=index, name=name, estimates=estimates,
                           variances=variances, onset_sample=onset,
                           detected_sample=self._diag.k_d, accepted_sample=k)
        # The angles are no candidates in the FaultEvent sense (channels explaining the data
        # equally well: the monitor prints them as such); they go with the event here.
        self.isolations.append(Isolation(event, self._candidates(fit, angles, order)))
        self._rerun(onset)
        self.mode = MONITOR
        self._restart_detector(k)
        self.events.append(event)
        return [event]

    def _rerun(self, onset: int) -> None:
        """Recompute window and weights from the onset on with the new compensation."""
        entries = list(self._history)
        start = next((i for i, e in enumerate(entries) if e[0] >= onset), None)
        if start is None:
            return
        _, _, _, ring, lp = entries[start]
        self._ring, self._lp = ring.copy(), lp.copy()
        self._recent.clear()
        for kk, z, u, _, _ in entries[start:]:
            # Gaps inside the history cannot happen: a gap clears it.
            o, _ = self._push(self._compensate(kk, z, u))
            self._recent.append((kk, o))
        # The weights restart at rest (the output-error paper's reset of the detector): an onset
        # off by a
        # sample leaves a short transient in the front end that they would remember for
        # 1 / (1 - a) samples, far above the GRGS noise. The front end itself is exact again
        # S samples after the onset.
        self._lp[:] = 0.0
        self.last_residuals = np.zeros(self.p + self.q)
        self.last_normalized = np.zeros(self.p + self.q)

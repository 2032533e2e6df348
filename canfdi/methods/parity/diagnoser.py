"""The per-sample diagnosis state machine: residuals -> detection -> identification -> isolation
-> acceptance -> compensation and reset -> on to the next fault.

MONITOR. Each sample's residuals (canfdi.core.residuals), normalised by their noise standard
deviation, feed a two-sided Page-Hinkley test per residual (thresholds calibrated on fault-free
residuals of the model for a stated false-alarm interval). An alarm at k_d starts a diagnosis.

DIAGNOSE. Every fault hypothesis (each actuator: u = eta u_c + lambda, eq. 24; each sensor:
z = y + b, eq. 34) predicts the residuals linearly in its parameters from the fault onset k_f on
(canfdi.core.residuals' signatures), so each hypothesis is identified by recursive least squares
in information form (P reset at the alarm, forgetting factor 1: the abrupt-fault setting of
DESIGN.md), over all residuals at once. As seed 003 shifts its step to find k_f, each hypothesis
is fitted for several onsets around the Page-Hinkley change point. From ``min_samples`` after the
alarm the fits are compared by their least-squares cost J: the best hypothesis is accepted when
every hypothesis outside its ambiguity group costs at least ``isolation_margin`` more (a
log-likelihood-ratio margin on the normalised residuals) and its estimates have settled (standard
deviation below ``settle_rel_std`` of their size) and it leaves about the noise (residual variance
per equation at most ``max_fit_variance`` times nominal: a transient such as one corrupt sample
is no persistent fault, and no step fits it). Hypotheses whose bias signatures over the window
are proportional fit equally well forever (the ambiguity group); the event then lists them all
as candidates, with the size each would have.
No acceptance by ``max_samples``: an "unexplained" event and the detector restarts.

ACCEPT. The estimate is folded into a compensation applied from k_f on (z_j - b, or
u_j = eta u_cj + lambda), the residual window is rebuilt from compensated samples and the
detector restarts (seed 003 Section 3.3), so a later fault on any channel is diagnosed on top of
the ones already found, repaired or not.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from canfdi.core.design import Design
from canfdi.core.detect import (
    ChangePointDetector,
    calibrate_threshold,
    onset_candidates,
    threshold_for_long_run_variance,
)
from canfdi.core.records import FaultEvent, Sample
from canfdi.core.residuals import ResidualBank

__all__ = ["BlockResult", "Diagnoser", "DiagnoserSettings", "Hypothesis", "calibrate_thresholds"]


@dataclass(frozen=True)
class BlockResult:
    """What ``Diagnoser.update_block`` did for N samples.

    events : the events, in order.
    residuals, normalized : (N, m), NaN where a sample had no residual (window filling).
    statistic : (N, m) the larger Page-Hinkley statistic after each sample.
    """

    events: list
    residuals: np.ndarray
    normalized: np.ndarray
    statistic: np.ndarray

MONITOR, DIAGNOSE = "monitor", "diagnose"


@dataclass(frozen=True)
class DiagnoserSettings:
    """Detection and acceptance settings (the config's detection: and identification:).

    drift : Page-Hinkley delta in residual noise standard deviations.
    false_alarm_interval : samples between false alarms per residual the thresholds target.
    min_samples, max_samples : samples after the alarm before a decision / before giving up.
    settle_rel_std : accept when each estimate's standard deviation is below this fraction of
        its size (an actuator's lambda: of max(|lambda|, 0.1 |eta - 1| mean|u_c|)).
    isolation_margin : cost margin over every hypothesis outside the best one's group.
    onset_before : onsets tried before the Page-Hinkley change point (all up to the alarm
        after it), at most max_onsets in all.
    prior_precision : P reset value is 1 / prior_precision (information form: J0 = this * I).
    max_fit_variance : accept only a fit whose cost per residual equation (normalised residuals:
        1 is the noise) is at most this.
    """

    drift: float = 0.5
    false_alarm_interval: float = 1.0e7
    min_samples: int = 200
    max_samples: int = 2000
    settle_rel_std: float = 0.01
    isolation_margin: float = 50.0
    onset_before: int = 3
    max_onsets: int = 16
    prior_precision: float = 1e-8
    max_fit_variance: float = 4.0


@dataclass(frozen=True)
class Hypothesis:
    """One fault hypothesis.

    target : "actuator" (u = eta u_c + lambda, eq. 24), "actuator_bias" (the same with eta = 1:
        a bias alone, one parameter), "sensor", or "sensors" (biases on several sensors at
        once: seed 001 eq. 41, over a largest set of sensors whose signatures are linearly
        independent).
    index, name : the channel (for "sensors": the first member).
    members : the sensor indices of a "sensors" hypothesis.
    """

    target: str
    index: int
    name: str
    members: tuple[int, ...] = ()

    @property
    def label(self) -> str:
        return f"{self.target}:{self.name}"

    @property
    def n_params(self) -> int:
        return {"actuator": 2, "actuator_bias": 1, "sensor": 1}.get(self.target,
                                                                     len(self.members))


def calibrate_thresholds(bank: ResidualBank, measurement_std: np.ndarray,
                         process_std: np.ndarray | None, model, drift: float,
                         interval: float, n: int = 100_000, seed: int = 0) -> np.ndarray:
    """Page-Hinkley thresholds (m,) in noise-std units for a false-alarm interval (samples).

    Parity residuals over a window are correlated in time, so the white-noise formula is wrong;
    the thresholds are calibrated on ``n`` fault-free residuals generated from the model's noise
    (seeded, so the design is reproducible) at two false-alarm intervals the record can show
    (n/20 and n/200), and extrapolated log-linearly to ``interval``, as the run length of the
    test grows exponentially with its threshold. Never below the white-noise (Siegmund) value.
    Results are cached for the process (the same design calibrates once).
    """
    key = (bank.M.tobytes(), bank.sigma.tobytes(), np.asarray(measurement_std).tobytes(),
           None if process_std is None else np.asarray(process_std).tobytes(),
           model.A.tobytes(), model.C.tobytes(), drift, interval, n, seed)
    if key not in _THRESHOLD_CACHE:
        _THRESHOLD_CACHE[key] = _calibrate(bank, measurement_std, process_std, model, drift,
                                           interval, n, seed)
    return _THRESHOLD_CACHE[key].copy()


_THRESHOLD_CACHE: dict[tuple, np.ndarray] = {}


def _calibrate(bank: ResidualBank, measurement_std: np.ndarray, process_std: np.ndarray | None,
               model, drift: float, interval: float, n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    length = n + bank.S
    x = np.zeros((length, bank.q + bank.p))
    x[:, : bank.q] = rng.standard_normal((length, bank.q)) * measurement_std
    if process_std is not None and np.any(process_std):
        state = np.zeros(model.n)
        noise = rng.standard_normal((length, model.n)) * process_std
        for k in range(length):
            x[k, : bank.q] += model.C @ state
            state = model.A @ state + noise[k]
    rn = bank.batch(x) / bank.sigma
    arl_hi, arl_lo = n / 20.0, n / 200.0
    # Thresholds are tens of noise stds: 0.02 is far below what matters.
    h_hi = np.asarray(calibrate_threshold(rn, drift, arl_hi, tol=0.02), dtype=float)
    h_lo = np.asarray(calibrate_threshold(rn, drift, arl_lo, tol=0.02), dtype=float)
    slope = np.maximum(h_hi - h_lo, 0.0) / np.log(arl_hi / arl_lo)
    h = h_hi + slope * np.log(max(interval, arl_hi) / arl_hi)
    # Far beyond the record the extrapolation runs low for strongly correlated residuals (the
    # 10^7-sample soak found s:omega_r, a 5-sample moving sum, alarming every ~1.3e6 samples
    # at a 1e7 target): bound it by Siegmund's threshold on the long-run variance (which is
    # never below the white-noise one).
    long_run = _long_run_variance(bank, measurement_std, process_std, rn)
    return np.maximum(h, threshold_for_long_run_variance(drift, interval, long_run))


def _long_run_variance(bank: ResidualBank, measurement_std: np.ndarray,
                       process_std: np.ndarray | None, rn: np.ndarray) -> np.ndarray:
    """(m,) long-run variance (sum of all autocovariances) of each normalised residual.

    For white measurement noise it is exact: r_i = sum_l sum_c M_i[l, c] x_c(k - S + l), so
    sum_tau cov(tau) = sum_c var(x_c) (sum_l M_i[l, c])^2. Process noise adds slowly decaying
    correlation the formula does not see: with process noise, batch means over the
    calibration record (blocks of 50 windows) estimate it too, and the larger value is used.
    """
    coef = bank.M.reshape(bank.m, bank.S + 1, -1)[:, :, : bank.q]
    var = np.asarray(measurement_std, dtype=float) ** 2 * np.ones(bank.q)
    exact = (coef.sum(axis=1) ** 2 @ var) / bank.sigma**2
    block = 50 * (bank.S + 1)
    n_blocks = len(rn) // block
    if process_std is None or not np.any(process_std) or n_blocks < 20:
        return exact
    means = rn[: n_blocks * block].reshape(n_blocks, block, -1).mean(axis=1)
    return np.maximum(exact, means.var(axis=0, ddof=1) * block)


def _proportional(a: np.ndarray, b: np.ndarray, tol: float = 1e-9) -> bool:
    """Whether two signatures are multiples of each other (and nonzero)."""
    na, nb = float(np.linalg.norm(a)), float(np.linalg.norm(b))
    if na == 0.0 or nb == 0.0:
        return False
    return abs(float(a @ b)) >= (1.0 - tol) * na * nb


class Diagnoser:
    """Streaming diagnoser: ``update(sample) -> events``.

    Parameters
    ----------
    design : the residual bank's design (canfdi.core.design.design_bank).
    settings : DiagnoserSettings.
    thresholds : (m,) Page-Hinkley thresholds in noise-std units (calibrate_thresholds).
    """

    def __init__(self, design: Design, settings: DiagnoserSettings, thresholds: np.ndarray
                 ) -> None:
        self.design = design
        self.settings = settings
        self.bank = ResidualBank(design)
        thresholds = np.asarray(thresholds, dtype=float).reshape(self.bank.m)
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
        joint = self._independent_sensors([h.index for h in keep if h.target == "sensor"])
        if len(joint) > 1:
            self.hypotheses.append(Hypothesis("sensors", joint[0], "+".join(
                design.output_names[j] for j in joint), members=tuple(joint)))
        self.d = max(h.n_params for h in self.hypotheses)
        # Hypotheses whose bias signatures over the window are proportional (a sensor's Gz_j,
        # an actuator's lambda part Gu_j) fit a bias equally well forever: they are reported
        # together, never told apart. (The design's isolability table, which compares only
        # which residuals respond, is coarser: T1 and u1 of the winding machine share their
        # residuals but not their signatures, and the data tell them apart.)
        single = [h for h in self.hypotheses if h.target != "sensors"]
        signature = {h: (self.bank.Gz if h.target == "sensor" else self.bank.Gu)[h.index]
                     .ravel() for h in single}
        self._twins = {h: {g for g in single if g != h
                           and _proportional(signature[h], signature[g])} for h in single}
        for h in self.hypotheses:
            self._twins.setdefault(h, set())
        self.detector = ChangePointDetector(self.bank.m, settings.drift, thresholds)
        n_onsets = settings.max_onsets
        self._history: deque = deque(maxlen=self.bank.S + n_onsets + 8)
        self._recent: deque = deque(maxlen=n_onsets + 8)
        self.compensation: list[dict] = []
        self.events: list[FaultEvent] = []
        self.reset()

    def _independent_sensors(self, sensors: list[int]) -> list[int]:
        """A largest subset, in index order, whose signatures are linearly independent."""
        chosen: list[int] = []
        basis = np.zeros((0, self.bank.Gz[0].size))
        for j in sensors:
            trial = np.vstack([basis, self.bank.Gz[j].ravel()])
            if np.linalg.matrix_rank(trial, tol=1e-9 * np.abs(trial).max()) > len(chosen):
                chosen.append(j)
                basis = trial
        return chosen

    # -- state ---------------------------------------------------------------------------
    def reset(self) -> None:
        """Back to monitoring with no compensation and empty windows."""
        self.mode = MONITOR
        self.bank.restart()
        self._history.clear()
        self._recent.clear()
        self.compensation = []
        self._restart_detector()
        self._last_k: int | None = None
        self.last_residuals: np.ndarray | None = None
        self.last_normalized: np.ndarray | None = None

    def _restart_detector(self, k: int = -1) -> None:
        """Zero the Page-Hinkley statistics; a change point cannot predate sample k."""
        self.detector.restart(k)
        self._diag = None

    @property
    def residual_names(self) -> list[str]:
        return self.bank.names

    @property
    def thresholds(self) -> np.ndarray:
        """(m,) Page-Hinkley thresholds in noise stds: the detector's (settable, e.g. scaled by
        a sensitivity check)."""
        return self.detector.h

    @thresholds.setter
    def thresholds(self, value: np.ndarray) -> None:
        self.detector.h = np.asarray(value, dtype=float).reshape(self.detector.m)

    @property
    def statistics(self) -> np.ndarray:
        """(m,) the larger Page-Hinkley statistic of each residual."""
        return self.detector.statistics

    # -- compensation ----------------------------------------------------------------------
    def _compensate(self, k: int, z: np.ndarray, u: np.ndarray) -> np.ndarray:
        x = np.empty(self.q + self.p)
        x[: self.q] = z
        x[self.q :] = u
        for c in self.compensation:
            if k < c["onset"]:
                continue
            if c["target"] == "sensor":
                x[c["index"]] -= c["bias"]
            else:
                j = self.q + c["index"]
                x[j] = c["eta"] * x[j] + c["lambda"]
        return x

    def _compensate_block(self, k: np.ndarray, Z: np.ndarray, U: np.ndarray) -> np.ndarray:
        """(N, q+p) compensated samples, the vectorised twin of _compensate."""
        X = np.hstack([Z, U]).astype(float, copy=True)
        for c in self.compensation:
            mask = k >= c["onset"]
            if not mask.any():
                continue
            if c["target"] == "sensor":
                X[mask, c["index"]] -= c["bias"]
            else:
                j = self.q + c["index"]
                X[mask, j] = c["eta"] * X[mask, j] + c["lambda"]
        return X

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
        n, m = len(k), self.bank.m
        gap = np.zeros(n, dtype=np.int64) if gap is None else np.asarray(gap)
        U = np.asarray(U, dtype=float)
        Z = np.asarray(Z, dtype=float)
        R = np.full((n, m), np.nan)
        Rn = np.full((n, m), np.nan)
        stat = np.zeros((n, m))
        events: list[FaultEvent] = []
        # A sample breaks continuity when it does not follow its predecessor.
        prev = np.concatenate([[self._last_k if self._last_k is not None else -2], k[:-1]])
        breaks = k != prev + 1
        if self._last_k is None:
            breaks[0] = False
        i = 0
        while i < n:
            if self.mode == DIAGNOSE or breaks[i]:
                events += self.update(Sample(k=int(k[i]), timestamp_ns=int(t_ns[i]), u=U[i],
                                             z=Z[i], gap=int(gap[i])))
                if self.last_residuals is not None:
                    R[i], Rn[i] = self.last_residuals, self.last_normalized
                stat[i] = self.statistics
                i += 1
                continue
            later = np.flatnonzero(breaks[i + 1:])
            j = i + 1 + int(later[0]) if len(later) else n
            i = self._monitor_stretch(k, t_ns, U, Z, i, j, R, Rn, stat, events)
        return BlockResult(events=events, residuals=R, normalized=Rn, statistic=stat)

    def _monitor_stretch(self, k, t_ns, U, Z, i: int, j: int, R, Rn, stat, events) -> int:
        """Vectorised monitoring of the continuous samples i..j-1; returns where it stopped
        (after the sample that raised an alarm, which ``update`` handled)."""
        S = self.bank.S
        X = self._compensate_block(k[i:j], Z[i:j], U[i:j])
        E = np.vstack([self.bank.tail, X])
        res = self.bank.batch(E)  # row r: the residuals at X row r, as update would give them
        rn = res / self.bank.sigma
        have = ~np.isnan(rn).all(axis=1)  # rows where update returns residuals
        ph, done = self.detector.run(k[i:j], rn)
        if done > 0:
            stat[i: i + done] = np.maximum(ph.g_up[:done], ph.g_down[:done])
            R[i: i + done] = res[:done]
            Rn[i: i + done] = rn[:done]
            # Bring the streaming state up to date with rows i..i+done-1.
            self.bank.load(E[: S + done])
            for r in range(max(0, done - self._history.maxlen), done):
                self._history.append((int(k[i + r]), np.array(Z[i + r], dtype=float),
                                      np.array(U[i + r], dtype=float)))
            for r in np.flatnonzero(have[:done])[-self._recent.maxlen:].tolist():
                self._recent.append((int(k[i + r]), E[r: r + S + 1].copy(), rn[r]))
            self._last_k = int(k[i + done - 1])
            if have[done - 1]:
                self.last_residuals, self.last_normalized = res[done - 1], rn[done - 1]
            else:
                self.last_residuals = self.last_normalized = None
        if done == len(X):
            return j
        stop = i + done
        events += self.update(Sample(k=int(k[stop]), timestamp_ns=int(t_ns[stop]), u=U[stop],
                                     z=Z[stop], gap=0))
        if self.last_residuals is not None:
            R[stop], Rn[stop] = self.last_residuals, self.last_normalized
        stat[stop] = self.statistics
        return stop + 1

    # -- the state machine -----------------------------------------------------------------
    def update(self, sample: Sample) -> list[FaultEvent]:
        """Process one sample; returns the events it caused (usually none)."""
        k = sample.k
        if self._last_k is not None and k != self._last_k + 1:
            missing = k - self._last_k - 1
            if 0 < missing <= self.bank.S:
                self.bank.skip(missing)  # residuals whose windows miss them are missing
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
            return []
        rn = r / self.bank.sigma
        self.last_normalized = rn
        window = self.bank.window.copy()
        self._recent.append((k, window, rn))
        if self.mode == MONITOR:
            return self._monitor(k, sample.timestamp_ns, rn)
        return self._diagnose(k, sample.timestamp_ns, window, rn)

    def _monitor(self, k: int, t: int, rn: np.ndarray) -> list[FaultEvent]:
        alarm = self.detector.step(k, rn)
        if not alarm.any():
            return []
        alarming = np.flatnonzero(alarm)
        change_point = self.detector.change_point(alarm)
        s = self.settings
        onsets = onset_candidates(change_point, k, self._recent[0][0], s.onset_before,
                                  s.max_onsets)
        self._start_diagnosis(k, onsets)
        for kk, window, rnn in self._recent:
            if kk >= min(onsets):
                self._accumulate(kk, window, rnn)
        event = FaultEvent(kind="detected", sample=k, timestamp_ns=t, detected_sample=k,
                           onset_sample=change_point,
                           residuals=tuple(self.bank.names[i] for i in alarming))
        self.events.append(event)
        return [event]

    def _start_diagnosis(self, k: int, onsets: list[int]) -> None:
        H, K = len(self.hypotheses), len(onsets)
        self.mode = DIAGNOSE
        self._diag = {
            "k_d": k, "onsets": np.array(onsets), "n": 0,
            "A": np.tile(np.eye(self.d) * self.settings.prior_precision, (H, K, 1, 1)),
            "b": np.zeros((H, K, self.d)), "rr": 0.0, "n_res": 0,
            "u_abs": np.zeros(self.p), "n_u": np.zeros(self.p),
        }

    def _regressors(self, k: int, window: np.ndarray) -> np.ndarray:
        """(H, K, m, d) normalised regressors of every hypothesis and onset at sample k."""
        d = self._diag
        S = self.bank.S
        positions = k - S + np.arange(S + 1)
        mask = (positions[None, :] >= d["onsets"][:, None]).astype(float)  # (K, S+1)
        # Every sensor's and actuator's signature under every onset at once (einsum rather
        # than a Python loop over hypotheses: this runs for each sample of a diagnosis).
        zs = np.einsum("jms,ks->jkm", self.bank.Gz, mask)  # (q, K, m)
        # A lost command only enters residuals that are missing (and masked) anyway.
        u = np.nan_to_num(window[:, self.q :])  # (S+1, p)
        ua = np.einsum("jms,ks,sj->jkm", self.bank.Gu, mask, u)  # (p, K, m)
        ub = np.einsum("jms,ks->jkm", self.bank.Gu, mask)
        out = np.zeros((len(self.hypotheses), len(d["onsets"]), self.bank.m, self.d))
        for h_i, h in enumerate(self.hypotheses):
            if h.target == "sensor":
                out[h_i, :, :, 0] = zs[h.index]
            elif h.target == "sensors":
                for c, j in enumerate(h.members):
                    out[h_i, :, :, c] = zs[j]
            elif h.target == "actuator_bias":
                out[h_i, :, :, 0] = ub[h.index]
            else:
                out[h_i, :, :, 0] = ua[h.index]
                out[h_i, :, :, 1] = ub[h.index]
        return out / self.bank.sigma[None, None, :, None]

    def _accumulate(self, k: int, window: np.ndarray, rn: np.ndarray) -> None:
        d = self._diag
        valid = ~np.isnan(rn)
        phi = self._regressors(k, window) * valid[None, None, :, None]  # missing: no equation
        rv = np.where(valid, rn, 0.0)
        d["A"] += np.einsum("hkmi,hkmj->hkij", phi, phi)
        d["b"] += np.einsum("hkmi,m->hki", phi, rv)
        d["rr"] += float(rv @ rv)
        d["n"] += 1
        d["n_res"] += int(valid.sum())
        u_now = window[-1, self.q :]
        seen = ~np.isnan(u_now)
        d["u_abs"][seen] += np.abs(u_now[seen])
        d["n_u"] += seen

    def _diagnose(self, k: int, t: int, window: np.ndarray, rn: np.ndarray
                  ) -> list[FaultEvent]:
        self._accumulate(k, window, rn)
        d, s = self._diag, self.settings
        since = k - d["k_d"]
        if since < s.min_samples:
            return []
        theta = np.linalg.solve(d["A"], d["b"][..., None])[..., 0]  # (H, K, d)
        cost = d["rr"] - np.einsum("hki,hki->hk", theta, d["b"])
        best_onset = np.argmin(cost, axis=1)  # (H,)
        # Each parameter beyond the first must earn twice the isolation margin, so a richer
        # model never wins on the noise it fits (a likelihood-ratio test in effect).
        penalty = np.array([2.0 * s.isolation_margin * (h.n_params - 1) for h in self.hypotheses])
        cost_h = cost[np.arange(len(cost)), best_onset] + penalty
        order = np.argsort(cost_h, kind="stable")
        best = int(order[0])
        h_best = self.hypotheses[best]
        twins = self._twins[h_best]
        outside = [i for i in order[1:] if self.hypotheses[i] not in twins]
        margin_ok = all(cost_h[i] - cost_h[best] >= s.isolation_margin for i in outside)
        kb = int(best_onset[best])
        A = d["A"][best, kb]
        P = np.linalg.inv(A)
        dof = max(d["n_res"] - h_best.n_params, 1)
        scale = max(float(cost[best, kb]) / dof, 1e-300)
        var = np.diag(P) * scale
        th = theta[best, kb]
        if h_best.target == "actuator":
            # A pure scale fault has lambda = 0: judge lambda against a tenth of the offset the
            # scale puts on the mean command when that is larger than lambda itself.
            u_mean = d["u_abs"][h_best.index] / max(d["n_u"][h_best.index], 1.0)
            lam_scale = max(abs(th[1]), 0.1 * abs(th[0]) * u_mean)
            settled = (np.sqrt(var[0]) <= s.settle_rel_std * abs(1.0 + th[0])
                       and np.sqrt(var[1]) <= s.settle_rel_std * lam_scale)
        else:
            n_b = h_best.n_params
            settled = bool(np.all(np.sqrt(var[:n_b]) <= s.settle_rel_std * np.abs(th[:n_b])))
        fits = scale <= s.max_fit_variance
        if margin_ok and fits and (settled or since >= s.max_samples):
            return self._accept(k, t, best, kb, theta, var, best_onset, cost_h)
        if since >= s.max_samples:
            return self._unexplained(k, t, theta, best_onset, order)
        return []

    def _unexplained(self, k: int, t: int, theta: np.ndarray, best_onset: np.ndarray,
                     order: np.ndarray) -> list[FaultEvent]:
        event = FaultEvent(kind="unexplained", sample=k, timestamp_ns=t,
                           detected_sample=self._diag["k_d"],
                           candidates=tuple(self._describe(i, theta[i, best_onset[i]])
                                            for i in order[:3]))
        self.events.append(event)
        self.mode = MONITOR
        self._restart_detector(k)
        return [event]

    def _describe(self, h_i: int, th: np.ndarray, var: np.ndarray | None = None) -> dict:
        h = self.hypotheses[h_i]
        if h.target == "actuator":
            est = {"eta": float(1.0 + th[0]), "lambda": float(th[1])}
            variances = {"eta": float(var[0]), "lambda": float(var[1])} if var is not None else {}
        elif h.target == "actuator_bias":
            est = {"eta": 1.0, "lambda": float(th[0])}
            variances = {"eta": 0.0, "lambda": float(var[0])} if var is not None else {}
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
        h = next((g for g in self.hypotheses if g.target == "sensor" and g.index == j), None)
        if h is None or not self._twins[h]:
            return ()
        gj = self.bank.Gz[j].ravel()
        out = [{"target": "sensor", "index": j, "name": self.design.output_names[j],
                "estimates": {"bias": bias}}]
        # (An actuator's bias-only variant shares its signature: list the actuator once.)
        for g in sorted((g for g in self._twins[h] if g.target != "actuator_bias"),
                        key=lambda g: (g.target, g.index)):
            # An actuator twin's bias lambda enters through Gu as a sensor bias does through Gz.
            actuator = g.target == "actuator"
            gt = (self.bank.Gu if actuator else self.bank.Gz)[g.index].ravel()
            ratio = float(gt @ gj) / float(gt @ gt)
            out.append({"target": g.target, "index": g.index, "name": g.name,
                        "estimates": {"lambda" if actuator else "bias": bias * ratio}})
        return tuple(out)

    def _accept(self, k: int, t: int, best: int, kb: int, theta: np.ndarray, var: np.ndarray,
                best_onset: np.ndarray, cost_h: np.ndarray) -> list[FaultEvent]:
        d = self._diag
        h = self.hypotheses[best]
        onset = int(d["onsets"][kb])
        th = theta[best, kb]
        faults = []  # (target, index, estimates, variances, candidates)
        if h.target in ("actuator", "actuator_bias"):
            desc = self._describe(best, th, var)
            faults.append(("actuator", h.index, desc["estimates"], desc["variances"], ()))
        else:
            members = h.members if h.target == "sensors" else (h.index,)
            for c, j in enumerate(members):
                # In a joint fit a member with no significant bias is healthy.
                if h.target == "sensors" and abs(th[c]) <= 5.0 * np.sqrt(var[c]):
                    continue
                faults.append(("sensor", j, {"bias": float(th[c])}, {"bias": float(var[c])},
                               self._sensor_twins(j, float(th[c]))))
        if not faults:
            # The best fit is a joint sensor bias with no member significant: no persistent
            # fault explains the alarm (a transient, such as one corrupt sample).
            return self._unexplained(k, t, theta, best_onset, np.argsort(cost_h, kind="stable"))
        events = []
        for target, index, est, variances, candidates in faults:
            names = self.design.input_names if target == "actuator" else self.design.output_names
            event = FaultEvent(
                kind="accepted", sample=k, timestamp_ns=t, target=target, index=index,
                name=names[index], estimates=est, variances=variances, onset_sample=onset,
                detected_sample=d["k_d"], accepted_sample=k, candidates=candidates,
            )
            entry = {"target": target, "index": index, "onset": onset}
            entry.update(est)
            self.compensation.append(entry)
            events.append(event)
        # Seed 003 Section 3.3: rebuild the window from compensated samples and restart.
        tail = []
        for kk, z, u in self._history:
            if tail and kk != tail[-1][0] + 1:
                tail = []
            tail.append((kk, z, u))
        x = np.array([self._compensate(kk, z, u) for kk, z, u in tail])
        self.bank.restart()
        self.bank.load(x)
        self._recent.clear()
        self.mode = MONITOR
        self._restart_detector(k)
        self.events.extend(events)
        return events

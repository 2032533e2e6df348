"""The HTML fleet report of `canfdi fleet`: drives ranked by what needs attention, and each one's
history.

`write_fleet_report(faults, logs, out_dir)` takes the two tables `canfdi fleet` writes to
Parquet (column contract in `FAULT_COLUMNS`, `LOG_COLUMNS`) and writes:

``index.html``
    The fleet: totals (drives, logs, unreadable logs, drive-days, samples, accepted faults,
    alarms, lost data), a fault timeline across the fleet (onset against drive, one marker per
    fault), and the drives ranked by their attention score with the reason of each rank in
    words, each linked to its page.
``<drive>.html``
    One per drive (a file name safe for any drive name: `drive_file_names`): its fault
    timeline (onset against channel and kind, one marker per fault), its estimates over time
    per (kind, channel) with a least-squares trend line and the slope per day with its
    standard deviation ("bias on omega grows 0.012 /day ± 0.003"), its faults, its logs
    (samples, frames by status, lost data, alarms, faults, errors) and the residual variances
    of its logs over time.

The pages are self-contained (figures inlined as base64 PNG, the style sheet inlined, no
script): they can be mailed or archived one by one. Every string from the tables is escaped.
Drawing costs about 0.1 s per figure (three per drive with faults): `render_drive` is a pure
function of the `Fleet` and one drive, so a caller may render drives in parallel.

Ranking rule
------------
A drive's attention score is the sum of

* 1 per accepted fault per drive-day,
* 2 per significant trend (an estimate drifting over the faults of one (kind, channel):
  at least 3 faults and a slope Student's t test at 5 % calls non-zero: |slope| > t(0.975,
  N - 2) sigma of the slope, 12.7 sigma for 3 faults, 2.3 for 10),
* 2 per unreadable log per drive-day,
* 0.5 per log with lost data per drive-day,
* 0.5 per alarm without an accepted fault per drive-day;

drives are ranked by score (highest first, then by name); a score of 0 is a healthy drive.
A drive-day is a UTC calendar day one of the drive's logs covers (a log without a start time
counts as one day).

Why these weights: rates per drive-day make a drive logging for a year comparable with one
logging for a week. A drift is the early warning the fleet view is for (a bias creeping up over
weeks before it trips anything), so one outweighs a fault a day; an unreadable log is a day the
drive was not diagnosed at all, so it weighs like two faults; lost data and alarms nobody
explained weaken a diagnosis without refuting it.

Numbers (`fit_trend`, `drive_days`, `summarize_fleet`, `drive_file_names`) are pure functions
of plain rows (`table_rows`: timestamps as integer ns since the epoch, UTC); the trend is a
line fitted by the project's one least squares (canfdi.core.identify.least_squares: weighted by
1 / variance when every estimate has one, its covariance scaled by the scatter about the line,
which equals ``numpy.polyfit(t, y, 1, w=1/std, cov=True)``). The rendering draws with
matplotlib's object API (canfdi.tools.figures: Agg, no pyplot), as `canfdi report` does.
"""

from __future__ import annotations

import base64
import hashlib
import html
import io
import math
import re
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy.stats import t as student_t

from canfdi.bus.frames import STATUS_NAMES
from canfdi.core.identify import least_squares
from canfdi.tools.figures import CSS, LEGEND_OUTSIDE, new_figure

if TYPE_CHECKING:
    import pyarrow

__all__ = ["FAULT_COLUMNS", "LOG_COLUMNS", "MIN_TREND_POINTS", "RANKING_RULE", "DriveSummary",
           "Fleet", "FleetReportError", "Trend", "drive_days", "drive_file_names", "fit_trend",
           "render_drive", "render_index", "summarize_fleet", "table_rows",
           "write_fleet_report"]

FAULT_COLUMNS = ("drive", "log", "log_start", "onset", "onset_s", "k", "bus_drive", "kind",
                 "channel", "estimate", "variance", "candidates", "method")
"""The faults table's columns (an optional ``parameter`` column, e.g. "eta" / "lambda", splits
a (kind, channel) into one trend per parameter)."""
LOG_COLUMNS = ("drive", "log", "log_start", "log_end", "samples", "frames",
               *(f"frames_{s}" for s in STATUS_NAMES), "lost_bytes", "lost_messages",
               "lost_seconds", "residual_names", "residual_variances", "alarms", "faults",
               "error", "seconds")
"""The logs table's columns."""
_TIMESTAMPS = ("log_start", "log_end", "onset")

W_FAULT_RATE = 1.0
W_TREND = 2.0
W_UNREADABLE = 2.0
W_LOSS = 0.5
W_UNEXPLAINED = 0.5
MIN_TREND_POINTS = 3
"""Fewer faults of one (kind, channel) give no trend: a line through 2 points has no scatter to
judge its slope by."""
SIGNIFICANCE = 0.05
"""A trend is significant when a two-sided Student's t test of its slope at this level rejects
zero: |slope| > t(1 - SIGNIFICANCE / 2, N - 2) standard deviations of the slope. A fixed 2 sigma
called three unrelated faults a trend (the slope's sigma from one degree of freedom is itself
a guess), which the bench's generated fleet showed on two drives."""
MAX_TIMELINE_DRIVES = 40
"""The fleet timeline shows at most this many drives (the highest ranked with faults)."""

RANKING_RULE = (
    f"A drive's attention score is the sum of {W_FAULT_RATE:g} per accepted fault per "
    f"drive-day, {W_TREND:g} per significant trend (an estimate drifting over the faults of one "
    f"(kind, channel): at least {MIN_TREND_POINTS} faults and a slope Student's t test at "
    f"{SIGNIFICANCE:.0%} calls non-zero: |slope| > t(0.975, N - 2) sigma of the slope, 12.7 "
    f"sigma for 3 faults, 2.3 for 10), {W_UNREADABLE:g} per unreadable log per drive-day, "
    f"{W_LOSS:g} per log with lost data per drive-day, {W_UNEXPLAINED:g} per alarm without an "
    f"accepted fault per drive-day; drives are ranked by score (highest first, then by name); "
    f"a score of 0 is a healthy drive.")
"""The rule in words, as the page shows it (the module docstring says the same)."""

_DAY_NS = 86_400 * 10**9
_KIND_STYLE = {"sensor": ("o", "tab:blue"), "actuator": ("s", "tab:orange")}
_OTHER_STYLE = ("^", "tab:purple")
_DEFAULT_PARAMETER = {"sensor": "bias"}


class FleetReportError(ValueError):
    """The tables do not follow the column contract (the message names what is missing)."""


# ------------------------------------------------------------------------------------------
# the tables as rows
# ------------------------------------------------------------------------------------------


def table_rows(table: pyarrow.Table, required: tuple[str, ...], name: str) -> list[dict]:
    """The rows of ``table`` as dicts, timestamps as integer ns since the epoch (UTC) or None.

    Raises
    ------
    FleetReportError
        A column of ``required`` is missing.
    """
    import pyarrow as pa

    missing = [c for c in required if c not in table.column_names]
    if missing:
        raise FleetReportError(f"the {name} table lacks the columns {', '.join(missing)}")
    for column in _TIMESTAMPS:
        if column in table.column_names and not pa.types.is_integer(table.schema.field(
                column).type):
            # ns integers, not datetime objects: to_pylist would drop the nanoseconds.
            i = table.column_names.index(column)
            table = table.set_column(i, column, table.column(column).cast(pa.int64()))
    return table.to_pylist()


# ------------------------------------------------------------------------------------------
# numbers
# ------------------------------------------------------------------------------------------


def fit_trend(t_days: np.ndarray, y: np.ndarray, variance: np.ndarray | None = None
              ) -> tuple[float, float, float, bool] | None:
    """A least-squares line ``y = intercept + slope t``.

    Parameters
    ----------
    t_days : (N,) times in days; y : (N,) estimates; variance : (N,) their variances or None.
        Points with a non-finite t or y are left out.

    Returns
    -------
    (slope per day, its standard deviation, intercept at t = 0, weighted), or None with fewer
    than `MIN_TREND_POINTS` points or a single time. Weighted by 1 / variance when every kept
    point has a finite positive variance; the covariance is scaled by the residual variance
    about the line (cost / (N - 2)), so the slope's uncertainty reflects the scatter the data
    show, not only the variances the diagnoser claimed.
    """
    t = np.asarray(t_days, dtype=float)
    v = np.asarray(y, dtype=float)
    keep = np.isfinite(t) & np.isfinite(v)
    if keep.sum() < MIN_TREND_POINTS or np.ptp(t[keep]) == 0.0:
        return None
    weights = None
    if variance is not None:
        var = np.asarray(variance, dtype=float)[keep]
        if np.all(np.isfinite(var)) and np.all(var > 0.0):
            weights = 1.0 / var
    X = np.column_stack([np.ones(int(keep.sum())), t[keep]])
    fit = least_squares(X, v[keep], weights)
    cov = fit.covariance * (float(fit.cost) / fit.dof)
    return (float(fit.theta[1]), math.sqrt(max(float(cov[1, 1]), 0.0)), float(fit.theta[0]),
            weights is not None)


@dataclass(frozen=True)
class Trend:
    """The estimates of one drive's faults on one (kind, channel, parameter) over time.

    onset_ns : (N,) onsets (ns since the epoch); values, variances : (N,) (NaN: unknown).
    slope, slope_std : per day (NaN without a fit); intercept : at the first onset.
    """

    kind: str
    channel: str
    parameter: str
    onset_ns: np.ndarray
    values: np.ndarray
    variances: np.ndarray
    slope: float = math.nan
    slope_std: float = math.nan
    intercept: float = math.nan
    weighted: bool = False

    @property
    def fitted(self) -> bool:
        return math.isfinite(self.slope)

    @property
    def significant(self) -> bool:
        return self.fitted and abs(self.slope) > self.threshold * self.slope_std

    @property
    def threshold(self) -> float:
        """Student's t quantile the slope must exceed, in its standard deviations."""
        n = int(np.sum(np.isfinite(self.values) & np.isfinite(self.onset_ns.astype(float))))
        return float(student_t.ppf(1.0 - SIGNIFICANCE / 2.0, max(n - 2, 1)))

    @property
    def span_days(self) -> float:
        return float(np.ptp(self.onset_ns)) / _DAY_NS if len(self.onset_ns) else 0.0

    def label(self) -> str:
        return f"{self.parameter} on {self.channel} ({self.kind})"

    def sentence(self) -> str:
        """e.g. "bias on omega grows 0.012 /day ± 0.003"."""
        if not self.fitted:
            return (f"{self.parameter} on {self.channel}: {len(self.values)} fault(s), too few "
                    f"(or all at one time) for a trend")
        verb = "grows" if self.slope > 0 else "falls" if self.slope < 0 else "stays"
        return (f"{self.parameter} on {self.channel} {verb} {abs(self.slope):.3g} /day "
                f"± {self.slope_std:.2g}")


def _trends(faults: list[dict]) -> list[Trend]:
    """One Trend per (kind, channel, parameter) of one drive's faults, fitted when it can be."""
    groups: dict[tuple[str, str, str], list[tuple[int, float, float]]] = {}
    for f in faults:
        t = _onset_ns(f)
        if t is None:
            continue
        kind, channel = str(f.get("kind")), str(f.get("channel"))
        parameter = f.get("parameter") or _DEFAULT_PARAMETER.get(kind, f"{kind} estimate")
        value = f.get("estimate")
        var = f.get("variance")
        groups.setdefault((kind, channel, str(parameter)), []).append(
            (t, math.nan if value is None else float(value), math.nan if var is None
             else float(var)))
    out = []
    for (kind, channel, parameter), points in sorted(groups.items()):
        points.sort()
        t_ns = np.array([p[0] for p in points], dtype=np.int64)
        values = np.array([p[1] for p in points])
        variances = np.array([p[2] for p in points])
        fit = fit_trend((t_ns - t_ns[0]) / _DAY_NS, values, variances)
        trend = Trend(kind, channel, parameter, t_ns, values, variances)
        if fit is not None:
            slope, std, intercept, weighted = fit
            trend = Trend(kind, channel, parameter, t_ns, values, variances, slope, std,
                          intercept, weighted)
        out.append(trend)
    return out


def _onset_ns(fault: dict) -> int | None:
    """A fault's onset: its ``onset`` column, else log start + onset_s, else None."""
    if fault.get("onset") is not None:
        return int(fault["onset"])
    if fault.get("log_start") is not None and fault.get("onset_s") is not None:
        return int(fault["log_start"]) + round(float(fault["onset_s"]) * 1e9)
    return None


def drive_days(logs: list[dict], faults: list[dict] | None = None) -> int:
    """The drive-days of one drive: the UTC calendar days its logs cover (start to end), plus
    one per log without a start time; from its faults' log starts when it has no logs row.
    At least 1 when it has a log or a fault."""
    days: set[int] = set()
    undated = 0
    for log in logs:
        start = log.get("log_start")
        if start is None:
            undated += 1
            continue
        end = log.get("log_end")
        end = start if end is None else max(int(end), int(start))
        days.update(range(int(start) // _DAY_NS, end // _DAY_NS + 1))
    faults = faults or []
    if not logs:
        days.update(int(f["log_start"]) // _DAY_NS for f in faults
                    if f.get("log_start") is not None)
    total = len(days) + undated
    return max(total, 1) if (logs or faults) else 0


def _int(value: Any) -> int:
    return int(value) if value is not None else 0


def _float(value: Any) -> float:
    return float(value) if value is not None and math.isfinite(float(value)) else 0.0


def _lost(log: dict) -> bool:
    return (_int(log.get("lost_bytes")) > 0 or _int(log.get("lost_messages")) > 0
            or _float(log.get("lost_seconds")) > 0.0 or bool(log.get("damage")))


@dataclass
class DriveSummary:
    """One drive: its rows, what they add up to, its score and the reasons for it.

    terms : (score contribution, reason in words), largest first; score : their sum.
    """

    drive: str
    logs: list[dict]
    faults: list[dict]
    trends: list[Trend]
    drive_days: int
    n_faults: int
    samples: int
    frames: int
    unreadable: list[dict]
    lossy: list[dict]
    lost_bytes: int
    lost_messages: int
    lost_seconds: float
    alarms: int
    unexplained: int
    terms: list[tuple[float, str]] = field(default_factory=list)
    rank: int = 0
    file: str = ""

    @property
    def score(self) -> float:
        return float(sum(w for w, _ in self.terms))

    @property
    def reasons(self) -> list[str]:
        if not self.terms:
            return ["nothing needs attention: no fault, no significant trend, no lost data, "
                    "every log read"]
        return [reason for _, reason in self.terms]


def _fault_count(faults: list[dict]) -> int:
    """Distinct faults (rows that differ only in the estimated parameter are one fault)."""
    return len({(f.get("log"), f.get("onset"), f.get("k"), f.get("kind"), f.get("channel"))
                for f in faults})


def _summarize_drive(drive: str, logs: list[dict], faults: list[dict]) -> DriveSummary:
    logs = sorted(logs, key=lambda r: (r.get("log_start") is None, r.get("log_start") or 0,
                                       str(r.get("log"))))
    faults = sorted(faults, key=lambda r: (_onset_ns(r) or 0, str(r.get("channel"))))
    days = drive_days(logs, faults)
    unreadable = [r for r in logs if r.get("error")]
    lossy = [r for r in logs if _lost(r)]
    unexplained = sum(max(_int(r.get("alarms")) - _int(r.get("faults")), 0) for r in logs)
    s = DriveSummary(
        drive=drive, logs=logs, faults=faults, trends=_trends(faults), drive_days=days,
        n_faults=_fault_count(faults), samples=sum(_int(r.get("samples")) for r in logs),
        frames=sum(_int(r.get("frames")) for r in logs), unreadable=unreadable, lossy=lossy,
        lost_bytes=sum(_int(r.get("lost_bytes")) for r in logs),
        lost_messages=sum(_int(r.get("lost_messages")) for r in logs),
        lost_seconds=sum(_float(r.get("lost_seconds")) for r in logs),
        alarms=sum(_int(r.get("alarms")) for r in logs), unexplained=unexplained)
    per_day = 1.0 / max(days, 1)
    terms = []
    for t in s.trends:
        if t.significant:
            terms.append((W_TREND, f"{t.sentence()} over {len(t.values)} faults in "
                                   f"{t.span_days:.3g} days: a significant trend "
                                   f"(|slope| > {t.threshold:.3g}σ)"))
    if s.n_faults:
        rate = s.n_faults * per_day
        terms.append((W_FAULT_RATE * rate, f"{s.n_faults} accepted fault(s) in {days} "
                                           f"drive-day(s): {rate:.3g} per drive-day"))
    if unreadable:
        first = unreadable[0]
        more = f" and {len(unreadable) - 1} more" if len(unreadable) > 1 else ""
        terms.append((W_UNREADABLE * len(unreadable) * per_day,
                      f"{len(unreadable)} of {len(logs)} log(s) unreadable ({first.get('log')}: "
                      f"{first.get('error')}{more})"))
    if lossy:
        terms.append((W_LOSS * len(lossy) * per_day,
                      f"{len(lossy)} log(s) lost data: {s.lost_messages:,} message(s), "
                      f"{s.lost_bytes:,} byte(s), {s.lost_seconds:.3g} s"))
    if unexplained:
        terms.append((W_UNEXPLAINED * unexplained * per_day,
                      f"{unexplained} alarm(s) without an accepted fault"))
    s.terms = sorted(terms, key=lambda wt: -wt[0])
    return s


@dataclass
class Fleet:
    """Every drive, ranked (rank 1 needs attention most), and the fleet's totals."""

    drives: list[DriveSummary]
    n_logs: int
    n_fault_rows: int

    def total(self, name: str) -> float:
        return sum(getattr(d, name) for d in self.drives)


def drive_file_names(drives: list[str]) -> dict[str, str]:
    """A file name ``<name>.html`` per drive, safe whatever the drive is called.

    Characters other than letters, digits, ``_ . -`` become ``_``, leading dots go (no
    ``..``, no hidden file), at most 80 characters. When that changed the name, or the name is
    ``index`` (the fleet page), or two drives differ only in case (case-insensitive file
    systems), a hash of the drive name is appended, so different drives never share a file
    (``a/b`` gets ``a_b-<hash>.html``, a drive ``a_b`` keeps ``a_b.html``).
    """
    base = {d: (re.sub(r"[^A-Za-z0-9_.-]+", "_", d).lstrip(".").strip("_")[:80] or "drive")
            for d in drives}
    folded: dict[str, int] = {}
    for d, b in base.items():
        if b == d:  # a changed name gets a hash anyway: it cannot take an unchanged one's
            folded[b.casefold()] = folded.get(b.casefold(), 0) + 1
    out = {}
    for d, b in base.items():
        if b != d or b.casefold() == "index" or folded[b.casefold()] > 1:
            b = f"{b}-{hashlib.sha1(d.encode('utf-8')).hexdigest()[:10]}"
        out[d] = f"{b}.html"
    return out


def summarize_fleet(faults: list[dict], logs: list[dict]) -> Fleet:
    """Every drive of either table summarized, scored and ranked (`RANKING_RULE`).

    faults, logs : rows as `table_rows` gives them.
    """
    by_drive: dict[str, tuple[list[dict], list[dict]]] = {}
    for r in logs:
        by_drive.setdefault(str(r.get("drive")), ([], []))[0].append(r)
    for r in faults:
        by_drive.setdefault(str(r.get("drive")), ([], []))[1].append(r)
    drives = [_summarize_drive(d, lg, fl) for d, (lg, fl) in by_drive.items()]
    drives.sort(key=lambda s: (-s.score, s.drive))
    files = drive_file_names([s.drive for s in drives])
    for rank, s in enumerate(drives, 1):
        s.rank, s.file = rank, files[s.drive]
    return Fleet(drives=drives, n_logs=len(logs), n_fault_rows=len(faults))


# ------------------------------------------------------------------------------------------
# figures (inlined PNG)
# ------------------------------------------------------------------------------------------


def _png(fig) -> str:
    """The figure as a data: URI (the page needs no other file)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def _dates(ns: np.ndarray | list[int]) -> np.ndarray:
    return np.asarray(ns, dtype=np.int64).astype("datetime64[ns]")


def _date_axis(ax) -> None:
    from matplotlib.dates import AutoDateLocator, ConciseDateFormatter

    locator = AutoDateLocator()
    ax.xaxis.set_major_locator(locator)
    ax.xaxis.set_major_formatter(ConciseDateFormatter(locator))


def _plain(text: str, legend: bool = False) -> str:
    """``text`` as matplotlib shows it literally: a ``$`` would start mathtext (and a name
    like ``a$^{$b`` fail to draw); a legend hides labels that start with ``_``."""
    text = text.replace("$", r"\$")
    return "\u200b" + text if legend and text.startswith("_") else text


def _style(kind: str) -> tuple[str, str]:
    return _KIND_STYLE.get(kind, _OTHER_STYLE)


def _timeline(rows: list[tuple[str, int, str]], title: str) -> str:
    """Onset (x) against a category (y), one marker per fault, marker and colour by kind.

    rows : (category, onset ns, kind); categories keep their first-seen order, top down.
    """
    from matplotlib.lines import Line2D

    cats = list(dict.fromkeys(c for c, _, _ in rows))
    fig, axes = new_figure(1, height=max(0.32 * len(cats), 1.6), width=11.0)
    ax = axes[0, 0]
    y_of = {c: len(cats) - 1 - i for i, c in enumerate(cats)}
    kinds = sorted({k for _, _, k in rows})
    for kind in kinds:
        marker, colour = _style(kind)
        sel = [(t, y_of[c]) for c, t, k in rows if k == kind]
        ax.plot(_dates([t for t, _ in sel]), [y for _, y in sel], linestyle="none",
                marker=marker, color=colour, ms=6, alpha=0.8)
    ax.set_yticks(range(len(cats)), [_plain(c) for c in reversed(cats)], fontsize=8)
    ax.set_ylim(-0.7, len(cats) - 0.3)
    _date_axis(ax)
    ax.set_xlabel("fault onset (UTC)")
    handles = [Line2D([], [], linestyle="none", marker=_style(k)[0], color=_style(k)[1],
                      label=_plain(k, legend=True)) for k in kinds]
    ax.legend(handles=handles, **LEGEND_OUTSIDE)
    ax.set_title(_plain(title), fontsize=10)
    return _png(fig)


def _estimates_figure(drive: DriveSummary) -> str:
    """Per (kind, channel, parameter): the estimates over time with ±2σ bars and the trend."""
    trends = drive.trends
    fig, axes = new_figure(len(trends), height=2.2, width=11.0, sharex=True)
    for ax, t in zip(axes[:, 0], trends, strict=True):
        marker, colour = _style(t.kind)
        std = np.sqrt(np.where(np.isfinite(t.variances), np.maximum(t.variances, 0.0), 0.0))
        ax.errorbar(_dates(t.onset_ns), t.values, yerr=2.0 * std, fmt=marker, color=colour,
                    ms=5, capsize=3, label="estimate ± 2σ")
        if t.fitted:
            ends = np.array([t.onset_ns[0], t.onset_ns[-1]])
            line = t.intercept + t.slope * (ends - t.onset_ns[0]) / _DAY_NS
            state = "significant" if t.significant else "not significant"
            ax.plot(_dates(ends), line, color="k", lw=1.4,
                    label=f"trend {t.slope:+.3g} /day ± {t.slope_std:.2g} ({state})")
        ax.set_ylabel(_plain(t.parameter))
        ax.set_title(_plain(f"{t.kind}: {t.sentence()}"), fontsize=9)
        ax.legend(**LEGEND_OUTSIDE)
        _date_axis(ax)
    axes[-1, 0].set_xlabel("fault onset (UTC)")
    return _png(fig)


def _variances_figure(drive: DriveSummary) -> str | None:
    """Each residual's variance per log against the log's start (None: fewer than 2 dated logs
    with variances, nothing over time to draw; the logs table lists them)."""
    series: dict[str, list[tuple[int, float]]] = {}
    for log in drive.logs:
        names, values = log.get("residual_names") or [], log.get("residual_variances") or []
        if log.get("log_start") is None:
            continue
        for name, value in zip(names, values, strict=False):
            if value is not None and math.isfinite(value):
                series.setdefault(str(name), []).append((int(log["log_start"]), float(value)))
    if len({t for pts in series.values() for t, _ in pts}) < 2:
        return None
    fig, axes = new_figure(1, height=2.6, width=11.0)
    ax = axes[0, 0]
    values = [v for pts in series.values() for _, v in pts]
    # log scale only where it helps: residuals of different sizes, or one that grew 10-fold
    spread = min(values) > 0 and max(values) > 10 * min(values)
    for i, (name, pts) in enumerate(sorted(series.items())):
        ax.plot(_dates([t for t, _ in pts]), [v for _, v in pts], marker="o", ms=4, lw=1.0,
                color=f"C{i % 10}", label=_plain(name, legend=True))
    if spread:
        ax.set_yscale("log")
    _date_axis(ax)
    ax.set_xlabel("log start (UTC)")
    ax.set_ylabel("residual variance")
    ax.legend(**LEGEND_OUTSIDE)
    ax.set_title("Residual variances per log (a residual whose noise grows: a sensor or the "
                 "model ageing)", fontsize=10)
    return _png(fig)


# ------------------------------------------------------------------------------------------
# pages
# ------------------------------------------------------------------------------------------

_e = html.escape


def _when(ns: int | None) -> str:
    if ns is None:
        return "–"
    t = datetime(1970, 1, 1, tzinfo=UTC) + timedelta(microseconds=int(ns) // 1000)
    return t.strftime("%Y-%m-%d %H:%M:%S")


def _figure_html(uri: str, caption: str) -> str:
    return (f'<figure><img src="{uri}" alt="{_e(caption)}"><figcaption>{_e(caption)}'
            f"</figcaption></figure>")


def _page(title: str, body: list[str]) -> str:
    # The empty icon: a page that stands alone asks its server for no /favicon.ico.
    return "\n".join(["<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
                      '<link rel="icon" href="data:,">',
                      f"<title>{_e(title)}</title>", f"<style>{CSS}</style></head><body>",
                      *body, "</body></html>"]) + "\n"


def _table(head: list[str], rows: list[list[tuple[str, bool]]]) -> str:
    """An HTML table; cells are (already escaped HTML, numeric?)."""
    out = ["<table><thead><tr>", *(f"<th>{_e(h)}</th>" for h in head), "</tr></thead><tbody>"]
    for row in rows:
        out.append("<tr>" + "".join(f"<td class='num'>{c}</td>" if num else f"<td>{c}</td>"
                                    for c, num in row) + "</tr>")
    out.append("</tbody></table>")
    return "".join(out)


def _num(value: float | int, fmt: str = ",") -> tuple[str, bool]:
    return _e(format(value, fmt)), True


def _lost_text(messages: int, nbytes: int, seconds: float) -> str:
    if not (messages or nbytes or seconds):
        return "–"
    return f"{messages:,} msg, {nbytes:,} B, {seconds:.3g} s"


def _variances_text(log: dict) -> str:
    names, values = log.get("residual_names") or [], log.get("residual_variances") or []
    return ", ".join(f"{n} {v:.3g}" for n, v in zip(names, values, strict=False)
                     if v is not None) or "–"


def render_index(fleet: Fleet) -> str:
    """index.html of the fleet."""
    body = ["<h1>canfdi fleet report</h1>"]
    drives = fleet.drives
    if not drives:
        body.append("<p class='note'>The fleet is empty: the tables hold no log and no fault. "
                    "Nothing was diagnosed.</p>")
    n_unreadable = sum(len(d.unreadable) for d in drives)
    totals = [("drives", f"{len(drives):,}"), ("logs", f"{fleet.n_logs:,}"),
              ("unreadable logs", f"{n_unreadable:,}"),
              ("drive-days", f"{int(fleet.total('drive_days')):,}"),
              ("samples", f"{int(fleet.total('samples')):,}"),
              ("frames", f"{int(fleet.total('frames')):,}"),
              ("accepted faults", f"{int(fleet.total('n_faults')):,}"),
              ("alarms", f"{int(fleet.total('alarms')):,}"),
              ("alarms without an accepted fault", f"{int(fleet.total('unexplained')):,}"),
              ("lost data", _lost_text(int(fleet.total("lost_messages")),
                                       int(fleet.total("lost_bytes")),
                                       float(fleet.total("lost_seconds"))))]
    body.append("<h2>Totals</h2>")
    body.append(_table(["", "fleet"], [[(_e(k), False), (_e(v), True)] for k, v in totals]))
    if drives and fleet.n_logs == 0:
        body.append("<p class='note'>The logs table is empty: samples, frames, lost data and "
                    "drive-days come from the faults table only.</p>")
    body.append("<h2>Fault timeline</h2>")
    with_faults = [d for d in drives if d.faults]
    if with_faults:
        shown = with_faults[:MAX_TIMELINE_DRIVES]
        rows = [(d.drive, t, str(f.get("kind"))) for d in shown for f in d.faults
                if (t := _onset_ns(f)) is not None]
        more = (f" (the {len(shown)} highest ranked of {len(with_faults)} drives with faults)"
                if len(with_faults) > len(shown) else "")
        caption = f"Every accepted fault's onset by drive, ranked top down{more}."
        body.append(_figure_html(_timeline(rows, "Faults across the fleet"), caption))
    else:
        body.append("<p>No fault was accepted in any log of the fleet.</p>")
    body.append("<h2>Drives by what needs attention</h2>")
    body.append(f"<p>{_e(RANKING_RULE)} A drive-day is a UTC calendar day one of the drive's "
                f"logs covers.</p>")
    if drives:
        rows_html = []
        for d in drives:
            reasons = "<ul>" + "".join(
                f"<li>{_e(r)} <small>(+{w:.3g})</small></li>" for w, r in d.terms) + "</ul>"
            if not d.terms:
                reasons = _e(d.reasons[0])
            rows_html.append([
                _num(d.rank), (f'<a href="{_e(d.file)}">{_e(d.drive)}</a>', False),
                _num(d.score, ".3g"), (reasons, False), _num(len(d.logs)),
                _num(d.drive_days), _num(d.n_faults), _num(len(d.unreadable)),
                (_e(_lost_text(d.lost_messages, d.lost_bytes, d.lost_seconds)), True)])
        body.append(_table(["rank", "drive", "score", "why", "logs", "drive-days", "faults",
                            "unreadable logs", "lost data"], rows_html))
    return _page("canfdi fleet report", body)


def render_drive(fleet: Fleet, d: DriveSummary) -> str:
    """<drive>.html: one drive's history."""
    body = ['<p><a href="index.html">← fleet</a></p>',
            f"<h1>Drive <code>{_e(d.drive)}</code></h1>",
            f"<p>Rank {d.rank} of {len(fleet.drives)}, attention score {d.score:.3g} "
            f"(the rule is on the <a href=\"index.html\">fleet page</a>):</p><ul>"]
    body += [f"<li>{_e(r)}</li>" for r in d.reasons]
    body.append("</ul>")
    body.append(f"<p>{len(d.logs):,} log(s), {d.drive_days:,} drive-day(s), {d.samples:,} "
                f"samples, {d.n_faults:,} accepted fault(s), {d.alarms:,} alarm(s), lost data: "
                f"{_e(_lost_text(d.lost_messages, d.lost_bytes, d.lost_seconds))}.</p>")
    body.append("<h2>Faults</h2>")
    if d.faults:
        rows = [(f"{f.get('channel')} ({f.get('kind')})", t, str(f.get("kind")))
                for f in d.faults if (t := _onset_ns(f)) is not None]
        if rows:
            body.append(_figure_html(_timeline(rows, f"Faults of {d.drive}"),
                                     "Fault timeline: each accepted fault's onset by channel "
                                     "and kind."))
        body.append(_figure_html(_estimates_figure(d),
                                 "Estimates over time per (kind, channel) with ±2σ bars and "
                                 "the least-squares trend line."))
        trend_rows = [[(_e(t.label()), False), _num(len(t.values)),
                       (_e(f"{t.slope:+.4g} ± {t.slope_std:.2g}") if t.fitted else "–", True),
                       (_e("yes" if t.significant else "no" if t.fitted else
                           f"fewer than {MIN_TREND_POINTS} faults"), False),
                       (_e(t.sentence()), False)] for t in d.trends]
        body.append(_table(["estimate", "faults", "slope per day ± σ", "significant",
                            "in words"], trend_rows))
        fault_rows = []
        for f in d.faults:
            var = f.get("variance")
            std = f" ± {math.sqrt(var):.2g}" if var is not None and var >= 0 else ""
            est = f.get("estimate")
            fault_rows.append([
                (_e(_when(_onset_ns(f))), False), (_e(str(f.get("log"))), False),
                (_e(f"{f.get('onset_s'):.3f}" if f.get("onset_s") is not None else "–"), True),
                (_e(str(f.get("k"))), True), (_e(str(f.get("kind"))), False),
                (_e(str(f.get("channel"))), False),
                (_e(f"{est:.5g}{std}" if est is not None else "–"), True),
                (_e(", ".join(map(str, f.get("candidates") or [])) or "–"), False),
                (_e(str(f.get("method"))), False),
                (_e(str(f.get("bus_drive")) if f.get("bus_drive") is not None else "–"),
                 False)])
        body.append(_table(["onset (UTC)", "log", "onset [s]", "k", "kind", "channel",
                            "estimate ± σ", "candidates", "method", "bus drive"], fault_rows))
    else:
        body.append("<p>No fault was accepted in this drive's logs.</p>")
    body.append("<h2>Logs</h2>")
    if d.logs:
        statuses = [s for s in STATUS_NAMES if any(_int(r.get(f"frames_{s}")) for r in d.logs)]
        rows = []
        for r in d.logs:
            rows.append([(_e(str(r.get("log"))), False), (_e(_when(r.get("log_start"))), False),
                         (_e(_when(r.get("log_end"))), False), _num(_int(r.get("samples"))),
                         _num(_int(r.get("frames"))),
                         *(_num(_int(r.get(f"frames_{s}"))) for s in statuses),
                         (_e(_lost_text(_int(r.get("lost_messages")),
                                        _int(r.get("lost_bytes")),
                                        _float(r.get("lost_seconds")))), True),
                         (_e(_variances_text(r)), False),
                         _num(_int(r.get("alarms"))), _num(_int(r.get("faults"))),
                         (f"<span class='note'>{_e(str(r['error']))}</span>"
                          if r.get("error") else "–", False)])
        body.append(_table(["log", "start (UTC)", "end (UTC)", "samples", "frames",
                            *(f"frames {s}" for s in statuses), "lost data",
                            "residual variances", "alarms", "faults", "error"], rows))
        uri = _variances_figure(d)
        if uri is not None:
            body.append(_figure_html(uri, "Residual variances of each log over time."))
    else:
        body.append("<p class='note'>The logs table has no row for this drive.</p>")
    return _page(f"canfdi fleet report: {d.drive}", body)


def write_fleet_report(faults: pyarrow.Table, logs: pyarrow.Table, out_dir: Path
                       ) -> list[Path]:
    """Write index.html and one <drive>.html per drive into ``out_dir`` (created).

    Returns
    -------
    The paths written, index.html first.

    Raises
    ------
    FleetReportError
        A table lacks a column of the contract (`FAULT_COLUMNS`, `LOG_COLUMNS`).
    OSError
        ``out_dir`` cannot be created or written.
    """
    fleet = summarize_fleet(table_rows(faults, FAULT_COLUMNS, "faults"),
                            table_rows(logs, LOG_COLUMNS, "logs"))
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    index = out / "index.html"
    index.write_text(render_index(fleet), encoding="utf-8")
    written = [index]
    for d in fleet.drives:
        path = out / d.file
        path.write_text(render_drive(fleet, d), encoding="utf-8")
        written.append(path)
    return written

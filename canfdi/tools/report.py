"""Figures and an HTML page from a canfdi MCAP log (`canfdi report`): Chan et al. 2006 Figs. 1-6.

`make_report(log, out_dir)` reads a log written by ``canfdi run`` / ``demo`` (its samples,
residuals, events and metadata: config, residual names and thresholds, the injected faults of a
demo) and writes into ``out_dir``:

``overview.png``
    The whole run: inputs u, outputs z (one panel per unit), the normalised residuals r/sigma
    (symlog scale) and every Page-Hinkley statistic divided by its threshold (alarm at 1), with
    the injected onsets, detections, acceptances and unexplained changes marked.
``residuals.png``
    Chan et al. 2006 Figs. 1-2: per residual, r/sigma with the +/-3 sigma noise band, and the
    Page-Hinkley statistic against its threshold h (the thresholds apply to the statistic, not
    to r/sigma), detections marked.
``fault_<n>_<target>_<name>.png``
    Chan et al. 2006 Figs. 4-6, one per accepted fault: the residuals and statistics zoomed around
    it,
    and each estimated parameter's trajectory from the onset to the acceptance with a +/-2
    sigma band, the accepted value, and the truth as a horizontal line when the log holds it.
``index.html``
    Every figure (referenced relatively) and the diagnosis table: fault, target, onset,
    detected, accepted, estimates +/- std, truth, error.

Estimate trajectories. A log holds the accepted estimate of each fault only (``/canfdi/events``;
the monitor writes nothing on ``/canfdi/estimates``). The log's method recomputes the trajectory
from the log itself when it can (canfdi.methods: ``estimate_history``; the parity method refits
the accepted hypothesis at the accepted onset over the logged residuals with its own regressors
and the one least squares, canfdi.methods.parity.history). Its last value is the accepted
estimate (checked: `Trajectory.mismatch`). Nothing is re-diagnosed, so this is fast for any log
length. Methods without a history (output_error, uio), or logs without residuals or config, get
the accepted estimates as points.

A damaged log is read around its damage (canfdi.io.scan skips the chunks that fail their CRC);
what it lost is in `LogContents.damage` (a canfdi.io.damage `Damage`), `Report.damage` and
the page.

Large logs are decimated for plotting (min and max per bucket, at most `MAX_POINTS` points per
line), so spikes stay visible. matplotlib is imported here only (Agg, no display, no pyplot
global state), never on the monitor's path. Nothing here prints: progress goes to an optional
callback.
"""

from __future__ import annotations

import html
import json
import math
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from canfdi.core.records import FaultEvent
from canfdi.tools.figures import CSS as _CSS
from canfdi.tools.figures import LEGEND_OUTSIDE as _OUTSIDE
from canfdi.tools.figures import new_figure as _figure

__all__ = ["MAX_POINTS", "LogContents", "NothingToReport", "Report", "ReportError", "Trajectory",
           "decimate", "diagnosis_rows", "estimate_trajectory", "make_report",
           "read_log_contents"]

MAX_POINTS = 5000
"""At most this many points per plotted line (min/max decimation beyond)."""

_PARAMS = ("eta", "lambda", "bias", "rate", "scale", "value", "std")
_LABEL = {"eta": "η", "lambda": "λ", "bias": "bias"}
Progress = Callable[[str], None]


class ReportError(ValueError):
    """Bad input: no such log, not an MCAP file, a config that cannot be read."""


class NothingToReport(ReportError):
    """The log holds no sample, residual or event (its message says so, with what damage
    lost): no figure is drawn, nothing is written."""


# ------------------------------------------------------------------------------------------
# reading the log
# ------------------------------------------------------------------------------------------


@dataclass
class LogContents:
    """What a log holds, as arrays; None or empty where the log lacks it (see ``notes``).

    samples : canfdi.io.reader.SampleArrays or None; residuals : ResidualArrays or None.
    thresholds : (m,) Page-Hinkley thresholds in residuals.names order, or None.
    events : every FaultEvent of ``/canfdi/events`` in order.
    truth : the injected faults (demo logs) or None.
    notes : what is missing, one sentence each.
    units : signal name -> unit (from the config's DBC, when it can be loaded).
    damage : canfdi.io.damage.Damage, what a damaged log lost (false when nothing).
    """

    path: Path
    metadata: dict[str, str]
    config: Any  # canfdi.config.MonitorConfig or None
    dt: float
    samples: Any
    residuals: Any
    thresholds: np.ndarray | None
    events: list[FaultEvent]
    truth: list[dict] | None
    notes: list[str] = field(default_factory=list)
    units: dict[str, str] = field(default_factory=dict)
    damage: Any = None

    @property
    def accepted(self) -> list[FaultEvent]:
        return [e for e in self.events if e.kind == "accepted"]


def _check_mcap(path: Path) -> dict[str, str]:
    """The metadata of a log canfdi report can read (canfdi.io.formats: one that holds a run's
    records, a canfdi MCAP); ReportError saying why for any other file."""
    from canfdi.io.formats import LogFormatError, LogReadError, format_of

    if not path.exists():
        raise ReportError(f"no such log: {path}")
    if path.is_dir():
        raise ReportError(f"{path} is a directory, not a log")
    try:
        fmt = format_of(path)
    except LogFormatError as exc:
        raise ReportError(str(exc)) from None
    if not fmt.records:
        raise ReportError(f"{path} is a {fmt.suffix} log of raw frames: canfdi report reads the "
                          f"MCAP logs of canfdi run and demo (canfdi replay diagnoses it)")
    try:
        return fmt.metadata(path)
    except OSError as exc:
        raise ReportError(f"cannot read {path}: {exc.strerror or exc}") from None
    except LogReadError as exc:
        raise ReportError(f"{exc} (canfdi report reads the MCAP logs of canfdi run and "
                          f"demo)") from None


def _event(message: dict) -> FaultEvent:
    fields = FaultEvent.__dataclass_fields__
    kw = {k: v for k, v in message.items() if k in fields}
    kw["candidates"] = tuple(kw.get("candidates") or ())
    kw["residuals"] = tuple(kw.get("residuals") or ())
    kw["undecided"] = tuple(kw.get("undecided") or ())
    kw["estimates"] = dict(kw.get("estimates") or {})
    kw["variances"] = dict(kw.get("variances") or {})
    return FaultEvent(**kw)


def _config(metadata: dict[str, str], config_path: Path | None, notes: list[str]):
    """The monitor config: the given file, else the one embedded in the log, else None."""
    from canfdi.config import ConfigError, load_config, parse_config

    if config_path is not None:
        try:
            return load_config(config_path)
        except ConfigError as exc:
            raise ReportError(f"config error: {exc}") from None
    text = metadata.get("config_yaml", "")
    if not text:
        notes.append("the log embeds no config (give one with --config): no estimate "
                     "trajectories, no units")
        return None
    import yaml

    try:
        return parse_config(yaml.safe_load(text))
    except (ConfigError, yaml.YAMLError) as exc:
        notes.append(f"the log's embedded config cannot be read ({exc}): no estimate "
                     f"trajectories")
        return None


def _units(config) -> dict[str, str]:
    """Signal units from the config's DBC (best effort: {} when it cannot be loaded)."""
    if config is None or config.bus.dbc is None:
        return {}
    try:
        from canfdi import dbc as dbc_files

        value = config.bus.dbc
        if Path(value).name == value and value.removesuffix(".dbc") in dbc_files.available():
            db = dbc_files.load(value)
        else:
            import cantools

            where = Path(value).expanduser()
            if not where.is_absolute() and config.path is not None:
                where = Path(config.path).parent / where
            db = cantools.database.load_file(where, database_format="dbc", strict=False)
    except Exception:  # units are a nicety: a missing DBC only loses them
        return {}
    return {s.name: s.unit for m in db.messages for s in m.signals if s.unit}


def read_log_contents(path: str | Path, config_path: Path | None = None,
                      progress: Progress | None = None) -> LogContents:
    """Everything `make_report` plots, read from one log (all its rotated segments).

    Raises
    ------
    ReportError
        No such file, not an MCAP file, an unreadable --config, or a log the readers reject.
    """
    from canfdi.io.damage import Damage
    from canfdi.io.reader import read_log, read_residuals, read_samples
    from canfdi.io.schemas import TOPIC_EVENTS
    from canfdi.io.segments import log_segments

    say = progress or (lambda _msg: None)
    path = Path(path)
    metadata = _check_mcap(path)
    notes: list[str] = []
    damage = Damage()
    try:
        if not metadata:
            notes.append("the log has no canfdi metadata (config, thresholds, truth)")
        config = _config(metadata, config_path, notes)
        say("reading samples")
        samples = read_samples(path, damage=damage)
        say(f"{len(samples.k):,} samples; reading residuals")
        residuals = read_residuals(path, damage=damage)
        say(f"{len(residuals.k):,} residual rows; reading events")
        events = [_event(msg) for segment in log_segments(path)
                  for _, _, msg in read_log(segment, [TOPIC_EVENTS], damage)]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        if isinstance(exc, ReportError):
            raise
        raise ReportError(f"cannot read {path}: {exc}") from None
    if len(samples.k) == 0:
        notes.append("the log holds no decoded samples (/canfdi/samples): no u, z plots")
        samples = None
    if len(residuals.k) == 0:
        notes.append("the log holds no residuals (/canfdi/residuals; a capture log, or "
                     "recorded without residuals): no residual figures, no estimate "
                     "trajectories (`canfdi replay LOG -o diagnosed.mcap` writes them; then "
                     "report diagnosed.mcap)")
        residuals = None
    if not any(e.kind == "accepted" for e in events):
        notes.append("the log holds no accepted fault: no fault figures")
    thresholds = None
    if residuals is not None:
        try:
            names = json.loads(metadata.get("residuals_json", "null"))
            values = json.loads(metadata.get("thresholds_json", "null"))
            by_name = dict(zip(names, values, strict=True))
            thresholds = np.array([by_name[n] for n in residuals.names], dtype=float)
        except (TypeError, ValueError, KeyError):
            notes.append("the log's metadata has no thresholds for its residuals: the "
                         "Page-Hinkley statistics are plotted without them")
    truth = None
    if "truth_json" in metadata:
        try:
            truth = json.loads(metadata["truth_json"])
        except ValueError:
            notes.append("the log's truth_json is not JSON: no truth lines")
    dt = float(config.model.dt) if config is not None and config.model.dt else 0.0
    if not dt and samples is not None and len(samples.k) > 1:
        dk = np.diff(samples.k)
        ok = dk > 0
        if ok.any():
            dt = float(np.median(np.diff(samples.t_ns)[ok] / dk[ok]) / 1e9)
    return LogContents(path=path, metadata=metadata, config=config, dt=dt or 1.0,
                       samples=samples, residuals=residuals, thresholds=thresholds,
                       events=events, truth=truth, notes=notes, units=_units(config),
                       damage=damage)


# ------------------------------------------------------------------------------------------
# the diagnosis table and the truth
# ------------------------------------------------------------------------------------------


def _match_truth(fault: dict, truth: list[dict] | None, used: set[int]
                 ) -> tuple[dict | None, dict | None]:
    """(truth entry, the estimates to compare with it) for a diagnosed fault: the injected
    fault on the same channel (or on one of its indistinguishable candidates) whose onset is
    nearest, each truth entry used once."""
    if not truth:
        return None, None
    options = [(fault["kind"], fault["index"], fault["estimate"])]
    options += [(c.get("target"), c.get("index"), c.get("estimates", {}))
                for c in fault.get("candidates", [])]
    for target, index, estimates in options:
        found = [(abs((t.get("onset_sample") or 0) - (fault["onset_sample"] or 0)), i)
                 for i, t in enumerate(truth)
                 if i not in used and t.get("target") == target and t.get("index") == index]
        if found:
            i = min(found)[1]
            used.add(i)
            return truth[i], estimates
    return None, None


def diagnosis_rows(contents: LogContents) -> list[dict]:
    """The diagnosis table: `canfdi.monitor.summary_json`'s faults plus ``std`` (square roots
    of the variances), ``truth`` ({param: value} of the matched injected fault, or None),
    ``truth_name`` and ``error`` (estimate - truth per parameter, from the candidate the
    truth is on)."""
    from canfdi.monitor import summary_json

    stats = {"frames_received": 0, "frames_valid": 0, "frames_invalid": 0,
             "invalid_by_reason": {}, "samples_complete": 0, "samples_broken": 0,
             "samples_missing": 0}
    faults = summary_json(contents.events, stats, contents.dt, contents.truth, 0)["faults"]
    used: set[int] = set()
    rows = []
    for f in faults:
        row = dict(f)
        row["std"] = {k: math.sqrt(max(v, 0.0)) for k, v in f["variance"].items()
                      if v is not None and math.isfinite(v)}
        t, est = _match_truth(f, contents.truth, used)
        row["truth"] = ({k: t[k] for k in _PARAMS if k in t} if t is not None else None)
        row["truth_name"] = t.get("name") if t is not None else None
        row["error"] = ({k: est[k] - t[k] for k in est if k in t} if t is not None else None)
        row["compared"] = est  # the estimates the truth is compared with (maybe a candidate's)
        rows.append(row)
    return rows


def missed_truth(contents: LogContents, rows: list[dict]) -> list[dict]:
    """Injected faults no diagnosed fault was matched to."""
    if not contents.truth:
        return []
    used: set[int] = set()
    for f in rows:
        _match_truth(f, contents.truth, used)
    return [t for i, t in enumerate(contents.truth) if i not in used]


# ------------------------------------------------------------------------------------------
# estimate trajectories
# ------------------------------------------------------------------------------------------


@dataclass
class Trajectory:
    """Running estimates of one accepted fault, onset to acceptance.

    k : (N,) sample indices; names : (d,) parameter names (eta, lambda / bias);
    values, std : (N, d); mismatch : largest |last value - accepted| relative to
    max(|accepted|, 1e-9) (round-off when the log and its config agree); source : how it was
    obtained.
    """

    k: np.ndarray
    names: list[str]
    values: np.ndarray
    std: np.ndarray
    mismatch: float
    source: str


def estimate_trajectory(contents: LogContents, event: FaultEvent) -> Trajectory | None:
    """The running estimates of an accepted fault, recomputed from the log by its method
    (canfdi.methods: ``estimate_history``), or None when the log or the method cannot give them
    (then ``contents.notes`` says why)."""
    from canfdi import methods

    cfg = contents.config
    label = f"{event.target} {event.name}"
    if contents.residuals is None or cfg is None:
        return None
    if event.onset_sample is None or event.accepted_sample is None:
        return None
    method = methods.get(cfg.method)
    if method.estimate_history is None:
        contents.notes.append(f"{label}: method {cfg.method}: no estimate history in the log, "
                              f"accepted estimates only")
        return None
    history = method.estimate_history(cfg, contents, event)
    if history is None:
        return None
    accepted = np.array([event.estimates[name] for name in history.names])
    mismatch = float(np.max(np.abs(history.values[-1] - accepted)
                            / np.maximum(np.abs(accepted), 1e-9)))
    if mismatch > 1e-3:
        contents.notes.append(f"{label}: the recomputed estimate ends {mismatch:.1%} from the "
                              f"accepted one (log and config disagree?)")
    return Trajectory(k=history.k, names=history.names, values=history.values, std=history.std,
                      mismatch=mismatch, source=history.source)


# ------------------------------------------------------------------------------------------
# plotting helpers
# ------------------------------------------------------------------------------------------


def decimate(x: np.ndarray, y: np.ndarray, max_points: int = MAX_POINTS
             ) -> tuple[np.ndarray, np.ndarray]:
    """At most about ``max_points`` points of a line (x (N,), y (N,) or (N, c)): the min and
    the max of each of max_points/2 buckets (NaN ignored unless a whole bucket is NaN), so
    spikes survive; unchanged when short enough."""
    n = len(x)
    if n <= max_points:
        return x, y
    buckets = max(max_points // 2, 1)
    edges = np.linspace(0, n, buckets + 1).astype(np.int64)
    starts, ends = edges[:-1], edges[1:] - 1
    lo = np.fmin.reduceat(y, starts, axis=0)
    hi = np.fmax.reduceat(y, starts, axis=0)
    xs = np.empty(2 * buckets, dtype=np.asarray(x).dtype)
    xs[0::2], xs[1::2] = x[starts], x[ends]
    ys = np.empty((2 * buckets, *y.shape[1:]), dtype=float)
    ys[0::2], ys[1::2] = lo, hi
    return xs, ys


def _time_axis(ax, dt: float) -> None:
    """Time in seconds along the top of ax (the bottom shows the sample index k, written in
    full: 300,000 rather than 0.3 with an offset of 1e6)."""
    from matplotlib.ticker import FuncFormatter

    ax.xaxis.set_major_formatter(FuncFormatter(lambda k, _pos: f"{k:,.0f}"))
    sec = ax.secondary_xaxis("top", functions=(lambda k: k * dt, lambda t: t / dt))
    sec.set_xlabel("time t [s]")


def _unit(contents: LogContents, name: str) -> str:
    unit = contents.units.get(name, "")
    return f"{name} [{unit}]" if unit else name


def _marks(contents: LogContents, lo: float | None = None, hi: float | None = None
           ) -> list[tuple[int, str, str, str]]:
    """(k, label, colour, linestyle) of every injected onset, detection, acceptance,
    refinement, unexplained change and noise mismatch in [lo, hi]."""
    out = []
    for t in contents.truth or []:
        if t.get("onset_sample") is not None:
            out.append((t["onset_sample"], "injected onset (truth)", "0.35", ":"))
    for e in contents.events:
        if e.kind == "detected":
            out.append((e.sample, "detected", "tab:red", "--"))
        elif e.kind == "named":
            out.append((e.sample, "named", "tab:cyan", ":"))
        elif e.kind == "accepted":
            out.append((e.sample, "accepted", "tab:green", "-"))
        elif e.kind == "refined":
            out.append((e.sample, "refined", "tab:olive", "-"))
        elif e.kind == "unexplained":
            out.append((e.sample, "unexplained", "tab:orange", "-."))
        elif e.kind == "mismatch":
            out.append((e.sample, "noise mismatch", "tab:purple", "-."))
        elif e.kind == "quiet":
            out.append((e.sample, "quieter than configured", "tab:blue", "-."))
    return [m for m in out if (lo is None or m[0] >= lo) and (hi is None or m[0] <= hi)]


def _draw_marks(axes, marks) -> None:
    for ax in axes:
        for k, _label, colour, style in marks:
            # Under the data: a short excursion at the mark stays visible on long runs.
            ax.axvline(k, color=colour, linestyle=style, linewidth=1.1, alpha=0.85, zorder=1)


def _mark_handles(marks) -> list:
    from matplotlib.lines import Line2D

    seen: dict[str, Any] = {}
    for _k, label, colour, style in marks:
        seen.setdefault(label, Line2D([], [], color=colour, linestyle=style, label=label))
    return list(seen.values())


def _symlog(ax, values: np.ndarray) -> None:
    """A symmetric log y scale (linear within +/-3) with ticks 0, +/-10, +/-100... only (the
    default ticks crowd around zero)."""
    from matplotlib.ticker import FixedFormatter, FixedLocator, NullLocator

    ax.set_yscale("symlog", linthresh=3.0, linscale=1.0)
    finite = np.abs(values[np.isfinite(values)])
    top = max(float(finite.max()) if finite.size else 3.0, 3.0)
    ticks = [10.0 ** e for e in range(1, max(1, math.ceil(math.log10(top))) + 1)]
    ticks = [-t for t in reversed(ticks)] + [0.0] + ticks
    ax.yaxis.set_major_locator(FixedLocator(ticks))
    ax.yaxis.set_major_formatter(FixedFormatter([f"{t:g}" for t in ticks]))
    ax.yaxis.set_minor_locator(NullLocator())
    ax.set_ylim(-1.3 * top, 1.3 * top)


def _diagnosing(ax, contents: LogContents, label: bool) -> None:
    """Shade each diagnosis (detection to acceptance or give-up): the Page-Hinkley statistic
    is held there, the identification runs."""
    ends = {e.detected_sample: e.sample for e in contents.events
            if e.kind in ("accepted", "unexplained") and e.detected_sample is not None}
    first = True
    for e in contents.events:
        if e.kind == "detected" and e.sample in ends:
            ax.axvspan(e.sample, ends[e.sample], color="gold", alpha=0.18, lw=0,
                       label="diagnosing (statistic held)" if label and first else None)
            first = False


def _residual_colour(i: int) -> str:
    return f"C{i % 10}"


def _save(fig, path: Path) -> Path:
    fig.savefig(path, dpi=100)
    return path


# ------------------------------------------------------------------------------------------
# figures
# ------------------------------------------------------------------------------------------


def _output_groups(contents: LogContents) -> list[list[int]]:
    """Output columns grouped by unit (one panel each); by name when no unit is known."""
    names = contents.samples.output_names
    groups: dict[str, list[int]] = {}
    for j, n in enumerate(names):
        groups.setdefault(contents.units.get(n) or f"#{n}", []).append(j)
    return list(groups.values())


def plot_overview(contents: LogContents, path: Path) -> Path:
    """The whole run: u, z, r/sigma and statistic/threshold, with every event marked."""
    smp, res = contents.samples, contents.residuals
    panels: list[str] = []
    if smp is not None:
        panels.append("u")
        panels += [f"z{i}" for i in range(len(_output_groups(contents)))]
    if res is not None:
        panels += ["r", "g"]
    if not panels:
        panels = ["empty"]
    fig, axes = _figure(len(panels), height=1.75)
    axes = axes[:, 0]
    marks = _marks(contents)
    for ax, panel in zip(axes, panels, strict=True):
        if panel == "u":
            x, U = decimate(smp.k, smp.U)
            for j, name in enumerate(smp.input_names):
                ax.plot(x, U[:, j], lw=0.8, label=_unit(contents, name))
            ax.set_ylabel("input u")
        elif panel.startswith("z"):
            cols = _output_groups(contents)[int(panel[1:])]
            x, Z = decimate(smp.k, smp.Z[:, cols])
            for c, j in enumerate(cols):
                ax.plot(x, Z[:, c], lw=0.8, label=_unit(contents, smp.output_names[j]),
                        color=f"C{j % 10}")
            unit = contents.units.get(smp.output_names[cols[0]], "")
            ax.set_ylabel(f"output z [{unit}]" if unit else "output z")
        elif panel == "r":
            x, Rn = decimate(res.k, res.Rn)
            for i, name in enumerate(res.names):
                ax.plot(x, Rn[:, i], lw=0.8, label=name, color=_residual_colour(i))
            _symlog(ax, Rn)
            ax.set_ylabel("r / σ (symlog)")
        elif panel == "g":
            _plot_statistic(ax, contents)
        else:
            ax.text(0.5, 0.5, "the log holds no samples and no residuals",
                    ha="center", va="center", transform=ax.transAxes)
        if panel != "empty":
            ax.legend(loc="upper left", bbox_to_anchor=(1.005, 1.0), fontsize=7,
                      framealpha=0.8)
    _draw_marks(axes, marks)
    axes[-1].set_xlabel("sample k")
    _time_axis(axes[0], contents.dt)
    handles = _mark_handles(marks)
    if handles:
        fig.legend(handles=handles, loc="outside lower center", ncol=len(handles), fontsize=8)
    fig.suptitle(f"{contents.path.name}: overview ({_run_label(contents)})")
    return _save(fig, path)


def _plot_statistic(ax, contents: LogContents) -> None:
    """The overview's panel of each residual's statistic over its threshold (the statistic
    alone when the log holds no thresholds), with the diagnosing spans."""
    res = contents.residuals
    if contents.thresholds is not None:
        ratio = res.stat / contents.thresholds[None, :]
        ax.set_ylabel(f"{_statistic_name(contents)[0]} / h")
        ax.axhline(1.0, color="k", lw=1.2, label="threshold (g = h)")
    else:
        ratio = res.stat
        ax.set_ylabel(_statistic_name(contents)[0])
    x, G = decimate(res.k, ratio)
    for i, name in enumerate(res.names):
        ax.plot(x, G[:, i], lw=0.8, label=name, color=_residual_colour(i))
    ax.set_ylim(bottom=0.0)
    _diagnosing(ax, contents, label=True)


def _run_label(contents: LogContents) -> str:
    name = contents.metadata.get("config_name") or (contents.config.name
                                                     if contents.config else "?")
    method = contents.metadata.get("method") or (contents.config.method
                                                 if contents.config else "?")
    n = len(contents.samples.k) if contents.samples is not None else 0
    return f"config {name}, method {method}, {n:,} samples, dt = {contents.dt:g} s"


def _statistic_name(contents: LogContents) -> tuple[str, str]:
    """(short, long) name of the detection statistic the log's method records (its registry
    entry says: Page-Hinkley for most)."""
    from canfdi import methods

    name = contents.metadata.get("method") or (contents.config.method if contents.config
                                               else methods.DEFAULT)
    try:
        return methods.get(name).statistic
    except ValueError:  # a method this installation does not know: name it generically
        return "statistic", "detection statistic"


def plot_residuals(contents: LogContents, path: Path) -> Path:
    """Chan et al. 2006 Figs. 1-2: per residual r/sigma (+/-3 sigma band) and its Page-Hinkley
    statistic against the threshold, over the whole run."""
    res = contents.residuals
    m = len(res.names)
    fig, axes = _figure(m, 2, height=1.6, width=12.0)
    x, Rn = decimate(res.k, res.Rn)
    _, G = decimate(res.k, res.stat)
    detections = [e for e in contents.events if e.kind == "detected"]
    for i, name in enumerate(res.names):
        ax_r, ax_g = axes[i]
        colour = _residual_colour(i)
        ax_r.plot(x, Rn[:, i], lw=0.7, color=colour, label=f"{name}: r / σ")
        ax_r.axhspan(-3, 3, color="0.6", alpha=0.25, label="±3σ noise")
        ax_r.set_ylabel(f"{name}\nr / σ")
        ax_g.plot(x, G[:, i], lw=0.8, color=colour,
                  label=f"{name}: {_statistic_name(contents)[0]}")
        if contents.thresholds is not None:
            h = contents.thresholds[i]
            ax_g.axhline(h, color="tab:red", lw=1.2, label=f"threshold h = {h:.3g}")
            top = np.nanmax(G[:, i]) if np.isfinite(G[:, i]).any() else h
            ax_g.set_ylim(0.0, max(1.3 * h, min(1.1 * top, 4.0 * h)))
        ax_g.set_ylabel(_statistic_name(contents)[0].split()[-1])  # g, or |r|/σ
        for e in detections:
            if name in e.residuals:
                for ax in (ax_r, ax_g):
                    ax.axvline(e.sample, color="tab:red", ls="--", lw=1.0)
        for t in contents.truth or []:
            if t.get("onset_sample") is not None:
                for ax in (ax_r, ax_g):
                    ax.axvline(t["onset_sample"], color="0.35", ls=":", lw=1.0)
        ax_r.legend(loc="upper left", fontsize=7, framealpha=0.8)
        ax_g.legend(loc="upper left", fontsize=7, framealpha=0.8)
    for ax in axes[-1]:
        ax.set_xlabel("sample k")
    for ax in axes[0]:
        _time_axis(ax, contents.dt)
    axes[0, 0].set_title("normalised residual r / σ")
    axes[0, 1].set_title(f"{_statistic_name(contents)[1]} against its threshold")
    marks = [m for m in _marks(contents) if m[1] == "injected onset (truth)"]
    marks += [(e.sample, "detected (this residual in alarm)", "tab:red", "--")
              for e in detections]
    handles = _mark_handles(marks)
    if handles:
        fig.legend(handles=handles, loc="outside lower center", ncol=len(handles), fontsize=8)
    fig.suptitle(f"{contents.path.name}: residuals and detection")
    return _save(fig, path)


def _truth_for(row: dict | None, param: str) -> float | None:
    if row is None or row.get("truth") is None:
        return None
    value = row["truth"].get(param)
    if value is None:
        return None
    if row.get("truth_name") == row.get("name"):
        return value
    # The truth is on an indistinguishable candidate: its signature is a multiple of the
    # diagnosed channel's, so in the diagnosed channel's terms it is scaled by the ratio of
    # their estimates.
    est = row["estimate"].get(param)
    other = (row.get("compared") or {}).get(param)
    if est is None or not other:
        return None
    return value * est / other


def plot_fault(contents: LogContents, number: int, event: FaultEvent, row: dict | None,
               traj: Trajectory | None, path: Path) -> Path:
    """Chan et al. 2006 Figs. 4-6 for one accepted fault: residuals and statistics around it, and
    each
    estimated parameter converging (truth as a horizontal line)."""
    res = contents.residuals
    k_f = event.onset_sample if event.onset_sample is not None else event.sample
    k_a = event.accepted_sample if event.accepted_sample is not None else event.sample
    k_d = event.detected_sample if event.detected_sample is not None else k_f
    span = max(k_a - min(k_f, k_d), 20)
    lo, hi = min(k_f, k_d) - max(int(0.3 * span), 20), k_a + max(int(0.3 * span), 20)
    params = list(event.estimates)
    n_panels = (2 if res is not None else 0) + len(params)
    fig, axes = _figure(max(n_panels, 1), height=1.9, width=12.0)
    axes = axes[:, 0]
    a = 0
    if res is not None:
        sel = (res.k >= lo) & (res.k <= hi)
        x = res.k[sel]
        xr, Rn = decimate(x, res.Rn[sel])
        ax = axes[a]
        for i, name in enumerate(res.names):
            ax.plot(xr, Rn[:, i], lw=0.8, label=name, color=_residual_colour(i))
        _symlog(ax, Rn)
        ax.set_ylabel("r / σ (symlog)")
        ax.legend(**_OUTSIDE)
        ax = axes[a + 1]
        if contents.thresholds is not None:
            ratio = res.stat[sel] / contents.thresholds[None, :]
            ax.axhline(1.0, color="k", lw=1.2, label="threshold (g = h)")
            ax.set_ylabel(f"{_statistic_name(contents)[0]} / h")
        else:
            ratio = res.stat[sel]
            ax.set_ylabel(_statistic_name(contents)[0])
        xg, G = decimate(x, ratio)
        for i, name in enumerate(res.names):
            ax.plot(xg, G[:, i], lw=0.8, label=name, color=_residual_colour(i))
        ax.set_ylim(bottom=0.0)
        _diagnosing(ax, contents, label=True)
        ax.legend(**_OUTSIDE)
        a += 2
    for p_i, param in enumerate(params):
        ax = axes[a + p_i]
        est = event.estimates[param]
        std = math.sqrt(max(event.variances.get(param, 0.0) or 0.0, 0.0))
        label = _LABEL.get(param, param)
        ys = [est]
        if traj is not None and param in traj.names:
            c = traj.names.index(param)
            xt, vt = decimate(traj.k, traj.values[:, c])
            _, st = decimate(traj.k, traj.std[:, c])
            ax.plot(xt, vt, color="tab:blue", lw=1.3, label=f"running estimate of {label}")
            ax.fill_between(xt, vt - 2 * st, vt + 2 * st, color="tab:blue", alpha=0.2,
                            label="±2σ")
            tail = traj.values[len(traj.values) // 5:, c]
            ys += [float(np.nanpercentile(tail, 2)), float(np.nanpercentile(tail, 98))]
        ax.hlines(est, k_a, hi, color="tab:green", lw=2.0,
                  label=f"accepted {label} = {est:.4g} ± {std:.2g}")
        ax.errorbar([k_a], [est], yerr=[2 * std], fmt="o", color="tab:green", ms=4, capsize=3)
        true = _truth_for(row, param)
        if true is not None:
            on = ""
            if row is not None and row.get("truth_name") != event.name:
                on = f" (on {row.get('truth_name')}, as {event.name})"
            ax.axhline(true, color="k", ls=":", lw=1.5,
                       label=f"truth {label} = {true:.4g}{on}")
            ys.append(true)
        y0, y1 = min(ys), max(ys)
        pad = max(0.15 * (y1 - y0), 0.05 * max(abs(y0), abs(y1)), 6 * std, 1e-6)
        ax.set_ylim(y0 - pad, y1 + pad)
        unit = ""
        if param in ("bias", "lambda"):
            unit = contents.units.get(event.name or "", "")
        ax.set_ylabel(f"{label} [{unit}]" if unit else label)
        ax.legend(**_OUTSIDE)
    marks = _marks(contents, lo, hi)
    marks.append((k_f, "estimated onset", "tab:purple", "-."))
    _draw_marks(axes, marks)
    axes[-1].set_xlabel("sample k")
    axes[-1].set_xlim(lo, hi)
    _time_axis(axes[0], contents.dt)
    handles = _mark_handles(marks)
    fig.legend(handles=handles, loc="outside lower center", ncol=len(handles), fontsize=8)
    twins = ""
    if event.candidates:
        twins = "\nindistinguishable from the bus: " + "; ".join(
            f"{c['name']} " + ", ".join(f"{_LABEL.get(k, k)} = {v:.4g}"
                                        for k, v in c["estimates"].items())
            for c in event.candidates if c.get("name") != event.name)
    source = f"; estimates: {traj.source}" if traj is not None else ""
    fig.suptitle(f"Fault {number}: {event.target} {event.index} ({event.name}), onset k={k_f}, "
                 f"detected k={k_d}, accepted k={k_a}{source}{twins}", fontsize=10)
    return _save(fig, path)


# ------------------------------------------------------------------------------------------
# the page
# ------------------------------------------------------------------------------------------


def _fmt(values: dict | None, std: dict | None = None) -> str:
    if not values:
        return "–"
    parts = []
    for k, v in values.items():
        text = f"{_LABEL.get(k, k)} = {v:.5g}"
        if std and k in std:
            text += f" ± {std[k]:.2g}"
        parts.append(text)
    return ", ".join(parts)


def _fmt_error(error: dict | None, truth: dict | None) -> str:
    """estimate - truth per parameter, with the relative error when the truth is not 0."""
    if not error:
        return "–"
    parts = []
    for k, v in error.items():
        text = f"{_LABEL.get(k, k)} {v:+.3g}"
        t = (truth or {}).get(k)
        if t:
            text += f" ({100.0 * v / abs(t):+.2g} %)"
        parts.append(text)
    return ", ".join(parts)


def write_html(contents: LogContents, rows: list[dict], figures: list[tuple[str, str]],
               path: Path) -> Path:
    """index.html: run facts, notes, the diagnosis table, every figure (relative links)."""
    e = html.escape
    meta = contents.metadata
    out = ["<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
           '<link rel="icon" href="data:,">',  # a page that stands alone asks for no favicon
           f"<title>canfdi report: {e(contents.path.name)}</title>",
           f"<style>{_CSS}</style></head><body>",
           f"<h1>canfdi report: <code>{e(contents.path.name)}</code></h1>",
           f"<p>{e(_run_label(contents))}; canfdi {e(meta.get('version', '?'))}.</p>"]
    if contents.damage:
        out.append("<h2>Damaged: what was lost</h2><ul>")
        out += [f'<li class="note">{e(line)}</li>' for line in contents.damage.lines()]
        out.append("</ul>")
    if contents.notes:
        out.append("<h2>Missing from this log</h2><ul>")
        out += [f'<li class="note">{e(n)}</li>' for n in contents.notes]
        out.append("</ul>")
    out.append("<h2>Diagnosis</h2>")
    if rows:
        out.append("<table><thead><tr><th>#</th><th>fault</th><th>target</th><th>onset k</th>"
                   "<th>detected k</th><th>accepted k</th><th>estimates ± std</th>"
                   "<th>truth</th><th>error (estimate − truth)</th><th>figure</th></tr>"
                   "</thead><tbody>")
        for n, r in enumerate(rows, 1):
            name = e(str(r["name"]))
            others = [c["name"] for c in r.get("candidates", []) if c.get("name") != r["name"]]
            if others:
                name += f"<br><small>or {e(', '.join(map(str, others)))}</small>"
            truth = _fmt(r["truth"])
            if r["truth"] is not None and r.get("truth_name") != r["name"]:
                truth += f" (on {r['truth_name']})"
            fig = r.get("figure")
            link = f'<a href="{e(fig, quote=True)}">{e(fig)}</a>' if fig else "–"
            out.append(
                f"<tr><td class='num'>{n}</td><td>{name}</td>"
                f"<td>{e(str(r['kind']))} {e(str(r['index']))}</td>"
                f"<td class='num'>{e(str(r['onset_sample']))}</td>"
                f"<td class='num'>{e(str(r['detected_sample']))}</td>"
                f"<td class='num'>{e(str(r['accepted_sample']))}</td>"
                f"<td>{e(_fmt(r['estimate'], r['std']))}</td>"
                f"<td>{e(truth)}</td><td>{e(_fmt_error(r['error'], r['truth']))}</td>"
                f"<td>{link}</td></tr>")
        out.append("</tbody></table>")
    else:
        out.append("<p>No fault was accepted in this log.</p>")
    missed = missed_truth(contents, rows)
    if missed:
        out.append("<p>Injected but not diagnosed:</p><ul>")
        out += [f"<li>{e(str(t.get('target')))} {e(str(t.get('index')))} "
                f"({e(str(t.get('name')))}) {e(str(t.get('kind')))} from k="
                f"{e(str(t.get('onset_sample')))}: {e(_fmt({k: t[k] for k in _PARAMS if k in t}))}"
                f"</li>" for t in missed]
        out.append("</ul>")
    unexplained = [ev for ev in contents.events if ev.kind == "unexplained"]
    if unexplained:
        out.append("<p>Unexplained changes (detected, no single fault fitted):</p><ul>")
        out += [f"<li>detected k={e(str(ev.detected_sample))}, given up k={e(str(ev.sample))}"
                f"</li>" for ev in unexplained]
        out.append("</ul>")
    out.append("<h2>Figures</h2>")
    for file, caption in figures:
        out.append(f'<figure><a href="{e(file, quote=True)}"><img src="{e(file, quote=True)}" '
                   f'alt="{e(caption, quote=True)}"></a><figcaption>{e(caption)}</figcaption>'
                   f"</figure>")
    out.append("</body></html>")
    path.write_text("\n".join(out) + "\n", encoding="utf-8")
    return path


# ------------------------------------------------------------------------------------------
# all of it
# ------------------------------------------------------------------------------------------


@dataclass
class Report:
    """What `make_report` wrote: ``html``, ``figures`` (paths, overview first), ``rows`` (the
    diagnosis table, `diagnosis_rows` plus ``figure``), ``notes`` (what the log lacked),
    ``damage`` (what a damaged log lost: canfdi.io.damage.Damage, false when nothing),
    ``residuals`` (whether the log held residuals: without, the page shows the samples only)."""

    html: Path
    figures: list[Path]
    rows: list[dict]
    notes: list[str]
    damage: Any = None
    residuals: bool = True

    def as_dict(self) -> dict:
        return {"html": str(self.html), "figures": [str(p) for p in self.figures],
                "faults": self.rows, "missing": self.notes,
                "damage": self.damage.as_dict() if self.damage is not None else []}


def _safe(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", text).strip("_") or "fault"


def make_report(log: str | Path, out_dir: str | Path, config_path: Path | None = None,
                progress: Progress | None = None) -> Report:
    """Read ``log`` and write the figures and index.html into ``out_dir`` (created).

    Raises
    ------
    ReportError
        Bad input (see `read_log_contents`), or ``out_dir`` cannot be created.
    NothingToReport
        The log holds no sample, residual or event.
    """
    say = progress or (lambda _msg: None)
    contents = read_log_contents(log, config_path, progress)
    if contents.samples is None and contents.residuals is None and not contents.events:
        lost = "; ".join(contents.damage.lines()) if contents.damage else ""
        raise NothingToReport(f"{log} holds no sample, residual or event: nothing to report "
                              "(a capture's frames: canfdi replay LOG --config FILE diagnoses "
                              "them)" + (f"; {lost}" if lost else ""))
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ReportError(f"cannot create {out}: {exc.strerror or exc}") from None
    rows = diagnosis_rows(contents)
    figures: list[tuple[str, str]] = []
    say("overview.png")
    plot_overview(contents, out / "overview.png")
    stat_name = _statistic_name(contents)[1]
    figures.append(("overview.png", "The whole run: inputs, outputs, normalised residuals, "
                                    f"{stat_name}s over their thresholds, events."))
    if contents.residuals is not None:
        say("residuals.png")
        plot_residuals(contents, out / "residuals.png")
        figures.append(("residuals.png", "Each residual r/σ with the ±3σ noise band, and its "
                                         f"{stat_name} against its threshold h."))
    for n, (event, row) in enumerate(zip(contents.accepted, rows, strict=True), 1):
        file = f"fault_{n}_{_safe(str(event.target))}_{_safe(str(event.name))}.png"
        say(file)
        traj = estimate_trajectory(contents, event)
        plot_fault(contents, n, event, row, traj, out / file)
        row["figure"] = file
        if traj is not None:
            row["trajectory_mismatch"] = traj.mismatch
        figures.append((file, f"Fault {n}: {event.target} {event.name}, residuals around it "
                              f"and the estimates converging"
                              + (" to the truth." if row.get("truth") else ".")))
    say("index.html")
    page = write_html(contents, rows, figures, out / "index.html")
    return Report(html=page, figures=[out / f for f, _ in figures], rows=rows,
                  notes=list(contents.notes), damage=contents.damage,
                  residuals=contents.residuals is not None)

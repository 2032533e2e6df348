"""The HTML fleet report (canfdi.tools.fleetreport): ranking and its reasons, the trend fit,
drive-days, safe file names, and pages that parse, escape the data and embed their figures."""

from __future__ import annotations

import base64
import re
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest

pa = pytest.importorskip("pyarrow", reason="the fleet extra (pyarrow) is not installed")

from canfdi.bus.frames import STATUS_NAMES  # noqa: E402
from canfdi.tools import fleetreport as fr  # noqa: E402

TS = pa.timestamp("ns", tz="UTC")
DAY = 86_400 * 10**9
HOUR = 3_600 * 10**9
T0 = 1_717_200_000 * 10**9  # 2024-06-01 00:00 UTC
PNG = b"\x89PNG\r\n\x1a\n"

FAULT_SCHEMA = pa.schema([
    ("drive", pa.string()), ("log", pa.string()), ("log_start", TS), ("onset", TS),
    ("onset_s", pa.float64()), ("k", pa.int64()), ("bus_drive", pa.string()),
    ("kind", pa.string()), ("channel", pa.string()), ("estimate", pa.float64()),
    ("variance", pa.float64()), ("candidates", pa.list_(pa.string())), ("method", pa.string())])
LOG_SCHEMA = pa.schema([
    ("drive", pa.string()), ("log", pa.string()), ("log_start", TS), ("log_end", TS),
    ("samples", pa.int64()), ("frames", pa.int64()),
    *((f"frames_{s}", pa.int64()) for s in STATUS_NAMES),
    ("lost_bytes", pa.int64()), ("lost_messages", pa.int64()), ("lost_seconds", pa.float64()),
    ("residual_names", pa.list_(pa.string())), ("residual_variances", pa.list_(pa.float64())),
    ("alarms", pa.int64()), ("faults", pa.int64()), ("error", pa.string()),
    ("seconds", pa.float64())])


def log_row(drive: str, day: int, *, error: str | None = None, alarms: int = 0,
            faults: int = 0, lost_messages: int = 0, variance: float = 1.0) -> dict:
    """One hour-long log of ``drive`` starting at T0 + day days (undated when unreadable)."""
    start = None if error else T0 + day * DAY
    row = {s: 0 for s in LOG_SCHEMA.names}
    row.update(drive=drive, log=f"{drive}/day{day:02d}.mcap", log_start=start,
               log_end=None if error else start + HOUR, samples=0 if error else 360_000,
               frames=0 if error else 720_000, residual_names=[] if error else ["r0", "r1"],
               residual_variances=[] if error else [variance, 2.0 * variance], alarms=alarms,
               faults=faults, error=error, seconds=1.5, lost_messages=lost_messages,
               lost_bytes=8 * lost_messages, lost_seconds=0.01 * lost_messages)
    if not error:
        row["frames_ok"], row["frames_crc"] = 719_990, 10
    return row


def fault_row(drive: str, day: int, estimate: float, *, channel: str = "omega",
              kind: str = "sensor", variance: float | None = 0.003**2) -> dict:
    start = T0 + day * DAY
    return dict(drive=drive, log=f"{drive}/day{day:02d}.mcap", log_start=start,
                onset=start + 600 * 10**9, onset_s=600.0, k=60_000, bus_drive=None, kind=kind,
                channel=channel, estimate=estimate, variance=variance, candidates=[channel],
                method="parity")


def tables(faults: list[dict], logs: list[dict]):
    return (pa.Table.from_pylist(faults, schema=FAULT_SCHEMA),
            pa.Table.from_pylist(logs, schema=LOG_SCHEMA))


SLOPE = 0.012
NOISE = 0.003


def fleet_tables():
    """creeping: a bias on omega growing SLOPE per day over 10 days (one fault a day);
    steady: the same faults with a constant bias; broken: 1 unreadable log of 3; lossy: lost
    messages in 1 log of 4; noisy: alarms nobody explained; healthy: nothing."""
    rng = np.random.default_rng(18)
    faults, logs = [], []
    for day in range(10):
        faults.append(fault_row("creeping", day, 0.05 + SLOPE * day + rng.normal(0, NOISE)))
        logs.append(log_row("creeping", day, alarms=1, faults=1, variance=1.0 + 0.1 * day))
        faults.append(fault_row("steady", day, 0.1 + NOISE * (-1) ** day))
        logs.append(log_row("steady", day, alarms=1, faults=1))
    logs += [log_row("broken", 0), log_row("broken", 1),
             log_row("broken", 2, error="not an MCAP file")]
    logs += [log_row("lossy", d, lost_messages=12 if d == 0 else 0) for d in range(4)]
    logs += [log_row("noisy", 0, alarms=3), log_row("noisy", 1)]
    logs += [log_row("healthy", d) for d in range(5)]
    return tables(faults, logs)


class Checker(HTMLParser):
    """Tags balanced (void elements aside), text, image sources, links, script tags."""

    VOID = frozenset({"meta", "img", "br", "hr", "link", "input", "source", "wbr", "col", "area"})

    def __init__(self) -> None:
        super().__init__(convert_charrefs=True)
        self.stack: list[str] = []
        self.errors: list[str] = []
        self.text: list[str] = []
        self.images: list[str] = []
        self.links: list[str] = []
        self.tags: set[str] = set()
        self.rows: list[list[str]] = []  # every table row, its cells' text

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        # the one link a page has: its empty icon, so that no browser asks for a favicon
        if not (tag == "link" and attrs.get("rel") == "icon" and attrs.get("href") == "data:,"):
            self.tags.add(tag)
        if tag == "img":
            self.images.append(attrs.get("src") or "")
        if tag == "a":
            self.links.append(attrs.get("href") or "")
        if tag == "tr":
            self.rows.append([])
        if tag in ("td", "th") and self.rows:
            self.rows[-1].append("")
        if tag not in self.VOID:
            self.stack.append(tag)

    def handle_endtag(self, tag):
        if tag in self.VOID:
            return
        if not self.stack or self.stack[-1] != tag:
            self.errors.append(f"</{tag}> closes {self.stack[-1:]}")
            return
        self.stack.pop()

    def handle_data(self, data):
        self.text.append(data)
        if self.rows and self.rows[-1] and "tr" in self.stack:
            self.rows[-1][-1] += data


def parse(path: Path) -> Checker:
    c = Checker()
    c.feed(path.read_text(encoding="utf-8"))
    c.close()
    assert not c.errors, c.errors
    assert c.stack == [], f"unclosed: {c.stack}"
    assert "script" not in c.tags and "link" not in c.tags  # no script, no external style
    for src in c.images:  # every figure inlined, a real PNG
        assert src.startswith("data:image/png;base64,")
        assert base64.b64decode(src.split(",", 1)[1]).startswith(PNG)
    return c


# ------------------------------------------------------------------------------------------
# numbers
# ------------------------------------------------------------------------------------------


def test_trend_slope_is_recovered_with_an_honest_uncertainty():
    rng = np.random.default_rng(7)
    t = np.arange(30.0)
    y = 0.05 + SLOPE * t + rng.normal(0, NOISE, t.size)
    slope, std, intercept, weighted = fr.fit_trend(t, y)
    expected_std = NOISE / np.sqrt(((t - t.mean()) ** 2).sum())
    assert abs(slope - SLOPE) < 4 * expected_std
    assert 0.5 * expected_std < std < 2.0 * expected_std
    assert abs(intercept - 0.05) < 0.01
    assert not weighted


def test_trend_equals_numpy_polyfit_unweighted_and_weighted():
    rng = np.random.default_rng(3)
    t = np.sort(rng.uniform(0, 20, 12))
    y = 1.0 - 0.02 * t + rng.normal(0, 0.01, t.size)
    var = rng.uniform(0.5, 2.0, t.size) * 1e-4
    for variance, w in ((None, None), (var, 1.0 / np.sqrt(var))):
        coef, cov = np.polyfit(t, y, 1, w=w, cov=True)
        slope, std, intercept, _ = fr.fit_trend(t, y, variance)
        assert slope == pytest.approx(coef[0], rel=1e-9)
        assert intercept == pytest.approx(coef[1], rel=1e-9)
        assert std == pytest.approx(np.sqrt(cov[0, 0]), rel=1e-6)


def test_no_trend_from_two_points_one_time_or_unknown_values():
    assert fr.fit_trend(np.array([0.0, 1.0]), np.array([1.0, 2.0])) is None
    assert fr.fit_trend(np.zeros(5), np.arange(5.0)) is None
    assert fr.fit_trend(np.arange(4.0), np.array([1.0, np.nan, np.nan, 2.0])) is None
    # an unknown variance makes the fit unweighted, not impossible
    fit = fr.fit_trend(np.arange(4.0), np.arange(4.0), np.array([1.0, np.nan, 1.0, 1.0]))
    assert fit is not None and not fit[3]


def test_drive_days_count_calendar_days_covered_and_undated_logs():
    same_day = [{"log_start": T0, "log_end": T0 + HOUR},
                {"log_start": T0 + 2 * HOUR, "log_end": T0 + 3 * HOUR}]
    assert fr.drive_days(same_day) == 1
    over_midnight = [{"log_start": T0 + 23 * HOUR, "log_end": T0 + 25 * HOUR}]
    assert fr.drive_days(over_midnight) == 2
    assert fr.drive_days([*same_day, {"log_start": None, "log_end": None}]) == 2
    assert fr.drive_days([], [{"log_start": T0}, {"log_start": T0 + DAY}]) == 2
    assert fr.drive_days([]) == 0


def test_ranking_order_scores_and_reasons():
    faults, logs = fleet_tables()
    fleet = fr.summarize_fleet(fr.table_rows(faults, fr.FAULT_COLUMNS, "faults"),
                               fr.table_rows(logs, fr.LOG_COLUMNS, "logs"))
    by = {d.drive: d for d in fleet.drives}
    assert [d.drive for d in fleet.drives] == ["creeping", "steady", "noisy", "broken",
                                               "lossy", "healthy"]
    assert [d.rank for d in fleet.drives] == [1, 2, 3, 4, 5, 6]

    creeping = by["creeping"]
    (trend,) = creeping.trends
    assert trend.significant and abs(trend.slope - SLOPE) < 4 * trend.slope_std
    assert creeping.score == pytest.approx(fr.W_TREND + fr.W_FAULT_RATE * 10 / 10)
    assert creeping.reasons[0].startswith("bias on omega grows 0.01")
    assert "significant trend" in creeping.reasons[0]
    assert "10 accepted fault(s) in 10 drive-day(s)" in creeping.reasons[1]

    steady = by["steady"]
    assert steady.trends[0].fitted and not steady.trends[0].significant
    assert steady.score == pytest.approx(fr.W_FAULT_RATE)
    assert len(steady.reasons) == 1

    assert by["broken"].drive_days == 3
    assert by["broken"].score == pytest.approx(fr.W_UNREADABLE / 3)
    assert by["broken"].reasons == ["1 of 3 log(s) unreadable (broken/day02.mcap: not an MCAP "
                                    "file)"]
    assert by["lossy"].score == pytest.approx(fr.W_LOSS / 4)
    assert "12 message(s), 96 byte(s)" in by["lossy"].reasons[0]
    assert by["noisy"].score == pytest.approx(fr.W_UNEXPLAINED * 3 / 2)
    assert by["noisy"].reasons == ["3 alarm(s) without an accepted fault"]
    assert by["healthy"].score == 0.0
    assert by["healthy"].reasons[0].startswith("nothing needs attention")


def test_the_rule_in_the_docstring_has_the_weights_the_code_uses():
    said = {phrase.strip(): float(w) for w, phrase in
            re.findall(r"^\* ([\d.]+) per (.+?)(?: \(|,$|;$)", fr.__doc__, re.M)}
    assert said == {"accepted fault per drive-day": fr.W_FAULT_RATE,
                    "significant trend": fr.W_TREND,
                    "unreadable log per drive-day": fr.W_UNREADABLE,
                    "log with lost data per drive-day": fr.W_LOSS,
                    "alarm without an accepted fault per drive-day": fr.W_UNEXPLAINED}


def test_drive_file_names_are_safe_and_distinct():
    drives = ["../etc/passwd", "a/b", "a_b", "..", ".hidden", "index", "Index", "ok-1", "OK-1",
              "<script>", "x" * 300, "plain.drive_7"]
    names = fr.drive_file_names(drives)
    files = list(names.values())
    assert len({f.casefold() for f in files}) == len(drives)
    for f in files:
        assert re.fullmatch(r"[A-Za-z0-9_][A-Za-z0-9_.-]*\.html", f), f
        assert f.casefold() != "index.html" and len(f) < 120
    assert names["a_b"] == "a_b.html" and names["plain.drive_7"] == "plain.drive_7.html"
    assert names["a/b"] != names["a_b"]


def test_missing_column_is_a_clear_error():
    faults, logs = fleet_tables()
    with pytest.raises(fr.FleetReportError, match="faults table lacks the columns channel"):
        fr.write_fleet_report(faults.drop_columns(["channel"]), logs, Path("unused"))


# ------------------------------------------------------------------------------------------
# the pages
# ------------------------------------------------------------------------------------------


def test_report_pages_one_per_drive_parse_and_embed_figures(tmp_path):
    faults, logs = fleet_tables()
    paths = fr.write_fleet_report(faults, logs, tmp_path / "out")
    out = tmp_path / "out"
    assert paths[0] == out / "index.html"
    assert sorted(p.name for p in out.iterdir()) == sorted(p.name for p in paths)
    assert len(paths) == 1 + 6

    index = parse(paths[0])
    text = " ".join(index.text)
    assert len(index.images) == 1  # the fleet timeline
    assert fr.RANKING_RULE in text
    ranked = [link for link in index.links if link.endswith(".html")]
    assert ranked == ["creeping.html", "steady.html", "noisy.html", "broken.html",
                      "lossy.html", "healthy.html"]
    totals = {row[0]: row[1] for row in index.rows if len(row) == 2}
    assert totals["logs"] == f"{logs.num_rows}" and totals["accepted faults"] == "20"
    assert totals["drives"] == "6" and totals["unreadable logs"] == "1"
    assert totals["drive-days"] == f"{10 + 10 + 3 + 4 + 2 + 5}"
    assert totals["lost data"] == "12 msg, 96 B, 0.12 s"
    assert totals["alarms without an accepted fault"] == "3"

    creeping = parse(out / "creeping.html")
    # fault timeline, estimates with trend, residual variances
    assert len(creeping.images) == 3
    page = " ".join(creeping.text)
    assert "bias on omega grows 0.01" in page and "Rank 1 of 6" in page
    assert "index.html" in creeping.links
    healthy = parse(out / "healthy.html")
    assert len(healthy.images) == 1  # residual variances only
    assert healthy.rows[1][-4] == "r0 1, r1 2"  # and their values in the logs table
    assert "No fault was accepted in this drive's logs." in " ".join(healthy.text)
    broken = " ".join(parse(out / "broken.html").text)
    assert "not an MCAP file" in broken


def test_data_is_escaped_and_odd_drive_names_stay_inside_out_dir(tmp_path):
    evil = "<script>alert(1)</script>"
    faults = [fault_row(evil, d, 0.1 * d, channel="<b>ch</b>") for d in range(3)]
    logs = [log_row(evil, 0, error="bad </td></tr> & <i>"), log_row(evil, 1),
            log_row("../../up", 0), log_row("a/b", 0)]
    # a $ would start matplotlib's mathtext: these names must draw as they are
    faults += [fault_row("x$^{$y", d, 0.1 * d, channel="$\\frac$") for d in range(3)]
    logs += [{**log_row("x$^{$y", d), "residual_names": ["_r0", "$r1"]} for d in range(3)]
    out = tmp_path / "out"
    paths = fr.write_fleet_report(*tables(faults, logs), out)
    assert len(paths) == 5 and all(p.parent == out for p in paths)
    assert sorted(p.name for p in out.iterdir()) == sorted(p.name for p in paths)
    assert not (tmp_path / "up.html").exists()
    for p in paths:
        c = parse(p)  # balanced and script-free: the names were escaped
        raw = p.read_text(encoding="utf-8")
        assert "<b>ch</b>" not in raw and "<i>" not in raw
    index = parse(paths[0])
    assert evil in " ".join(index.text)
    (evil_page,) = [p for p in paths if p.name.startswith("script")]
    c = parse(evil_page)
    page = " ".join(c.text)
    assert evil in page and "<b>ch</b>" in page and "bad </td></tr> & <i>" in page


def test_empty_fleet_and_fleet_without_faults_still_give_a_valid_report(tmp_path):
    paths = fr.write_fleet_report(*tables([], []), tmp_path / "empty")
    assert paths == [tmp_path / "empty" / "index.html"]
    c = parse(paths[0])
    assert "The fleet is empty" in " ".join(c.text) and c.images == []

    logs = [log_row("quiet", d) for d in range(3)]
    paths = fr.write_fleet_report(*tables([], [*logs, log_row("single", 0)]), tmp_path / "q")
    assert [p.name for p in paths] == ["index.html", "quiet.html", "single.html"]
    assert "No fault was accepted in any log of the fleet." in " ".join(parse(paths[0]).text)
    quiet, single = parse(paths[1]), parse(paths[2])
    assert "No fault was accepted in this drive's logs." in " ".join(quiet.text)
    assert len(quiet.images) == 1  # residual variances over 3 logs
    assert single.images == []  # one log: nothing over time to draw, the table has them
    assert single.rows[1][-4] == "r0 1, r1 2"

    faults = [fault_row("orphan", d, 1.0) for d in range(2)]
    paths = fr.write_fleet_report(*tables(faults, []), tmp_path / "nologs")
    page = " ".join(parse(paths[1]).text)
    assert "The logs table has no row for this drive." in page
    assert "The logs table is empty" in " ".join(parse(paths[0]).text)


def test_three_unrelated_faults_are_no_trend_but_ten_on_a_line_are():
    """|slope| = 5.2 sigma from three points is what one degree of freedom gives by chance
    (Student's t at 5 %: 12.7 sigma); a fixed 2 sigma called it a trend."""
    def trend(days, values):
        slope, std, intercept, weighted = fr.fit_trend(np.array(days, float), np.array(values))
        onset = (np.array(days) * 86_400e9).astype(np.int64)
        return fr.Trend("sensor", "omega", "bias", onset, np.array(values, float),
                        np.full(len(days), np.nan), slope, std, intercept, weighted)

    three = trend([0, 1, 2], [0.0, 1.0, 1.5])
    assert 2.0 < abs(three.slope) / three.slope_std < 12.7
    assert not three.significant and three.threshold == pytest.approx(12.706, abs=1e-3)
    rng = np.random.default_rng(3)
    days = np.arange(10.0)
    ten = trend(days, 0.05 + 0.01 * days + rng.normal(0, 0.002, 10))
    assert ten.significant and ten.threshold == pytest.approx(2.306, abs=1e-3)

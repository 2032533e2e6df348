"""`canfdi fleet` on a 2-worker LocalCluster over a handful of generated drive logs (faults on
some, a bus of two drives, a candump log, a truncated MCAP, a file that is no log): every fault
row and every log row equals what serial `canfdi replay --json` says of that log; the
in-process path gives the same tables; the report is written beside the tables."""

from __future__ import annotations

import contextlib
import io
import json
import os
from pathlib import Path

import pytest

from canfdi.bus.frames import STATUS_NAMES, VALID_STATUSES
from canfdi.tools.fleet import (
    FleetLogSpec,
    find_logs,
    fleet_tables,
    plan_tasks,
    run_fleet,
    write_drive_log,
)
from tests.cli import canfdi_main as main
from tests.conftest import REPO

pq = pytest.importorskip("pyarrow.parquet")
pytest.importorskip("distributed")

pytestmark = pytest.mark.slow

ONE = REPO / "deploy" / "config" / "dc_motor.yaml"
TWO = REPO / "deploy" / "config" / "dc_motor_two_drives_cia402.yaml"
DAY = 86_400 * 10**9
T0 = 1_740_787_200 * 10**9  # 2025-03-01 UTC


@pytest.fixture(scope="module")
def fleet(tmp_path_factory) -> dict:
    root = tmp_path_factory.mktemp("fleet")
    logs = root / "logs"
    specs = [
        (FleetLogSpec("truck1", 0, T0 + 8 * 3600 * 10**9, 40.0, 11,
                      ({"target": "sensor", "index": 0, "kind": "bias", "onset": 12.0,
                        "bias": 0.3},)), ONE),
        (FleetLogSpec("truck1", 1, T0 + DAY + 9 * 3600 * 10**9, 35.0, 12,
                      ({"target": "sensor", "index": 1, "kind": "bias", "onset": 10.0,
                        "bias": 0.5},)), ONE),  # i_a: candidates i_a, i_f_plus_i_a
        (FleetLogSpec("truck2", 0, T0 + 7 * 3600 * 10**9, 45.0, 13,
                      ({"target": "actuator", "index": 0, "kind": "scale_bias", "onset": 15.0,
                        "eta": 1.5, "lam": 3.0},)), ONE),
        (FleetLogSpec("truck2", 1, T0 + DAY + 7 * 3600 * 10**9, 30.0, 14), ONE),
        (FleetLogSpec("pair", 0, T0 + 10 * 3600 * 10**9, 40.0, 15,
                      ({"target": "sensor", "index": 0, "kind": "bias", "onset": 15.0,
                        "bias": 0.5},)), TWO),
        (FleetLogSpec("truck3", 0, T0 + 6 * 3600 * 10**9, 40.0, 16,
                      ({"target": "sensor", "index": 2, "kind": "bias", "onset": 20.0,
                        "bias": -0.5},), truncate=0.6), ONE),
    ]
    for spec, config in specs:
        write_drive_log(spec, str(logs), str(config))
    # The same drive's day as a candump log (any format canfdi reads), and a file that is not
    # a log of its suffix.
    from canfdi.io.logs import frame_blocks, write_frames

    write_frames(logs / "truck2" / "2025-03-03.log",
                 frame_blocks(logs / "truck2" / "2025-03-02.mcap"))
    (logs / "truck3" / "2025-03-02.mcap").write_bytes(b"this is not an MCAP file\n" * 40)
    mapping = root / "map.yaml"
    mapping.write_text(f'"*/pair/*": {TWO}\n"*": {os.path.relpath(ONE, root)}\n')  # relative
    out = root / "out" / "fleet.parquet"
    err, said = io.StringIO(), io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(said):
        rc = main(["fleet", str(logs), "--config-map", str(mapping), "-o", str(out),
                   "--jobs", "2", "--no-progress", "--json"])
    assert rc == 0, err.getvalue()
    return {"root": root, "logs": logs, "mapping": mapping, "out": out,
            "summary": json.loads(said.getvalue()),
            "faults": pq.read_table(out), "table": pq.read_table(
                out.with_name("fleet.logs.parquet"))}


def replay(log: Path, config: Path) -> tuple[int, dict | None, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main(["replay", str(log), "--config", str(config), "--json", "--no-progress"])
    return rc, (json.loads(out.getvalue()) if out.getvalue().strip() else None), err.getvalue()


def config_of(log: str) -> Path:
    return TWO if "/pair/" in log else ONE


def test_every_fault_row_equals_serial_replay(fleet):
    rows = fleet["faults"].to_pylist()
    logs = fleet["table"].to_pylist()
    assert len(logs) == 8
    assert sum(r["faults"] for r in logs) >= 4
    checked = 0
    for log in logs:
        rc, result, _ = replay(Path(log["log"]), config_of(log["log"]))
        mine = [r for r in rows if r["log"] == log["log"]]
        if result is None:  # replay refused the log (not a log of its suffix): an error row
            assert rc == 2 and log["error"] and not mine
            continue
        several = "drives" in result
        expected = [
            (f["onset_sample"], f["kind"], f["name"], f["drive"] if several else None, p,
             v, f["variance"].get(p), [c["name"] for c in f["candidates"]])
            for f in result["faults"] for p, v in f["estimate"].items()]
        got = [(r["k"], r["kind"], r["channel"], r["bus_drive"], r["parameter"],
                r["estimate"], r["variance"], r["candidates"]) for r in mine]
        assert got == expected, log["log"]
        assert log["faults"] == len(result["faults"])
        assert log["alarms"] == result["detections"]
        assert log["samples"] == result["samples"]
        frames = result["frames"]
        assert log["frames"] == frames["received"]
        assert sum(log[f"frames_{s}"] for s in VALID_STATUSES) == frames["valid"]
        for status in STATUS_NAMES:
            if status not in VALID_STATUSES:
                assert log[f"frames_{status}"] == frames["invalid_by_reason"][status]
        assert bool(log["lost_bytes"]) == bool(result["damage"]), log["log"]
        assert log["error"] == result.get("no_samples")
        checked += len(mine)
    assert checked == len(rows) > 0


def test_the_tables_say_drives_times_and_damage(fleet):
    logs = {r["log"]: r for r in fleet["table"].to_pylist()}
    by_name = {Path(k).relative_to(fleet["logs"]).as_posix(): v for k, v in logs.items()}
    assert {r["drive"] for r in logs.values()} == {"truck1", "truck2", "truck3", "pair"}
    first = by_name["truck1/2025-03-01.mcap"]
    start = first["log_start"]
    assert start.year == 2025 and start.month == 3 and start.day == 1 and start.hour == 8
    assert first["log_end"] > start and first["error"] is None and first["seconds"] > 0
    assert len(first["residual_names"]) == len(first["residual_variances"]) > 0
    assert all(v > 0 for v in first["residual_variances"])
    pair = by_name["pair/2025-03-01.mcap"]
    assert all(":" in n for n in pair["residual_names"])  # drive:residual on a bus of two
    cut = by_name["truck3/2025-03-01.mcap"]  # one chunk, cut: nothing left but its loss
    assert cut["lost_bytes"] > 0 and cut["lost_seconds"] > 0 and cut["error"]
    bad = by_name["truck3/2025-03-02.mcap"]
    assert bad["error"] and bad["log_start"] is None and bad["samples"] == 0
    assert by_name["truck2/2025-03-03.log"]["samples"] == by_name[
        "truck2/2025-03-02.mcap"]["samples"] > 0
    faults = fleet["faults"].to_pylist()
    assert [r["candidates"] for r in faults if r["channel"] == "i_a"] == [
        ["i_a", "i_f_plus_i_a"]]
    faults = [r for r in faults if r["drive"] == "pair"]
    assert faults and {r["bus_drive"] for r in faults} <= {"left", "right"}
    for r in fleet["faults"].to_pylist():
        assert r["onset"] >= r["log_start"] and r["onset_s"] == pytest.approx(
            (r["onset"] - r["log_start"]).total_seconds(), abs=1e-6)
        assert r["method"] == "parity"


def test_the_in_process_path_gives_the_same_tables(fleet):
    from canfdi.tools.fleet import ConfigMap

    tasks = plan_tasks(find_logs([fleet["logs"]]),
                       config_map=ConfigMap.load(fleet["mapping"]))
    faults, logs = fleet_tables(run_fleet(tasks, None))

    def same(table):
        return [{k: v for k, v in r.items() if k != "seconds"} for r in table.to_pylist()]

    assert faults.to_pylist() == fleet["faults"].to_pylist()
    assert same(logs) == same(fleet["table"])


def test_the_report_is_written_beside_the_tables(fleet):
    report = fleet["out"].with_name("fleet-report")
    assert (report / "index.html").is_file()
    assert len(list(report.glob("*.html"))) == 1 + 4  # index and one page per drive


def test_the_json_summary_is_one_object_that_agrees_with_the_tables(fleet):
    summary, logs = fleet["summary"], fleet["table"].to_pylist()
    assert summary["logs"] == len(logs) == 8
    assert summary["faults"] == sum(r["faults"] for r in logs)  # (a row per parameter there)
    assert summary["errors"] == len(summary["errors_by_log"]) == sum(
        r["error"] is not None for r in logs)
    assert str(fleet["out"]) in summary["written"]
    assert all(Path(p).exists() for p in summary["written"])

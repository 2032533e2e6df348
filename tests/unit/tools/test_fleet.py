"""canfdi.tools.fleet's pure parts (no Dask): the running variance, drives, config maps, the
fault rows, the table contract the report reads, the generated fleet's plan, the in-process
path on a short log; and `canfdi fleet`'s bad inputs: one line, exit status 2."""

from __future__ import annotations

import re
import sys
from pathlib import Path

import numpy as np
import pytest

from canfdi.bus.frames import STATUS_NAMES
from canfdi.core.records import FaultEvent
from canfdi.tools.fleet import (
    CREEP_BIAS,
    ConfigMap,
    FleetError,
    LogTask,
    NoDask,
    RunningVariance,
    check_configs,
    diagnose_log,
    drive_of,
    fault_rows,
    find_logs,
    fleet_summary,
    parse_drive_pattern,
    plan_fleet,
    plan_tasks,
    report_dir,
    tables_paths,
    task_mapper,
)
from tests.cli import canfdi_main as main
from tests.conftest import REPO

CONFIG = REPO / "deploy" / "config" / "dc_motor.yaml"


@pytest.mark.parametrize("seed", range(5))
def test_running_variance_equals_numpy_over_any_cut(seed):
    rng = np.random.default_rng(seed)
    data = rng.normal(3.0, 2.0, (500, 4)) * [1.0, 10.0, 0.01, 1e3]
    data[rng.random(data.shape) < 0.2] = np.nan
    data[:50, 2] = np.nan  # a residual that starts late
    rv = RunningVariance(4)
    cuts = np.sort(rng.choice(np.arange(1, 500), size=12, replace=False))
    for block in np.split(data, cuts):
        rv.add(block)
    assert rv.variance() == pytest.approx(np.nanvar(data, axis=0), rel=1e-10)
    assert rv.count.tolist() == (~np.isnan(data)).sum(axis=0).tolist()


def test_running_variance_of_a_residual_never_seen_is_nan():
    rv = RunningVariance(2)
    rv.add(np.array([[1.0, np.nan], [2.0, np.nan]]))
    assert rv.variance()[0] == 0.25 and np.isnan(rv.variance()[1])


@pytest.mark.parametrize("path, root, pattern, drive", [
    ("fleet/truck7/2025-03-01.mcap", "fleet", None, "truck7"),
    ("fleet/truck7_2025-03-01.mcap", "fleet", None, "truck7"),  # at the top of DIR
    ("logs/truck7_2025-03-01.asc.gz", None, None, "truck7"),
    ("logs/plain.blf", None, None, "plain"),
    ("site3/bus-17/2025/03/01.mcap", None, r"bus-(?P<drive>\d+)", "17"),
])
def test_drive_of(path, root, pattern, drive):
    compiled = parse_drive_pattern(pattern) if pattern else None
    assert drive_of(Path(path), Path(root) if root else None, compiled) == drive


@pytest.mark.parametrize("text, words", [
    ("truck(", "not a regular expression"),
    (r"truck(\d+)", "no named group 'drive'"),
])
def test_bad_drive_patterns(text, words):
    with pytest.raises(FleetError, match=re.escape(words)):
        parse_drive_pattern(text)


def test_a_pattern_that_names_no_drive():
    with pytest.raises(FleetError, match=re.escape("names no drive in logs/x.mcap")):
        drive_of(Path("logs/x.mcap"), None, parse_drive_pattern(r"truck(?P<drive>\d+)"))


def test_config_map_first_match_wins_relative_to_the_map(tmp_path):
    (tmp_path / "a.yaml").write_text("x")
    (tmp_path / "b.yaml").write_text("x")
    mapping = tmp_path / "map.yaml"
    mapping.write_text('"*/trucks/*": a.yaml\n"*/trucks/t1/*": b.yaml\n"*.blf": b.yaml\n')
    m = ConfigMap.load(mapping)
    assert m.config_for(Path("x/trucks/t1/d.mcap")) == tmp_path / "a.yaml"
    assert m.config_for(Path("cars/c.blf")) == tmp_path / "b.yaml"
    assert m.config_for(Path("cars/c.mcap")) is None
    logs = [(Path("cars/c.mcap"), None), (Path("cars/d.mcap"), None)]
    with pytest.raises(FleetError, match=r"no pattern matches cars/c.mcap and 1 more"):
        plan_tasks(logs, config_map=m)


@pytest.mark.parametrize("text, words", [
    ("- a\n- b\n", "a mapping of log path patterns"),
    ("{}\n", "a mapping of log path patterns"),
    ('"*": [a]\n', "a pattern and a config file name"),
    ('"*": nope.yaml\n', "no such config"),
    ("a: [\n", "not YAML"),
])
def test_bad_config_maps(tmp_path, text, words):
    mapping = tmp_path / "map.yaml"
    mapping.write_text(text)
    with pytest.raises(FleetError, match=re.escape(words)):
        ConfigMap.load(mapping)


def test_find_logs(tmp_path):
    (tmp_path / "d" / "x").mkdir(parents=True)
    (tmp_path / "d" / "x" / "1.mcap").write_bytes(b"")
    (tmp_path / "d" / "0.asc.gz").write_bytes(b"")
    (tmp_path / "d" / "notes.md").write_text("not a log")
    (tmp_path / "empty").mkdir()
    found = find_logs([tmp_path / "d", tmp_path / "d" / "x" / "1.mcap"])
    assert found == [(tmp_path / "d" / "0.asc.gz", tmp_path / "d"),
                     (tmp_path / "d" / "x" / "1.mcap", tmp_path / "d")]  # each log once
    with pytest.raises(FleetError, match="no log under it"):
        find_logs([tmp_path / "empty"])
    with pytest.raises(FleetError, match="no such log or directory"):
        find_logs([tmp_path / "nope.mcap"])


def test_fault_rows_one_per_estimated_parameter():
    accepted = FaultEvent(kind="accepted", sample=1300, timestamp_ns=10**12 + 13 * 10**9,
                          target="actuator", index=0, name="V",
                          estimates={"eta": 1.5, "lambda": 3.0}, variances={"eta": 1e-4},
                          onset_sample=1000, detected_sample=1002, accepted_sample=1300,
                          candidates=({"name": "V"}, {"name": "W"}), drive="left")
    events = [FaultEvent(kind="detected", sample=1002, timestamp_ns=0), accepted]
    rows = fault_rows(events, drive="truck1", log="a.mcap", log_start=10**12, dt=0.01,
                      method="parity", several=True)
    assert [(r["parameter"], r["estimate"], r["variance"]) for r in rows] == [
        ("eta", 1.5, 1e-4), ("lambda", 3.0, None)]
    for r in rows:
        assert r["onset"] == 10**12 + 10 * 10**9 and r["onset_s"] == 10.0 and r["k"] == 1000
        assert r["kind"] == "actuator" and r["channel"] == "V" and r["bus_drive"] == "left"
        assert r["candidates"] == ["V", "W"] and r["method"] == "parity"
    alone = fault_rows(events, drive="t", log="a", log_start=None, dt=0.01, method="parity",
                       several=False)
    assert alone[0]["bus_drive"] is None and alone[0]["onset_s"] is None


def test_the_tables_follow_the_report_contract():
    pytest.importorskip("pyarrow")
    from canfdi.tools.fleet import fleet_tables, schemas
    from canfdi.tools.fleetreport import FAULT_COLUMNS, LOG_COLUMNS

    faults, logs = schemas()
    assert set(FAULT_COLUMNS) <= set(faults.names)
    assert set(LOG_COLUMNS) <= set(logs.names)
    assert [f"frames_{s}" for s in STATUS_NAMES] == [n for n in logs.names
                                                    if n.startswith("frames_")]
    empty_faults, empty_logs = fleet_tables([])
    assert empty_faults.schema == faults and empty_logs.num_rows == 0


def test_an_unreadable_log_is_a_row_with_its_error(tmp_path):
    pytest.importorskip("pyarrow")
    from canfdi.tools.fleet import fleet_tables

    bad = tmp_path / "x.mcap"
    bad.write_bytes(b"\x89MCAP0\r\n garbage")
    results = [diagnose_log(LogTask(str(bad), "x.mcap", "x", str(CONFIG))),
               diagnose_log(LogTask(str(tmp_path / "gone.blf"), "gone.blf", "y",
                                    str(CONFIG)))]
    faults, logs = fleet_tables(results)
    rows = logs.to_pylist()
    assert faults.num_rows == 0
    assert all(r["error"] and r["log_start"] is None and r["samples"] == 0 for r in rows)
    assert "no such log" in rows[1]["error"]
    s = fleet_summary(rows, wall_s=2.0, workers=1)
    assert s["logs"] == 2 and s["errors"] == 2 and s["drives"] == 2 and s["samples"] == 0


def test_the_generated_fleet():
    specs = plan_fleet(40, seed=3)
    assert plan_fleet(40, seed=3) == specs  # seeded
    assert len({s.drive for s in specs}) == 4 and len(specs) == 40
    assert all(60 <= s.seconds <= 600 for s in specs)
    creep = [s for s in specs if s.drive == "drive00"]
    assert [s.faults[0]["bias"] for s in creep] == pytest.approx(
        [CREEP_BIAS[0] + CREEP_BIAS[1] * d for d in range(10)])
    assert len({s.name for s in specs}) == 40  # <drive>/<date>.mcap, one a day
    cut = [s for s in specs if s.truncate]
    assert len(cut) == 1 and cut[0].drive != "drive00"
    assert all(s.start_ns // 86_400_000_000_000 == 20148 + s.day for s in specs)


def test_out_paths():
    assert tables_paths(Path("o/f.parquet")) == (Path("o/f.parquet"),
                                                 Path("o/f.logs.parquet"))
    assert report_dir(Path("o/f.parquet")) == Path("o/f-report")


@pytest.mark.parametrize("args, words", [
    (["nope_dir", "--config", str(CONFIG), "-o", "x.parquet"], "no such log or directory"),
    (["{log}", "--config", str(CONFIG), "-o", "x.csv"], "a file name ending in .parquet"),
    (["{log}", "--config", str(CONFIG), "-o", "x.parquet", "--jobs", "0"], "--jobs: at least"),
    (["{log}", "--config", str(CONFIG), "-o", "x.parquet", "--drive-pattern", "("],
     "not a regular expression"),
    (["{log}", "--config-map", "{map}", "-o", "x.parquet"], "no such config"),
    (["{log}", "--config", "/nonexistent.yaml", "-o", "x.parquet"], "config error"),
])
def test_bad_arguments_exit_2_with_one_line(tmp_path, capsys, args, words):
    pytest.importorskip("pyarrow")
    pytest.importorskip("distributed")
    log = tmp_path / "t1_a.mcap"
    log.write_bytes(b"")
    mapping = tmp_path / "map.yaml"
    mapping.write_text('"*": missing.yaml\n')
    argv = [a.format(log=log, map=mapping) for a in args]
    assert main(["fleet", *argv, "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert words in err and len(err.splitlines()) == 1, err


def test_without_the_extra_it_says_what_to_install(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "distributed", None)  # import distributed fails
    log = tmp_path / "a.mcap"
    log.write_bytes(b"")
    assert main(["fleet", str(log), "--config", str(CONFIG), "-o",
                 str(tmp_path / "x.parquet")]) == 2
    err = capsys.readouterr().err
    assert "pip install 'canfdi[fleet]'" in err and len(err.strip().splitlines()) == 1


def test_a_bad_config_stops_the_fleet_before_any_worker(tmp_path):
    check_configs([str(CONFIG)])  # a good one passes
    bad = tmp_path / "bad.yaml"
    bad.write_text("model: {}\n")
    with pytest.raises(ValueError):
        check_configs([str(CONFIG), str(bad)])


def test_without_jobs_or_a_scheduler_the_tasks_map_here():
    with task_mapper(None, None) as mapper:
        assert mapper is None


def test_a_mapper_without_dask_says_what_to_install(monkeypatch):
    monkeypatch.setitem(sys.modules, "distributed", None)  # import distributed fails
    with pytest.raises(NoDask, match=re.escape("pip install 'canfdi[fleet]'")), \
            task_mapper(2, None):
        pass

"""`canfdi replay LOG -o OUT.mcap` (issue 28): any log to the MCAP a live run writes, which
`canfdi report` draws; a canfdi MCAP replays with the config recorded in it."""

from __future__ import annotations

import json

import pytest

from canfdi.io.reader import read_log, read_metadata
from tests.cli import canfdi_main as main
from tests.conftest import REPO

CONFIG = REPO / "deploy" / "config" / "dc_motor.yaml"


@pytest.mark.parametrize("suffix", [".log", ".blf", ".asc"])
def test_any_log_replayed_to_an_mcap_gives_a_full_report(tmp_path, capsys, suffix):
    log = tmp_path / f"drive{suffix}"
    assert main(["sim", "--scenario", "dc_motor_consecutive", "-o", str(log), "--quiet"]) == 0
    capsys.readouterr()
    out = tmp_path / "diagnosed.mcap"
    assert main(["replay", str(log), "--config", str(CONFIG), "-o", str(out), "--json",
                 "--no-progress"]) == 0
    replayed = json.loads(capsys.readouterr().out)
    assert len(replayed["faults"]) == 3
    topics = {topic for topic, _, _ in read_log(out)}
    assert {"/can/frames", "/canfdi/samples", "/canfdi/residuals", "/canfdi/events"} <= topics
    assert read_metadata(out)["config_name"] == "dc_motor"
    assert main(["report", str(out), "-o", str(tmp_path / "report"), "--json",
                 "--no-progress"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert len(report["faults"]) == 3 and report["missing"] == []
    # Its own config is in it: replayed again without --config, the same diagnoses.
    assert main(["replay", str(out), "--json", "--no-progress"]) == 0
    captured = capsys.readouterr()
    again = json.loads(captured.out)
    assert "using the config recorded in" in captured.err
    assert [f["onset_sample"] for f in again["faults"]] == [
        f["onset_sample"] for f in replayed["faults"]]


def test_without_a_config_to_use_and_over_a_file_it_is_one_line_and_2(tmp_path, capsys):
    log = tmp_path / "drive.log"
    assert main(["sim", "--scenario", "dc_motor_actuator", "--duration", "1", "-o", str(log),
                 "--quiet"]) == 0
    capsys.readouterr()
    assert main(["replay", str(log), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "give --config" in err[0]
    taken = tmp_path / "taken.mcap"
    taken.write_bytes(b"someone's")
    assert main(["replay", str(log), "--config", str(CONFIG), "-o", str(taken),
                 "--no-progress"]) == 2
    assert "exists" in capsys.readouterr().err and taken.read_bytes() == b"someone's"


def test_every_documented_topic_is_in_a_demo_log(tmp_path, capsys):
    """docs/mcap.md's topics, each read back from a demo's log (issue 28: /canfdi/status and
    /canfdi/estimates were documented and never written)."""
    import re

    documented = set(re.findall(r"^\| `(/[a-z/]+)` \|", (REPO / "docs" / "mcap.md").read_text(),
                                re.MULTILINE))
    assert {"/canfdi/status", "/canfdi/estimates", "/can/frames"} <= documented
    log = tmp_path / "demo.mcap"
    assert main(["demo", "--no-live", "--json", "-o", str(log)]) == 0
    demo = json.loads(capsys.readouterr().out)
    messages: dict[str, list] = {}
    for topic, _, message in read_log(log):
        messages.setdefault(topic, []).append(message)
    assert documented <= set(messages), documented - set(messages)
    estimates = messages["/canfdi/estimates"]
    accepted = demo["faults"]
    assert len(estimates) >= len(accepted) == 3
    assert {e["hypothesis"] for e in estimates} >= {
        f"dc_motor/{f['kind']}:{f['name']}" for f in accepted}
    assert all(m["state"].startswith("dc_motor=") for m in messages["/canfdi/status"])

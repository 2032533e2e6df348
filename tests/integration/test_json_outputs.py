"""--json on the verbs that report (issue 28): one object on stdout, with the keys their help
names; without it, words."""

from __future__ import annotations

import json

from canfdi.cli import main
from tests.conftest import REPO

CONFIG = REPO / "deploy" / "config" / "dc_motor.yaml"


def _json(capsys) -> dict:
    out = capsys.readouterr().out.strip().splitlines()
    assert len(out) == 1, out
    return json.loads(out[0])


def test_export_run_capture_and_sim_print_one_object_with_json(tmp_path, capsys):
    log = tmp_path / "drive.log"
    assert main(["sim", "--scenario", "dc_motor_actuator", "--duration", "2", "-o", str(log),
                 "--quiet", "--json"]) == 0
    sim = _json(capsys)
    assert sim["frames"] == 600 and sim["output"] == str(log)
    assert main(["export", str(log), "-o", str(tmp_path / "drive.asc"), "--json",
                 "--no-progress"]) == 0
    export = _json(capsys)
    assert export == {"output": str(tmp_path / "drive.asc"), "format": "asc", "frames": 600,
                      "skipped": 0, "seconds": export["seconds"], "damage": []}
    assert main(["run", "--config", str(CONFIG), "--duration", "0.3", "--no-record",
                 "--quiet", "--json", "--channel", "canfdi-json-test"]) == 0
    run = _json(capsys)
    assert {"frames", "sent", "bus_errors", "faults"} <= set(run) and run["frames"] == 0
    out = tmp_path / "capture.mcap"
    assert main(["capture", "--config", str(CONFIG), "-o", str(out), "--duration", "0.3",
                 "--json", "--channel", "canfdi-json-test"]) == 0
    capture = _json(capsys)
    assert capture["output"] == str(out) and capture["frames"] == 0
    assert capture["recording"]["segments"] == [str(out)]


def test_sim_says_words_without_json(tmp_path, capsys):
    assert main(["sim", "--scenario", "dc_motor_actuator", "--duration", "1", "-o",
                 str(tmp_path / "d.log"), "--quiet"]) == 0
    out = capsys.readouterr().out.strip()
    assert out == f"canfdi sim: dc_motor_actuator: 100 samples, 300 frames -> {tmp_path / 'd.log'}"
